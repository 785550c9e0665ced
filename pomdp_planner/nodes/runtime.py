"""How a node process runs: start-up errors, the callback guard, ``main``.

:func:`run_nodes` is the Jazzy idiom (``rclpy.init``, build the nodes, spin, clean exit on Ctrl-C
and SIGTERM) with the project's :class:`~.executor.NodeExecutor`. A node that cannot start raises
:class:`NodeConfigError`: a value rclpy refuses as a parameter is declared
(:class:`~.params.ParameterNode`), the core's errors through :func:`config_errors` (their messages
name the field, i.e. the parameter), an undeclared parameter under ``strict_parameters``
(:func:`~.params.check_given_parameters`). ``run_nodes`` prints it as one ``[FATAL]`` line, exit
code 1, and so it does when rcl refuses the command line itself (a parameter file it cannot
parse, a malformed ``-p``). The nodes are built, their parameters checked, then started
(:meth:`~.params.ParameterNode.start`: a managed node's autostart). What the process writes to
stderr while starting is held until then (at most :data:`HOLD_STDERR_SECONDS`): on a refusal,
the ``[FATAL]`` line is all that is printed.
"""

from __future__ import annotations

import _thread
import ast
import functools
import inspect
import os
import re
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import rclpy
import yaml
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.node import Node

from ..core.errors import InputError, short_repr
from .executor import NodeExecutor, shutdown_executor
from .params import NodeConfigError, ParameterNode, check_given_parameters, deferred_start


@contextmanager
def config_errors() -> Iterator[None]:
    """Translate the core's errors raised while a node starts (bad model file, bad parameter value;
    their messages name the field) into :class:`NodeConfigError`."""
    try:
        yield
    except InputError as exc:  # a model file, parameter value or belief the core refuses
        raise NodeConfigError(str(exc)) from None


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


#: Seconds after a Ctrl-C before the old way (``KeyboardInterrupt`` in the main thread) is used
#: after all, should the spin not have ended (never needed in our tests: a safety net).
SIGINT_FALLBACK_SECONDS = 3.0


class _SigintWhileSpinning:
    """Python's SIGINT handler for a node process: stop the spin without a ``KeyboardInterrupt``.

    ``rclpy.init`` installs a C-level SIGINT handler that first calls the handler that was there
    before (by default Python's, which raises ``KeyboardInterrupt`` at whatever bytecode the main
    thread runs next) and then wakes the executors. Inside the executor's wait loop that can be
    the middle of ``rclpy.task.Future.__init__``: the half-built task then prints "Exception
    ignored in: Future.__del__ ... AttributeError: '_exception'" at exit (seen once in CI, rclpy
    7.1.6). Ending the spin on the context's shutdown alone is not enough either: the wake-up can
    come before the shutdown, and the executor then waits again (a node that never stopped, once
    in CI). So this handler, installed *before* ``rclpy.init`` so that rclpy chains to it, asks
    the spin to stop (:meth:`NodeExecutor.spin_until`: a wait condition checked after every
    wake-up) and wakes the executor itself. Before the spin (building the nodes) it raises
    ``KeyboardInterrupt`` as usual; and should the spin not end within
    :data:`SIGINT_FALLBACK_SECONDS`, the old way is used after all (``_thread.interrupt_main``).
    """

    def __init__(self) -> None:
        self.executor: NodeExecutor | None = None
        self.requested = False
        self.fallback: threading.Timer | None = None
        self.stop = lambda: self.requested  # one object: the executor reuses its wait generator

    def __call__(self, signum, frame) -> None:
        if self.executor is None:
            raise KeyboardInterrupt
        if self.requested:
            return
        self.requested = True
        self.executor.wake()
        self.fallback = threading.Timer(SIGINT_FALLBACK_SECONDS, _thread.interrupt_main)
        self.fallback.daemon = True
        self.fallback.start()


#: Longest time start-up output is held (:class:`_HeldStderr`): a start that takes longer (a large
#: model's set-up, which the planner announces when it expects it to take more than 2 s) shows its
#: log lines after this delay, and as they come from then on.
HOLD_STDERR_SECONDS = 2.0


class _HeldStderr:
    """Hold what the process writes to stderr (file descriptor 2: Python's and rcl's logging alike)
    until :meth:`release`, or at most ``limit`` seconds; ``release(keep=False)`` drops it (a
    refused start-up: the ``[FATAL]`` line alone is printed, not the log lines of the nodes built
    before the refusal)."""

    def __init__(self, limit: float = HOLD_STDERR_SECONDS) -> None:
        sys.stderr.flush()
        self._lock = threading.Lock()
        self._file = tempfile.TemporaryFile()
        self._saved: int | None = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        self._timer = threading.Timer(limit, self.release)
        self._timer.daemon = True
        self._timer.start()

    def release(self, keep: bool = True) -> None:
        with self._lock:
            if self._saved is None:
                return
            self._timer.cancel()
            sys.stderr.flush()
            os.dup2(self._saved, 2)
            os.close(self._saved)
            self._saved = None
            if keep:
                self._file.seek(0)
                data = memoryview(self._file.read())
                while data:
                    data = data[os.write(2, data):]
            self._file.close()


