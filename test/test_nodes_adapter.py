"""The measurement adapter node and soft evidence in the filter node (launch-free: plain pytest + rclpy).

* a scripted measurement stream (Float64, Range, PointStamped, and likelihoods) through the adapter
  gives the filter node the beliefs it gets from the same readings typed as ``[epoch, priority,
  z]`` (bit-identical; soft evidence to rounding), the test acting as the planner;
* each kind of bad reading is counted in ``/diagnostics`` and dropped;
* a burst from a ~1 kHz sensor into the running loop (adapter, filter, planner): the loop goes on,
  every reading is accounted for, nothing queues;
* a bad parameter stops the executable with one ``[FATAL]`` line; soft-evidence messages on the
  filter's ``likelihood_topics`` are decoded strictly.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from geometry_msgs.msg import Point, PointStamped
from nodes_support import S3, die_with_test, make_harness, rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy
from sensor_msgs.msg import Range
from std_msgs.msg import Float64, Float64MultiArray, Int64MultiArray
from test_nodes_multiprocess import domain  # noqa: F401 (a fixture)

from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.measurement_adapter import MeasurementAdapter
from pomdp_planner.nodes.messages import (
    MessageError,
    OutOfRangeError,
    decode_belief,
    decode_likelihood,
    encode_action,
    encode_likelihood,
    encode_observation,
)
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.processes import node_command
from pomdp_planner.nodes.qos import RECORDER_QOS, SENSOR_QOS, STREAM_QOS

harness = pytest.fixture(make_harness)
MODEL = load_model_file(S3)  # S = A = Z = 3
EDGES = [0.5, 1.5]


def bin_by_hand(x: float) -> int:
    return sum(x >= e for e in EDGES)


class Probe(Node):
    """The test's planner and sensor in one namespace: publishes actions, sensor messages and typed
    observations; records beliefs and the adapter's outputs."""

    def __init__(self, h, ns: str, sensor_type=None):
        super().__init__("probe", namespace=ns, context=h.context)
        self.cond = h.cond
        self.beliefs: dict[int, np.ndarray] = {}
        self.outputs: list[tuple] = []
        self.actions: list[tuple[int, int]] = []
        self.action_pub = self.create_publisher(Int64MultiArray, "action", STREAM_QOS)
        self.obs_pub = self.create_publisher(Int64MultiArray, "observation", STREAM_QOS)
        self.lik_pub = self.create_publisher(Float64MultiArray, "likelihood", STREAM_QOS)
        self.sensor_pub = self.create_publisher(sensor_type, "measurement", SENSOR_QOS) if sensor_type else None
        self.create_subscription(Float64MultiArray, "belief", self._on_belief, RECORDER_QOS)
        self.create_subscription(Int64MultiArray, "observation", self._record(self.outputs, tuple), RECORDER_QOS)
        self.create_subscription(Int64MultiArray, "action", self._record(self.actions, tuple), RECORDER_QOS)

    def _record(self, store, conv):
        def cb(msg):
            with self.cond:
                store.append(conv(msg.data))
                self.cond.notify_all()
        return cb

    def _on_belief(self, msg):
        b = decode_belief(msg, MODEL.S)
        with self.cond:
            self.beliefs[b.epoch] = b.belief
            self.cond.notify_all()


def adapter(h, ns="", **params) -> MeasurementAdapter:
    params.setdefault("model_file", S3)
    if params.get("input_type") != "likelihood":
        params.setdefault("bin_edges", EDGES)
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    return h.add(MeasurementAdapter(context=h.context, namespace=ns or None, parameter_overrides=overrides))


def belief_filter(h, ns="", soft_only=False, **params) -> BeliefFilter:
    """A filter node; ``soft_only``: no observation topic (``observation_topics: []``, which only a
    parameter file or ``-p`` can say: rclpy types an empty list given in code as a byte array)."""
    params.setdefault("model_file", S3)
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    cli = ["--ros-args", "-p", "observation_topics:=[]"] if soft_only else None
    return h.add(BeliefFilter(context=h.context, namespace=ns or None, parameter_overrides=overrides, cli_args=cli))


def loop_state(node, get):
    with node.lock:
        return get(node.loop)


def clock(node) -> float:
    return node.get_clock().now().nanoseconds * 1e-9


