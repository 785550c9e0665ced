"""The managed nodes as processes (as ``ros2 run`` starts them): a failing configure is one log line
and leaves the process alive and configurable (``autostart:=false``), and with ``autostart`` (the
default) a node that cannot configure still ends with one ``[FATAL]`` line and exit code 1."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import S3, LifecycleClient, die_with_test, rclpy, remove_dead_shm, shm_entries
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from test_nodes_multiprocess import domain  # noqa: F401 (a fixture)

from pomdp_planner.nodes.executor import NodeExecutor, shutdown_executor
from pomdp_planner.nodes.processes import node_command, stop_nodes

BAD = "no/such/model.yaml"


def rclpy_wait(future, timeout: float = 10.0) -> None:
    """Poll ``future`` (the executor spins in another thread)."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(timeout), "no answer"


def test_a_failing_configure_is_one_log_line_and_the_process_stays_configurable(domain, tmp_path):  # noqa: F811
    log = tmp_path / "planner.log"
    shm_before = shm_entries()
    with open(log, "wb") as fh:
        proc = subprocess.Popen([*node_command("planner"), "--ros-args", "-p", f"model_file:={BAD}",
                                 "-p", "autostart:=false"], stdout=fh, stderr=subprocess.STDOUT,
                                preexec_fn=die_with_test)
    procs = {"planner": (proc, log)}
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("lifecycle_test_client", context=ctx)
    executor = NodeExecutor(num_threads=2, context=ctx)
    executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()
    try:
        lc = LifecycleClient(node, "/planner")
        assert lc.wait_for_services(timeout=30.0), "no lifecycle services"
        assert lc.state() == "unconfigured"
        assert not lc.change("configure")
        assert lc.state() == "unconfigured" and proc.poll() is None  # alive, where it was
        params = AsyncParameterClient(node, "/planner")
        assert params.wait_for_services(timeout_sec=10.0)
        future = params.set_parameters([Parameter("model_file", value=S3)])
        rclpy_wait(future)
        assert future.result().results[0].successful
        assert lc.change("configure") and lc.change("activate") and lc.state() == "active"
    finally:
        codes = stop_nodes(procs, timeout=15.0)
        shutdown_executor(executor)
        node.destroy_node()
        ctx.try_shutdown()
        if codes.get("planner", 0) < 0:  # killed: only a killed process leaves segments behind
            remove_dead_shm(shm_before)
    text = log.read_text(errors="replace")
    assert codes["planner"] == 0 and "Traceback" not in text, text[-2000:]
    failed = [line for line in text.splitlines() if "configure failed" in line and "health ERROR" not in line]
    assert len(failed) == 1 and "[ERROR]" in failed[0], text[-2000:]
    # (a diagnostics report while it was unconfigured logs the change to ERROR as well: "health ERROR: ...")
    assert failed[0].split("[planner]: ", 1)[1].startswith(
        f"configure failed, still unconfigured: model_file: '{BAD}' not found (looked in ")
    assert "configured in" in text and "activated: planning the next belief" in text


@pytest.mark.parametrize("name", ["planner", "belief_filter"])
def test_with_autostart_a_node_that_cannot_configure_prints_one_fatal_line_and_exits_1(domain, name):  # noqa: F811
    res = subprocess.run([*node_command(name), "--ros-args", "-p", f"model_file:={BAD}"], capture_output=True,
                         text=True, timeout=120, preexec_fn=die_with_test)
    lines = [line for line in (res.stdout + res.stderr).splitlines() if line.strip()]
    assert res.returncode == 1, lines
    assert len(lines) == 1 and lines[0].startswith(f"[FATAL] [{name}]: model_file: '{BAD}' not found"), lines
