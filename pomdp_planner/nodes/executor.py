"""The executor every node process spins: a work-around for a bug of rclpy 7.1.x (Jazzy).

rclpy 7.1.6, the Jazzy wheel on PyPI that this project installs, re-submits tasks that are still
queued in a ``MultiThreadedExecutor``'s thread pool, in a loop that never blocks
(ros2/rclpy#1452; fixed upstream after Jazzy by ros2/rclpy#1469 and #1547, not in this wheel).
:class:`NodeExecutor` hands each task to the pool once; ``test/test_nodes_executor.py`` proves
both the fix and that the stock executor still re-submits, so it fails when a fixed rclpy
arrives and this module can go. Built on private attributes of rclpy's executor
(``_executor``, ``_futures``, ``_is_shutdown``, ``_context``, ``_spin_once_impl``), which is why
it is kept apart. :meth:`NodeExecutor.spin_until` is how a node process stops on Ctrl-C
(``runtime.run_nodes``).

:func:`shutdown_executor` stops such an executor so that callbacks still running finish before
nodes are destroyed (Jazzy's ``Executor.shutdown`` does not wait for them).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, ShutdownException


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
    number of threads) is rclpy's. (The samples of the nodes' inputs are taken by each node's
    input reader, :class:`~.take.InputReader`, which hands the executor only those it passes.)
    """

    def __init__(self, num_threads: int | None = None, *, context=None):
        super().__init__(num_threads, context=context)
        workers = self._executor._max_workers
        self._executor.shutdown(wait=False)
        self._queued: set = set()  # tasks submitted to the pool that no worker has started yet
        self._queued_cv = threading.Condition()
        self._executor = _StartReportingPool(workers, self._task_started)

    def spin_until(self, stop: Callable[[], bool]) -> None:
        """``spin()`` that also returns once ``stop()`` is true: rclpy's wait condition (the one
        ``spin_once_until_future_complete`` uses, private ``_spin_once_impl``) is checked after every
        wake-up, so ``stop`` set and :meth:`wake` called from a signal handler end the spin at
        once, whatever the context's state. Pass the same ``stop`` object every time (rclpy then
        reuses its wait generator)."""
        while self._context.ok() and not self._is_shutdown and not stop():
            self._spin_once_impl(None, stop)

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


def shutdown_executor(executor, timeout_sec: float = 2.0) -> None:
    """Stop ``executor``; let callbacks already running finish before nodes are destroyed.

    Jazzy's ``Executor.shutdown`` does not wait for running callbacks, and
    ``MultiThreadedExecutor`` never stops its thread pool; a callback that then touches a
    destroyed node or a shut-down context leaves "exception was never retrieved" (or "coroutine
    was never awaited") on stderr at exit. So also stop the pool (``_executor``, a
    ``concurrent.futures.ThreadPoolExecutor``: running callbacks, e.g. a search of at most
    ``time_budget``, complete; queued ones are cancelled) and settle the executor's leftover
    tasks (``_futures`` and ``_tasks``): the exceptions of finished ones are retrieved (expected at shutdown),
    unstarted ones are cancelled and their coroutines closed. Private attributes, hence the guards.
    """
    executor.shutdown(timeout_sec=timeout_sec)
    pool = getattr(executor, "_executor", None)
    if pool is not None and hasattr(pool, "shutdown"):
        pool.shutdown(wait=True, cancel_futures=True)
    # _futures: tasks handed to the pool; _tasks: tasks the wait loop made and had not yielded yet
    # (several entities ready at once: it yields one per call), never started at shutdown
    tasks = list(getattr(executor, "_futures", []))
    tasks += [entry[0] for entry in list(getattr(executor, "_tasks", [])) if entry and entry[0] not in tasks]
    for task in tasks:
        if task.done():
            task.exception()
        else:
            task.cancel()
            handler = getattr(task, "_handler", None)
            if hasattr(handler, "close"):
                handler.close()
