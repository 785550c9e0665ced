"""The visualiser's rules (``core/loop/visual_loop.py``) without ROS: the grid shape from the model
or the parameter, the occupancy values against a hand computation, the bars, the true state paired
by epoch, the decision's line, malformed samples counted."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import Level
from pomdp_planner.core.loop.samples import BeliefSample
from pomdp_planner.core.loop.visual_loop import GridError, VisualLoop, decision_text, grid_shape, occupancy
from pomdp_planner.core.model import POMDP

INFO = {"epoch": 5.0, "action_priority": 2.0, "depth": 3.0, "nodes_expanded": 10.0, "pruned_percent": 20.0,
        "certified": 0.0, "time_used": 0.01, "latency": 0.012, "deadline_hit": 0.0, "deadline_miss": 0.0,
        "bound_lower": 1.0, "bound_upper": 3.0}


@pytest.fixture(scope="module")
def s3() -> POMDP:
    return load_model_file("tracking_s3_info")


def test_grid_shape_comes_from_the_model_then_the_parameter(s3):
    assert grid_shape(s3) is None and grid_shape(s3, []) is None
    assert grid_shape(s3, [1, 3]) == (1, 3) and grid_shape(s3, [3, 1]) == (3, 1)
    m8 = load_model_file("perimeter_s8")
    grid = replace(m8, metadata={**m8.metadata, "grid": {"rows": 2, "cols": 4}})
    assert grid_shape(grid) == (2, 4)
    assert grid_shape(grid, [4, 2]) == (2, 4)  # the model's own shape wins over the parameter
    generated = replace(m8, metadata={**m8.metadata, "generator": {"domain": "grid", "rows": 4, "cols": 2}})
    assert grid_shape(generated) == (4, 2)
    m8 = replace(m8, metadata={**m8.metadata, "generator": {"domain": "tracking", "rows": 4, "cols": 2}})
    assert grid_shape(m8) is None


@pytest.mark.parametrize("given, match", [([2, 2], r"grid_shape: \[2, 2\] has 4 cells, the model 3 states"),
                                          ([3], r"grid_shape: must be \[rows, cols\]"),
                                          ([0, 3], "two positive integers"),
                                          ([1, 3, 1], r"must be \[rows, cols\]")])
def test_a_grid_shape_that_does_not_fit_is_one_line(s3, given, match):
    with pytest.raises(GridError, match=match):
        grid_shape(s3, given)


def test_occupancy_is_the_probability_relative_to_the_mode():
    b = np.array([0.1, 0.4, 0.0, 0.25, 0.25])
    assert occupancy(b) == (25, 100, 0, 62, 62)  # round(100 * p / 0.4): 62.5 rounds to even
    assert occupancy(np.full(4, 0.25)) == (100, 100, 100, 100)


def test_bars_true_state_and_text(s3):
    loop = VisualLoop(s3, None, now=0.0, spacing=2.0, bar_height=3.0)
    assert loop.scene() is None and loop.report(0.0).message == "waiting for the first belief"
    loop.true_state(4, 2, 0.1)
    loop.belief(BeliefSample(4, np.array([0.2, 0.3, 0.5])), 0.2)
    assert loop.changed
    scene = loop.scene()
    assert not loop.changed
    assert scene.epoch == 4 and scene.true_state == 2
    assert [b.state for b in scene.bars] == [0, 1, 2]
    assert [b.probability for b in scene.bars] == [0.2, 0.3, 0.5]
    assert [b.height for b in scene.bars] == pytest.approx([0.6, 0.9, 1.5])
    assert [(b.x, b.y) for b in scene.bars] == [(1.0, 0.0), (3.0, 0.0), (5.0, 0.0)]
    assert scene.bars[2].rgba[0] > scene.bars[0].rgba[0]  # the mode is the reddest
    assert scene.text == "belief of epoch 4; no decision yet"
    loop.plan_info(INFO, 0.3)
    scene = loop.scene()
    assert scene.text == "belief of epoch 4; epoch 5: priority 2, bounds [1, 3], not certified, depth 3"
    loop.belief(BeliefSample(5, np.array([0.2, 0.3, 0.5])), 0.4)
    assert loop.scene().true_state is None  # no true state of epoch 5 (yet)
    loop.true_state(5, 0, 0.5)
    assert loop.changed and loop.scene().true_state == 0
    loop.true_state(6, 7, 0.6)  # out of range: counted, not kept
    loop.rejected("belief", "belief: expected 3 probabilities, got 2", 0.7)
    r = loop.report(1.0)
    assert r.level == Level.WARN
    assert r.values["out_of_range_true_states"] == 1 and r.values["malformed_messages"] == 1
    assert r.values["epoch"] == 5 and "belief: expected 3 probabilities" in r.message


def test_decision_text_names_the_action_and_says_no_bounds(s3):
    m = load_model_file("perimeter_s8")
    names = m.action_names
    text = decision_text({**INFO, "certified": 1.0, "bound_lower": 0.0, "bound_upper": 0.0}, m)
    assert text == f"epoch 5: priority 2 ({names[1]}), no bounds, certified, depth 3" if names else text


def test_grid_scene_places_states_row_major(s3):
    loop = VisualLoop(s3, (3, 1), now=0.0)
    loop.belief(BeliefSample(0, np.array([0.5, 0.25, 0.25])), 0.0)
    scene = loop.scene()
    assert [(b.x, b.y) for b in scene.bars] == [(0.5, 0.5), (0.5, 1.5), (0.5, 2.5)]
    assert scene.grid == (3, 1) and scene.occupancy == (100, 50, 50)


def test_a_grid_with_obstacles_shows_its_free_cells_and_marks_the_obstacles_unknown():
    from pomdp_planner.core.domains.grid import grid_model

    model = grid_model(2, 3, obstacles=[[0, 1], [1, 2]])  # free cells (0,0) (0,2) (1,0) (1,1): S = 4
    assert model.S == 4 and grid_shape(model) == (2, 3)
    loop = VisualLoop(model, grid_shape(model), now=0.0)
    loop.belief(BeliefSample(0, np.array([0.1, 0.2, 0.3, 0.4])), 0.0)
    scene = loop.scene()
    assert [(b.x, b.y) for b in scene.bars] == [(0.5, 0.5), (2.5, 0.5), (0.5, 1.5), (1.5, 1.5)]
    assert scene.occupancy == (25, -1, 50, 75, 100, -1)  # row-major; the obstacles (0,1) and (1,2) unknown
    bad = replace(model, metadata={**model.metadata, "grid": {"rows": 2, "cols": 3, "obstacles": [[0, 1]]}})
    with pytest.raises(GridError, match=r"^the model's grid: \[2, 3\] has 5 free cells, the model 4 states$"):
        grid_shape(bad)
