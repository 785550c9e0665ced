"""Start-up parameters of every node: a refused value is one ``[FATAL]`` line and exit code 1 (real
processes, as ``ros2 run`` starts them); a parameter a node does not declare is reported (a WARN with
the closest declared name, the diagnostics' ``unknown_parameters``; ``strict_parameters`` refuses)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import REPO, S3, die_with_test, make_harness, rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from pomdp_planner.core.options import MAX_DEPTH_RANGE, TIME_BUDGET_RANGE
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.params import check_given_parameters, deferred_start
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.processes import node_command, stop_nodes
from pomdp_planner.nodes.runtime import NodeConfigError
from pomdp_planner.nodes.target_simulator import TargetSimulator

harness = pytest.fixture(make_harness)
CLOSED_LOOP_S3 = str(REPO / "config" / "closed_loop_s3.yaml")
TB = f"{TIME_BUDGET_RANGE[0]:g}..{TIME_BUDGET_RANGE[1]:g}"
DEPTH = f"{MAX_DEPTH_RANGE[0]}..{MAX_DEPTH_RANGE[1]}"


def _env() -> dict[str, str]:
    return {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF", "PYTHONUNBUFFERED": "1"}


def _params_file(tmp_path: Path, content) -> list[str]:
    """``--params-file`` arguments for ``content``: None (none), raw text, or {node: {name: value}}."""
    if content is None:
        return []
    path = tmp_path / "params.yaml"
    text = content if isinstance(content, str) else yaml.safe_dump(
        {node: {"ros__parameters": values} for node, values in content.items()})
    path.write_text(text)
    return ["--params-file", str(path)]


# (executable, ROS arguments, parameter file, the [FATAL] line's node, what the line must contain)
BAD_STARTUP = [
    ("planner", ["-p", "time_budget:=100"], None, "planner", f"time_budget: must be a number in {TB}, got 100.0"),
    ("planner", [], {"planner": {"max_depth": 0}}, "planner", f"max_depth: must be an integer in {DEPTH}, got 0"),
    ("planner", [], {"planner": {"time_budget": "fast"}}, "planner",
     f"time_budget: must be a number in {TB}, got 'fast'"),
    ("planner", ["-p", "max_depth:=abc"], None, "planner", f"max_depth: must be an integer in {DEPTH}, got 'abc'"),
    ("planner", ["-p", "bound_variant:=5"], None, "planner", "bound_variant: must be a string (one of "),
    ("planner", ["-p", "bound_constant:=paper"], None, "planner",
     "bound_constant: expected one of mlr, fosd, got 'paper'"),
    ("planner", ["-p", "use_sim_time:=abc"], None, "planner", "use_sim_time: must be true or false, got 'abc'"),
    ("planner", ["-p", "strict_parameters:=true", "-p", "time_budgett:=0.2"], None, "planner",
     "time_budgett (did you mean time_budget?): not a parameter of this node; refused because strict_parameters"),
    ("target_simulator", ["-p", "seed:=-3"], None, "target_simulator",
     "seed: must be an integer in 0..2147483647, got -3"),
    ("target_simulator", [], {"target_simulator": {"step_period": "fast"}}, "target_simulator",
     "step_period: must be a number in 0..3600, got 'fast'"),
    ("target_simulator", ["-p", "initial_state:=7"], None, "target_simulator",
     "initial_state: must be an integer in -1..2, got 7"),
    ("belief_filter", ["-p", "epoch_timeout:=0"], None, "belief_filter", "epoch_timeout: must be a number in "),
    ("belief_filter", [], {"belief_filter": {"max_pending_epochs": 2.5}}, "belief_filter",
     "max_pending_epochs: must be an integer in 1..10000, got 2.5"),
    ("closed_loop", ["--params-file", CLOSED_LOOP_S3, "-p", "planner:max_depth:=0"], None, "planner",
     f"max_depth: must be an integer in {DEPTH}, got 0"),
    ("closed_loop", ["--params-file", CLOSED_LOOP_S3, "-p", "seed:=abc"], None, "target_simulator",
     "seed: must be an integer in 0..2147483647, got 'abc'"),
    # what rcl refuses on the command line itself
    ("planner", [], 'planner:\n  ros__parameters:\n    max_depth: [1, "a"]\n', "pomdp_planner",
     "params.yaml, line 3 'max_depth: [1, \"a\"]': "),
    ("planner", [], "planner:\n  ros__parameters:\n    max_depth: [1\n", "pomdp_planner",
     "params.yaml, line 4: not YAML"),
    ("belief_filter", ["--params-file", "no_such_file.yaml"], None, "pomdp_planner",
     "--params-file no_such_file.yaml: cannot be read"),
    ("target_simulator", ["-p", "seed"], None, "pomdp_planner", "-p seed: must be name:=value"),
]


@pytest.fixture(scope="module")
def bad_startup_runs(tmp_path_factory) -> list[subprocess.CompletedProcess]:
    """Every case of :data:`BAD_STARTUP` run as a process (a few at a time: each is mostly start-up)."""
    def run(case):
        exe, args, params, _, _ = case
        cwd = tmp_path_factory.mktemp(exe)
        cmd = [*node_command(exe), "--ros-args", *args, *_params_file(cwd, params)]
        try:
            return subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=cwd, env=_env(),
                                  preexec_fn=die_with_test)
        except subprocess.TimeoutExpired as exc:  # still running: a failure of its case only
            text = (exc.stderr or b"").decode(errors="replace") if isinstance(exc.stderr, bytes) else exc.stderr or ""
            return subprocess.CompletedProcess(cmd, None, "", text + "\n(still running after 60 s)")

    with ThreadPoolExecutor(max_workers=4) as pool:
        return list(pool.map(run, BAD_STARTUP))


@pytest.mark.parametrize("case", range(len(BAD_STARTUP)),
                         ids=[f"{c[0]}-{c[4].split(':')[0]}" for c in BAD_STARTUP])
def test_a_refused_startup_parameter_is_one_fatal_line(bad_startup_runs, case):
    """Exit code 1 and exactly one line on stderr, ``[FATAL] [<node>]: <parameter>: ...`` naming the
    value and what is allowed; no traceback, nothing on stdout."""
    _, _, _, node, expected = BAD_STARTUP[case]
    proc = bad_startup_runs[case]
    lines = proc.stderr.splitlines()
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert len(lines) == 1, proc.stderr[-3000:]
    assert lines[0].startswith(f"[FATAL] [{node}]: "), lines[0]
    assert expected in lines[0], lines[0]
    assert "Traceback" not in proc.stderr and proc.stdout == ""


def _wait_for(path: Path, text: str, proc, timeout: float = 60.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        log = path.read_text(errors="replace")
        if text in log:
            return log
        time.sleep(0.05)
    return path.read_text(errors="replace")


def test_an_undeclared_parameter_is_a_warning_naming_the_closest_name(tmp_path):
    """A typo in the node's own section is reported once with the closest declared name, the node
    runs on; a wildcard section's parameters meant for other nodes (``seed``, the simulator's), a
    parameter no node has and that is no near miss, and rclpy's ``qos_overrides`` are not reported."""
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"seed": 4, "frobnicate": 1}},
                                      "planner": {"ros__parameters": {"time_budgett": 0.2}}}))
    log = tmp_path / "planner.log"
    with open(log, "wb") as fh:
        proc = subprocess.Popen([*node_command("planner"), "--ros-args", "--params-file", str(params),
                                 "-p", "qos_overrides./belief.subscription.depth:=5"],
                                stdout=fh, stderr=subprocess.STDOUT, cwd=tmp_path, env=_env(), preexec_fn=die_with_test)
    try:
        text = _wait_for(log, "time_budgett", proc)
        running = proc.poll() is None
    finally:
        codes = stop_nodes({"planner": (proc, log)})
    text = log.read_text(errors="replace")
    assert running, text
    warnings = [line for line in text.splitlines() if line.startswith("[WARN]") and "health WARN" not in line]
    assert len(warnings) == 1, text
    assert "parameter time_budgett is not a parameter of this node and is ignored; did you mean time_budget?" \
        in warnings[0]
    assert text.index("time_budgett") < text.index("configured in")  # reported before the managed node configures
    assert codes["planner"] == 0 and "Traceback" not in text


