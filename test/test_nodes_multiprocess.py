"""The node executables as separate processes (as ``ros2 run`` starts them), observed from the test.

Processes talk on localhost only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) in a ROS domain
picked for this test; SIGINT (and SIGTERM) must end each with exit code 0 and no traceback.
"""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import REPO, Recorder, die_with_test, rclpy, remove_dead_shm, shm_entries, stop_after_kills
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from pomdp_planner.core.belief import update
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.io.run_bag import read_run_bag
from pomdp_planner.core.io.run_record import read_run_record
from pomdp_planner.core.simulate import simulate
from pomdp_planner.nodes.processes import node_command, parameter_set_model, parameter_set_values, stop_nodes

S3_MODEL = load_model(REPO / "config" / "models" / "tracking_s3_info.yaml")


@pytest.fixture
def domain(monkeypatch):
    """A ROS domain for this test (localhost only), set in this process before rclpy.init."""
    domain_id = random.Random(os.getpid() + time.time_ns()).randint(1, 101)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id))
    monkeypatch.setenv("ROS_PYTHON_CHECK_FIELDS", "1")
    return domain_id


def _log(path: Path, handles: list):
    fh = open(path, "wb")  # closed in the test's finally
    handles.append(fh)
    return fh


def _spin_until(executor, predicate, timeout):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)  # returns as soon as a message arrives
    return True


def _observer() -> tuple[Context, Recorder, SingleThreadedExecutor, set[str]]:
    """The test's own context, a recorder on it and its executor (spun by ``_spin_until``), and
    the shared-memory segments that existed before (a killed process leaves some behind)."""
    shm_before = shm_entries()
    ctx = Context()
    rclpy.init(context=ctx)
    rec = Recorder(ctx, threading.Condition())
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(rec)
    return ctx, rec, executor, shm_before


def test_three_processes_closed_loop_and_clean_sigint(domain, tmp_path):
    ctx, rec, executor, shm_before = _observer()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    common = ["-p", f"model_file:={REPO / 'config' / 'models' / 'tracking_s3_info.yaml'}"]
    args = {
        "target_simulator": [*common, "-p", "seed:=5"],
        "belief_filter": common,
        "planner": [*common, "-p", "time_budget:=0.02", "-p", "max_depth:=2"],
    }
    procs, logs, handles = {}, {}, []
    killed = False
    try:
        for name in ("target_simulator", "belief_filter"):
            logs[name] = tmp_path / f"{name}.err"
            procs[name] = (subprocess.Popen([*node_command(name), "--ros-args", *args[name]], env=env,
                                            stdout=subprocess.DEVNULL, stderr=_log(logs[name], handles),
                                            preexec_fn=die_with_test), logs[name])
        # start the planner only once the test sees the prior and the initial state: no epoch is missed
        assert _spin_until(executor, lambda: rec.beliefs and rec.true_states, 30), "no prior / initial state"
        logs["planner"] = tmp_path / "planner.err"
        procs["planner"] = (subprocess.Popen([*node_command("planner"), "--ros-args", *args["planner"]], env=env,
                                             stdout=subprocess.DEVNULL, stderr=_log(logs["planner"], handles),
                                             preexec_fn=die_with_test),
                            logs["planner"])
        # discovery between this process and the planner may take a while (the loop may run ahead)
        assert _spin_until(executor, lambda: len(rec.actions) >= 20 and len(rec.belief_epochs(S3_MODEL.S)) > 30,
                           60), (
            f"loop did not run: {len(rec.beliefs)} beliefs; " + logs["planner"].read_text(errors="replace")[-2000:])
        for name, (p, _) in procs.items():
            assert p.poll() is None, f"{name} exited early with {p.returncode}"
        # SIGTERM (as a service manager would stop it) must be as clean as Ctrl-C
        sim = procs["target_simulator"][0]
        sim.send_signal(signal.SIGTERM)
        sim.wait(timeout=15.0)
    finally:
        codes = stop_nodes(procs, timeout=15.0)
        killed = any(c != 0 for c in codes.values())
        executor.shutdown(timeout_sec=1.0)
        rec.destroy_node()
        ctx.try_shutdown()
        for fh in handles:
            fh.close()
        if killed:  # only a killed process leaves segments behind
            remove_dead_shm(shm_before)

    for name, code in codes.items():
        err = logs[name].read_text(errors="replace")
        assert code == 0, f"{name}: exit code {code}\n{err[-2000:]}"
        assert "Traceback" not in err, f"{name}: traceback on SIGINT\n{err[-2000:]}"

    # the closed loop as observed from outside: epochs in order, beliefs = core replay of the
    # observations with the actions they carry, and those are the planner's actions (the action
    # topic is latched with depth 1: the test may have missed the first ones before discovery)
    beliefs = {b.epoch: b.belief for b in rec.decoded_beliefs(S3_MODEL.S)}
    actions = dict(rec.actions)
    obs = {t: (p, z) for t, p, z in rec.observations["observation"]}
    n = max(beliefs)
    assert set(range(n + 1)) <= set(beliefs) and set(range(1, n + 1)) <= set(obs)
    assert n >= 30
    assert len(actions) >= 20
    b = np.full(S3_MODEL.S, 1.0 / S3_MODEL.S)
    for t in range(1, n + 1):
        if t in actions:
            assert obs[t][0] == actions[t], f"epoch {t}: observation under {obs[t][0]}, action {actions[t]}"
        b = update(S3_MODEL, b, obs[t][0] - 1, obs[t][1])
        np.testing.assert_allclose(beliefs[t], b, rtol=1e-9, atol=1e-12)


