"""Issue 11, the planner node's side: it builds its planner through the core's assumption gate, so
on the model failing Assumption 1 it never certifies a decision and plans exhaustively."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticStatus
from nodes_support import S3, make_harness, rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray

from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.search import Planner
from pomdp_planner.nodes.messages import encode_belief
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.qos import LATCHED_QOS

harness = pytest.fixture(make_harness)
FAILING = str(Path(__file__).resolve().parent / "models" / "fails_assumption1_s3.yaml")
BELIEFS = ([0.3, 0.4, 0.3], [0.1, 0.8, 0.1])  # the failing model's bounds agree at the first, cross at the second


def _planner(h, model_file, **params):
    overrides = [Parameter("model_file", value=model_file)] + [Parameter(k, value=v) for k, v in params.items()]
    return h.add(PlannerNode(context=h.context, parameter_overrides=overrides))


def test_node_on_a_failing_model_plans_exhaustively_and_certifies_nothing(harness):
    h = harness
    node = _planner(h, FAILING, max_depth=3, time_budget=30.0)
    assert node.setup.mode == "exhaustive" and not node.setup.guaranteed and not node.report.holds
    assert "Assumption 1 fails" in node.setup.reason
    rec = h.recorder()
    pub_node = h.add(rclpy.node.Node("test_belief_pub", context=h.context))
    pub = pub_node.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    h.start()
    model = load_model(FAILING)
    for epoch, b in enumerate(BELIEFS):
        pub.publish(encode_belief(epoch, b))
        assert h.wait_until(lambda n=epoch + 1: len(rec.actions) >= n, timeout=20)
        expected = Planner(model).search(np.array(b), 3, use_bounds=False).priority
        assert rec.actions[epoch] == (epoch + 1, expected)
    assert h.wait_until(lambda: (rec.diag_values("planner") or [{}])[-1].get("decisions") == "2", timeout=5)
    d = rec.diag_values("planner")[-1]
    assert d["certified"] == "0" and d["last.certified"] == "false" and d["last.use_bounds"] == "false"
    assert d["assumptions_hold"] == "false" and d["_level"] == DiagnosticStatus.WARN


def test_node_on_a_valid_model_prunes_with_the_guarantee(harness):
    node = _planner(harness, S3)
    assert node.setup.mode == "prune" and node.setup.guaranteed and node._planner.guaranteed


def test_node_refusal_is_the_gates_refusal(harness):
    node = _planner(harness, FAILING, refuse_if_assumptions_fail=True)
    assert node.refusing and node.setup.mode == "refuse" and node.setup.planner is None


def test_node_on_a_discount_one_model_plans_exhaustively_and_says_why(harness, tmp_path):
    """A finite-horizon model (discount 1) that satisfies Assumption 1 still has no myopic bounds
    (Theorem 2 needs discount < 1): the node searches exhaustively and its diagnostics say why."""
    path = tmp_path / "finite.yaml"
    path.write_text(Path(S3).read_text().replace("discount: 0.99", "discount: 1"))
    h = harness
    node = _planner(h, str(path), max_depth=2, time_budget=30.0)
    assert node.report.holds and node.setup.mode == "exhaustive" and not node.setup.guaranteed
    assert node.setup.reason.startswith("discount: the bound LP (Theorem 2) needs discount < 1")
    assert "discount: the bound LP (Theorem 2) needs discount < 1" in node._bounds_message
    rec = h.recorder()
    pub_node = h.add(rclpy.node.Node("test_belief_pub", context=h.context))
    pub = pub_node.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    h.start()
    b = np.array([0.2, 0.5, 0.3])
    pub.publish(encode_belief(0, b))
    assert h.wait_until(lambda: len(rec.actions) >= 1, timeout=20)
    assert rec.actions[0] == (1, Planner(load_model(path)).search(b, 2, use_bounds=False).priority)
    assert h.wait_until(lambda: "discount" in (rec.diag_values("planner") or [{}])[-1].get("bounds", ""), timeout=5)
