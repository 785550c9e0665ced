"""Liveness of the node loop, in-process: forged and malformed messages, stray and lost samples,
dead and restarted nodes. The rules themselves are tested without ROS in test_loop_*.py; here
the nodes must apply them.

Every test waits on events with generous upper bounds (a loaded 2-core machine); none asserts a
duration. A node is "killed" in-process by taking it off the executor: it stops taking input and
publishing, as a dead process does.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticStatus
from nodes_support import S3, make_harness
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, Int64MultiArray, MultiArrayDimension
from test_nodes_closed_loop import start_loop

from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.messages import encode_action, encode_belief, encode_observation
from pomdp_planner.nodes.qos import STREAM_QOS
from pomdp_planner.nodes.target_simulator import TargetSimulator

harness = pytest.fixture(make_harness)
S = 3
FAST = {"stall_warn_after": 0.5, "stall_error_after": 1.5, "resend_period": 0.3}  # short liveness times


def _fast(**extra):
    return {**FAST, **extra}


def _loop(h, **kw):
    return start_loop(h, sim_params=_fast(**kw.pop("sim_params", {})),
                      filter_params=_fast(**kw.pop("filter_params", {})),
                      planner_params=_fast(**kw.pop("planner_params", {})), **kw)


def _publisher(h, msg_type, topic):
    node = h.add(Node(f"test_pub_{len(h.nodes)}", context=h.context))
    return node.create_publisher(msg_type, topic, STREAM_QOS)


def _kill(h, node):
    """Take ``node`` off the executor: it takes no input and publishes nothing any more."""
    h.executor.remove_node(node)


def _latest(rec, prefix):
    vals = rec.diag_values(prefix)
    return vals[-1] if vals else {}


def _advances(h, flt, by, timeout=30):
    start = flt.loop.epoch
    return h.wait_until(lambda: flt.loop.epoch >= start + by, timeout=timeout)


# ----------------------------------------------------------------- point 1: epochs from the wire


def test_forged_belief_far_ahead_is_dropped_and_the_loop_goes_on(harness):
    """A single belief whose layout says epoch 10^15 must not become an action for that epoch
    (which the simulator would jump to, and the filter then walk epoch by epoch); sent through the
    filter's own publisher, so that the writer rule does not drop it first."""
    h = harness
    sim, flt, planner, rec = _loop(h)
    assert h.wait_until(lambda: flt.loop.epoch > 20, timeout=30)
    flt.belief_pub.publish(encode_belief(10**15, [0.2, 0.3, 0.5]))
    assert _advances(h, flt, 100), f"loop stalled at epoch {flt.loop.epoch}"
    assert h.wait_until(lambda: planner.loop.health.counts.get("out_of_window", 0) == 1, timeout=10)
    with h.cond:
        assert max(t for t, _ in rec.actions) < 10**6  # no action for the forged epoch
    assert sim.loop.epoch < 10**6 and flt.loop.epoch < 10**6
    assert flt.loop.buffer.pending_epochs <= 1


def test_observation_far_ahead_neither_stalls_nor_walks_the_filter(harness):
    """A single observation 50 000 epochs ahead of the loop (from the simulator's own publisher):
    dropped (out of the window), not buffered, never walked; the filter keeps pace with the simulator."""
    h = harness
    sim, flt, _planner, rec = _loop(h)
    assert h.wait_until(lambda: flt.loop.epoch > 20, timeout=30)
    ahead = flt.loop.epoch + 50_000
    sim.obs_pubs[0].publish(encode_observation(ahead, 1, 0))
    assert _advances(h, flt, 100), f"filter stalled at epoch {flt.loop.epoch} (simulator at {sim.loop.epoch})"
    # two more diagnostics reports: longer than epoch_timeout, after which a buffered reading would be
    # reached by releasing every epoch in between as lost
    n = len(rec.diag_values("belief_filter"))
    assert h.wait_until(lambda: len(rec.diag_values("belief_filter")) >= n + 2, timeout=10)
    assert _advances(h, flt, 100), f"filter stalled at epoch {flt.loop.epoch} (simulator at {sim.loop.epoch})"
    assert flt.loop.epoch < ahead and max(rec.belief_epochs(S)) < ahead
    assert flt.loop.buffer.pending_epochs == 0  # never buffered
    assert h.wait_until(lambda: int(_latest(rec, "belief_filter").get("out_of_window", -1)) == 1, timeout=10)