#: A row of the demo's table; bounds, depth, certified and latency are ``-`` for a decision whose
#: plan_info the monitor missed (it discovered the planner late).
ROW = re.compile(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+(\d+)\s+(?:\[(\d+), (\d+)\]|-)\s+(\d+)"
                 r"\s+(\d+|-)\s+(yes|no|-)\s+([\d.]+|-)$")


@pytest.mark.parametrize(("model", "keep"), [("s3", True), ("perimeter_s8", False)])
def test_demo_runs_and_exits_cleanly(domain, tmp_path, model, keep):
    """``make demo`` in small: three processes, a legend, the table (with the root bound interval
    beside the planner's action and the greedy action), the summary with the planner's discounted
    return beside greedy's, exit code 0; on the paper's S = 3 model and on the perimeter model of
    the README's node-loop example (its own parameter files, ``config/<node>_perimeter_s8.yaml``).
    The node logs' temporary directory is removed, unless ``--keep-logs`` (then it holds the three
    logs and the run record ``run.csv``, and the last line says where); ``--record FILE`` writes the
    record there instead (here a rosbag2 bag, ``run.mcap``, with the loop's readings). The record
    holds the table's rows (epoch, true state, action, bounds, certified, the belief's mode), as the
    run-record reader reads them."""
    steps = 5
    record = None if keep else tmp_path / "run.mcap"  # with --keep-logs: run.csv in the logs' directory; else a bag
    proc = subprocess.run([sys.executable, "-m", "pomdp_planner.nodes.demo", "--steps", str(steps), "--model", model,
                           "--time-budget", "0.02", "--domain-id", str(domain), *(["--keep-logs"] if keep else []),
                           *([] if record is None else ["--record", str(record)])],
                          capture_output=True, text=True, timeout=90, cwd=REPO,
                          env={**os.environ, "TMPDIR": str(tmp_path)}, preexec_fn=die_with_test)
    logs = "".join(f"\n--- {log.name}\n{log.read_text(errors='replace')[-3000:]}"
                   for log in sorted(tmp_path.glob("pomdp_planner_demo_*/*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    lines = proc.stdout.splitlines()
    m = load_model(parameter_set_model(model))
    assert lines[0].startswith(f"pomdp_planner demo: {m.name}: S=")
    assert lines[1].startswith(f"legend: action, bounds, greedy: priorities 1..{m.A}")
    assert any("certified yes: the bounds agree" in line for line in lines[1:6])
    header = next(i for i, line in enumerate(lines) if line.split()[:2] == ["step", "true"])
    assert lines[header].split()[5:8] == ["action", "bounds", "greedy"]
    body = [line for line in lines[header + 2:] if not line.startswith("(the monitor matched the nodes late")]
    rows = [ROW.match(line) for line in body[:steps]]
    assert all(rows), body[:steps]
    rows = [r.groups() for r in rows]
    first = int(rows[0][0])  # 0 unless the monitor matched the nodes late (then it says so)
    assert [int(r[0]) for r in rows] == list(range(first, first + steps))
    certified = decisions = 0
    for r in rows:
        action, greedy = int(r[5]), int(r[8])
        assert 1 <= action <= m.A and 1 <= greedy <= m.A
        if r[10] != "-":
            lower, upper = int(r[6]), int(r[7])
            assert 1 <= lower <= action <= upper <= m.A  # B&B picks among the priorities the bounds leave
            assert (r[10] == "yes") == (lower == upper)  # certified exactly when they agree (guaranteed bounds)
            certified += r[10] == "yes"
            decisions += 1
    assert decisions >= 1
    assert f"summary over {steps} steps: mean reward" in proc.stdout and "other than greedy's on" in proc.stdout
    assert f"certified {certified} of {decisions} decisions shown" in proc.stdout
    # greedy's discounted return: the core's simulation from the simulator's seed, computed here again
    seed = parameter_set_values(model, "target_simulator")["seed"]
    greedy_return = simulate(m, "myopic", steps, seed=seed).discounted_return
    line = next(line for line in lines if line.startswith(f"discounted return over {steps} steps"))
    assert f"from seed {seed}" in line and line.endswith(f", greedy {greedy_return:.4f}"), line
    assert re.search(r"planner -?\d+\.\d{4}, greedy", line)
    left = list(tmp_path.glob("pomdp_planner_demo_*"))
    if keep:
        assert len(left) == 1 and lines[-1] == f"node logs kept in {left[0]}"
        assert sorted(p.name for p in left[0].iterdir()) == ["belief_filter.log", "planner.log", "run.csv",
                                                              "target_simulator.log"]
        record = left[0] / "run.csv"
    else:
        assert left == [] and "node logs" not in proc.stdout
    # the run record: the table's rows, as pomdp-planner plot reads them
    assert f"run record ({steps} rows) in {record}; draw it with: pomdp-planner plot {record} -o run.png" in lines
    if record.suffix == ".mcap":  # a rosbag2 bag: the same rows, and the loop's readings as they came
        bag = read_run_bag(record)
        rec = bag.record
        assert bag.observations and all(1 <= p <= m.A and 0 <= z < m.Z for p, z in bag.observations.values())
    else:
        rec = read_run_record(record)
    assert (rec.model, rec.S, rec.A, rec.time_budget) == (m.name, m.S, m.A, 0.02)
    assert rec.epoch.tolist() == [int(r[0]) for r in rows] and rec.true_state.tolist() == [int(r[1]) for r in rows]
    assert rec.action.tolist() == [int(r[5]) for r in rows]
    assert [(lo, up) if lo else None for lo, up in zip(rec.lower.tolist(), rec.upper.tolist(), strict=True)] == \
        [(int(r[6]), int(r[7])) if r[6] else None for r in rows]
    assert rec.certified.tolist() == [r[10] == "yes" for r in rows]
    assert [int(b.argmax()) for b in rec.beliefs] == [int(r[2]) for r in rows]
    assert "Traceback" not in proc.stderr


def test_closed_loop_entry_point_one_process(domain, tmp_path):
    """``closed_loop``: the three nodes in one process, with the shipped combined parameter file."""
    ctx = Context()
    rclpy.init(context=ctx)
    rec = Recorder(ctx, threading.Condition())
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(rec)
    err = tmp_path / "closed_loop.err"
    with open(err, "wb") as fh:
        proc = subprocess.Popen([*node_command("closed_loop"), "--ros-args", "--params-file",
                                 str(REPO / "config" / "closed_loop_s3.yaml"), "-p", "planner:time_budget:=0.02"],
                                env=dict(os.environ), stdout=subprocess.DEVNULL, stderr=fh, preexec_fn=die_with_test)
        try:
            ok = _spin_until(executor, lambda: len(rec.beliefs) >= 10 and rec.diag_values("planner"), 60)
        finally:
            codes = stop_nodes({"closed_loop": (proc, err)}, timeout=15.0)
            executor.shutdown(timeout_sec=1.0)
            rec.destroy_node()
            ctx.try_shutdown()
    text = err.read_text(errors="replace")
    assert ok, text[-2000:]
    assert codes["closed_loop"] == 0 and "Traceback" not in text, text[-2000:]
    epochs = rec.belief_epochs(S3_MODEL.S)
    assert epochs == sorted(epochs)


# ----------------------------------------------------------------- restarts

RESTART_PARAMS = {  # a small epoch window, so that a restarted filter joins after ~100 epochs already
    "target_simulator": ["-p", "seed:=5", "-p", "epoch_window:=50"],
    "belief_filter": ["-p", "epoch_window:=50"],
    "planner": ["-p", "time_budget:=0.02", "-p", "max_depth:=2", "-p", "epoch_window:=50"],
}
RESUMED_BY = 5  # epochs every output must advance past its pre-kill newest for "the loop resumed"
OUTPUT = {"target_simulator": "observation", "belief_filter": "belief", "planner": "action"}


def _newest(rec) -> dict[str, int]:
    """Newest epoch on each output of the loop (the last message; re-sends repeat it)."""
    with rec.cond:
        obs = rec.observations["observation"]
        return {"observation": obs[-1][0] if obs else -1, "action": rec.actions[-1][0] if rec.actions else -1,
                "belief": int(rec.beliefs[-1].layout.dim[1].label.split("=")[1]) if rec.beliefs else -1}


def _actions_sent(rec) -> dict[int, set[int]]:
    """The priorities the recorder saw on ``action`` for each epoch (a restarted planner may send two)."""
    sent: dict[int, set[int]] = {}
    with rec.cond:
        for t, p in rec.actions:
            sent.setdefault(t, set()).add(p)
    return sent


def _paired(rec) -> list[tuple[int, int]]:
    """(epoch, priority applied) of the recorded observations whose epoch the recorder also saw an action for."""
    sent = _actions_sent(rec)
    with rec.cond:
        observations = list(rec.observations["observation"])
    return [(t, p) for t, p, _ in observations if t in sent]


@pytest.mark.parametrize("mode", ["free", "timer"])
def test_kill_9_and_restart_each_node_one_at_a_time(domain, tmp_path, mode):
    """Restarts are a designed feature: each node in turn is killed (SIGKILL, no clean-up) and
    started again, the others keep running (same processes); the loop resumes: observations,
    beliefs and actions all advance past where they were. The restarted simulator continues the
    loop's numbering, the restarted filter says which belief it started from; in free-running
    mode every observation carries one of the actions the planner(s) sent for its epoch. The
    recovery times are printed (``-s``), not asserted."""
    ctx, rec, executor, shm_before = _observer()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    model = ["-p", f"model_file:={REPO / 'config' / 'models' / 'tracking_s3_info.yaml'}"]
    period = {"free": "0.0", "timer": "0.05"}[mode]
    args = {name: [*model, *extra] for name, extra in RESTART_PARAMS.items()}
    args["target_simulator"] += ["-p", f"step_period:={period}"]
    procs, handles, recovery = {}, [], {}

    def start(name, tag=""):
        log = tmp_path / f"{name}{tag}.err"
        procs[name] = (subprocess.Popen([*node_command(name), "--ros-args", *args[name]], env=env,
                                        stdout=subprocess.DEVNULL, stderr=_log(log, handles),
                                        preexec_fn=die_with_test), log)

    try:
        for name in ("belief_filter", "planner", "target_simulator"):
            start(name)
        # the recorder joins a loop that is already running (discovery takes 0.1-3.5 s here, the free-running loop
        # ~100 epochs/s, a late reader gets the last 100 samples of each topic): wait until it has recorded the
        # same 100+ epochs on both ``observation`` and ``action``, so that the pairing checked at the end has data
        need = (lambda: len(_paired(rec)) > 100) if mode == "free" else (lambda: True)
        assert _spin_until(executor, lambda: min(_newest(rec).values()) > 120 and need(), 90), \
            f"loop did not run: {_newest(rec)}, {len(_paired(rec))} epochs recorded on both observation and action"
        for name in ("target_simulator", "belief_filter", "planner"):
            others = {n: p for n, (p, _) in procs.items() if n != name}
            p = procs[name][0]
            p.kill()
            p.wait(timeout=10)
            t_kill = time.monotonic()
            start(name, ".restarted")
            # what the dead node published last: let the recorder drain it (its topic quiet for 0.5 s)
            topic = OUTPUT[name]
            last = {"value": _newest(rec)[topic], "since": time.monotonic()}

            def quiet(topic=topic, last=last):
                now = _newest(rec)[topic]
                if now != last["value"]:
                    last.update(value=now, since=time.monotonic())
                return time.monotonic() - last["since"] > 0.5
            assert _spin_until(executor, quiet, 30)
            before = _newest(rec)
            with rec.cond:
                first_new = len(rec.observations["observation"])
            ok = _spin_until(executor, lambda b=before: all(_newest(rec)[k] >= b[k] + RESUMED_BY for k in b), 90)
            recovery[name] = time.monotonic() - t_kill
            assert ok, f"{mode}: loop did not resume after restarting {name}: {before} -> {_newest(rec)}"
            assert all(q.poll() is None for q in others.values()), f"another node died while {name} restarted"
            if name == "target_simulator":  # it continued the loop's numbering: (almost) nothing re-simulated
                with rec.cond:
                    again = [t for t, _, _ in rec.observations["observation"][first_new:] if t <= before["observation"]]
                assert len(again) <= 2, f"the restarted simulator re-simulated epochs {again[:5]}..{again[-5:]}"
            if name == "belief_filter":  # says which belief it started from, in diagnostics (and log, below)
                assert _spin_until(executor, lambda: any("joined a running loop" in d.get("started_from", "")
                                                         for d in rec.diag_values("belief_filter")), 10)
        print(f"\n{mode}: seconds from kill -9 to the loop resumed ({RESUMED_BY} epochs on every output): "
              + ", ".join(f"{n} {t:.1f}" for n, t in recovery.items()))
    finally:
        codes = stop_after_kills(procs, executor, rec, ctx, handles, shm_before)
    for name, code in codes.items():
        err = procs[name][1].read_text(errors="replace")
        assert code == 0 and "Traceback" not in err, f"{name}: exit code {code}\n{err[-2000:]}"
    sim_log = (tmp_path / "target_simulator.restarted.err").read_text(errors="replace")
    assert "joined the loop at epoch" in sim_log and "joined the loop at epoch 0 " not in sim_log, sim_log[-2000:]
    filter_log = (tmp_path / "belief_filter.restarted.err").read_text(errors="replace")
    assert "joined a running loop at epoch" in filter_log, filter_log[-2000:]
    assert filter_log.count("lost (no reading)") <= 1, "the restarted filter walked the epochs it missed"
    if mode == "free":  # pairing: each observation carries an action the planner sent for its epoch
        sent, checked = _actions_sent(rec), _paired(rec)
        assert len(checked) > 100
        assert all(p in sent[t] for t, p in checked)
