"""Bad input on the node topics, reordered/delayed delivery, several sensors (launch-free)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticStatus
from nodes_support import S3, make_harness, rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, Int64MultiArray, MultiArrayDimension

from pomdp_planner.core.belief import update
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.search import Planner
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.messages import (
    PLAN_INFO_FIELDS,
    MessageError,
    decode_belief,
    decode_plan_info,
    encode_belief,
    encode_observation,
    encode_plan_info,
)
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.qos import LATCHED_QOS, STREAM_QOS

harness = pytest.fixture(make_harness)


def _filter(h, model_file=S3, **params):
    overrides = [Parameter("model_file", value=model_file)] + [Parameter(k, value=v) for k, v in params.items()]
    return h.add(BeliefFilter(context=h.context, parameter_overrides=overrides))


def _publisher(h, topic="observation"):
    node = h.add(rclpy.node.Node(f"test_pub_{len(h.nodes)}", context=h.context))
    return node.create_publisher(Int64MultiArray, topic, STREAM_QOS)


def _latest_diag(rec, prefix="belief_filter"):
    vals = rec.diag_values(prefix)
    return vals[-1] if vals else {}


def _counts_reach(rec, key, n, prefix="belief_filter"):
    return lambda: any(int(d.get(key, -1)) >= n for d in rec.diag_values(prefix))


@pytest.fixture
def perfect_sensor_model(tmp_path):
    """S = 2, static state, perfect sensor: observation 1 is impossible under the prior [1, 0];
    observation 2 is impossible in every state (it contradicts the model)."""
    doc = {
        "name": "perfect_sensor", "discount": 0.9, "states": 2, "actions": 2, "observations": 3,
        "transition": [[[1, 0], [0, 1]], [[1, 0], [0, 1]]],
        "observation": [[[1, 0, 0], [0, 1, 0]], [[0.5, 0.5, 0], [0.5, 0.5, 0]]],
        "reward": [[0, 0], [0, 0]],
    }
    path = tmp_path / "perfect.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def test_filter_bad_observations_counted_and_node_keeps_running(harness, perfect_sensor_model):
    h = harness
    _filter(h, perfect_sensor_model, initial_distribution=[1.0, 0.0])
    rec = h.recorder()
    pub = _publisher(h)
    h.start()
    assert h.wait_until(lambda: len(rec.beliefs) >= 1)  # the latched prior (epoch 0)
    # out of range observation, out of range action, wrong length, wrong label: dropped
    pub.publish(encode_observation(1, 1, 3))
    pub.publish(encode_observation(1, 3, 0))
    pub.publish(Int64MultiArray(data=[1, 1]))
    bad_label = encode_observation(1, 1, 0)
    bad_label.layout.dim = [MultiArrayDimension(label="z,a,t", size=3, stride=3)]
    pub.publish(bad_label)
    assert h.wait_until(_counts_reach(rec, "out_of_range_observations", 2), timeout=5)
    assert h.wait_until(_counts_reach(rec, "malformed_messages", 2), timeout=5)
    assert rec.belief_epochs(2) == [0]  # nothing published from bad input (the prior may be re-sent)
    # impossible observation: the filter restarts from the uniform prior pushed through the
    # transition, then applies the reading: [0.5, 0.5] * [0, 1] -> [0, 1] (core/filter.py)
    pub.publish(encode_observation(1, 1, 1))
    assert h.wait_until(lambda: 1 in rec.belief_epochs(2))
    np.testing.assert_allclose(rec.beliefs_by_epoch(2)[1], [0.0, 1.0])
    assert h.wait_until(_counts_reach(rec, "impossible_observations", 1), timeout=5)
    assert any(d["_level"] == DiagnosticStatus.WARN for d in rec.diag_values("belief_filter"))
    # still running: a possible observation of the next epoch is applied normally
    pub.publish(encode_observation(2, 2, 0))
    assert h.wait_until(lambda: 2 in rec.belief_epochs(2))
    np.testing.assert_allclose(rec.beliefs_by_epoch(2)[2], [0.0, 1.0])
    # a reading no state can produce contradicts the model: dropped, the prediction published
    pub.publish(encode_observation(3, 1, 2))
    assert h.wait_until(lambda: 3 in rec.belief_epochs(2))
    np.testing.assert_allclose(rec.beliefs_by_epoch(2)[3], [0.0, 1.0])
    assert h.wait_until(_counts_reach(rec, "contradicting_observations", 1), timeout=5)


def test_filter_reordered_delayed_duplicated_delivery_pairs_by_carried_action(harness):
    h = harness
    model = load_model(S3)
    _filter(h, S3, epoch_timeout=5.0)
    rec = h.recorder()
    pub = _publisher(h)
    h.start()
    assert h.wait_until(lambda: len(rec.beliefs) >= 1)
    # epochs 1..5 with their carried actions, delivered as 3, 5, 1, 1 (dup), 4, 2
    seq = {1: (2, 0), 2: (1, 2), 3: (3, 1), 4: (1, 1), 5: (2, 2)}
    for t in (3, 5, 1, 1, 4):
        pub.publish(encode_observation(t, *seq[t]))
    assert h.wait_until(lambda: 1 in rec.belief_epochs(3))  # epoch 1 applied, 2 still missing
    assert h.wait_until(_counts_reach(rec, "duplicates", 1), timeout=5)
    assert rec.belief_epochs(3) == [0, 1]
    pub.publish(encode_observation(2, *seq[2]))
    assert h.wait_until(lambda: len(rec.belief_epochs(3)) >= 6)
    assert rec.belief_epochs(3) == [0, 1, 2, 3, 4, 5]
    got = rec.beliefs_by_epoch(3)
    b = np.full(3, 1 / 3)  # replay with the core filter in epoch order, actions as carried
    for t in range(1, 6):
        p, z = seq[t]
        b = update(model, b, p - 1, z)
        np.testing.assert_allclose(got[t], b, rtol=1e-12, atol=1e-15)
    diag = _latest_diag(rec)
    assert int(diag.get("gaps", 0)) == 0


def test_filter_gap_is_reported_and_loop_goes_on(harness):
    h = harness
    _filter(h, S3, epoch_timeout=60.0, max_pending_epochs=2)
    rec = h.recorder()
    pub = _publisher(h)
    h.start()
    assert h.wait_until(lambda: len(rec.beliefs) >= 1)
    for t in (2, 3):  # epoch 1 never arrives; two later epochs waiting force the gap
        pub.publish(encode_observation(t, 1, 0))
    assert h.wait_until(lambda: len(rec.belief_epochs(3)) >= 4, timeout=5)
    assert rec.belief_epochs(3) == [0, 1, 2, 3]
    assert h.wait_until(_counts_reach(rec, "gaps", 1), timeout=5)


def test_filter_two_sensors_one_prediction_then_one_update_per_sensor(harness, tmp_path):
    h = harness
    model = load_model(S3)
    # second sensor: a different (noisier) observation model with 2 symbols
    doc = yaml.safe_load(Path(S3).read_text())
    O2 = np.array([[[0.9, 0.1], [0.5, 0.5], [0.2, 0.8]]] * 3)
    doc.pop("generator")
    doc["transition"] = model.P.tolist()
    doc["observation"] = O2.tolist()
    doc["observations"] = 2
    p2 = tmp_path / "sensor2.yaml"
    p2.write_text(yaml.safe_dump(doc))
    _filter(h, S3, observation_topics=["cam", "radar"], observation_model_files=["", str(p2)], epoch_timeout=30.0)
    rec = h.recorder(obs_topics=("cam", "radar"))
    cam, radar = _publisher(h, "cam"), _publisher(h, "radar")
    h.start()
    assert h.wait_until(lambda: len(rec.beliefs) >= 1)
    radar.publish(encode_observation(1, 2, 1))
    radar.publish(encode_observation(1, 2, 2))  # out of range for the 2-symbol radar
    assert h.wait_until(_counts_reach(rec, "out_of_range_observations", 1), timeout=5)
    assert rec.belief_epochs(3) == [0]  # epoch 1 waits for the camera
    cam.publish(encode_observation(1, 2, 0))
    assert h.wait_until(lambda: 1 in rec.belief_epochs(3))
    # independent: b' ∝ (b P[a]) * O_cam[a, :, z1] * O_radar[a, :, z2]
    expected = (np.full(3, 1 / 3) @ model.P[1]) * model.O[1, :, 0] * O2[1, :, 1]
    np.testing.assert_allclose(rec.beliefs_by_epoch(3)[1], expected / expected.sum(), rtol=1e-12)


def test_belief_encoding_roundtrip_and_rejections():
    b = np.array([0.2, 0.3, 0.5])
    msg = encode_belief(7, b)
    got = decode_belief(msg, 3)
    assert got.epoch == 7
    np.testing.assert_allclose(got.belief, b)
    with pytest.raises(MessageError, match="expected 3 probabilities"):
        decode_belief(encode_belief(7, [0.5, 0.5]), 3)
    with pytest.raises(MessageError, match="non-finite"):
        decode_belief(encode_belief(7, [np.nan, 0.5, 0.5]), 3)
    with pytest.raises(MessageError, match="sums to"):
        decode_belief(encode_belief(7, [0.5, 0.5, 0.5]), 3)
    with pytest.raises(MessageError, match="layout"):
        decode_belief(Float64MultiArray(data=[0.2, 0.3, 0.5]), 3)


def _planner(h, model_file=S3, **params):
    overrides = [Parameter("model_file", value=model_file)] + [Parameter(k, value=v) for k, v in params.items()]
    return h.add(PlannerNode(context=h.context, parameter_overrides=overrides))


def test_planner_bad_beliefs_counted_no_action_then_keeps_running(harness):
    h = harness
    _planner(h, time_budget=0.02, max_depth=2)
    rec = h.recorder()
    node = h.add(rclpy.node.Node("test_belief_pub", context=h.context))
    pub = node.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    h.start()
    bad = [
        encode_belief(0, [0.5, 0.5]),                # wrong length
        encode_belief(1, [np.nan, 0.5, 0.5]),        # NaN
        encode_belief(2, [0.7, 0.7, -0.4]),          # off the simplex
        Float64MultiArray(data=[0.2, 0.3, 0.5]),     # no epoch in the layout
    ]
    for msg in bad:
        pub.publish(msg)
        n = bad.index(msg) + 1
        assert h.wait_until(_counts_reach(rec, "bad_beliefs", n, "planner"), timeout=10)
    assert rec.actions == []  # nothing published from a bad belief
    pub.publish(encode_belief(5, [0.2, 0.3, 0.5]))
    assert h.wait_until(lambda: len(rec.actions) == 1, timeout=10)
    assert rec.actions[0][0] == 6 and 1 <= rec.actions[0][1] <= 3  # epoch t + 1, a priority
    assert h.wait_until(lambda: _latest_diag(rec, "planner").get("decisions") == "1", timeout=5)
    assert any(d["_level"] == DiagnosticStatus.WARN and "bad beliefs" in d["_message"]
               for d in rec.diag_values("planner"))


@pytest.fixture
def non_tp2_model(tmp_path):
    """A tracking-sized model whose transitions swap states: TP2 (A1) fails."""
    doc = {
        "name": "swap", "discount": 0.9, "states": 2, "actions": 2, "observations": 2,
        "transition": [[[0.1, 0.9], [0.9, 0.1]], [[0.2, 0.8], [0.8, 0.2]]],
        "observation": [[[0.8, 0.2], [0.2, 0.8]], [[0.6, 0.4], [0.4, 0.6]]],
        "reward": [[1.0, 0.5], [0.0, 0.6]],
    }
    path = tmp_path / "swap.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


@pytest.mark.parametrize("refuse", [False, True])
def test_planner_assumptions_fail_exhaustive_fallback_or_refusal(harness, non_tp2_model, refuse):
    h = harness
    planner = _planner(h, non_tp2_model, refuse_if_assumptions_fail=refuse, max_depth=2)
    assert not planner.loop.assumptions.holds
    rec = h.recorder()
    node = h.add(rclpy.node.Node("test_belief_pub", context=h.context))
    pub = node.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    h.start()
    pub.publish(encode_belief(0, [0.5, 0.5]))
    assert h.wait_until(lambda: rec.diag_values("planner"), timeout=5)
    if refuse:
        assert h.wait_until(lambda: _latest_diag(rec, "planner")["_level"] == DiagnosticStatus.ERROR, timeout=5)
        assert rec.actions == []
    else:
        assert h.wait_until(lambda: len(rec.actions) == 1, timeout=10)
        assert h.wait_until(lambda: _latest_diag(rec, "planner").get("last.use_bounds") == "false", timeout=5)
        d = _latest_diag(rec, "planner")
        assert d["_level"] == DiagnosticStatus.WARN and d["assumptions_hold"] == "false"
        # the exhaustive fallback is the core's exhaustive search
        expected = Planner(load_model(non_tp2_model)).plan(np.array([0.5, 0.5]), 2, use_bounds=False).priority
        assert rec.actions[0] == (1, expected)


def test_plan_info_carries_the_deadline_miss_flag():
    """plan_info round-trips every field, the planner's miss verdict included (the demo counts it)."""
    fields = {k: float(i) for i, k in enumerate(PLAN_INFO_FIELDS)}
    fields["deadline_miss"] = 1.0
    msg = encode_plan_info(**fields)
    assert decode_plan_info(msg) == fields
    assert "deadline_miss" in msg.layout.dim[0].label
    msg.data = list(msg.data)[:-1]
    with pytest.raises(MessageError, match="plan_info"):
        decode_plan_info(msg)