# ----------------------------------------------------------------- in-process


@pytest.fixture
def context_with_args():
    """An rclpy context initialised with global arguments (as a process's command line)."""
    contexts = []

    def make(args):
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"
        ctx = Context()
        rclpy.init(args=args, context=ctx)
        contexts.append((ctx, []))
        return ctx, contexts[-1][1]

    yield make
    for ctx, nodes in contexts:
        for n in nodes:
            n.destroy_node()
        ctx.try_shutdown()


def test_a_parameter_given_to_every_node_of_a_process_is_reported_once(context_with_args):
    """``closed_loop -p max_dept:=3 -p zzz:=1 -p time_budget:=0.05``: each given to all three nodes;
    ``time_budget`` is the planner's (no report), ``max_dept`` is reported once, by the planner (the
    closest name), ``zzz`` once (by the first node: no name is close)."""
    args = ["closed_loop", "--ros-args", "-p", f"model_file:={S3}", "-p", "max_dept:=3", "-p", "zzz:=1",
            "-p", "time_budget:=0.05"]
    ctx, nodes = context_with_args(args)
    nodes += [TargetSimulator(context=ctx), BeliefFilter(context=ctx), PlannerNode(context=ctx)]
    check_given_parameters(nodes, args)
    sim, flt, planner = nodes
    assert planner.unknown_parameters == {"max_dept": "max_depth"}
    assert sim.unknown_parameters == {"zzz": ""} and flt.unknown_parameters == {}


