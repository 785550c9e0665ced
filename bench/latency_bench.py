"""Observation-to-action latency of the node loop (a benchmark, not a test).

For each time budget, runs the closed loop (S = 8 model by default, ``max_depth`` high enough
that the budget binds) and measures, at a probe node, the time from receiving the observation of
epoch ``t`` to receiving the planner's action of epoch ``t + 1``: belief filter update, belief
transport, planning (anytime search under ``time_budget``) and action transport. Both
timestamps are taken by the same probe, so no clock synchronisation is involved.

    python bench/latency_bench.py                        # in-process (one NodeExecutor)
    python bench/latency_bench.py --processes            # three processes, as ros2 run starts them
    python bench/latency_bench.py --budgets 0.05 0.1 0.5 --decisions 40 --model s8

Prints, per budget: median and 99th percentile of the latency and of the overhead beyond the
budget, the planner's own time_used (median), the depth reached, and how many decisions
exceeded ``time_budget + deadline_slack``.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from pomdp_planner.nodes import demo
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.common import NodeExecutor, resolve_path, shutdown_executor
from pomdp_planner.nodes.messages import decode_plan_info
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.target_simulator import TargetSimulator


class Probe(Node):
    def __init__(self, context):
        super().__init__("latency_probe", context=context)
        deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.obs_time: dict[int, float] = {}
        self.act_time: dict[int, float] = {}
        self.info: dict[int, dict] = {}
        self.cond = threading.Condition()
        self.create_subscription(Int64MultiArray, "observation", self._on_obs, deep)
        self.create_subscription(Int64MultiArray, "action", self._on_act, deep)
        self.create_subscription(Float64MultiArray, "plan_info", self._on_info, deep)

    def _on_obs(self, msg):
        with self.cond:
            self.obs_time.setdefault(int(msg.data[0]), time.perf_counter())

    def _on_act(self, msg):
        with self.cond:
            self.act_time.setdefault(int(msg.data[0]), time.perf_counter())
            self.cond.notify_all()

    def _on_info(self, msg):
        info = decode_plan_info(msg)
        with self.cond:
            self.info[int(info["epoch"])] = info
            self.cond.notify_all()

    def complete_epochs(self) -> list[int]:
        """Epochs ``t`` with observation ``t``, action ``t + 1`` and plan_info ``t + 1`` all received
        (call with ``cond`` held). The probe may match the three topics at different times, and the
        loop runs hundreds of epochs per second, so counting actions alone is not enough."""
        return sorted(t for t in self.obs_time if t + 1 in self.act_time and t + 1 in self.info)


def measure(budget: float, decisions: int, model_key: str, max_depth: int, processes: bool) -> dict:
    domain_id = random.randint(1, 101)
    os.environ.update(demo.ros_env(domain_id))
    if not processes:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"
    ctx = Context()
    rclpy.init(context=ctx)
    probe = Probe(ctx)
    executor = NodeExecutor(context=ctx)
    executor.add_node(probe)
    nodes, procs = [], {}
    if processes:
        extra = {"planner": ["-p", f"time_budget:={budget}", "-p", f"max_depth:={max_depth}"]}
        procs = demo.start_nodes(model_key, domain_id, Path(tempfile.mkdtemp(prefix="latency_bench_")), extra)
    else:
        model_file = str(resolve_path(f"config/models/tracking_{model_key}_info.yaml"))
        for cls, params in ((TargetSimulator, {}), (BeliefFilter, {}),
                            (PlannerNode, {"time_budget": budget, "max_depth": max_depth})):
            overrides = [Parameter("model_file", value=model_file)] + [Parameter(k, value=v) for k, v in params.items()]
            nodes.append(cls(context=ctx, parameter_overrides=overrides))
            executor.add_node(nodes[-1])
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    warmup = 5
    try:
        with probe.cond:
            ok = probe.cond.wait_for(lambda: len(probe.complete_epochs()) >= decisions + warmup, timeout=600)
        if not ok:
            raise RuntimeError("the loop did not produce enough decisions")
        with probe.cond:
            epochs = probe.complete_epochs()[warmup:warmup + decisions]
            lat = np.array([probe.act_time[t + 1] - probe.obs_time[t] for t in epochs])
            used = np.array([probe.info[t + 1]["time_used"] for t in epochs])
            depth = np.array([probe.info[t + 1]["depth"] for t in epochs])
    finally:
        if procs:
            demo.stop_nodes(procs)
        shutdown_executor(executor)
        thread.join(timeout=2.0)
        for n in [*nodes, probe]:
            n.destroy_node()
        ctx.try_shutdown()
    return {
        "budget": budget, "n": len(lat), "median": float(np.median(lat)), "p99": float(np.percentile(lat, 99)),
        "over_median": float(np.median(lat - budget)), "over_p99": float(np.percentile(lat - budget, 99)),
        "search_median": float(np.median(used)), "depth_min": int(depth.min()), "depth_max": int(depth.max()),
        "misses": int(np.sum(lat > budget + 0.02)),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--budgets", type=float, nargs="+", default=[0.05, 0.1, 0.5])
    p.add_argument("--decisions", type=int, default=40)
    p.add_argument("--model", choices=("s3", "s8"), default="s8")
    p.add_argument("--max-depth", type=int, default=6)
    p.add_argument("--processes", action="store_true", help="three node processes instead of one executor")
    args = p.parse_args(argv)
    mode = "three processes" if args.processes else "one process, NodeExecutor"
    print(f"observation-to-action latency, {args.model}, max_depth {args.max_depth}, {mode}, "
          f"{args.decisions} decisions per budget (after 5 warm-up), load average {os.getloadavg()[0]:.1f}")
    print(f"{'budget s':>8} {'median ms':>9} {'p99 ms':>8} {'over med ms':>11} {'over p99 ms':>11} "
          f"{'search med ms':>13} {'depth':>5} {'>budget+20ms':>12}")
    for b in args.budgets:
        r = measure(b, args.decisions, args.model, args.max_depth, args.processes)
        depth = f"{r['depth_min']}" if r["depth_min"] == r["depth_max"] else f"{r['depth_min']}-{r['depth_max']}"
        print(f"{b:>8.3f} {1e3 * r['median']:>9.1f} {1e3 * r['p99']:>8.1f} {1e3 * r['over_median']:>11.1f} "
              f"{1e3 * r['over_p99']:>11.1f} {1e3 * r['search_median']:>13.1f} {depth:>5} "
              f"{r['misses']:>5}/{r['n']:<6}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
