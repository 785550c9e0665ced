"""Launch-free support for the ROS 2 node tests: plain pytest and rclpy, no launch files, no ``ros2``.

* :class:`RosHarness` (the ``harness`` fixture of each node test, via :func:`make_harness`): one
  ``rclpy`` Context per test, initialised with ``ROS_AUTOMATIC_DISCOVERY_RANGE=OFF`` (nodes of one
  context still talk to each other; nothing leaks to or from other tests, processes or machines)
  and ``ROS_PYTHON_CHECK_FIELDS=1`` (a wrong message field type raises instead of being
  serialised as garbage); one ``NodeExecutor`` (the nodes' own executor) spinning in a daemon
  thread; teardown shuts the executor down, then destroys the nodes, then the context.
* :class:`Recorder`: a node that records every message of the loop's topics and of
  ``/diagnostics`` under a lock, and notifies a condition variable; tests wait on it with
  :meth:`RosHarness.wait_until` (a predicate and an upper bound, never a fixed sleep).
* Discovery runs in DDS threads with no event to wait on, so :meth:`RosHarness.wait_matched` polls
  a publisher's match count (again with an upper bound).
* :class:`LifecycleClient`: the standard ``lifecycle_msgs`` services of a managed node
  (``get_state``, ``change_state``, ``get_available_transitions``) called from an rclpy client, as
  ``ros2 lifecycle`` and a lifecycle manager call them.
* Node processes a test starts: :func:`die_with_test` (``preexec_fn``) ends them when the test
  process dies, however it dies; :func:`remove_dead_shm` removes the shared-memory files that
  processes killed with SIGKILL left behind, and no file still in use.
"""

from __future__ import annotations

import ctypes
import fcntl
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402
from std_msgs.msg import Float64MultiArray, Int64MultiArray  # noqa: E402

from pomdp_planner.nodes.executor import NodeExecutor, shutdown_executor  # noqa: E402
from pomdp_planner.nodes.messages import decode_belief  # noqa: E402
from pomdp_planner.nodes.processes import stop_nodes  # noqa: E402
from pomdp_planner.nodes.qos import RECORDER_QOS  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
S3 = str(REPO / "config" / "models" / "tracking_s3_info.yaml")
S8 = str(REPO / "config" / "models" / "tracking_s8_info.yaml")
SHM = Path("/dev/shm")

_PR_SET_PDEATHSIG = 1
_libc = ctypes.CDLL(None, use_errno=True) if sys.platform == "linux" else None
if _libc is not None:
    _libc.signal.restype = ctypes.c_void_p  # the previous handler, a pointer: not truncated to an int


def die_with_test() -> None:
    """``preexec_fn`` for a node process a test starts: SIGINT (how Ctrl-C ends a node: a clean exit
    that releases its shared memory) reaches it when the test process dies, even by SIGKILL, so a
    killed pytest leaves no orphan node talking in its ROS domain (Linux ``PR_SET_PDEATHSIG``; the
    signal survives the wheels' re-exec at start-up). SIGINT is set back to its default first: a
    test run in the background of a non-interactive shell would pass it on ignored. Runs in the
    child between fork and exec, so it only calls libc through handles made beforehand. The signal
    comes when the *thread* that started the process ends: start node processes from the test's
    own thread, or from a pool that outlives them."""
    if _libc is None:
        return
    parent = os.getppid()
    _libc.signal(signal.SIGINT, 0)  # SIG_DFL
    _libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGINT), 0, 0, 0)
    if os.getppid() != parent:  # the test died before the prctl: the signal would never come
        os._exit(1)


def shm_entries(shm: Path = SHM) -> set[str]:
    """Names of the Fast DDS shared-memory files (segments, ports and their lock files) in ``shm``."""
    return {p.name for p in shm.glob("fastrtps_*")} if shm.is_dir() else set()


def shm_mapped(pid: int | str, shm: Path = SHM) -> set[str]:
    """Names of the files in ``shm`` that process ``pid`` has mapped (empty if it cannot be inspected:
    ended, or another user's)."""
    prefix = f"{shm}/"
    try:
        lines = Path(f"/proc/{pid}/maps").read_text(errors="replace").splitlines()
    except OSError:
        return set()
    fields = (line.split(maxsplit=5) for line in lines)
    return {f[5].removeprefix(prefix).removesuffix(" (deleted)") for f in fields
            if len(f) == 6 and f[5].startswith(prefix)}