def sensor_message(kind: str, x: float, stamp: float):
    sec = int(stamp)
    header = dict(stamp=rclpy.time.Time(seconds=sec, nanoseconds=int((stamp - sec) * 1e9)).to_msg())
    if kind == "float64":
        return Float64(data=x)
    if kind == "range":
        msg = Range(min_range=0.0, max_range=10.0, range=x)
    else:  # point, norm = x (values away from the edges: the norm's rounding cannot change the bin)
        msg = PointStamped(point=Point(x=0.6 * x, y=0.8 * x, z=0.0))
    msg.header.stamp = header["stamp"]
    return msg


SENSOR_TYPES = {"float64": Float64, "range": Range, "point": PointStamped}


@pytest.mark.parametrize("kind", ["float64", "range", "point"])
def test_measurements_through_the_adapter_give_the_beliefs_of_the_typed_observations(harness, kind):
    """Three filters: ``/a`` fed by an adapter of ``kind``, ``/b`` by ``[t, p, z]`` typed by hand,
    ``/c`` by a likelihood adapter whose sensor reports the column ``O[a][:, z]``. The test is the
    planner: it publishes each action, waits until both adapters have heard it, then the sensors
    publish a NaN reading and the reading (again, should best-effort delivery lose it)."""
    h = harness
    ad_a = adapter(h, "/a", input_type=kind, point_field="norm", resend_period=0.0)
    ad_c = adapter(h, "/c", input_type="likelihood", resend_period=0.0)
    for ns in ("/a", "/b"):
        belief_filter(h, ns, epoch_timeout=30.0)
    belief_filter(h, "/c", soft_only=True, epoch_timeout=30.0, likelihood_topics=["likelihood"])
    pa, pb, pc = Probe(h, "/a", SENSOR_TYPES[kind]), Probe(h, "/b"), Probe(h, "/c", Float64MultiArray)
    for p in (pa, pb, pc):
        h.add(p)
    h.start()
    for pub, n in ((pa.sensor_pub, 1), (pc.sensor_pub, 1), (pb.obs_pub, 2), (pa.action_pub, 3)):
        assert h.wait_matched(pub, n)  # the filter of /b and the probe; action: adapter, filter, probe
    rng = np.random.default_rng(11)
    values = [0.2, 1.0, 2.3, 0.45, 1.55, 2.9]  # every bin, none near an edge
    epochs = 15
    for t in range(1, epochs + 1):
        p, x = int(rng.integers(1, 4)), float(rng.choice(values))
        z = bin_by_hand(x)
        for probe in (pa, pb, pc):
            probe.action_pub.publish(encode_action(t, p))
        assert h.wait_until(lambda t=t: all(loop_state(ad, lambda lp: lp.pending and lp.pending.epoch) == t
                                            for ad in (ad_a, ad_c)), timeout=10)
        pb.obs_pub.publish(encode_observation(t, p, z))
        column = [float(v) for v in MODEL.O[p - 1][:, z]]
        for _ in range(20):
            pa.sensor_pub.publish(sensor_message(kind, math.nan, clock(ad_a)))
            pa.sensor_pub.publish(sensor_message(kind, x, clock(ad_a)))
            pc.sensor_pub.publish(Float64MultiArray(data=[math.nan] * 3))
            pc.sensor_pub.publish(Float64MultiArray(data=column))
            if h.wait_until(lambda t=t: all(t in probe.beliefs for probe in (pa, pb, pc)), timeout=0.5):
                break
        assert all(t in probe.beliefs for probe in (pa, pb, pc)), f"epoch {t}: no belief"
    for t in range(1, epochs + 1):
        assert np.array_equal(pa.beliefs[t], pb.beliefs[t]), t
        np.testing.assert_allclose(pc.beliefs[t], pb.beliefs[t], rtol=1e-12, atol=1e-15)
    assert sorted(set(pa.outputs)) == sorted(set(pb.outputs))  # the adapter's observations are the typed ones
    for ad in (ad_a, ad_c):
        c = loop_state(ad, lambda lp: dict(lp.health.counts))
        assert c["forwarded"] == epochs and c["nan_readings"] >= 1
        assert c["readings"] == (c["forwarded"] + c["nan_readings"] + c["surplus_readings"] + c["before_first_action"]
                                 + c["early_readings"])