def _malformed_ints(label_len: int, epoch_far: int) -> list[Int64MultiArray]:
    bad_label = encode_action(5, 1)
    bad_label.layout.dim = [MultiArrayDimension(label="x" * 100_000, size=2, stride=2)]
    return [
        Int64MultiArray(data=[1]),                                    # wrong length
        Int64MultiArray(data=list(range(label_len + 1))),             # wrong length
        Int64MultiArray(data=[-5, 1, 0][:label_len]),                 # negative epoch
        Int64MultiArray(data=[2**63 - 1, 1, 0][:label_len]),          # the largest int64 epoch
        Int64MultiArray(data=[epoch_far, 1, 0][:label_len]),          # 10^15 ahead
        Int64MultiArray(data=[3, -1, -1][:label_len]),                # negative priority / observation
        bad_label,                                                    # a 100 kB layout label
    ]


ROUNDS = 10


def test_malformed_messages_on_every_topic_are_counted_and_dropped(harness):
    """Wrong length, NaN, negative, huge and far-ahead epochs, a 5000-digit epoch label and huge
    labels on action, observation and belief, many times over, through the loop's own publishers
    (the writers the nodes follow): counted, dropped (the huge labels unread, as oversized); the
    loop goes on and no node holds more than it did."""
    h = harness
    _sim, flt, planner, rec = _loop(h)
    assert h.wait_until(lambda: flt.loop.epoch > 20, timeout=30)
    far = 10**15
    beliefs = [
        encode_belief(30, [0.5, 0.5]),                       # wrong length
        encode_belief(30, [np.nan, 0.5, 0.5]),               # NaN
        encode_belief(30, [0.7, 0.7, -0.4]),                 # negative, off the simplex
        encode_belief(far, [0.2, 0.3, 0.5]),                 # 10^15 ahead
        Float64MultiArray(data=[0.2, 0.3, 0.5]),             # no epoch
    ]
    huge_label = encode_belief(1, [0.2, 0.3, 0.5])
    huge_label.layout.dim[1].label = "epoch=" + "9" * 5000  # int() of it would raise: more than 4300 digits
    beliefs.append(huge_label)
    pubs = [(planner.action_pub, _malformed_ints(2, far)), (_sim.obs_pubs[0], _malformed_ints(3, far)),
            (flt.belief_pub, beliefs)]
    for _ in range(ROUNDS):  # within the readers' history depth (100): none is lost unread
        for pub, msgs in pubs:
            for msg in msgs:
                pub.publish(msg)
    assert _advances(h, flt, 100), f"loop stalled at epoch {flt.loop.epoch}"
    # counted by each node (diagnostics), nothing acted on
    def counted(node, *keys):
        return sum(int(_latest(rec, node).get(k, 0)) for k in keys)

    assert h.wait_until(lambda: counted("planner", "bad_beliefs", "oversized_samples") >= ROUNDS * 5, timeout=10)
    assert int(_latest(rec, "planner").get("oversized_samples", 0)) >= ROUNDS  # the 5000-digit label, unread
    assert int(_latest(rec, "planner").get("out_of_window", 0)) >= ROUNDS
    assert h.wait_until(lambda: counted("target_simulator", "malformed_actions", "oversized_samples") >= ROUNDS * 6,
                        timeout=10)
    fl = _latest(rec, "belief_filter")
    assert int(fl["malformed_messages"]) + int(fl["out_of_range_observations"]) >= ROUNDS * 5
    with h.cond:  # the recorder has the forged actions too; the planner answered none of the beliefs
        epochs = {a[0] for a in rec.actions}
    assert far + 1 not in epochs and not any(10**6 <= t < far for t in epochs)
    assert flt.loop.buffer.pending_epochs <= flt.loop.buffer.max_pending + 1
    assert planner.loop.mailbox is None or planner.loop.mailbox.epoch < 10**6


# ----------------------------------------------------------------- point 2: no single message stops the loop


class _HoldAfterPublish:
    """Wraps the planner's action publisher: after publishing the action of epoch ``at``, the
    planning callback waits until the belief that answers it has come, then makes a stray
    publish stale beliefs, and returns only once they have been delivered (the recorder has them).
    A depth-1 belief reader then holds the stray, not the real belief."""

    def __init__(self, pub, at, rec, stray, h):
        self._pub, self._at, self._rec, self._stray, self._h = pub, at, rec, stray, h
        self.done = threading.Event()

    def publish(self, msg):
        self._pub.publish(msg)
        if msg.data[0] != self._at or self.done.is_set():
            return
        assert self._h.wait_until(lambda: self._at in self._rec.belief_epochs(S), timeout=10)
        n = len(self._rec.beliefs)
        for _ in range(3):
            self._stray.publish(encode_belief(1, [0.2, 0.3, 0.5]))
        assert self._h.wait_until(lambda: len(self._rec.beliefs) >= n + 3, timeout=10)
        self.done.set()

    def __getattr__(self, name):
        return getattr(self._pub, name)


