"""The rule "One writer" in the nodes (in process: plain pytest + rclpy, the writers are test nodes
named as the loop's nodes would be, or not):

* a writer still in the graph is not replaced when its samples stop coming while another writer
  speaks (what a flood that crowds its samples out of the reader's history looks like to the
  node), also after ten times ``stall_warn_after``; it is followed again when it is heard;
* a stray present at start-up is followed only until the expected writer speaks: the planner then
  answers the filter's beliefs within 2 s, and the sensor manager its target's filter's (the
  stray's epochs forgotten); the stray going on, or stopping, changes nothing after that;
* the measurement adapter with its sensor driver named in ``expected_writers`` forwards only that
  driver's readings beside a stray that spoke first.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import S3, make_harness
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64, Float64MultiArray, Int64MultiArray

from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.measurement_adapter import MeasurementAdapter
from pomdp_planner.nodes.messages import decode_belief, encode_action, encode_belief, encode_observation
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.qos import RECORDER_QOS, SENSOR_QOS, STREAM_QOS
from pomdp_planner.nodes.sensor_manager import SensorManager

harness = pytest.fixture(make_harness)


def _params(**kw):
    return [Parameter(k, value=v) for k, v in kw.items()]


class Talker:
    """A node named ``name`` publishing ``make(k)`` on ``topic`` every ``period`` seconds in its own
    thread while :attr:`on` is set (it stays in the graph while it is silent)."""

    def __init__(self, h, name: str, msg_type, topic: str, qos, period: float, make, ns: str | None = None):
        self.node = h.add(Node(name, namespace=ns, context=h.context))
        self.pub = self.node.create_publisher(msg_type, topic, qos)
        self.period, self.make = period, make
        self.on = threading.Event()
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> Talker:
        self.on.set()
        if not self._thread.is_alive():
            self._thread.start()
        return self

    def _run(self) -> None:
        nxt = time.monotonic()
        while not self._stop.is_set():
            if self.on.is_set():
                self.pub.publish(self.make(self.sent))
                self.sent += 1
            nxt += self.period
            time.sleep(max(0.0, nxt - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


def _writer_state(node, name: str) -> tuple[str | None, int, str]:
    with node.lock:
        w = node.loop.health.writers[name]
        return w.established, w.changes, w.label(w.established)


def test_a_writer_in_the_graph_is_not_replaced_when_its_samples_stop_coming(harness):
    h = harness
    flt = h.add(BeliefFilter(context=h.context, parameter_overrides=_params(model_file=S3, stall_warn_after=0.5)))
    beliefs: list[int] = []
    probe = h.add(Node("probe", context=h.context))
    probe.create_subscription(Float64MultiArray, "belief", lambda m: beliefs.append(decode_belief(m, 3).epoch),
                              RECORDER_QOS)
    sim = Talker(h, "target_simulator", Int64MultiArray, "observation", STREAM_QOS, 0.05,
                 lambda k: encode_observation(k + 1, 1, k % 3))
    flood = Talker(h, "flood", Int64MultiArray, "observation", STREAM_QOS, 0.005,
                   lambda k: encode_observation(100 + k, 2, 0))
    h.start()
    assert h.wait_matched(sim.pub, 1) and h.wait_matched(flood.pub, 1)
    sim.start()
    assert h.wait_until(lambda: len(beliefs) >= 5, timeout=15)
    followed, _changes, label = _writer_state(flt, "observation")
    assert label.startswith("/target_simulator [")
    sim.on.clear()  # silent, in the graph: as a crowded-out writer looks to the reader
    flood.start()
    time.sleep(5.0)  # ten times stall_warn_after, the flood going on
    flood.on.clear()
    assert _writer_state(flt, "observation")[:2] == (followed, 0)
    with flt.lock:
        foreign = flt.loop.health.counts["foreign_samples"]
    assert foreign >= 100
    seen = len(beliefs)
    sim.start()  # heard again: followed at once
    assert h.wait_until(lambda: len(beliefs) >= seen + 5, timeout=15)
    assert _writer_state(flt, "observation")[:2] == (followed, 0)
    sim.close()
    flood.close()


@pytest.mark.parametrize("manager", [False, True], ids=["planner", "sensor_manager"])
def test_a_stray_present_at_start_up_is_dropped_once_the_expected_writer_speaks(harness, manager):
    """A stray's beliefs (epochs from 500 on, 10 Hz) come first and are followed; the filter's
    (a node named belief_filter, epochs from 0) are answered within 2 s of its first belief, and
    not one action more answers the stray, which goes on for 2 s and then stops."""
    h = harness
    topic, action_topic = ("t1/belief", "t1/action") if manager else ("belief", "action")
    if manager:
        node = h.add(SensorManager(context=h.context, parameter_overrides=_params(
            model_file=S3, targets=["t1"], time_budget=0.02, max_depth=1)))
    else:
        node = h.add(PlannerNode(context=h.context, parameter_overrides=_params(
            model_file=S3, time_budget=0.02, max_depth=1)))
    actions: list[tuple[float, int]] = []
    probe = h.add(Node("probe", context=h.context))
    probe.create_subscription(Int64MultiArray, action_topic,
                              lambda m: actions.append((time.monotonic(), int(m.data[0]))), RECORDER_QOS)
    belief = np.array([0.6, 0.3, 0.1])
    stray = Talker(h, "stray", Float64MultiArray, topic, STREAM_QOS, 0.1, lambda k: encode_belief(500 + k, belief))
    real = Talker(h, "belief_filter", Float64MultiArray, "belief", STREAM_QOS, 0.1, lambda k: encode_belief(k, belief),
                  ns="/t1" if manager else None)  # /t1/belief_filter writes /t1/belief
    h.start()
    assert h.wait_matched(stray.pub, 1) and h.wait_matched(real.pub, 1)
    stray.start()
    assert h.wait_until(lambda: any(e > 500 for _, e in actions), timeout=15), "the stray was not followed"
    t_real = time.monotonic()
    real.start()
    assert h.wait_until(lambda: any(e < 500 for _, e in actions), timeout=15), "the filter was never answered"
    first = min(t for t, e in actions if e < 500)
    who = "sensor_manager" if manager else "planner"
    print(f"{who}: the filter's beliefs answered {first - t_real:.2f} s after its first one")
    assert first - t_real <= 2.0, f"the filter's first belief answered after {first - t_real:.2f} s"
    time.sleep(2.0)
    stray.on.clear()
    stray_after = [e for t, e in actions if e > 500 and t > first + 0.5]
    assert not stray_after, f"actions for the stray's epochs after the switch: {stray_after}"
    time.sleep(1.0)
    name = "t1/belief" if manager else "belief"
    _established, changes, label = _writer_state(node, name)
    assert changes == 1 and label.startswith("/t1/belief_filter [" if manager else "/belief_filter [")
    sent = real.sent
    assert h.wait_until(lambda: max(e for _, e in actions) >= sent + 2, timeout=10)  # still answering the filter
    stray.close()
    real.close()


def test_the_adapter_forwards_only_its_named_sensor_beside_a_stray_that_spoke_first(harness):
    h = harness
    ad = h.add(MeasurementAdapter(context=h.context, parameter_overrides=_params(
        model_file=S3, bin_edges=[0.5, 1.5], expected_writers=["sonar"], resend_period=0.0)))
    outputs: list[tuple[int, int, int]] = []
    probe = h.add(Node("probe", context=h.context))
    probe.create_subscription(Int64MultiArray, "observation", lambda m: outputs.append(tuple(m.data)), RECORDER_QOS)
    planner = Talker(h, "planner", Int64MultiArray, "action", STREAM_QOS, 0.1, lambda k: encode_action(k + 1, 1))
    stray = Talker(h, "stray_range", Float64, "measurement", SENSOR_QOS, 0.2, lambda k: Float64(data=2.9))  # bin 2
    sonar = Talker(h, "sonar", Float64, "measurement", SENSOR_QOS, 0.05, lambda k: Float64(data=0.2))  # bin 0
    h.start()
    assert all(h.wait_matched(t.pub, 1) for t in (planner, stray, sonar))
    stray.start()
    planner.start()
    assert h.wait_until(lambda: any(z == 2 for _, _, z in outputs), timeout=15), "the stray was not followed"
    sonar.start()
    assert h.wait_until(lambda: any(z == 0 for _, _, z in outputs), timeout=15), "the sonar was never forwarded"
    switch = min(k for k, (_, _, z) in enumerate(outputs) if z == 0)
    n = len(outputs)
    assert h.wait_until(lambda: len(outputs) >= n + 30, timeout=30)
    assert all(z == 0 for _, _, z in outputs[switch:]), outputs[switch:]
    _established, changes, label = _writer_state(ad, "measurement")
    assert changes == 1 and label.startswith("/sonar [")
    with ad.lock:
        assert ad.loop.health.counts["foreign_samples"] >= 10
    for t in (planner, stray, sonar):
        t.close()