def remove_dead_shm(before: set[str], shm: Path = SHM) -> list[str]:
    """Remove the Fast DDS shared-memory files that appeared since ``before`` and that no live
    process uses; return their names.

    A process killed with SIGKILL leaves its segment and its ports behind. Every Fast DDS segment
    and port has a lock file ``<name>_el`` (or ``_sl``) that its owner holds locked while it lives
    (what ``fastdds shm clean`` tests): a lock that can be taken belongs to a dead process. A dead
    node's port may still be mapped by live writers that have not yet noticed the death; a node
    restarted with the same participant id opens that same port again and receives what they
    write. So a file goes only if its owner is dead *and* no process maps it. Unlinking a file in
    use (another test's, another run's on this machine, however new) cuts its users off from
    every participant that opens it later: a node restarted there would receive nothing, ever."""
    candidates = sorted(n for n in shm_entries(shm) - before if n.endswith(("_el", "_sl")))
    in_use = set().union(*(shm_mapped(p.name, shm) for p in Path("/proc").glob("[0-9]*"))) if candidates else set()
    removed = []
    for lock in candidates:
        name = lock[:-3]
        if name in in_use:
            continue
        files = [name, lock] + ([f"sem.{name}_mutex"] if name.startswith("fastrtps_port") else [])
        if _locked_while(shm / lock, lambda files=files: [(shm / f).unlink(missing_ok=True) for f in files]):
            removed += files
    return removed


def stop_after_kills(procs: dict, executor, node: Node, ctx: Context, handles: list, shm_before: set[str]
                     ) -> dict[str, int]:
    """The teardown of a test that killed node processes: stop the rest (SIGINT), shut the test's
    executor, node and context down, close the log handles, and remove the shared memory the
    killed processes left (:func:`remove_dead_shm`); returns the exit codes."""
    codes = stop_nodes(procs, timeout=15.0)
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    ctx.try_shutdown()
    for fh in handles:
        fh.close()
    remove_dead_shm(shm_before)
    return codes


def _locked_while(lock: Path, action: Callable[[], object]) -> bool:
    """Take Fast DDS lock file ``lock`` (free only if its owner is dead) and run ``action`` holding
    it; False if the lock is held (or the file is gone)."""
    try:
        with open(lock, "ab") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            action()
    except OSError:
        return False
    return True


def owner_dead(name: str, shm: Path = SHM) -> bool:
    """Whether the process that created Fast DDS file ``name`` (a segment or a port) has ended."""
    return any(_locked_while(shm / f"{name}{suffix}", lambda: None) for suffix in ("_el", "_sl"))


class Recorder(Node):
    """Subscribes to the loop's topics and records every message (thread-safe)."""

    def __init__(self, context: Context, cond: threading.Condition, obs_topics=("observation",)):
        super().__init__("test_recorder", context=context)
        self.cond = cond
        self.actions: list[tuple[int, int]] = []
        self.observations: dict[str, list[tuple[int, int, int]]] = {t: [] for t in obs_topics}
        self.beliefs: list = []
        self.true_states: list[tuple[int, int]] = []
        self.diagnostics: list = []
        deep = RECORDER_QOS  # transient-local like the publishers, a deep history: every message is recorded
        self.create_subscription(Int64MultiArray, "action", self._rec(self.actions, tuple), deep)
        for t in obs_topics:
            self.create_subscription(Int64MultiArray, t, self._rec(self.observations[t], tuple), deep)
        self.create_subscription(Int64MultiArray, "true_state", self._rec(self.true_states, tuple), deep)
        self.create_subscription(Float64MultiArray, "belief", self._rec(self.beliefs, None), deep)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._rec(self.diagnostics, None), 50)

    def _rec(self, store: list, conv):
        def cb(msg):
            with self.cond:
                store.append(conv(msg.data) if conv else msg)
                self.cond.notify_all()
        return cb

    def diag_values(self, name_prefix: str) -> list[dict]:
        """All diagnostic statuses whose name starts with ``name_prefix``, as dicts (+ level, message)."""
        out = []
        with self.cond:
            msgs = list(self.diagnostics)
        for arr in msgs:
            for st in arr.status:
                if st.name.startswith(name_prefix):
                    d = {kv.key: kv.value for kv in st.values}
                    d["_level"] = st.level
                    d["_message"] = st.message
                    out.append(d)
        return out

    def decoded_beliefs(self, S: int):
        with self.cond:
            msgs = list(self.beliefs)
        return [decode_belief(m, S) for m in msgs]

    def belief_epochs(self, S: int) -> list[int]:
        """Epochs of the beliefs received, each once, in order of first arrival (the filter re-sends
        its last belief while no reading answers it: a repeat is the same message again)."""
        seen: dict[int, None] = {}
        for b in self.decoded_beliefs(S):
            seen.setdefault(b.epoch)
        return list(seen)

    def beliefs_by_epoch(self, S: int) -> dict:
        """The newest belief received for each epoch."""
        return {b.epoch: b.belief for b in self.decoded_beliefs(S)}