def test_one_stale_belief_cannot_stop_the_loop(harness):
    """A valid belief with a stale epoch, arriving after the real one and before the planner takes
    it, must not take the real one's place (the planner reads every belief and plans the newest
    valid, not-yet-planned one)."""
    h = harness
    _sim, flt, planner, rec = _loop(h)
    at = 30
    hold = _HoldAfterPublish(planner.action_pub, at, rec, flt.belief_pub, h)  # the filter's writer: not foreign
    planner.action_pub = hold
    assert hold.done.wait(timeout=60), "the loop never reached the held decision"
    assert _advances(h, flt, 50), f"loop stopped at epoch {flt.loop.epoch} after one stale belief"
    assert planner.loop.health.counts["stale_beliefs"] >= 3


def test_stray_publishers_on_every_topic_cannot_stop_the_loop(harness):
    """Stale beliefs, observations and actions from a second publisher on each topic at 20 Hz
    while the loop runs free: it keeps going, every node drops the second writer's samples as
    foreign and names it in its diagnostics."""
    h = harness
    sim, flt, planner, rec = _loop(h)
    assert h.wait_until(lambda: flt.loop.epoch > 5, timeout=30)
    node = h.add(Node("stray", context=h.context))
    pubs = [(node.create_publisher(Float64MultiArray, "belief", STREAM_QOS), encode_belief(2, [0.2, 0.3, 0.5])),
            (node.create_publisher(Int64MultiArray, "observation", STREAM_QOS), encode_observation(2, 1, 0)),
            (node.create_publisher(Int64MultiArray, "action", STREAM_QOS), encode_action(2, 1))]
    node.create_timer(0.05, lambda: [p.publish(m) for p, m in pubs])
    for _ in range(3):  # keeps going, in three rounds of 100 epochs
        assert _advances(h, flt, 100), f"loop stalled at epoch {flt.loop.epoch}"
    for n in (planner, sim, flt):
        assert n.loop.health.counts["foreign_samples"] > 0 and n.loop.health.counts["writer_changes"] == 0
    assert h.wait_until(lambda: "/stray [" in _latest(rec, "target_simulator").get("_message", ""), timeout=10)


class _DropOnce:
    """Wraps a publisher: the first message whose epoch is ``epoch`` is lost."""

    def __init__(self, pub, epoch):
        self._pub, self._epoch, self.dropped = pub, epoch, False

    def publish(self, msg):
        epoch = int(msg.layout.dim[1].label.split("=")[1]) if isinstance(msg, Float64MultiArray) else msg.data[0]
        if epoch == self._epoch and not self.dropped:
            self.dropped = True
            return
        self._pub.publish(msg)

    def __getattr__(self, name):
        return getattr(self._pub, name)


@pytest.mark.parametrize("lost", ["observation", "belief", "action"])
def test_a_lost_sample_is_re_sent(harness, lost):
    """One sample lost for good between two nodes (say, replaced in a reader's history before it
    was taken): the sender re-publishes its last output after ``resend_period`` (at-least-once,
    receivers idempotent), so the loop resumes instead of waiting for ever."""
    h = harness
    sim, flt, planner, _rec = _loop(h)
    at = 20
    if lost == "observation":
        sim.obs_pubs[0] = drop = _DropOnce(sim.obs_pubs[0], at)
    elif lost == "belief":
        flt.belief_pub = drop = _DropOnce(flt.belief_pub, at)
    else:
        planner.action_pub = drop = _DropOnce(planner.action_pub, at)
    assert h.wait_until(lambda: drop.dropped, timeout=30)
    assert h.wait_until(lambda: flt.loop.epoch > at + 30, timeout=30), f"loop stopped at epoch {flt.loop.epoch}"
    node, counter = {"observation": (sim, "resent_observations"), "belief": (flt, "resent_beliefs"),
                     "action": (planner, "resent_actions")}[lost]
    resent = node.loop.health.counts[counter]
    assert resent >= 1


# ----------------------------------------------------------------- point 3: liveness in diagnostics

# who stops when, in the free-running loop: the node whose input is missing names it, and the epoch
DEAD = {
    "planner": {"target_simulator": "action: no new action", "belief_filter": "observation: no new reading"},
    "belief_filter": {"target_simulator": "action: no new action", "planner": "belief: no new belief"},
    "target_simulator": {"belief_filter": "observation: no new reading", "planner": "belief: no new belief"},
}