def _params_file_error(path: str, error: str) -> str:
    """One line for a parameter file rcl could not parse: the file, the line (and its text) and rcl's reason."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        return f"--params-file {path}: cannot be read ({getattr(exc, 'strerror', None) or exc})"
    try:
        yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = "" if mark is None else f", line {mark.line + 1}"
        return f"--params-file {path}{where}: not YAML ({getattr(exc, 'problem', None) or 'syntax error'})"
    m = re.search(r"line(?:_num)? (\d+)", error)
    lines = text.splitlines()
    if m and 1 <= int(m.group(1)) <= len(lines):
        n = int(m.group(1))
        return f"--params-file {path}, line {n} {short_repr(lines[n - 1].strip())}: {error}"
    return f"--params-file {path}: {error}"


def command_line_error(message: str) -> str:
    """One line for an error of ``rclpy.init`` (rcl refused the ROS arguments), without rcl's
    source locations."""
    text = re.sub(r", at [^,]*:\d+", "", message).removeprefix("failed to initialize rcl: ").strip()
    m = re.match(r"Couldn't parse params file: '--params-file (.*?)'\. Error: (.*)", text, re.S)
    if m:
        return _params_file_error(m.group(1), m.group(2).strip())
    m = re.match(r"Couldn't parse parameter override rule: '(?:-p|--param) (.*?)'", text)
    if m:
        return f"-p {m.group(1)}: must be name:=value (or node_name:name:=value)"
    return text


def _node_name(make: Callable[[], Node]) -> str | None:
    """The default node name of a node factory (its ``node_name`` argument), if it has one."""
    try:
        default = inspect.signature(make).parameters["node_name"].default
    except (KeyError, TypeError, ValueError):
        return None
    return default if isinstance(default, str) else None


def _unknown_args(exc: Exception) -> str:
    """The arguments rcl did not know (``UnknownROSArgsError`` says ``['--foo']``), joined."""
    try:
        args = ast.literal_eval(str(exc))
    except (ValueError, SyntaxError):
        return str(exc)
    return ", ".join(map(str, args)) if isinstance(args, list) else str(args)


def run_nodes(factories: Sequence[Callable[[], Node]], args: Sequence[str] | None = None) -> int:
    """The Jazzy idiom: init, build nodes, spin a :class:`NodeExecutor`, clean exit on Ctrl-C/SIGTERM.

    Returns the process exit code: 0 on a normal or signalled shutdown, 1 if a node could not
    start (bad parameter, model file or command line; the reason is printed as one line, without
    traceback). Parameters given to a node that it does not declare are reported once the nodes
    are built (:func:`~.params.check_given_parameters`).
    """
    argv = list(sys.argv if args is None else args)
    sigint = _SigintWhileSpinning()
    signal.signal(signal.SIGINT, sigint)  # before rclpy.init, which chains to it (see the class)
    held = _HeldStderr()
    nodes: list[Node] = []
    executor = None
    code = 0
    make = None
    try:
        try:
            rclpy.init(args=args)
        except _rclpy_impl.UnknownROSArgsError as exc:
            held.release(keep=False)
            print(f"[FATAL] [pomdp_planner]: --ros-args: unknown argument {_unknown_args(exc)} (the ROS arguments "
                  "are -p, -r, --params-file, --log-level, -e, --enclave, ...)", file=sys.stderr)
            return 1
        except _rclpy_impl.RCLError as exc:
            held.release(keep=False)
            print(f"[FATAL] [pomdp_planner]: {command_line_error(str(exc))}", file=sys.stderr)
            return 1
        with deferred_start():
            for make in factories:
                nodes.append(make())
        make = None
        check_given_parameters(nodes, argv)
        for n in nodes:
            if isinstance(n, ParameterNode):
                n.start()
        held.release()
        executor = NodeExecutor()
        for n in nodes:
            executor.add_node(n)
        sigint.executor = executor
        executor.spin_until(sigint.stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy_impl.RCLError:
        if rclpy.ok():
            raise
        # the context was shut down (Ctrl-C, SIGTERM) while rclpy was building a wait set: a
        # clean exit like the others, not a traceback
    except NodeConfigError as exc:
        held.release(keep=False)
        name = exc.node or (None if make is None else _node_name(make)) or "pomdp_planner"
        print(f"[FATAL] [{name}]: {exc}", file=sys.stderr)
        code = 1
    finally:
        held.release()
        # A second Ctrl-C during teardown must not print a traceback either.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if sigint.fallback is not None:
            sigint.fallback.cancel()
        if executor is not None:
            shutdown_executor(executor)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    return code


def main_for(factories: Sequence[Callable[[], Node]]) -> None:
    sys.exit(run_nodes(factories, args=sys.argv))
