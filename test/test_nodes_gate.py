"""The planner node builds its planner through the core's assumption gate: on the model failing
Assumption 1 it plans exhaustively, and neither its diagnostics nor ``plan_info`` claim a
certificate or a guarantee (the loop's rule is tested without ROS in test_loop_planner.py)."""

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
from pomdp_planner.nodes.messages import decode_plan_info, encode_belief
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
    setup = node.loop.setup
    assert setup.mode == "exhaustive" and not setup.guaranteed and not node.loop.assumptions.holds
    assert "Assumption 1 fails" in setup.reason
    rec = h.recorder()
    infos = []
    rec.create_subscription(Float64MultiArray, "plan_info", lambda m: infos.append(decode_plan_info(m)), LATCHED_QOS)
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
    assert "certified" not in d and "last.certified" not in d and d["last.use_bounds"] == "false"
    assert d["guaranteed"] == "false" and d["guarantee"].startswith("exhaustive search: Assumption 1 fails")
    assert d["assumptions_hold"] == "false" and d["_level"] == DiagnosticStatus.WARN
    assert "certif" not in d["_message"] and "guarantee covers" not in str(d)
    assert h.wait_until(lambda: len(infos) == 2, timeout=5)
    assert [i["certified"] for i in infos] == [0.0, 0.0]


def test_node_on_a_valid_model_prunes_with_the_guarantee(harness):
    node = _planner(harness, S3)
    setup = node.loop.setup
    assert setup.mode == "prune" and setup.guaranteed and setup.planner.guaranteed


def test_node_refusal_is_the_gates_refusal(harness):
    node = _planner(harness, FAILING, refuse_if_assumptions_fail=True)
    assert node.loop.refusing and node.loop.setup.mode == "refuse" and node.loop.setup.planner is None


def test_node_on_a_discount_one_model_plans_exhaustively_and_says_why(harness, tmp_path):
    """A finite-horizon model (discount 1) that satisfies Assumption 1 still has no myopic bounds
    (Theorem 2 needs discount < 1): the node searches exhaustively and its diagnostics say why."""
    path = tmp_path / "finite.yaml"
    path.write_text(Path(S3).read_text().replace("discount: 0.99", "discount: 1"))
    h = harness
    node = _planner(h, str(path), max_depth=2, time_budget=30.0)
    setup = node.loop.setup
    assert node.loop.assumptions.holds and setup.mode == "exhaustive" and not setup.guaranteed
    assert setup.reason.startswith("discount: the bound LP (Theorem 2) needs discount < 1")
    assert "discount: the bound LP (Theorem 2) needs discount < 1" in node.loop.bounds_message
    rec = h.recorder()
    pub_node = h.add(rclpy.node.Node("test_belief_pub", context=h.context))
    pub = pub_node.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    h.start()
    b = np.array([0.2, 0.5, 0.3])
    pub.publish(encode_belief(0, b))
    assert h.wait_until(lambda: len(rec.actions) >= 1, timeout=20)
    assert rec.actions[0] == (1, Planner(load_model(path)).search(b, 2, use_bounds=False).priority)
    assert h.wait_until(lambda: "discount" in (rec.diag_values("planner") or [{}])[-1].get("bounds", ""), timeout=5)