def test_each_bad_reading_is_counted_in_diagnostics_and_dropped(harness):
    h = harness
    ad = adapter(h, input_type="range", max_age=0.5, resend_period=0.0)
    rec = h.recorder()
    probe = h.add(Probe(h, "/", Range))
    h.start()
    assert h.wait_matched(probe.sensor_pub, 1) and h.wait_matched(probe.action_pub, 2)

    def send(x, stamp_offset, counter, limits=(0.0, 10.0)):
        """Publish one Range until the adapter has counted it under ``counter``."""
        before = loop_state(ad, lambda lp: lp.health.counts[counter])
        for _ in range(20):
            msg = sensor_message("range", x, clock(ad) + stamp_offset)
            msg.min_range, msg.max_range = limits
            probe.sensor_pub.publish(msg)
            if h.wait_until(lambda: loop_state(ad, lambda lp: lp.health.counts[counter]) > before, timeout=0.5):
                return
        raise AssertionError(f"{counter} never counted")

    send(1.0, 0.0, "before_first_action")
    probe.action_pub.publish(encode_action(1, 2))
    assert h.wait_until(lambda: loop_state(ad, lambda lp: lp.pending is not None), timeout=10)
    send(math.nan, 0.0, "nan_readings")
    send(1.0, -2.0, "stale_readings")
    send(1.0, 2.0, "future_readings")
    send(20.0, 0.0, "out_of_limits_readings")
    assert probe.outputs == []
    send(1.0, 0.0, "forwarded")
    newest = loop_state(ad, lambda lp: lp.newest_stamp)
    probe.action_pub.publish(encode_action(2, 3))
    assert h.wait_until(lambda: loop_state(ad, lambda lp: lp.pending.epoch) == 2, timeout=10)
    send(0.1, newest - clock(ad) - 0.1, "out_of_order_readings")  # stamped before the newest one seen
    send(math.inf, 0.0, "forwarded")  # nothing within max_range: the last bin
    assert h.wait_until(lambda: len(set(probe.outputs)) == 2, timeout=10)
    assert sorted(set(probe.outputs)) == [(1, 2, 1), (2, 3, 2)]
    keys = ("nan_readings", "stale_readings", "future_readings", "out_of_limits_readings", "out_of_order_readings")
    assert h.wait_until(lambda: any(all(int(d.get(k, 0)) >= 1 for k in keys)
                                    for d in rec.diag_values("measurement_adapter: measurements")), timeout=10)
    d = rec.diag_values("measurement_adapter: measurements")[-1]
    assert d["forwarded"] == "2" and d["input_type"] == "range" and d["param.bin_edges"] == "0.5, 1.5"
    assert any(x["_level"] == b"\x01" and "since the last report" in x["_message"]
               for x in rec.diag_values("measurement_adapter"))


def test_a_fast_sensor_burst_neither_stalls_the_loop_nor_queues_anything(harness):
    """The real loop (adapter, filter, planner) with a sensor publishing about every millisecond
    for 3000 readings, then every 20 ms: actions keep coming during and after the burst, every
    reading the adapter received is forwarded or accounted for, and nothing holds a backlog."""
    h = harness
    ad = adapter(h, resend_period=0.0)
    filt = belief_filter(h)
    h.add(PlannerNode(context=h.context, parameter_overrides=[
        Parameter("model_file", value=S3), Parameter("time_budget", value=0.01), Parameter("max_depth", value=2)]))
    probe = h.add(Probe(h, "/", Float64))
    h.start()
    assert h.wait_matched(probe.sensor_pub, 1)
    burst, stop, sent = 3000, threading.Event(), [0]

    def sensor():
        i = 0
        while not stop.is_set():
            probe.sensor_pub.publish(Float64(data=0.1 * (i % 25)))
            i += 1
            sent[0] = i
            time.sleep(0.001 if i < burst else 0.02)

    thread = threading.Thread(target=sensor, daemon=True)
    thread.start()
    try:
        assert h.wait_until(lambda: sent[0] >= burst, timeout=120)
        with h.cond:
            at_burst_end = max((a for a, _ in probe.actions), default=0)
        assert at_burst_end >= 2, "no action answered during the burst"
        assert h.wait_until(lambda: max(a for a, _ in probe.actions) >= at_burst_end + 5, timeout=30), \
            "the loop stalled after the burst"
    finally:
        stop.set()
        thread.join(timeout=5)
    with ad.lock:
        c = dict(ad.loop.health.counts)
        assert ad.loop.health.logs == [] and ad.loop._out.samples == []
    assert c["readings"] <= sent[0]
    assert c["readings"] == c["forwarded"] + c["surplus_readings"] + c["before_first_action"] + c["early_readings"]
    with h.cond:
        answered = {o[0] for o in probe.outputs}
    assert c["forwarded"] == len(answered) and answered == set(range(1, max(answered) + 1))
    assert c["surplus_readings"] > c["forwarded"]  # the sensor was faster than the loop: one reading per epoch
    qos = ad.input_sub.qos_profile
    assert qos.history == HistoryPolicy.KEEP_LAST and qos.depth == SENSOR_QOS.depth == 10
    assert loop_state(filt, lambda lp: lp.buffer.pending_epochs <= lp.buffer.max_pending + 1)


