"""The harness's hold on the node processes it starts (``nodes_support``): they end with the test
process however it ends, and cleaning up after SIGKILL removes the dead node's shared memory only."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import S3, SHM, die_with_test, owner_dead, remove_dead_shm, shm_entries, shm_mapped

from pomdp_planner.nodes.processes import node_command

pytestmark = pytest.mark.skipif(sys.platform != "linux" or not SHM.is_dir(), reason="Linux only (prctl, /dev/shm)")


def _env() -> dict[str, str]:
    domain = random.Random(os.getpid() + time.time_ns()).randint(1, 101)
    return dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1")


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie awaiting its reaper counts as ended)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def _wait(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


#: A stand-in for a test process: starts a planner with ``die_with_test``, says its pid, then waits.
STAND_IN = textwrap.dedent("""
    import subprocess, sys, time
    sys.path.insert(0, sys.argv[1])
    from nodes_support import die_with_test
    node = subprocess.Popen(sys.argv[3:], stdout=subprocess.DEVNULL, stderr=open(sys.argv[2], "wb"),
                            preexec_fn=die_with_test)
    print(node.pid, flush=True)
    time.sleep(600)
""")


def test_a_node_process_ends_when_the_test_process_is_killed(tmp_path):
    """SIGKILL to the test process (a stand-in here) ends the node it started: no orphan is left
    talking in the test's ROS domain, and the node exits the way Ctrl-C ends it (no traceback)."""
    log = tmp_path / "planner.err"
    test = subprocess.Popen([sys.executable, "-c", STAND_IN, str(Path(__file__).parent), str(log),
                             *node_command("planner"), "--ros-args", "-p", f"model_file:={S3}"],
                            env=_env(), stdout=subprocess.PIPE, text=True, preexec_fn=die_with_test)
    node = int(test.stdout.readline())
    try:
        assert _wait(lambda: "[planner]" in log.read_text(errors="replace"), 60), log.read_text(errors="replace")
        test.kill()
        test.wait()
        assert _wait(lambda: not _alive(node), 30), f"node {node} outlived the killed test process"
    finally:
        if _alive(node):
            os.kill(node, signal.SIGKILL)
    assert "Traceback" not in log.read_text(errors="replace")


def test_cleaning_up_removes_what_killed_nodes_left_and_nothing_in_use(tmp_path):
    """``remove_dead_shm`` after SIGKILL: nothing of live nodes goes; a killed node's ports stay
    while a live node still has them mapped (a node restarted with the same participant id takes
    those ports again: unlinked, it would never receive what the live node writes into them);
    once every node is dead, everything they left goes."""
    before = shm_entries()
    env = _env()
    procs, logs = {}, {}
    for name in ("belief_filter", "planner"):
        logs[name] = tmp_path / f"{name}.err"
        with open(logs[name], "wb") as fh:
            procs[name] = subprocess.Popen([*node_command(name), "--ros-args", "-p", f"model_file:={S3}"], env=env,
                                           stdout=subprocess.DEVNULL, stderr=fh, preexec_fn=die_with_test)
    planner, filt = procs["planner"], procs["belief_filter"]

    def new(proc):
        return shm_mapped(proc.pid) & (shm_entries() - before)

    try:  # matched: each has mapped the other's segment
        assert _wait(lambda: len([n for n in new(planner) & new(filt) if "port" not in n]) >= 2, 60), \
            "".join(log.read_text(errors="replace") for log in logs.values())
        planner_files, filter_files = new(planner), new(filt)
        assert not (planner_files | filter_files) & set(remove_dead_shm(before))  # both alive: nothing goes
        planner.kill()
        planner.wait()
        dead_ports = {n for n in filter_files if n.startswith("fastrtps_port") and owner_dead(n)}
        assert dead_ports, filter_files  # the planner's ports, which the filter still writes into
        removed = set(remove_dead_shm(before))
        assert not removed & shm_mapped(filt.pid), removed
        assert dead_ports <= shm_entries()
        filt.kill()
        filt.wait()
        remove_dead_shm(before)
        assert not (planner_files | filter_files) & shm_entries()
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
