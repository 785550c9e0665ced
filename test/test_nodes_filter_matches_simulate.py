"""The belief filter node and ``simulate`` share one epoch filter (core/filter.py): same readings,
identical beliefs, impossible readings included.

``simulate`` runs a seeded random policy on a model whose initial belief excludes the true
state; its trace (actions, observations) is then fed, message by message, to the node's
observation callback, called directly (no executor, no timing): the node's code path is
decode -> epoch buffer -> core filter -> encode. The node's belief after each epoch must equal
the simulator's bit for bit, and both must count the same recoveries.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import make_harness
from rclpy.parameter import Parameter

from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.simulate import simulate
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.messages import encode_observation

harness = pytest.fixture(make_harness)
STEPS = 60

# S = 4, a slow drift between neighbours; the sensors tell "low" (states 0, 1: readings 0, 1)
# from "high" (states 2, 3: readings 2, 3) for sure, and the state within each half noisily.
DRIFT = [[[0.8, 0.2, 0, 0], [0.1, 0.8, 0.1, 0], [0, 0.1, 0.8, 0.1], [0, 0, 0.2, 0.8]],
         [[0.9, 0.1, 0, 0], [0.05, 0.9, 0.05, 0], [0, 0.05, 0.9, 0.05], [0, 0, 0.1, 0.9]]]
HALVES = [[[0.7, 0.3, 0, 0], [0.3, 0.7, 0, 0], [0, 0, 0.7, 0.3], [0, 0, 0.3, 0.7]],
          [[0.9, 0.1, 0, 0], [0.1, 0.9, 0, 0], [0, 0, 0.9, 0.1], [0, 0, 0.1, 0.9]]]


@pytest.fixture
def halves_model(tmp_path):
    doc = {"name": "halves", "discount": 0.9, "transition": DRIFT, "observation": HALVES,
           "reward": np.zeros((4, 2)).tolist()}
    path = tmp_path / "halves.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def test_node_and_simulate_give_identical_beliefs_including_impossible_readings(harness, halves_model):
    model = load_model(halves_model)
    prior = [1.0, 0.0, 0.0, 0.0]  # certain of state 0 while the target is in state 3
    trace = simulate(model, "random", STEPS, seed=4, initial_state=3, initial_belief=np.array(prior))
    assert trace.recovered[0] and not trace.recovered.all()  # the first reading is impossible, later ones not

    node = harness.add(BeliefFilter(context=harness.context, parameter_overrides=[
        Parameter("model_file", value=halves_model), Parameter("initial_distribution", value=prior)]))
    np.testing.assert_array_equal(node.loop.belief, trace.beliefs[0])
    for t in range(STEPS):
        node._on_observation(0, encode_observation(t + 1, int(trace.actions[t]) + 1, int(trace.observations[t])))
        assert node.loop.epoch == t + 1
        np.testing.assert_array_equal(node.loop.belief, trace.beliefs[t + 1], err_msg=f"epoch {t + 1}")
    assert node.loop.health.counts["impossible_observations"] == int(trace.recovered.sum())
    assert node.loop.health.counts["contradicting_observations"] == 0