@pytest.mark.parametrize("S", [1, 3, 256, 10_000])  # 10 000: a 100 x 100 grid model's beliefs
def test_the_size_bound_of_each_topic_admits_every_message_the_loop_sends(S):
    """The bound a node drops samples by (``wire_bounds``) against rclpy's own CDR serialization:
    every message the loop's encoders make fits (epochs at ``MAX_EPOCH``, the longest labels), and
    the bound leaves room for fewer than 20 values more (the labels' slack)."""
    from rclpy.serialization import serialize_message

    from pomdp_planner.nodes.messages import (
        MAX_EPOCH,
        encode_action,
        encode_likelihood,
        encode_true_state,
        wire_bounds,
    )

    limits = {topic: b.max_bytes for topic, b in wire_bounds(S).items()}
    largest = {"belief": encode_belief(MAX_EPOCH, np.full(S, 1.0 / S)),
               "likelihood": encode_likelihood(MAX_EPOCH, 1, np.ones(S)),
               "action": encode_action(MAX_EPOCH, 1), "observation": encode_observation(MAX_EPOCH, 1, 0),
               "true_state": encode_true_state(MAX_EPOCH, S - 1),
               "plan_info": encode_plan_info(**dict.fromkeys(PLAN_INFO_FIELDS, 1.0))}
    assert set(largest) == set(limits)
    for topic, msg in largest.items():
        size = len(serialize_message(msg))
        assert size <= limits[topic] < size + 8 * 20, (topic, size, limits[topic])
