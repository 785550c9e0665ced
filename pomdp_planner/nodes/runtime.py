"""How a node process runs: start-up errors, the callback guard, ``main``.

:func:`run_nodes` is the Jazzy idiom (``rclpy.init``, build the nodes, spin, clean exit on Ctrl-C
and SIGTERM) with the project's :class:`~.executor.NodeExecutor`. A node that cannot start raises
:class:`NodeConfigError`; :func:`config_errors` turns the core's errors (which name the field, i.e.
the parameter) into it, and ``run_nodes`` prints it as one ``[FATAL]`` line, exit code 1.
"""

from __future__ import annotations

import _thread
import functools
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.node import Node

from ..core.errors import InputError
from .executor import NodeExecutor, shutdown_executor


class NodeConfigError(ValueError):
    """A node parameter makes the node unable to start (message names the parameter)."""


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


def run_nodes(factories: Sequence[Callable[[], Node]], args: Sequence[str] | None = None) -> int:
    """The Jazzy idiom: init, build nodes, spin a :class:`NodeExecutor`, clean exit on Ctrl-C/SIGTERM.

    Returns the process exit code: 0 on a normal or signalled shutdown, 1 if a node could not
    start (bad parameter or model file, or a value a parameter's descriptor refuses; the reason
    is printed as one line, without traceback).
    """
    sigint = _SigintWhileSpinning()
    signal.signal(signal.SIGINT, sigint)  # before rclpy.init, which chains to it (see the class)
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
        print(f"[FATAL] pomdp_planner: {exc}", file=sys.stderr)
        code = 1
    except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
        # a value the parameter's descriptor refuses (range, type) as it is declared: rclpy's
        # message ends with ": <name>"; one line that starts with the name instead
        text, _, name = str(exc).rpartition(": ")
        print(f"[FATAL] pomdp_planner: {name}: {text}", file=sys.stderr)
        code = 1
    finally:
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
