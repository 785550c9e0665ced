"""The ``run_recorder`` node: a short loop of the three nodes recorded by it reads back with the
run-record reader, row ``t`` holding exactly the belief and true state of epoch ``t``, the action
``[t + 1, p]`` and that decision's ``plan_info`` (as an independent subscriber saw them; the rows
still waiting at exit with what they have), bounds only where the planner published them, and
``pomdp-planner plot`` draws it; a second writer and an oversized sample are dropped before they
reach the record; bad messages are counted in ``/diagnostics``; a file it cannot write is one
``[FATAL]`` line, a full disk later one error (diagnostics ERROR) with the file ending on a whole
row; SIGINT ends it cleanly with the record complete."""

from __future__ import annotations

import errno
import io
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticStatus
from nodes_support import S3, die_with_test, make_harness
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, Int64MultiArray
from test_run_record import png_size

from pomdp_planner.cli import main as cli_main
from pomdp_planner.core.io.run_bag import read_run_bag
from pomdp_planner.core.io.run_record import read_run_record
from pomdp_planner.core.loop.samples import ActionSample, BeliefSample
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.messages import decode_plan_info, encode_action, encode_true_state
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.processes import node_command
from pomdp_planner.nodes.qos import RECORDER_QOS, STREAM_QOS
from pomdp_planner.nodes.run_recorder import RunRecorderNode
from pomdp_planner.nodes.target_simulator import TargetSimulator

harness = pytest.fixture(make_harness)
ROWS = 40


def _params(**kw):
    return [Parameter(k, value=v) for k, v in kw.items()]


def _rows_written(node: RunRecorderNode) -> int:
    with node.inputs.lock:
        return node.loop.health.counts["rows_written"]


