"""Ctrl-C of a node process (``nodes.runtime.run_nodes``): a clean stop, never a ``KeyboardInterrupt``
inside the executor.

rclpy's SIGINT handler ends the spin and then calls Python's; Python's default raises
``KeyboardInterrupt`` at an arbitrary bytecode of the main thread, once (CI) in the middle of an
``rclpy.task.Future.__init__``, so that the half-built task printed "Exception ignored in:
Future.__del__ ... AttributeError" at exit. While the nodes spin, the Python-level handler must
therefore not raise; during start-up it must, so that Ctrl-C still stops a node being built.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy")
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from nodes_support import S3, die_with_test  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402

from pomdp_planner.nodes.executor import NodeExecutor  # noqa: E402
from pomdp_planner.nodes.processes import node_command  # noqa: E402
from pomdp_planner.nodes.runtime import _SigintWhileSpinning  # noqa: E402

NODE = textwrap.dedent("""
    import signal, sys, time
    from rclpy.node import Node
    from pomdp_planner.nodes.runtime import run_nodes

    class Busy(Node):
        def __init__(self):
            super().__init__("sigint_probe")
            time.sleep(float(sys.argv[1]))  # start-up work (a model being loaded)
            self.reported = False
            self.create_timer(0.001, self.tick)  # keeps the executor creating tasks

        def tick(self):
            if not self.reported:
                self.reported = True
                handler = signal.getsignal(signal.SIGINT)
                print("spinning, SIGINT handler:", getattr(handler, "__name__", type(handler).__name__), flush=True)

    print("building", flush=True)
    sys.exit(run_nodes([Busy], args=sys.argv[:1]))
""")


def _start(startup_seconds: float) -> subprocess.Popen:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF", PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-c", NODE, str(startup_seconds)], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=die_with_test)


def _wait_for_line(proc: subprocess.Popen, prefix: str, timeout: float = 30.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith(prefix):
            return line
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise AssertionError(f"no line {prefix!r}: {proc.stderr.read()[-2000:]}")


class _FakeExecutor:
    def __init__(self):
        self.woken = 0

    def wake(self):
        self.woken += 1


def test_handler_raises_before_the_spin_and_requests_a_stop_during_it():
    handler = _SigintWhileSpinning()
    with pytest.raises(KeyboardInterrupt):
        handler(signal.SIGINT, None)
    handler.executor = fake = _FakeExecutor()
    assert handler(signal.SIGINT, None) is None
    assert handler.stop() and fake.woken == 1
    handler(signal.SIGINT, None)  # a second Ctrl-C changes nothing
    assert fake.woken == 1
    handler.fallback.cancel()


def test_spin_until_returns_on_stop_and_wake_while_the_context_is_ok():
    """The mechanism the handler relies on: ``spin_until`` returns after ``stop`` is set and the
    executor woken, although nothing shut the context down (a plain ``spin()`` would wait on)."""
    context = Context()
    rclpy.init(context=context)
    node = Node("spin_until_probe", context=context)
    executor = NodeExecutor(num_threads=2, context=context)
    executor.add_node(node)
    flag = {"stop": False}
    stop = lambda: flag["stop"]  # noqa: E731
    done = threading.Event()
    thread = threading.Thread(target=lambda: (executor.spin_until(stop), done.set()), daemon=True)
    thread.start()
    try:
        assert not done.wait(0.3)  # nothing to do, context ok: it waits
        flag["stop"] = True
        executor.wake()
        assert done.wait(10), "spin_until did not return after stop + wake"
        assert context.ok()
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_sigint_while_spinning_stops_cleanly_without_keyboardinterrupt():
    """The spinning process has our handler installed (before the fix: Python's default, which
    raises), stops on one SIGINT (rclpy's handler ends the spin), exit code 0, nothing on stderr."""
    proc = _start(0.0)
    line = _wait_for_line(proc, "spinning")
    assert "_SigintWhileSpinning" in line, line
    time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=15)
    assert proc.returncode == 0, err[-2000:]
    assert err.strip() == "", err[-2000:]


def test_sigint_during_startup_still_stops_the_process():
    """Ctrl-C while a node is being built (before the spin): a clean stop, exit code 0, no traceback."""
    proc = _start(20.0)
    _wait_for_line(proc, "building")
    time.sleep(0.5)
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err[-2000:]
    assert "Traceback" not in err, err[-2000:]
    assert "spinning" not in out  # it stopped during the start-up, it did not go on to spin
    assert time.monotonic() - t0 < 15  # interrupted the 20 s start-up instead of waiting it out


@pytest.mark.parametrize("executable", ["planner", "target_simulator"])
def test_sigint_from_the_packages_first_import_on_is_a_clean_exit_and_at_most_one_line(executable, tmp_path):
    """Ctrl-C at any moment of a node executable's start-up once the package is imported (the
    interpreter's own start before that is Python's): exit code 0 or 130, no traceback, at most
    one line besides the node's log lines. The moment of the package's import is read from
    ``PYTHONPROFILEIMPORTTIME`` (a line per finished import, on stderr)."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF", PYTHONUNBUFFERED="1", PYTHONPROFILEIMPORTTIME="1")
    for delay in (0.0, 0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6):
        proc = subprocess.Popen([*node_command(executable), "--ros-args", "-p", f"model_file:={S3}"], env=env,
                                cwd=tmp_path, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                preexec_fn=die_with_test)
        lines: list[str] = []
        imported = threading.Event()

        def read(proc=proc, lines=lines, imported=imported):
            for line in proc.stderr:
                lines.append(line.rstrip("\n"))
                if line.startswith("import time:") and line.rsplit("|", 1)[-1].strip() == "pomdp_planner":
                    imported.set()

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            assert imported.wait(60), "the package was never imported: " + "\n".join(lines[-5:])
            time.sleep(delay)
            proc.send_signal(signal.SIGINT)
            code = proc.wait(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
        reader.join(timeout=5)
        said = [ln for ln in lines if ln.strip() and not ln.startswith("import time:")
                and not ln.startswith(("[INFO]", "[DEBUG]"))]
        assert code in (0, 130), (delay, code, said[-20:])
        assert len(said) <= 1 and not any("Traceback" in ln or "KeyboardInterrupt" in ln for ln in said), \
            (delay, said[-20:])
        if said:
            assert said[0] == f"{executable}: interrupted while starting", said
