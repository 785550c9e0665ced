"""The ``belief_visualizer`` node: what it publishes for beliefs, decisions and true states typed by
the test (the MarkerArray's bars, true-state sphere and text, the OccupancyGrid of a grid model,
stamped headers in ``frame_id``), malformed samples counted in ``/diagnostics``, a grid shape that
does not fit the model refused at start-up with one line."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import OccupancyGrid
from nodes_support import S3, make_harness
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, Int64MultiArray
from visualization_msgs.msg import Marker, MarkerArray

from pomdp_planner.nodes.belief_visualizer import BeliefVisualizer
from pomdp_planner.nodes.messages import encode_belief, encode_plan_info, encode_true_state
from pomdp_planner.nodes.params import NodeConfigError
from pomdp_planner.nodes.qos import LATCHED_QOS, STREAM_QOS

harness = pytest.fixture(make_harness)
INFO = {"epoch": 8.0, "action_priority": 1.0, "depth": 1.0, "nodes_expanded": 3.0, "pruned_percent": 66.0,
        "certified": 1.0, "time_used": 0.001, "latency": 0.002, "deadline_hit": 0.0, "deadline_miss": 0.0,
        "bound_lower": 1.0, "bound_upper": 1.0}


class Listener(Node):
    def __init__(self, context, cond: threading.Condition):
        super().__init__("listener", context=context)
        self.cond = cond
        self.markers: list[MarkerArray] = []
        self.grids: list[OccupancyGrid] = []
        self.diags: list = []
        self.create_subscription(MarkerArray, "belief_markers", lambda m: self._add(self.markers, m), LATCHED_QOS)
        self.create_subscription(OccupancyGrid, "belief_grid", lambda m: self._add(self.grids, m), LATCHED_QOS)
        self.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda m: self._add(self.diags, *[s for s in m.status
                                                                   if s.name.startswith("belief_visualizer")]), 10)
        self.pubs = {"belief": self.create_publisher(Float64MultiArray, "belief", STREAM_QOS),
                     "plan_info": self.create_publisher(Float64MultiArray, "plan_info", STREAM_QOS),
                     "true_state": self.create_publisher(Int64MultiArray, "true_state", STREAM_QOS)}

    def _add(self, into: list, *msgs) -> None:
        with self.cond:
            into.extend(msgs)
            self.cond.notify_all()


def _texts(ma: MarkerArray, ns: str) -> list[Marker]:
    return [m for m in ma.markers if m.ns == ns]


def test_markers_show_the_belief_the_true_state_and_the_decision(harness):
    h = harness
    viz = h.add(BeliefVisualizer(context=h.context, parameter_overrides=[
        Parameter("model_file", value=S3), Parameter("frame_id", value="world"), Parameter("bar_height", value=2.0),
        Parameter("publish_period", value=0.02)]))
    ears = h.add(Listener(h.context, h.cond))
    h.start()
    for pub in ears.pubs.values():
        assert h.wait_matched(pub, 1)
    b = np.array([0.125, 0.625, 0.25])
    ears.pubs["true_state"].publish(encode_true_state(7, 1))
    ears.pubs["plan_info"].publish(encode_plan_info(**INFO))
    ears.pubs["belief"].publish(encode_belief(7, b))

    def complete():
        return ears.markers and any(m.action == Marker.ADD for m in _texts(ears.markers[-1], "true_state")) \
            and "epoch 8" in _texts(ears.markers[-1], "decision")[0].text
    assert h.wait_until(complete, timeout=10)
    ma = ears.markers[-1]
    bars = sorted(_texts(ma, "belief"), key=lambda m: m.id)
    assert [m.id for m in bars] == [0, 1, 2] and all(m.type == Marker.CUBE for m in bars)
    assert [m.scale.z for m in bars] == pytest.approx(2.0 * b)  # height = probability * bar_height
    assert [m.pose.position.z for m in bars] == pytest.approx(b)  # standing on z = 0
    assert [m.pose.position.x for m in bars] == pytest.approx([0.5, 1.5, 2.5])
    assert [m.text for m in bars] == ["state 0: 0.1250", "state 1: 0.6250", "state 2: 0.2500"]
    (sphere,) = _texts(ma, "true_state")
    assert sphere.type == Marker.SPHERE and sphere.pose.position.x == pytest.approx(1.5)
    assert sphere.pose.position.z > 2.0 * b[1] and sphere.text == "true state 1"
    (text,) = _texts(ma, "decision")
    assert text.type == Marker.TEXT_VIEW_FACING
    assert text.text == "belief of epoch 7; epoch 8: priority 1, bounds [1, 1], certified, depth 1"
    for m in ma.markers:
        assert m.header.frame_id == "world"
        assert m.header.stamp.sec > 0
    assert not ears.grids  # not a grid model: no belief_grid

    # the next epoch: no true state for it yet, so the sphere goes
    ears.pubs["belief"].publish(encode_belief(8, np.array([0.5, 0.25, 0.25])))
    assert h.wait_until(lambda: _texts(ears.markers[-1], "true_state")[0].action == Marker.DELETE, timeout=10)
    # a malformed belief: counted and named in the diagnostics, the shown belief stays
    bad = encode_belief(9, np.array([0.5, 0.5]))
    ears.pubs["belief"].publish(bad)
    assert h.wait_until(lambda: any(dict((kv.key, kv.value) for kv in s.values).get("malformed_messages") == "1"
                                    for s in ears.diags), timeout=10)
    status = next(s for s in ears.diags if dict((kv.key, kv.value) for kv in s.values)["malformed_messages"] == "1")
    assert status.level == b"\x01" and "expected 3 probabilities" in status.message
    assert viz.loop.newest.epoch == 8


def test_a_grid_model_gets_an_occupancy_grid(harness):
    h = harness
    h.add(BeliefVisualizer(context=h.context, parameter_overrides=[
        Parameter("model_file", value=S3), Parameter("grid_shape", value=[3, 1]), Parameter("spacing", value=0.5),
        Parameter("publish_period", value=0.02)]))
    ears = h.add(Listener(h.context, h.cond))
    h.start()
    assert h.wait_matched(ears.pubs["belief"], 1)
    ears.pubs["belief"].publish(encode_belief(3, np.array([0.2, 0.2, 0.6])))
    assert h.wait_until(lambda: ears.grids and ears.markers, timeout=10)
    grid = ears.grids[-1]
    assert grid.header.frame_id == "map" and grid.header.stamp.sec > 0
    assert (grid.info.width, grid.info.height, grid.info.resolution) == (1, 3, 0.5)
    assert list(grid.data) == [33, 33, 100]
    bars = sorted(_texts(ears.markers[-1], "belief"), key=lambda m: m.id)
    assert [m.pose.position.x for m in bars] == pytest.approx([0.25, 0.25, 0.25])
    assert [m.pose.position.y for m in bars] == pytest.approx([0.25, 0.75, 1.25])  # row r at (r + 1/2) * spacing


def test_a_grid_shape_that_does_not_fit_is_refused(harness):
    with pytest.raises(NodeConfigError, match=r"grid_shape: \[2, 2\] has 4 cells, the model 3 states"):
        BeliefVisualizer(context=harness.context, parameter_overrides=[
            Parameter("model_file", value=S3), Parameter("grid_shape", value=[2, 2])])
