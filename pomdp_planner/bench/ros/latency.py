"""Observation-to-action latency of the node loop (a benchmark, not a test).

For each time budget, runs the free-running closed loop (S = 8 model by default) and measures,
per decision, the time from the simulator publishing the observation of epoch ``t`` to the
planner publishing its action of epoch ``t + 1``: belief filter update, belief transport,
planning (anytime search under ``time_budget``) and publishing the action. The two times are the
writers' source timestamps as a probe node receives them with each message
(``MessageInfo.source_timestamp``, the system clock; all processes run on this machine, so no
synchronisation is involved). The same interval at the probe, from its DDS reception of the
observation to that of the action and from callback to callback, is reported as a 99th
percentile too: that adds what an observer of the loop sees (transport to it, its own executor).

On the shipped models the bounds certify most decisions at depth 1 within a millisecond, so the
loop runs as fast as messages flow (a test of the transport and the executors); ``--no-bounds``
(exhaustive search, ``max_depth`` high enough) makes every search use its whole budget, to
measure the overhead beyond the budget.

    python -m pomdp_planner.bench.ros.latency               # in-process (one NodeExecutor)
    python -m pomdp_planner.bench.ros.latency --processes   # three processes, as ros2 run starts them
    python -m pomdp_planner.bench.ros.latency --budgets 0.05 0.1 0.5 --decisions 300 --model s3 --no-bounds

Prints, per budget: median and 99th percentile of the loop latency and of the overhead beyond
the budget, the planner's own time_used (median), the depth reached, how many decisions exceeded
``time_budget`` + 20 ms (the default ``deadline_slack``), and the 99th percentiles at the probe.
"""

from __future__ import annotations

import os
import random
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ...core.io.paths import resolve_path
from ...core.one_line import Parser
from ...nodes.belief_filter import BeliefFilter
from ...nodes.executor import NodeExecutor, shutdown_executor
from ...nodes.messages import decode_plan_info
from ...nodes.planner import PlannerNode
from ...nodes.processes import ros_env, start_nodes, stop_nodes
from ...nodes.qos import RECORDER_QOS
from ...nodes.target_simulator import TargetSimulator


class Probe(Node):
    def __init__(self, context):
        super().__init__("latency_probe", context=context)
        # per epoch: (writer's source timestamp, probe's DDS reception, probe's callback), s, system clock
        self.obs_time: dict[int, tuple[float, float, float]] = {}
        self.act_time: dict[int, tuple[float, float, float]] = {}
        self.info: dict[int, dict] = {}
        self.cond = threading.Condition()
        self.create_subscription(Int64MultiArray, "observation", self._on_obs, RECORDER_QOS)
        self.create_subscription(Int64MultiArray, "action", self._on_act, RECORDER_QOS)
        self.create_subscription(Float64MultiArray, "plan_info", self._on_info, RECORDER_QOS)

    @staticmethod
    def _times(info) -> tuple[float, float, float]:
        return info["source_timestamp"] * 1e-9, info["received_timestamp"] * 1e-9, time.time()

    def _on_obs(self, msg, info):
        with self.cond:
            self.obs_time.setdefault(int(msg.data[0]), self._times(info))

    def _on_act(self, msg, info):
        with self.cond:
            self.act_time.setdefault(int(msg.data[0]), self._times(info))
            self.cond.notify_all()

    def _on_info(self, msg):
        info = decode_plan_info(msg)
        with self.cond:
            self.info[int(info["epoch"])] = info
            self.cond.notify_all()

    def measured_epochs(self, warmup_epochs: int = 5, warmup_s: float = 1.0) -> list[int]:
        """Epochs ``t`` with observation ``t``, action ``t + 1`` and plan_info ``t + 1`` all received,
        after a warm-up (call with ``cond`` held). The probe matches the three writers at different
        times while the loop runs hundreds of epochs per second, and a reader that matches a
        transient-local writer mid-stream first gets its history and then the live samples in
        order: measured on three processes, the actions reached the probe up to 0.3 s late for
        about the first 0.25 s after it matched the planner (the loop itself was not delayed). So
        the first ``warmup_epochs`` complete epochs and those within ``warmup_s`` of the first
        are skipped."""
        done = sorted(t for t in self.obs_time if t + 1 in self.act_time and t + 1 in self.info)
        if not done:
            return []
        start = self.act_time[done[0] + 1][1] + warmup_s
        return [t for t in done[warmup_epochs:] if self.act_time[t + 1][1] >= start]


