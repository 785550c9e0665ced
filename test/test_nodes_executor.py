"""``executor.NodeExecutor``: every ready callback is handed to the thread pool once.

Regression test for the stalls of the free-running node loop (README, "Latency"): Jazzy's
``MultiThreadedExecutor`` yields a task again while it still waits in the pool's queue and
submits it again, in a loop that never blocks, so a busy pool turned into hundreds of queued
duplicates and a spinning thread that held the GIL. Here both workers are kept busy by
callbacks in their own groups while a third group's callback is ready: its task must be queued
once, not re-submitted while it waits. Counts, not wall-clock times, are asserted.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import make_harness

rclpy = pytest.importorskip("rclpy")
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

from pomdp_planner.nodes.executor import NodeExecutor, shutdown_executor  # noqa: E402

harness = pytest.fixture(make_harness)
BUSY = 0.05  # s a callback holds its worker (time.sleep: without the GIL)
RUNS = 4     # callbacks per timer before the run stops


def _run_busy_pool(context, executor_cls) -> tuple[Counter, Counter]:
    """Three timers in three groups, two workers, each callback sleeps ``BUSY``; returns
    (submissions per task, callbacks run per timer)."""
    node = Node("busy_pool", context=context)
    executor = executor_cls(num_threads=2, context=context)
    submitted: Counter = Counter()
    alive = []  # keeps every submitted task alive, so that no id() is reused
    pool_submit = executor._executor.submit

    def counting_submit(fn, /, *args, **kwargs):
        alive.append(fn)
        submitted[id(fn)] += 1
        return pool_submit(fn, *args, **kwargs)

    executor._executor.submit = counting_submit
    ran: Counter = Counter()
    done = threading.Event()

    def work(k):
        def cb():
            ran[k] += 1
            time.sleep(BUSY)
            if min(ran[j] for j in range(3)) >= RUNS:
                done.set()
        return cb

    for k in range(3):
        node.create_timer(0.001, work(k), callback_group=MutuallyExclusiveCallbackGroup())
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        assert done.wait(timeout=30.0), f"callbacks did not all run {RUNS} times: {dict(ran)}"
    finally:
        shutdown_executor(executor)
        thread.join(timeout=5.0)
        node.destroy_node()
    return submitted, ran


def test_node_executor_submits_each_task_once(harness):
    submitted, ran = _run_busy_pool(harness.context, NodeExecutor)
    assert min(ran.values()) >= RUNS
    dup = {k: n for k, n in submitted.items() if n > 1}
    assert not dup, f"{len(dup)} tasks submitted more than once (max {max(dup.values())} times)"
    # one submission per callback run, plus at most one per timer still queued at the stop
    assert sum(submitted.values()) <= sum(ran.values()) + 3


def test_stock_executor_resubmits_queued_tasks(harness):
    """Documents the upstream behaviour the fix is for (if a future rclpy fixes it, this test
    fails and NodeExecutor can go: see its docstring)."""
    submitted, _ = _run_busy_pool(harness.context, MultiThreadedExecutor)
    assert max(submitted.values()) > 1


def test_node_executor_reports_a_shut_down_context_as_shutdown():
    """Ctrl-C shuts the context down while the executor may be between two waits: it must say
    so with rclpy's ExternalShutdownException (a clean exit in run_nodes), not fail building a
    wait set on the dead context (RCLError; seen once as a node exiting 1 on SIGINT)."""
    context = Context()
    rclpy.init(context=context)
    node = Node("shutdown_probe", context=context)
    executor = NodeExecutor(num_threads=2, context=context)
    executor.add_node(node)
    node.destroy_node()
    rclpy.shutdown(context=context)
    with pytest.raises(ExternalShutdownException):
        executor.wait_for_ready_callbacks(timeout_sec=0.1)
    executor.shutdown()