@pytest.mark.parametrize("exe, args, message", [
    ("measurement_adapter", ["-p", "input_type:=sonar"],
     "input_type: expected one of float64, range, point, likelihood, got 'sonar'"),
    ("measurement_adapter", ["-p", "bin_edges:=[1.0]"],
     "bin_edges: 1 edges for an observation model with Z = 3 observations"),
    ("measurement_adapter", ["-p", "bin_edges:=[1.0, 0.5]"], "bin_edges: edges must increase strictly"),
    ("measurement_adapter", ["-p", "max_age:=-1.0"],
     "[measurement_adapter]: max_age: must be a number in 0..3600, got -1.0"),
    ("measurement_adapter", ["-p", "settle_time:=soon"],
     "[measurement_adapter]: settle_time: must be a number in 0..60, got 'soon'"),
    ("planner", ["-p", "time_budget:=-1.0"], "[planner]: time_budget: must be a number in 0.001..60, got -1.0"),
])
def test_a_bad_parameter_stops_the_executable_with_one_fatal_line(exe, args, message):
    proc = subprocess.run([*node_command(exe), "--ros-args", "-p", f"model_file:={S3}", *args],
                          capture_output=True, text=True, timeout=60,
                          env={**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}, preexec_fn=die_with_test)
    assert proc.returncode == 1, proc.stderr[-2000:]
    fatal = [line for line in proc.stderr.splitlines() if "[FATAL]" in line]
    assert len(fatal) == 1 and message in fatal[0], proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr


def test_likelihood_messages_round_trip_and_bad_ones_are_refused():
    got = decode_likelihood(encode_likelihood(7, 2, [0.5, 0.0, 3.0]), 3, 3)
    assert (got.epoch, got.priority, got.likelihood) == (7, 2, (0.5, 0.0, 3.0))
    with pytest.raises(OutOfRangeError, match=r"action_priority 4 out of range 1\.\.3"):
        decode_likelihood(encode_likelihood(7, 4, [1.0, 1.0, 1.0]), 3, 3)
    with pytest.raises(MessageError, match="expected 3 values"):
        decode_likelihood(encode_likelihood(7, 1, [1.0, 1.0]), 3, 3)
    with pytest.raises(MessageError, match="negative"):
        decode_likelihood(encode_likelihood(7, 1, [1.0, -1.0, 1.0]), 3, 3)
    with pytest.raises(MessageError, match="every entry is 0"):
        decode_likelihood(encode_likelihood(7, 1, [0.0, 0.0, 0.0]), 3, 3)
    with pytest.raises(MessageError, match="layout must be"):
        decode_likelihood(Float64MultiArray(data=[1.0, 1.0, 1.0]), 3, 3)
    bad = encode_likelihood(7, 1, [1.0, 1.0, 1.0])
    bad.layout.dim[1].label = "epoch=-1"
    with pytest.raises(MessageError, match="layout must be"):
        decode_likelihood(bad, 3, 3)


def test_the_filter_node_counts_bad_soft_evidence_and_applies_good_evidence(harness):
    h = harness
    filt = belief_filter(h, soft_only=True, likelihood_topics=["likelihood"])
    probe = h.add(Probe(h, "/"))
    h.start()
    assert h.wait_matched(probe.lik_pub, 1) and h.wait_until(lambda: 0 in probe.beliefs)
    probe.lik_pub.publish(encode_likelihood(1, 9, [1.0, 1.0, 1.0]))
    probe.lik_pub.publish(Float64MultiArray(data=[1.0, 1.0, 1.0]))
    assert h.wait_until(lambda: loop_state(filt, lambda lp: lp.health.counts["out_of_range_observations"] == 1
                                           and lp.health.counts["malformed_messages"] == 1), timeout=10)
    probe.lik_pub.publish(encode_likelihood(1, 2, [0.25, 1.0, 4.0]))
    assert h.wait_until(lambda: 1 in probe.beliefs, timeout=10)
    post = np.full(3, 1 / 3) @ MODEL.P[1] * np.array([0.25, 1.0, 4.0])
    np.testing.assert_allclose(probe.beliefs[1], post / post.sum(), rtol=1e-12)