def measure(budget: float, decisions: int, model_key: str, max_depth: int, processes: bool,
            use_bounds: bool = True) -> dict:
    domain_id = random.randint(1, 101)
    os.environ.update(ros_env(domain_id))
    if not processes:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"
    ctx = Context()
    rclpy.init(context=ctx)
    probe = Probe(ctx)
    executor = NodeExecutor(context=ctx)
    executor.add_node(probe)
    nodes, procs = [], {}
    if processes:
        extra = {"planner": ["-p", f"time_budget:={budget}", "-p", f"max_depth:={max_depth}",
                             "-p", f"use_bounds:={str(use_bounds).lower()}"],
                 "target_simulator": ["-p", "step_period:=0.0"]}  # free running (the files say 10 Hz)
        procs = start_nodes(model_key, domain_id, Path(tempfile.mkdtemp(prefix="latency_bench_")), extra)
    else:
        model_file = str(resolve_path(f"config/models/tracking_{model_key}_info.yaml"))
        for cls, params in ((TargetSimulator, {}), (BeliefFilter, {}),
                            (PlannerNode, {"time_budget": budget, "max_depth": max_depth, "use_bounds": use_bounds})):
            overrides = [Parameter("model_file", value=model_file)] + [Parameter(k, value=v) for k, v in params.items()]
            nodes.append(cls(context=ctx, parameter_overrides=overrides))
            executor.add_node(nodes[-1])
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        with probe.cond:
            ok = probe.cond.wait_for(lambda: len(probe.measured_epochs()) >= decisions, timeout=600)
        if not ok:
            raise RuntimeError("the loop did not produce enough decisions")
        with probe.cond:
            epochs = probe.measured_epochs()[:decisions]
            # columns: loop (source timestamps), at the probe's DDS reception, at the probe's callbacks
            lat_all = np.array([np.subtract(probe.act_time[t + 1], probe.obs_time[t]) for t in epochs])
            lat = lat_all[:, 0]
            used = np.array([probe.info[t + 1]["time_used"] for t in epochs])
            depth = np.array([probe.info[t + 1]["depth"] for t in epochs])
    finally:
        if procs:
            stop_nodes(procs)
        shutdown_executor(executor)
        thread.join(timeout=2.0)
        for n in [*nodes, probe]:
            n.destroy_node()
        ctx.try_shutdown()
    return {
        "budget": budget, "n": len(lat), "median": float(np.median(lat)), "p99": float(np.percentile(lat, 99)),
        "over_median": float(np.median(lat - budget)), "over_p99": float(np.percentile(lat - budget, 99)),
        "search_median": float(np.median(used)), "depth_min": int(depth.min()), "depth_max": int(depth.max()),
        "misses": int(np.sum(lat > budget + 0.02)), "p99_probe": float(np.percentile(lat_all[:, 1], 99)),
        "p99_callback": float(np.percentile(lat_all[:, 2], 99)),
    }


def main(argv=None) -> int:
    p = Parser(prog="python -m pomdp_planner.bench.ros.latency", description=__doc__.split("\n")[0])
    p.add_argument("--budgets", type=float, nargs="+", default=[0.05, 0.1, 0.5])
    p.add_argument("--decisions", type=int, default=40)
    p.add_argument("--model", choices=("s3", "s8"), default="s8")
    p.add_argument("--max-depth", type=int, default=6)
    p.add_argument("--processes", action="store_true", help="three node processes instead of one executor")
    p.add_argument("--no-bounds", action="store_true", help="exhaustive search (use_bounds false): the budget binds")
    args = p.parse_args(argv)
    mode = "three processes" if args.processes else "one process, NodeExecutor"
    search = "exhaustive search" if args.no_bounds else "branch-and-bound"
    print(f"observation-to-action latency, {args.model}, {search}, max_depth {args.max_depth}, {mode}, "
          f"{args.decisions} decisions per budget (after >= 5 and >= 1 s of warm-up), "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'budget s':>8} {'median ms':>9} {'p99 ms':>8} {'over med ms':>11} {'over p99 ms':>11} "
          f"{'search med ms':>13} {'depth':>5} {'>budget+20ms':>12} {'probe p99 ms':>12} {'callback p99 ms':>15}")
    for b in args.budgets:
        r = measure(b, args.decisions, args.model, args.max_depth, args.processes, not args.no_bounds)
        depth = f"{r['depth_min']}" if r["depth_min"] == r["depth_max"] else f"{r['depth_min']}-{r['depth_max']}"
        print(f"{b:>8.3f} {1e3 * r['median']:>9.1f} {1e3 * r['p99']:>8.1f} {1e3 * r['over_median']:>11.1f} "
              f"{1e3 * r['over_p99']:>11.1f} {1e3 * r['search_median']:>13.1f} {depth:>5} "
              f"{r['misses']:>5}/{r['n']:<6} {1e3 * r['p99_probe']:>12.1f} {1e3 * r['p99_callback']:>15.1f}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