@pytest.mark.parametrize("use_bounds, suffix", [(True, "csv"), (False, "csv"), (True, "mcap")])
def test_a_recorded_loop_reads_back_pairs_by_epoch_and_plots(harness, tmp_path, use_bounds, suffix):
    """The same as a CSV and as a rosbag2 bag (``file`` ending in .mcap), which also keeps the
    reading that made each row's belief."""
    h = harness
    path, png = tmp_path / f"run.{suffix}", tmp_path / "run.png"
    recorder = h.add(RunRecorderNode(context=h.context, parameter_overrides=_params(
        model_file=S3, file=str(path), time_budget=0.02, expect_true_state=True)))
    infos: list = []
    listener = h.add(Node("plan_info_listener", context=h.context))

    def on_info(msg):
        with h.cond:
            infos.append(decode_plan_info(msg))
            h.cond.notify_all()

    listener.create_subscription(Float64MultiArray, "plan_info", on_info, RECORDER_QOS)
    rec = h.recorder()
    sim = TargetSimulator(context=h.context, parameter_overrides=_params(model_file=S3, seed=5))
    flt = BeliefFilter(context=h.context, parameter_overrides=_params(model_file=S3))
    planner = PlannerNode(context=h.context, parameter_overrides=_params(
        model_file=S3, time_budget=0.02, max_depth=2, use_bounds=use_bounds))
    h.start()  # the observers spin; the loop cannot advance before its nodes are added
    for pub, n in ((flt.belief_pub, 3), (planner.action_pub, 4), (planner.info_pub, 2), (sim.state_pub, 2),
                   (sim.obs_pubs[0], 2)):
        assert h.wait_matched(pub, n), f"{pub.topic_name}: subscribers not matched"
    for node in (sim, flt, planner):
        h.add(node)
    assert h.wait_until(lambda: _rows_written(recorder) >= ROWS, timeout=60), f"{_rows_written(recorder)} rows"
    h.executor.remove_node(recorder)
    h.nodes.remove(recorder)
    complete = _rows_written(recorder)  # written as the loop ran; at exit the waiting rows follow with what they have
    recorder.destroy_node()

    if suffix == "mcap":
        bag = read_run_bag(path)
        record = bag.record
        with h.cond:
            readings = {o[0]: (o[1], o[2]) for o in rec.observations["observation"]}
        assert bag.observations and all(readings[t] == r for t, r in bag.observations.items())
        # one writer to one reader delivers in order: no reading is missing below the newest kept; the
        # newest rows' readings may still have been in flight at exit (another reader than the rows')
        newest = max(bag.observations)
        assert set(bag.observations) >= {t for t in record.epoch.tolist() if 0 < t <= newest}
        assert newest >= record.epoch[complete // 2]
        assert set(bag.topics) == {"run_record", "belief", "action", "true_state", "observation", "plan_info"}
    else:
        record = read_run_record(path)
    assert (record.model, record.S, record.A, record.time_budget) == ("tracking_s3_info", 3, 3, 0.02)
    n = len(record.epoch)
    assert n >= ROWS and record.epoch.tolist() == list(range(n))  # matched before the loop ran: every epoch
    beliefs = rec.beliefs_by_epoch(3)
    with h.cond:
        actions, states, plan = dict(rec.actions), dict(rec.true_states), {int(i["epoch"]): i for i in infos}
    for k, t in enumerate(record.epoch.tolist()):
        np.testing.assert_array_equal(record.beliefs[k], beliefs[t])  # the same floats, read back
        assert record.action[k] == actions[t + 1]
        at_exit = k >= complete  # its true state or plan_info may still have been in flight
        assert record.true_state[k] == states[t] or (at_exit and record.true_state[k] == -1)
        if at_exit and record.depth[k] == -1:  # written without its plan_info: no bound, no certificate
            assert not record.has_bounds[k] and not record.certified[k]
            continue
        i = plan[t + 1]
        assert int(i["action_priority"]) == actions[t + 1]
        if math.isnan(i["bound_lower"]):
            assert record.lower[k] == record.upper[k] == 0  # empty: no bound the planner did not publish
        else:
            assert (record.lower[k], record.upper[k]) == (i["bound_lower"], i["bound_upper"])
        assert record.guaranteed[k] == record.has_bounds[k]  # the planner publishes only guaranteed bounds
        assert record.certified[k] == bool(i["certified"]) and record.depth[k] == i["depth"]
        assert record.latency[k] == i["latency"]
    if use_bounds:  # the S = 3 model passes the gate: the planner publishes guaranteed bounds
        assert record.has_bounds[:complete].all()
        assert np.all(record.certified[:complete] == (record.lower == record.upper)[:complete])
    else:
        assert not record.has_bounds.any() and not record.certified.any()
    assert cli_main(["plot", str(path), "-o", str(png), "--width", "6", "--height", "4", "--dpi", "50"]) == 0
    assert png_size(png) == (300, 200)


def test_bad_messages_are_counted_in_the_diagnostics(harness, tmp_path):
    h = harness
    recorder = h.add(RunRecorderNode(context=h.context, parameter_overrides=_params(
        model_file=S3, file=str(tmp_path / "run.csv"))))
    rec = h.recorder()
    pub = rec.create_publisher(Int64MultiArray, "true_state", STREAM_QOS)
    belief_pub = rec.create_publisher(Float64MultiArray, "belief", STREAM_QOS)
    h.start()
    assert h.wait_matched(pub, 2) and h.wait_matched(belief_pub, 2)
    pub.publish(encode_true_state(3, 7))  # no state 7 in an S = 3 model
    bad = Float64MultiArray()
    bad.data = [0.5, 0.5]
    belief_pub.publish(bad)

    def status():
        found = rec.diag_values("run_recorder: recording")
        return found[-1] if found and found[-1].get("malformed_messages") == "2" else None

    assert h.wait_until(lambda: status() is not None, timeout=10), rec.diag_values("run_recorder")
    st = status()
    assert st["file"] == str(tmp_path / "run.csv") and st["rows_written"] == "0"
    assert st["_level"] == DiagnosticStatus.WARN and "since the last report: 2 malformed messages" in st["_message"]
    assert recorder.loop.health.counts["malformed_messages"] == 2


class _FullDisk(io.RawIOBase):
    """The recorder's file, on a disk with ``room`` bytes left: a write beyond it is cut short, the
    next one fails with ENOSPC (what write(2) does on a full file system)."""

    def __init__(self, raw: io.FileIO, room: int):
        self.raw, self.room = raw, room

    def writable(self) -> bool:
        return True

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = self.raw.write(bytes(data)[:self.room])
        self.room -= n
        return n

    def truncate(self, size=None):
        return self.raw.truncate(size)

    def seek(self, pos, whence=0):
        return self.raw.seek(pos, whence)

    def close(self) -> None:
        self.raw.close()
        super().close()


def test_a_full_disk_is_one_error_and_leaves_the_file_ending_on_a_whole_row(harness, tmp_path):
    h = harness
    path = tmp_path / "run.csv"
    recorder = h.add(RunRecorderNode(context=h.context, parameter_overrides=_params(model_file=S3, file=str(path))))
    rec = h.recorder()
    h.start()
    head = path.stat().st_size
    recorder.writer.stream = _FullDisk(recorder.writer.stream, 45)  # room for a row and a half
    for t in range(4):
        recorder.inputs.call(recorder.loop.belief, BeliefSample(t, np.array([0.2, 0.3, 0.5])))
        recorder.inputs.call(recorder.loop.action, ActionSample(t + 1, 1))
        recorder.inputs.call(recorder.loop.plan_info, {
            "epoch": t + 1, "action_priority": 1, "depth": 1, "nodes_expanded": 1, "pruned_percent": 0.0,
            "certified": 0, "time_used": 0.001, "latency": 0.002, "deadline_hit": 0, "deadline_miss": 0,
            "bound_lower": math.nan, "bound_upper": math.nan})
    assert recorder.writer is None and recorder.last_row is not None
    assert recorder.write_error == (f"file: cannot write {path}: No space left on device; recording stopped (the "
                                    f"file ends on the row of epoch {recorder.last_row})")
    data = path.read_bytes()
    assert head < len(data) <= head + 45 and data.endswith(b"\n")
    assert read_run_record(path).epoch.tolist() == list(range(recorder.last_row + 1))

    def error():
        found = rec.diag_values("run_recorder: recording")
        return found[-1] if found and found[-1]["_level"] == DiagnosticStatus.ERROR else None

    assert h.wait_until(lambda: error() is not None, timeout=10)
    assert error()["_message"].startswith(recorder.write_error)


def test_a_second_writer_and_an_oversized_sample_are_dropped_before_they_reach_the_record(harness, tmp_path):
    """The recorder follows one writer per topic: a stranger's action for an epoch the established
    writer has answered is foreign (not a conflict), named in the diagnostics; a belief of 10^6
    values is dropped unread (``oversized_samples``), not decoded (no malformed message)."""
    import array

    h = harness
    recorder = h.add(RunRecorderNode(context=h.context, parameter_overrides=_params(
        model_file=S3, file=str(tmp_path / "run.csv"))))
    rec = h.recorder()
    planner = h.add(Node("planner_like", context=h.context))
    stranger = h.add(Node("stranger", context=h.context))
    own, forged = (n.create_publisher(Int64MultiArray, "action", STREAM_QOS) for n in (planner, stranger))
    belief_pub = stranger.create_publisher(Float64MultiArray, "belief", STREAM_QOS)
    h.start()
    assert all(h.wait_matched(p, 2) for p in (own, forged, belief_pub))
    own.publish(encode_action(1, 1))
    watch = recorder.loop.health.writers["action"]
    assert h.wait_until(lambda: watch.established is not None, timeout=10)
    forged.publish(encode_action(1, 3))  # a different decision for the same epoch
    big = Float64MultiArray()
    big.data = array.array("d", bytes(8 * 10**6))
    belief_pub.publish(big)

    def status():
        found = rec.diag_values("run_recorder: recording")
        return next((st for st in reversed(found) if st.get("foreign_samples") == "1"
                     and st.get("oversized_samples") == "1"), None)

    assert h.wait_until(lambda: status() is not None, timeout=15), rec.diag_values("run_recorder")[-1:]
    st = status()
    assert st["input.action.writer"].startswith("/planner_like [") and st["input.action.foreign_samples"] == "1"
    assert st["conflicts"] == "0" and st["malformed_messages"] == "0"
    assert st["_level"] == DiagnosticStatus.WARN and "/stranger" in st["_message"]


def _env() -> dict[str, str]:
    return {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF", "PYTHONUNBUFFERED": "1"}


@pytest.mark.parametrize(("file", "expected"), [
    (None, "file: must name the CSV file to write, e.g. -p file:=run.csv"),
    ("no_such_folder/run.csv", "file: cannot write no_such_folder/run.csv: the folder no_such_folder does not exist"),
    (".", "file: cannot write .: it is a directory, not a regular file"),
])
def test_a_file_it_cannot_write_is_one_fatal_line(tmp_path, file, expected):
    args = [] if file is None else ["-p", f"file:={file}"]
    proc = subprocess.run([*node_command("run_recorder"), "--ros-args", "-p", f"model_file:={S3}", *args],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path, env=_env(),
                          preexec_fn=die_with_test)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr[-3000:]
    assert lines[0].startswith("[FATAL] [run_recorder]: " + expected), lines[0]
    assert proc.stdout == "" and "Traceback" not in proc.stderr


def test_sigint_ends_it_cleanly_with_the_record_readable_so_far(tmp_path):
    log = tmp_path / "recorder.log"
    with open(log, "wb") as fh:
        proc = subprocess.Popen([*node_command("run_recorder"), "--ros-args", "-p", f"model_file:={S3}",
                                 "-p", "file:=run.csv"], cwd=tmp_path, env=_env(), stdout=fh, stderr=subprocess.STDOUT,
                                preexec_fn=die_with_test)
    try:
        deadline = time.monotonic() + 60
        while "recording tracking_s3_info" not in log.read_text(errors="replace") and time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text(errors="replace")
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text(errors="replace")
    assert "Traceback" not in text
    assert (tmp_path / "run.csv").read_text().splitlines() == [
        "# pomdp_planner run record 1; model=tracking_s3_info; S=3; A=3; time_budget=none",
        "epoch,true_state,b0,b1,b2,action,lower,upper,guaranteed,depth,certified,latency"]