class LifecycleClient:
    """Calls the lifecycle services of the managed node ``target`` (e.g. ``"/planner"``) from ``node``.

    The futures are polled, never spun (the harness's executor spins ``node`` in another thread)."""

    def __init__(self, node: Node, target: str, timeout: float = 30.0):
        self.timeout = timeout
        self._get = node.create_client(GetState, f"{target}/get_state")
        self._change = node.create_client(ChangeState, f"{target}/change_state")
        self._transitions = node.create_client(GetAvailableTransitions, f"{target}/get_available_transitions")

    def wait_for_services(self, timeout: float = 10.0) -> bool:
        return all(c.wait_for_service(timeout_sec=timeout) for c in (self._get, self._change, self._transitions))

    def _call(self, client, request):
        future = client.call_async(request)
        deadline = time.monotonic() + self.timeout
        while not future.done():
            if time.monotonic() > deadline:
                raise TimeoutError(f"{client.srv_name}: no answer within {self.timeout} s")
            time.sleep(0.005)
        return future.result()

    def state(self) -> str:
        """The label of the node's current state (``GetState``)."""
        return self._call(self._get, GetState.Request()).current_state.label

    def change(self, label: str) -> bool:
        """``ChangeState`` by transition label (``configure``, ``activate``, ...); its ``success``."""
        return self._call(self._change, ChangeState.Request(transition=Transition(label=label))).success

    def request(self, transition_id: int = 0, label: str = "") -> bool:
        """``ChangeState`` with this transition id and label, as any client may send it; its ``success``."""
        req = ChangeState.Request(transition=Transition(id=transition_id, label=label))
        return self._call(self._change, req).success

    def transitions(self) -> list[tuple[str, str]]:
        """``GetAvailableTransitions``: ``(transition label, goal state label)`` pairs."""
        res = self._call(self._transitions, GetAvailableTransitions.Request())
        return [(t.transition.label, t.goal_state.label) for t in res.available_transitions]


class RosHarness:
    def __init__(self):
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"
        os.environ["ROS_PYTHON_CHECK_FIELDS"] = "1"
        self.context = Context()
        rclpy.init(context=self.context)
        self.cond = threading.Condition()
        self.executor = NodeExecutor(num_threads=4, context=self.context)
        self.nodes: list[Node] = []
        self._thread: threading.Thread | None = None

    def add(self, node: Node) -> Node:
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def recorder(self, obs_topics=("observation",)) -> Recorder:
        return self.add(Recorder(self.context, self.cond, obs_topics))

    def start(self) -> None:
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # executor shut down during teardown
            pass

    def wait_until(self, predicate: Callable[[], bool], timeout: float = 10.0) -> bool:
        """Wait (on the recorder's condition, re-checking at least every 50 ms) until ``predicate()``."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(min(left, 0.05))
        return True

    @staticmethod
    def wait_matched(publisher, count: int, timeout: float = 10.0) -> bool:
        """Poll (discovery runs in DDS threads, no event to wait on) until ``count`` subscribers match."""
        deadline = time.monotonic() + timeout
        while publisher.get_subscription_count() < count:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.005)
        return True

    def close(self) -> None:
        shutdown_executor(self.executor)
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for n in self.nodes:
            n.destroy_node()
        self.context.try_shutdown()


def make_harness():
    h = RosHarness()
    try:
        yield h
    finally:
        h.close()


@contextmanager
def node_process_and_client(name: str, args: list[str], log: Path):
    """A node executable ``name`` started with ``args`` (output to ``log``) and, in this process, a
    client node spun by a ``NodeExecutor`` in a thread: yields ``(process, client node, codes)``.
    On leaving: the process stopped with SIGINT (``codes[name]``: its exit code), the client and
    its context shut down, and the shared memory a killed process left removed."""
    from rclpy.context import Context

    from pomdp_planner.nodes.executor import shutdown_executor
    from pomdp_planner.nodes.processes import node_command

    shm_before = shm_entries()
    with open(log, "wb") as fh:
        proc = subprocess.Popen([*node_command(name), *args], stdout=fh, stderr=subprocess.STDOUT,
                                preexec_fn=die_with_test)
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("lifecycle_test_client", context=ctx)
    executor = NodeExecutor(num_threads=2, context=ctx)
    executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()
    codes: dict[str, int] = {}
    try:
        yield proc, node, codes
    finally:
        codes.update(stop_nodes({name: (proc, log)}, timeout=15.0))
        shutdown_executor(executor)
        node.destroy_node()
        ctx.try_shutdown()
        if codes.get(name, 0) < 0:  # killed: only a killed process leaves segments behind
            remove_dead_shm(shm_before)