def test_wildcard_parameters_are_reported_only_as_near_misses(harness, tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "model_file": S3, "time_budgett": 0.2, "seed": 3, "frobnicate": 1,
        "qos_overrides": {"/belief": {"subscription": {"depth": 5}}}}}}))
    cli = ["--ros-args", "--params-file", str(params)]
    planner = harness.add(PlannerNode(context=harness.context, cli_args=cli))
    sim = harness.add(TargetSimulator(context=harness.context, cli_args=cli))
    check_given_parameters([planner])
    check_given_parameters([sim])
    assert planner.unknown_parameters == {"time_budgett": "time_budget"}
    assert sim.unknown_parameters == {}


def test_strict_parameters_refuses_to_start(harness):
    planner = harness.add(PlannerNode(context=harness.context, parameter_overrides=[
        Parameter("model_file", value=S3), Parameter("strict_parameters", value=True),
        Parameter("max_dpeth", value=2), Parameter("colour", value="red")]))
    assert planner.describe_parameter("strict_parameters").read_only
    with pytest.raises(NodeConfigError, match=r"^max_dpeth \(did you mean max_depth\?\), colour: not parameters of "
                                              r"this node; refused because strict_parameters is true$") as err:
        check_given_parameters([planner])
    assert err.value.node == "planner"


def test_unknown_parameters_appear_in_the_diagnostics(harness):
    h = harness
    planner = h.add(PlannerNode(context=h.context, parameter_overrides=[
        Parameter("model_file", value=S3), Parameter("time_budgett", value=0.2)]))
    flt = h.add(BeliefFilter(context=h.context, parameter_overrides=[Parameter("model_file", value=S3)]))
    check_given_parameters([planner, flt])
    rec = h.recorder()
    h.start()
    assert h.wait_until(lambda: rec.diag_values("planner") and rec.diag_values("belief_filter"), timeout=15)
    assert rec.diag_values("planner")[-1]["unknown_parameters"] == "time_budgett (did you mean time_budget?)"
    assert rec.diag_values("belief_filter")[-1]["unknown_parameters"] == "none"


def test_a_node_built_for_a_process_starts_only_once_its_parameters_are_checked(harness):
    """Under ``deferred_start`` (as ``run_nodes`` builds a process's nodes) a managed node does not
    configure as it is made: ``strict_parameters`` refuses before any configure runs, and
    :meth:`start` then walks the autostart."""
    overrides = [Parameter("model_file", value=S3), Parameter("strict_parameters", value=True)]
    with deferred_start():
        strict = harness.add(PlannerNode(context=harness.context, parameter_overrides=[
            *overrides, Parameter("max_dpeth", value=2)]))
        fine = harness.add(BeliefFilter(context=harness.context, parameter_overrides=overrides))
    assert strict.lifecycle_state == fine.lifecycle_state == "unconfigured"
    assert strict.loop is None and strict.model is None
    with pytest.raises(NodeConfigError, match=r"^max_dpeth \(did you mean max_depth\?\): not a parameter"):
        check_given_parameters([strict, fine])
    assert strict.lifecycle_state == "unconfigured" and strict.model is None  # no configure ran
    fine.start()
    assert fine.lifecycle_state == "active" and fine.loop is not None


def test_a_refused_declaration_is_a_node_config_error_in_process(harness):
    """The same one line for a node built in-process (``parameter_overrides``), naming the node."""
    with pytest.raises(NodeConfigError, match=rf"^max_depth: must be an integer in {DEPTH}, got 0$") as err:
        PlannerNode(context=harness.context, parameter_overrides=[Parameter("model_file", value=S3),
                                                                  Parameter("max_depth", value=0)])
    assert err.value.node == "planner"


HOLD_SCRIPT = """
import os, sys, time
from pomdp_planner.nodes.runtime import _HeldStderr
held = _HeldStderr(limit={limit})
os.write(2, b"held line\\n")
sys.stderr.write("python line\\n")
{then}
print("done", flush=True)
time.sleep({sleep})
"""


@pytest.mark.parametrize(("then", "limit", "shown"), [
    ("held.release()", 60, True), ("held.release(keep=False)", 60, False), ("pass", 0.1, True)])
def test_start_up_output_is_held_then_shown_or_dropped(then, limit, shown):
    """What start-up writes to stderr (C and Python alike) is shown on release, dropped on a refusal,
    and shown anyway once the hold's time limit has passed (a long start is not silent)."""
    script = HOLD_SCRIPT.format(limit=limit, then=then, sleep=30 if then == "pass" else 0)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env())
    try:
        assert proc.stdout.readline() == "done\n"
        if then == "pass":  # the child still sleeps: its held lines must come by themselves
            assert proc.stderr.readline() == "held line\n" and proc.stderr.readline() == "python line\n"
            return
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    assert err == ("held line\npython line\n" if shown else "")