def test_a_publisher_of_another_type_on_the_sensor_topic_is_named_once_and_in_diagnostics(domain, tmp_path):  # noqa: F811
    """A driver publishing ``Float64`` where the adapter (a process) reads a ``Range``: the middleware
    never delivers its samples, and the graph knows its type: one WARN line naming it, and the
    diagnostics say so (WARN) while it is there."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    log = tmp_path / "adapter.log"
    with open(log, "wb") as fh:
        proc = subprocess.Popen([*node_command("measurement_adapter"), "--ros-args", "-p", f"model_file:={S3}",
                                 "-p", "input_type:=range", "-p", "bin_edges:=[0.5, 1.5]"], stdout=fh,
                                stderr=subprocess.STDOUT, preexec_fn=die_with_test)
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("sonar_driver", context=ctx)
    statuses: list[tuple[int, str, dict]] = []

    def on_diag(msg):
        for st in msg.status:
            if st.name == "measurement_adapter: measurements":
                level = st.level[0] if isinstance(st.level, bytes) else st.level
                statuses.append((level, st.message, {kv.key: kv.value for kv in st.values}))

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    pub = node.create_publisher(Float64, "measurement", SENSOR_QOS)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()
    try:
        deadline = time.monotonic() + 60
        while not any(v.get("input.measurement.wrong_type_publishers") == "1" for _, _, v in statuses):
            assert time.monotonic() < deadline and proc.poll() is None, statuses[-1:]
            pub.publish(Float64(data=1.0))
            time.sleep(0.1)
        seen = len(statuses)
        while len(statuses) < seen + 3:  # three more reports: still said, and the line not repeated
            assert time.monotonic() < deadline, statuses[-1:]
            time.sleep(0.1)
        level, message, _ = statuses[-1]
        assert level == 1 and "/sonar_driver publishes std_msgs/msg/Float64, not sensor_msgs/msg/Range" in message
    finally:
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=20)
        executor.shutdown()
        node.destroy_node()
        ctx.try_shutdown()
    text = log.read_text(errors="replace")
    named = [ln for ln in text.splitlines() if "publishes std_msgs/msg/Float64" in ln]
    # the warning itself once; the line of a health change (OK -> WARN, once per change) may quote
    # the report that names it
    lines = [ln for ln in named if "]: health " not in ln]
    assert all("]: health WARN: " in ln for ln in named if ln not in lines)
    assert code == 0 and "Traceback" not in text
    assert len(lines) == 1 and "[WARN]" in lines[0] and lines[0].endswith(
        "publishes std_msgs/msg/Float64, not the sensor_msgs/msg/Range this node reads: its samples never reach it")
    assert "measurement: /sonar_driver [" in lines[0]


@pytest.mark.parametrize("kind", ["range", "point"])
def test_a_reading_with_a_frame_id_of_8_mb_is_dropped_unread(harness, kind):
    """A header's ``frame_id`` makes a reading oversized like any other part (rule "Bounded samples"):
    dropped before it is decoded, counted; the next reading is forwarded."""
    h = harness
    ad = adapter(h, input_type=kind, resend_period=0.0)
    probe = h.add(Probe(h, "/", SENSOR_TYPES[kind]))
    h.start()
    assert h.wait_matched(probe.sensor_pub, 1) and h.wait_matched(probe.action_pub, 2)
    probe.action_pub.publish(encode_action(1, 2))
    assert h.wait_until(lambda: loop_state(ad, lambda lp: lp.pending and lp.pending.epoch) == 1, timeout=10)
    big = sensor_message(kind, 1.0, clock(ad))
    big.header.frame_id = "f" * (8 * 1024 * 1024)
    probe.sensor_pub.publish(big)
    assert h.wait_until(lambda: loop_state(ad, lambda lp: lp.health.counts["oversized_samples"]) == 1, timeout=10)
    assert loop_state(ad, lambda lp: lp.health.counts["readings"]) == 0  # never decoded
    for _ in range(20):
        probe.sensor_pub.publish(sensor_message(kind, 1.0, clock(ad)))
        if h.wait_until(lambda: probe.outputs, timeout=0.5):
            break
    assert probe.outputs[0] == (1, 2, 1)
