"""The ``sensor_manager`` node: in-process (beliefs typed by the test, the actions, the joint record
and the diagnostics it answers with; start-up refusals), and K = 3 targets as real processes
(3 simulators, 3 filters, the manager on localhost in a ROS domain of their own): every joint
record within the budget, every action paired with its target's belief, and a target's filter
killed (SIGKILL) and restarted while the loop runs.

Efforts are checked against the table written out here (priority p costs 3 - p), never against
the node's own arithmetic; waits are on events with generous bounds, no durations asserted."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticArray
from nodes_support import REPO, die_with_test, make_harness, rclpy, shm_entries, stop_after_kills
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, Int64MultiArray
from test_nodes_multiprocess import _spin_until, domain  # noqa: F401 (a fixture)

from pomdp_planner.nodes.messages import decode_allocation, decode_belief, encode_belief
from pomdp_planner.nodes.processes import node_command
from pomdp_planner.nodes.qos import RECORDER_QOS, STREAM_QOS
from pomdp_planner.nodes.runtime import NodeConfigError
from pomdp_planner.nodes.sensor_manager import SensorManager

harness = pytest.fixture(make_harness)
PERIMETER = str(REPO / "config" / "models" / "perimeter_s3.yaml")
TRACKING = str(REPO / "config" / "models" / "tracking_s3_info.yaml")
EFFORT = {1: 2, 2: 1, 3: 0}  # priority p costs 3 - p (the default efforts of a 3-priority model)
TARGETS = ("target1", "target2", "target3")
SETS = {"target1": "perimeter_s3", "target2": "perimeter_s3", "target3": "s3"}  # config/<node>_<set>.yaml


class TargetsRecorder(Node):
    """Every message on ``<ns>/action``, ``<ns>/belief`` and ``<ns>/observation`` of each target, on
    ``allocation`` and ``/diagnostics``; each record starts with its arrival number (thread-safe)."""

    def __init__(self, context: Context, targets, cond: threading.Condition):
        super().__init__("test_targets_recorder", context=context)
        self.cond = cond
        self.targets = tuple(targets)
        self.seq = 0
        self.actions = {t: [] for t in targets}  # (seq, epoch, priority)
        self.beliefs = {t: [] for t in targets}  # (seq, epoch)
        self.observations = {t: [] for t in targets}  # (seq, epoch, priority, z)
        self.allocations = []  # (seq, decision, [ActionSample | None] per target)
        self.diagnostics = []  # the sensor manager's statuses, as dicts (+ _level, _message)
        self.statuses = {}  # the newest status of every node, for failure messages
        for t in targets:
            self._record(Int64MultiArray, f"{t}/action", self.actions[t], lambda m: tuple(m.data))
            self._record(Int64MultiArray, f"{t}/observation", self.observations[t], lambda m: tuple(m.data))
            self._record(Float64MultiArray, f"{t}/belief", self.beliefs[t],
                         lambda m: (decode_belief(m, len(m.data)).epoch,))
        self._record(Int64MultiArray, "allocation", self.allocations, lambda m: decode_allocation(m, self.targets))
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)

    def _record(self, kind, topic, store: list, conv) -> None:
        def cb(msg):
            with self.cond:
                self.seq += 1
                store.append((self.seq, *conv(msg)))
                self.cond.notify_all()
        self.create_subscription(kind, topic, cb, RECORDER_QOS)

    def _on_diagnostics(self, msg):
        with self.cond:
            for st in msg.status:
                self.statuses[st.name] = f"{st.level}: {st.message} " + str({kv.key: kv.value for kv in st.values})
                if st.name.startswith("sensor_manager"):
                    self.diagnostics.append({**{kv.key: kv.value for kv in st.values}, "_level": st.level,
                                             "_message": st.message})
            self.cond.notify_all()

    def newest_action(self, t: str) -> int:
        with self.cond:
            return self.actions[t][-1][1] if self.actions[t] else -1


def cost(actions) -> int:
    """The effort of a set of actions in force (``None``: none yet, the least effort, 0)."""
    return sum(0 if a is None else EFFORT[a.priority] for a in actions)


# ----------------------------------------------------------------- in-process
def test_each_targets_belief_is_answered_on_its_action_topic_with_one_joint_record(harness):
    h = harness
    h.add(SensorManager(context=h.context, parameter_overrides=[
        Parameter("targets", value=["a", "b"]), Parameter("model_files", value=[PERIMETER, TRACKING]),
        Parameter("effort_budget", value=1.0), Parameter("discount", value=0.95),
        Parameter("search", value="exhaustive"), Parameter("time_budget", value=1.0), Parameter("max_depth", value=1)]))
    rec = h.add(TargetsRecorder(h.context, ("a", "b"), h.cond))
    node = h.add(Node("test_beliefs", context=h.context))
    pubs = {t: node.create_publisher(Float64MultiArray, f"{t}/belief", STREAM_QOS) for t in ("a", "b")}
    h.start()
    assert all(h.wait_matched(p, 2) for p in pubs.values())  # the manager and the recorder
    pubs["a"].publish(encode_belief(7, np.array([0.6, 0.3, 0.1])))
    pubs["b"].publish(encode_belief(0, np.full(3, 1 / 3)))
    assert h.wait_until(lambda: rec.allocations and rec.actions["a"] and rec.actions["b"], timeout=15)
    (_, decision, in_force), = rec.allocations
    (_, ta, pa), (_, tb, pb) = rec.actions["a"][0], rec.actions["b"][0]
    assert (decision, ta, tb) == (1, 8, 1)  # each target's action names its own belief's epoch + 1
    assert [(a.epoch, a.priority) for a in in_force] == [(ta, pa), (tb, pb)] and cost(in_force) <= 1
    node.create_publisher(Float64MultiArray, "b/belief", STREAM_QOS).publish(encode_belief(1, np.ones(4) / 4))
    assert h.wait_until(lambda: any(d.get("bad_beliefs") == "1" for d in rec.diagnostics), timeout=15)
    d = rec.diagnostics[-1]
    assert "(bound)" in d["_message"] and d["last.bound_guaranteed"] == "true" and d["bound_guaranteed"] == "true"
    assert float(d["last.gap"]) == pytest.approx(float(d["last.dual_bound"]) - float(d["last.lower_bound"]), abs=1e-5)
    assert d["effort_in_force"] == str(cost(in_force)) and d["target.a.action_epoch"] == "8"
    assert {"last.lambda", "input.a/belief.last_new_epoch", "input.b/belief.seconds_since_new"} <= set(d)


def test_a_belief_larger_than_the_targets_model_implies_is_dropped_unread(harness):
    h = harness
    h.add(SensorManager(context=h.context, parameter_overrides=[
        Parameter("targets", value=["a", "b"]), Parameter("model_file", value=PERIMETER),
        Parameter("effort_budget", value=1.0), Parameter("max_depth", value=1)]))
    rec = h.add(TargetsRecorder(h.context, ("a", "b"), h.cond))
    node = h.add(Node("test_beliefs", context=h.context))
    pub = node.create_publisher(Float64MultiArray, "a/belief", STREAM_QOS)
    h.start()
    assert h.wait_matched(pub, 2)
    pub.publish(encode_belief(3, np.full(10_000, 1e-4)))
    assert h.wait_until(lambda: any(d.get("oversized_samples") == "1" for d in rec.diagnostics), timeout=15)
    d = next(d for d in rec.diagnostics if d.get("oversized_samples") == "1")
    assert d["bad_beliefs"] == "0" and d["target.a.belief_epoch"] == "none" and not rec.actions["a"]


@pytest.mark.parametrize("overrides, text", [
    ({}, "targets: give at least one target namespace"),
    ({"targets": ["a", "a"]}, r"targets\[1\]: 'a' is given twice"),
    ({"targets": ["a", "b"], "model_files": [PERIMETER]}, "model_files: 1 model files for 2 targets"),
    ({"targets": ["a"], "model_files": ["no/such/model.yaml"]}, r"model_files\[0\]"),
    ({"targets": ["a", "b"], "efforts": [1.0, 0.0]}, "efforts: 2 values"),
    ({"targets": ["a", "b"], "efforts": [1.0, 1.0, 1.0], "effort_budget": 1.0}, "effort_budget: 1 is below"),
    ({"targets": ["a", "b"], "model_files": [PERIMETER, TRACKING]}, "discount: the targets' models have different"),
    ({"targets": ["a"], "search": "greedy"}, "search: expected one of bnb, exhaustive"),
])
def test_bad_start_up_parameters_refuse_to_start(harness, overrides, text):
    with pytest.raises(NodeConfigError, match=text):
        SensorManager(context=harness.context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])


@pytest.mark.parametrize("args, text", [
    (["-p", "effort_budget:=-1.0"], "[FATAL] [sensor_manager]: effort_budget: must be a number in 0..1e+06, got -1.0"),
    (["-p", "effort_budgett:=1.0", "-p", "strict_parameters:=true"],
     "[FATAL] [sensor_manager]: effort_budgett (did you mean effort_budget?): not a parameter of this node"),
])
def test_a_refused_start_is_one_fatal_line(args, text):
    proc = subprocess.run([*node_command("sensor_manager"), "--ros-args", "-p", "targets:=[a]", *args],
                          capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF"))
    assert proc.returncode == 1, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(text), proc.stderr


# ----------------------------------------------------------------- K = 3 as processes
def _arguments(t: str, k: int) -> dict[str, list[str]]:
    config = REPO / "config"
    ns = ["-r", f"__ns:=/{t}"]
    return {
        "target_simulator": [*ns, "--params-file", str(config / f"target_simulator_{SETS[t]}.yaml"),
                             "-p", f"seed:={k + 1}", "-p", "default_priority:=3", "-p", "step_period:=0.0"],
        "belief_filter": [*ns, "--params-file", str(config / f"belief_filter_{SETS[t]}.yaml")],
    }


def unpaired(rec: TargetsRecorder, t: str) -> list[int]:
    """The action epochs ``e`` of target ``t`` for which the recorder has no belief of epoch ``e - 1``
    (it matched the filters before the loop started, and a restarted filter's history holds the rest)."""
    with rec.cond:
        beliefs = {e for _, e in rec.beliefs[t]}
        return sorted({e for _, e, _ in rec.actions[t] if e - 1 not in beliefs})


def logs(procs, rec=None) -> str:
    """The last lines of every node's log (and, with ``rec``, who the recorder sees on each topic),
    for a failure message."""
    graph = "" if rec is None else "recorded beliefs: " + ", ".join(
        f"{t} {len(rec.beliefs[t])}" for t in TARGETS) + "; graph: " + ", ".join(
        f"{t}/{x}: {rec.count_publishers('/' + t + '/' + x)} pub {rec.count_subscribers('/' + t + '/' + x)} sub"
        for t in TARGETS for x in ("observation", "belief", "action")) + "\n"
    if rec is not None:
        graph += "\n".join(f"{name}: {text}" for name, text in sorted(rec.statuses.items())) + "\n"
    return graph + "\n".join(f"--- {name}\n" + "\n".join(log.read_text(errors="replace").splitlines()[-6:])
                     for name, (_, log) in procs.items())


RESUMED_BY = 5  # action epochs every target must advance past its pre-kill newest for "the loop resumed"


@pytest.mark.usefixtures("domain")
def test_three_targets_within_budget_paired_and_a_filter_restarted(tmp_path):
    """The loop of launch/multi_target.launch.xml, free running, as seven processes; the test
    records every action, belief, observation and joint record. Then target2's filter is killed
    (SIGKILL): the others go on, target2 is held, the diagnostics name its silent input; then the
    filter is started again and every target's actions advance again. Checked at the end: every
    joint record costs at most B = 2; every action on a target's topic is that target's entry of a
    joint record; every action ``[t + 1, p]`` follows a belief of epoch ``t`` of its target; every
    observation was taken under an action the manager sent for its epoch; clean exits. The times
    are printed (``-s``), not asserted. The node processes die with the test; at the end only the
    killed filter's shared memory is removed (files of dead owners that no process maps)."""
    shm_before = shm_entries()
    ctx = Context()
    rclpy.init(context=ctx)
    rec = TargetsRecorder(ctx, TARGETS, threading.Condition())
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(rec)
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONFAULTHANDLER="1")
    procs, handles = {}, []

    def start(name, args, tag=""):
        log = tmp_path / f"{name}{tag}.err"
        fh = open(log, "wb")
        handles.append(fh)
        procs[name] = (subprocess.Popen([*node_command(name.split(":")[0]), "--ros-args", *args], env=env,
                                        stdout=subprocess.DEVNULL, stderr=fh, preexec_fn=die_with_test), log)

    manager = ["--params-file", str(REPO / "config" / "sensor_manager_mixed_s3.yaml"),
               "-p", "time_budget:=0.02", "-p", "max_depth:=2"]
    try:
        for k, t in enumerate(TARGETS):
            start(f"belief_filter:{t}", _arguments(t, k)["belief_filter"])
        start("sensor_manager", manager)
        for k, t in enumerate(TARGETS):
            start(f"target_simulator:{t}", _arguments(t, k)["target_simulator"])
        assert _spin_until(executor, lambda: min(rec.newest_action(t) for t in TARGETS) > 30
                           and len(rec.allocations) > 30, 60), \
            f"loop did not run: {[rec.newest_action(t) for t in TARGETS]}, {len(rec.allocations)} joint records\n" \
            + logs(procs, rec)
        victim = "belief_filter:target2"
        p = procs[victim][0]
        p.kill()
        p.wait(timeout=10)
        t_kill = time.monotonic()
        # let the recorder drain what was in flight: target2's actions quiet for 0.5 s (it is held: re-sends only)
        last = {"value": rec.newest_action("target2"), "since": time.monotonic()}

        def quiet():
            now = rec.newest_action("target2")
            if now != last["value"]:
                last.update(value=now, since=time.monotonic())
            return time.monotonic() - last["since"] > 0.5
        assert _spin_until(executor, quiet, 30)
        before = {t: rec.newest_action(t) for t in TARGETS}
        # the others go on without target2, and the diagnostics name it once its input has stalled
        assert _spin_until(executor, lambda: all(rec.newest_action(t) >= before[t] + RESUMED_BY
                                                 for t in ("target1", "target3")), 30), \
            "the others waited for target2\n" + logs(procs, rec)
        assert _spin_until(executor, lambda: any("target2/belief: no new belief" in d["_message"]
                                                 and "target2 held at priority" in d["_message"]
                                                 for d in rec.diagnostics), 30), rec.diagnostics[-1:]
        assert rec.newest_action("target2") == before["target2"]  # held: nothing new for it meanwhile
        before = {t: rec.newest_action(t) for t in TARGETS}
        t_restart = time.monotonic()
        with rec.cond:
            seq_restart = rec.seq
        start(victim, _arguments("target2", 1)["belief_filter"], ".restarted")
        ok = _spin_until(executor, lambda: all(rec.newest_action(t) >= before[t] + RESUMED_BY for t in TARGETS), 60)
        assert ok, f"loop did not resume after restarting target2's filter: {before} -> " \
                   f"{ {t: rec.newest_action(t) for t in TARGETS} }; target2's beliefs since the restart: " \
                   f"{[e for q, e in rec.beliefs['target2'] if q > seq_restart][:20]}; observations: " \
                   f"{[e for q, e, *_ in rec.observations['target2'] if q > seq_restart][:20]}\n" \
                   + logs(procs, rec)
        assert all(q.poll() is None for q, _ in procs.values()), "a node died"
        now = time.monotonic()
        # the recorder may discover the restarted filter later than the manager did: wait for its history
        assert _spin_until(executor, lambda: not any(unpaired(rec, t) for t in TARGETS), 30), \
            {t: unpaired(rec, t)[:5] for t in TARGETS}
        print(f"\nsensor manager, K = 3: target2's filter killed (-9), restarted {t_restart - t_kill:.1f} s later; "
              f"{now - t_restart:.1f} s from the restart to every target's action {RESUMED_BY} epochs on")
    finally:
        codes = stop_after_kills(procs, executor, rec, ctx, handles, shm_before)
    for name, code in codes.items():
        err = procs[name][1].read_text(errors="replace")
        assert code == 0 and "Traceback" not in err, f"{name}: exit code {code}\n{err[-2000:]}"

    # every joint record within the budget; each target's entries only move forward
    assert len(rec.allocations) > 30 + RESUMED_BY
    for _, decision, in_force in rec.allocations:
        assert cost(in_force) <= 2, (decision, in_force)
    for k, t in enumerate(TARGETS):
        entries = {(f[k].epoch, f[k].priority) for _, _, f in rec.allocations if f[k] is not None}
        sent = {(e, p) for _, e, p in rec.actions[t]}
        in_flight = {(e, p) for e, p in sent if e > max(e for e, _ in entries)}  # the last decision's record may
        assert len(in_flight) <= 1  # not have reached the recorder when it stopped (another topic)
        assert sent - in_flight <= entries, f"{t}: actions outside every joint record: {sorted(sent - entries)[:5]}"
        assert not unpaired(rec, t), f"{t}: actions without the belief of the epoch before: {unpaired(rec, t)[:5]}"
        by_epoch: dict[int, set[int]] = {}
        for e, p in sent:
            by_epoch.setdefault(e, set()).add(p)
        checked = [(e, p) for _, e, p, _ in rec.observations[t] if e in by_epoch]
        assert len(checked) > 30 and all(p in by_epoch[e] for e, p in checked), t
