"""Shared pieces of the nodes: model paths, QoS profiles, parameter descriptors, diagnostics, main().

Model paths (parameter ``model_file``, and the per-sensor ``observation_model_files``): an
absolute path is used as is; a relative one is looked up, first hit wins, under

1. the installed package share directory (``get_package_share_directory('pomdp_planner')``,
   where ``config/`` is installed), then
2. the source tree this module was imported from (running from a checkout), then
3. the current directory.

So ``config/models/tracking_s8_info.yaml`` works both installed and from source.
"""

from __future__ import annotations

import functools
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, ShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..core.belief import BeliefError, check_belief, start_belief, uniform_belief
from ..core.io.model_yaml import load_model
from ..core.model import POMDP, ModelError

PACKAGE = "pomdp_planner"
SOURCE_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_MODEL = "config/models/tracking_s3_info.yaml"

# ----------------------------------------------------------------- QoS
# Two profiles, chosen by what a topic means (README, "Topics"). Both are reliable and
# transient-local: reliable because every node acts on every sample it gets; transient-local so
# that the start order of the nodes does not matter (the prior belief, published before a planner
# exists, and the first action reach nodes that match later) and so that transient-local readers
# (recorders, `ros2 topic echo --qos-durability transient_local`) are compatible at all: a
# volatile writer does not match a transient-local reader. Neither durability nor history depth
# costs latency: with the executor fixed (NodeExecutor) the measured observation-to-action
# latency was the same (1.8-1.9 ms median, 2.6-3.1 ms p99 over 300 S = 8 decisions) with the
# earlier depths (1 for action and belief, 20 for the rest) and with depth 50 everywhere, and the
# per-hop times were the same with volatile observation streams.

#: Per-epoch streams where every sample matters (``action``, ``observation``, ``true_state``,
#: ``belief`` as published, ``plan_info``), for their writers and for the readers that must see
#: every epoch (the simulator's and the filter's subscriptions). KEEP_LAST with a depth far beyond
#: how many epochs a reader can fall behind: a reliable writer keeps a sample until every reader
#: has it unless ``depth`` newer ones replace it first (then it is lost for good; with depth 1 a
#: single transport loss of an action could not be repaired once the next one was out). Not
#: KEEP_ALL: a stuck recorder must not block the loop's publishers. A late joiner gets at most the
#: last ``depth`` epochs, which the nodes' epoch checks handle (stale epochs are dropped).
STREAM_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: "Latest value" (latched), depth 1: readers for which only the newest sample is useful (the
#: planner's ``belief`` subscription: a backlog of older beliefs is never planned for; a late
#: planner gets the newest belief of the filter's history) and gauges (``belief_entropy``).
LATCHED_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


class NodeConfigError(ValueError):
    """A node parameter makes the node unable to start (message names the parameter)."""


def resolve_path(path: str, field: str = "model_file") -> Path:
    """Resolve a (possibly relative) model path as the module docstring says."""
    if not path:
        raise NodeConfigError(f"{field}: empty path")
    p = Path(path).expanduser()
    if p.is_absolute():
        if not p.is_file():
            raise NodeConfigError(f"{field}: file {p} does not exist")
        return p
    candidates = []
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        try:
            candidates.append(Path(get_package_share_directory(PACKAGE)) / p)
        except (PackageNotFoundError, OSError):  # OSError: AMENT_PREFIX_PATH unset (plain venv, source tree)
            pass
    except ImportError:  # pragma: no cover - ament_index_python ships with rclpy
        pass
    candidates += [SOURCE_ROOT / p, Path.cwd() / p]
    for c in candidates:
        if c.is_file():
            return c
    places = list(dict.fromkeys(str(c.parent) for c in candidates))
    raise NodeConfigError(f"{field}: {path!r} not found (looked in {', '.join(places)})")


def load_node_model(path: str, field: str = "model_file") -> POMDP:
    try:
        return load_model(resolve_path(path, field))
    except ModelError as exc:
        raise NodeConfigError(f"{field}: {exc}") from None


def load_observation_models(model: POMDP, files: Sequence[str] | None, num_sensors: int) -> list[np.ndarray]:
    """One observation array ``O (A x S x Z_k)`` per sensor; ``""`` (or no list) = the model's own."""
    files = list(files or [])
    if not files:
        files = [""] * num_sensors
    if len(files) != num_sensors:
        raise NodeConfigError(
            f"observation_model_files: {len(files)} entries for {num_sensors} observation_topics "
            "(give one per topic, '' for the model's own)"
        )
    out = []
    for k, f in enumerate(files):
        if not f:
            out.append(model.O)
            continue
        O = load_node_model(f, f"observation_model_files[{k}]").O
        if O.shape[:2] != (model.A, model.S):
            raise NodeConfigError(
                f"observation_model_files[{k}]: observation model has shape {O.shape}, expected "
                f"{model.A} x {model.S} x Z"
            )
        out.append(O)
    return out


def initial_distribution(model: POMDP, values: Sequence[float] | None) -> np.ndarray:
    """Parameter ``initial_distribution`` if set, else the model file's ``start`` (core), else uniform."""
    try:
        if values is not None and len(values) > 0:
            return check_belief(model, np.asarray(values, dtype=float), field="initial_distribution")
        start = start_belief(model)
    except (BeliefError, ModelError) as exc:
        raise NodeConfigError(str(exc)) from None
    return uniform_belief(model) if start is None else start


def shannon_entropy(b: np.ndarray) -> float:
    b = np.asarray(b, dtype=float)
    nz = b[b > 0.0]
    return float(-(nz * np.log(nz)).sum())


# ----------------------------------------------------------------- parameters
def descriptor(description: str, *, read_only: bool = False, float_range: tuple[float, float] | None = None,
               int_range: tuple[int, int] | None = None, type_: int | None = None,
               constraints: str = "") -> ParameterDescriptor:
    d = ParameterDescriptor(description=description, read_only=read_only, additional_constraints=constraints)
    if type_ is not None:
        d.type = type_
    if float_range is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(float_range[0]),
                                                     to_value=float(float_range[1]), step=0.0)]
    if int_range is not None:
        d.integer_range = [IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=1)]
    return d