@pytest.mark.parametrize("dead", sorted(DEAD))
def test_a_dead_node_is_named_by_the_others_diagnostics(harness, dead):
    h = harness
    *loop, rec = _loop(h)
    nodes = dict(zip(("target_simulator", "belief_filter", "planner"), loop, strict=True))
    assert h.wait_until(lambda: nodes["belief_filter"].loop.epoch > 20, timeout=30)
    _kill(h, nodes[dead])
    n0 = len(rec.diagnostics)
    for name, text in DEAD[dead].items():
        def says(name=name, text=text, level=DiagnosticStatus.ERROR):
            return any(d["_level"] == level and text in d["_message"] and " (last: epoch " in d["_message"]
                       for d in rec.diag_values(name)[n0:])
        assert h.wait_until(says, timeout=20), (name, _latest(rec, name).get("_message"))
        d = next(d for d in reversed(rec.diag_values(name)) if text in d["_message"])
        key = {"target_simulator": "input.action", "belief_filter": "input.observation",
               "planner": "input.belief"}[name]
        assert float(d[f"{key}.seconds_since_new"]) >= FAST["stall_error_after"]
        assert d[f"{key}.last_new_epoch"] != "none"


def test_restarted_timer_simulator_continues_the_loops_numbering(harness):
    """Timer mode: a simulator that restarts (here: a new one replaces a dead one) joins the loop
    at the filter's epoch instead of counting from 1 again, which the filter would drop as
    duplicates (with diagnostics OK) until the old count was reached."""
    h = harness
    old, flt, _planner, rec = _loop(h, sim_params={"step_period": 0.02})
    assert h.wait_until(lambda: flt.loop.epoch > 100, timeout=60)
    _kill(h, old)
    t_dead = flt.loop.epoch
    new = h.add(TargetSimulator("target_simulator", context=h.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in {"model_file": S3, "seed": 9, "step_period": 0.02, **FAST}.items()]))
    assert _advances(h, flt, 50), f"filter stuck at epoch {flt.loop.epoch}"
    assert new.loop.joined_at == f"epoch {t_dead}" or int(new.loop.joined_at.split()[1]) >= t_dead - 1
    with h.cond:
        first_new = min(t for t, _, _ in rec.observations["observation"][-40:])
    assert first_new > t_dead - 2
    assert flt.loop.health.counts["duplicates"] < 5


def test_filter_resyncs_to_a_simulator_counting_on_a_numbering_of_its_own(harness):
    """The filter's restart rule: stalled (nothing applied for stall_warn_after) while readings
    count upward on another numbering (a restarted simulator that could not join), it follows them,
    keeping its belief, and says so in its log and diagnostics."""
    h = harness
    flt = h.add(BeliefFilter(context=h.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in {"model_file": S3, **FAST}.items()]))
    rec = h.recorder()
    pub = _publisher(h, Int64MultiArray, "observation")
    h.start()
    for t in range(1, 1001):
        pub.publish(encode_observation(t, 2, t % 3))
    assert h.wait_until(lambda: flt.loop.epoch == 1000, timeout=30)
    node = h.add(Node("restarted_sim", context=h.context))
    counter = iter(range(1, 10**6))
    node.create_timer(0.02, lambda: pub.publish(encode_observation(next(counter), 2, 1)))
    assert h.wait_until(lambda: 0 < flt.loop.epoch < 1000, timeout=20), f"filter at {flt.loop.epoch}"
    assert flt.loop.health.counts["resyncs"] == 1
    resynced = flt.loop.epoch
    assert h.wait_until(lambda: flt.loop.epoch > resynced + 10, timeout=10)
    assert h.wait_until(lambda: any("re-synced from epoch 1000" in d["_message"]
                                    for d in rec.diag_values("belief_filter")), timeout=10)


# ----------------------------------------------------------------- point 6: event-driven filter


def test_idle_filter_polls_nothing_and_still_releases_incomplete_epochs_on_time(harness):
    """The filter's release by time-out is a one-shot timer armed for the buffer's next deadline:
    idle, no timer faster than its 4 Hz watchdog is running; an epoch missing a sensor is still
    applied once epoch_timeout has passed."""
    h = harness
    flt = h.add(BeliefFilter(context=h.context, parameter_overrides=[
        Parameter("model_file", value=S3), Parameter("observation_topics", value=["cam", "radar"]),
        Parameter("epoch_timeout", value=0.3)]))
    rec = h.recorder(obs_topics=("cam", "radar"))
    radar = _publisher(h, Int64MultiArray, "radar")
    h.start()

    def running_fast_timers():
        return [t.timer_period_ns for t in flt.timers if not t.is_canceled() and t.timer_period_ns < 0.2e9]

    assert running_fast_timers() == []
    radar.publish(encode_observation(1, 2, 1))  # the camera's reading never comes
    assert h.wait_until(lambda: 1 in rec.belief_epochs(S), timeout=10)
    assert flt.loop.health.counts["incomplete_epochs"] == 1
    assert h.wait_until(lambda: running_fast_timers() == [], timeout=5)