def declare_optional_array(node: Node, name: str, kind: str, description: str) -> None:
    """Declare a read-only, statically typed array parameter without a default (``kind``: string/double)."""
    ptype, ros_type = {
        "string": (Parameter.Type.STRING_ARRAY, ParameterType.PARAMETER_STRING_ARRAY),
        "double": (Parameter.Type.DOUBLE_ARRAY, ParameterType.PARAMETER_DOUBLE_ARRAY),
    }[kind]
    node.declare_parameter(name, ptype, descriptor(description, read_only=True, type_=ros_type))


def optional_array(node: Node, name: str) -> list | None:
    """Value of a statically typed array parameter declared without a default (None if unset)."""
    if not node.has_parameter(name):
        return None
    value = node.get_parameter_or(name, None)
    value = None if value is None else value.value
    return None if value is None else list(value)


# ----------------------------------------------------------------- diagnostics
def status(name: str, hardware_id: str, level: bytes, message: str, values: dict) -> DiagnosticStatus:
    return DiagnosticStatus(
        level=level, name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()],
    )


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


# ----------------------------------------------------------------- callbacks
def callback(method):
    """Decorate a node callback: an exception raised while the context is shutting down (e.g. a
    publish after Ctrl-C, while a search was still running) is expected and swallowed, so the
    exit stays clean; any other exception propagates."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except Exception:
            if self.context.ok():
                raise
            return None

    return wrapper


# ----------------------------------------------------------------- executor
class _StartReportingPool(ThreadPoolExecutor):
    """A thread pool that reports each submitted callable when a worker starts it."""

    def __init__(self, max_workers: int, on_start: Callable[[object], None]):
        super().__init__(max_workers)
        self._on_start = on_start

    def submit(self, fn, /, *args, **kwargs):
        def run():
            self._on_start(fn)
            return fn(*args, **kwargs)

        return super().submit(run)


class NodeExecutor(MultiThreadedExecutor):
    """``MultiThreadedExecutor`` without the re-submission busy loop of rclpy 7.1 (Jazzy).

    Jazzy's ``Executor._wait_for_ready_callbacks`` yields again every task that is "not executing
    and not done" before it waits for new work. On a ``MultiThreadedExecutor`` a task it has just
    handed to the thread pool is exactly that until a worker picks it up, so the spinning thread
    submits the same task again and again without ever blocking in the wait set, holding the GIL
    the workers need to start it (ros2/rclpy#1452, fixed upstream after Jazzy by ros2/rclpy#1469
    and #1547). Measured on the in-process node loop (2 cores, S = 8): about 8 re-submissions per
    epoch, up to 250 stale entries in the pool's queue, the spinning thread on two thirds of a
    CPU during a stall while the workers hardly ran, and messages that the DDS layer had received
    within 0.1 ms of publication waiting 50-900 ms to be taken; in bad runs the loop ran up to
    18x slower (README, "Latency"). The same happens in each node process.

    This subclass hands every task to the pool once: when the wait loop yields a task that is
    still queued (submitted, not yet started), it waits, without the GIL, until a worker starts
    it and then asks for the next ready work. A task that has run and is suspended (a coroutine
    awaiting a future) is submitted again as before. Everything else (callback groups, wait sets,
    number of threads) is rclpy's.
    """

    def __init__(self, num_threads: int | None = None, *, context=None):
        super().__init__(num_threads, context=context)
        workers = self._executor._max_workers
        self._executor.shutdown(wait=False)
        self._queued: set = set()  # tasks submitted to the pool that no worker has started yet
        self._queued_cv = threading.Condition()
        self._executor = _StartReportingPool(workers, self._task_started)

    def _task_started(self, task) -> None:
        with self._queued_cv:
            self._queued.discard(task)
            self._queued_cv.notify_all()

    def wait_for_ready_callbacks(self, *args, **kwargs):
        while True:
            # Looking again after a wait below: the context may have been shut down meanwhile
            # (Ctrl-C); say so the way rclpy's own wait does, instead of building a wait set on
            # an invalid context (an RCLError).
            if self._is_shutdown:
                raise ShutdownException()
            if not self._context.ok():
                raise ExternalShutdownException()
            handler, entity, node = super().wait_for_ready_callbacks(*args, **kwargs)
            with self._queued_cv:
                if handler not in self._queued:
                    self._queued.add(handler)  # the caller (_spin_once_impl) submits it now
                    return handler, entity, node
                # Yielded again while still in the pool's queue: do not queue it twice; wait for
                # a worker to start it (bounded, so that shutdown is noticed), then look again.
                self._queued_cv.wait_for(lambda h=handler: h not in self._queued or self._is_shutdown,
                                         timeout=0.05)


# ----------------------------------------------------------------- main
def shutdown_executor(executor, timeout_sec: float = 2.0) -> None:
    """Stop ``executor``; let callbacks already running finish before nodes are destroyed.

    Jazzy's ``Executor.shutdown`` does not wait for running callbacks, and
    ``MultiThreadedExecutor`` never stops its thread pool; a callback that then touches a
    destroyed node or a shut-down context leaves "exception was never retrieved" (or "coroutine
    was never awaited") on stderr at exit. So also stop the pool (``_executor``, a
    ``concurrent.futures.ThreadPoolExecutor``: running callbacks, e.g. a search of at most
    ``time_budget``, complete; queued ones are cancelled) and settle the executor's leftover
    tasks (``_futures``): the exceptions of finished ones are retrieved (expected at shutdown),
    unstarted ones are cancelled and their coroutines closed. Private attributes, hence the guards.
    """
    executor.shutdown(timeout_sec=timeout_sec)
    pool = getattr(executor, "_executor", None)
    if pool is not None and hasattr(pool, "shutdown"):
        pool.shutdown(wait=True, cancel_futures=True)
    for task in list(getattr(executor, "_futures", [])):
        if task.done():
            task.exception()
        else:
            task.cancel()
            handler = getattr(task, "_handler", None)
            if hasattr(handler, "close"):
                handler.close()


def run_nodes(factories: Sequence[Callable[[], Node]], args: Sequence[str] | None = None) -> int:
    """The Jazzy idiom: init, build nodes, spin a :class:`NodeExecutor`, clean exit on Ctrl-C/SIGTERM.

    Returns the process exit code: 0 on a normal or signalled shutdown, 1 if a node could not
    start (bad parameter or model file; the reason is printed, without traceback).
    """
    rclpy.init(args=args)
    nodes: list[Node] = []
    executor = None
    code = 0
    try:
        for make in factories:
            nodes.append(make())
        executor = NodeExecutor()
        for n in nodes:
            executor.add_node(n)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy_impl.RCLError:
        if rclpy.ok():
            raise
        # the context was shut down (Ctrl-C, SIGTERM) while rclpy was building a wait set: a
        # clean exit like the others, not a traceback
    except NodeConfigError as exc:
        print(f"[FATAL] pomdp_planner: {exc}", file=sys.stderr)
        code = 1
    finally:
        # A second Ctrl-C during teardown must not print a traceback either.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if executor is not None:
            shutdown_executor(executor)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    return code


def main_for(factories: Sequence[Callable[[], Node]]) -> None:
    sys.exit(run_nodes(factories, args=sys.argv))
