"""Soak benchmark: the closed loop as three processes for a long run, with the memory (RSS) and CPU
of each process sampled over time (a benchmark, not a test).

    python -m pomdp_planner.bench.ros.soak                       # free running, >= 50 000 epochs or 10 min
    python -m pomdp_planner.bench.ros.soak --step-period 0.1 --minutes 2   # the shipped 10 Hz sensor rate
    python -m pomdp_planner.bench.ros.soak --nodes belief_filter --minutes 1   # one node alone (idle)

Starts the node executables as ``ros2 run`` would (``nodes/processes.py``) with the shipped
parameter files ``config/<node>_<model>.yaml`` and ``step_period`` from the command line (0 = free
running, one step per decision: the most epochs per minute, so the strongest test of growth per
epoch). Every ``--sample`` seconds it reads each process's resident set size (``VmRSS`` of
``/proc/<pid>/status``; psutil is not a dependency) and CPU time (``utime + stime`` of
``/proc/<pid>/stat``), and the loop's epoch from the belief filter's ``/diagnostics`` (the probe
subscribes to nothing else, so it adds no load to the loop's topics). It stops at ``--epochs``
epochs or after ``--minutes``, whichever comes first, and prints a table of the samples, then per
process: RSS at the end of the warm-up and at the end, the least-squares growth of RSS per 10 000
epochs over the samples after the warm-up (the first ``--warmup`` of the run; per minute when the
loop does not advance) with the spread of the residuals (the noise to compare it with), and the
mean CPU over the measured part of the run in % of one core.
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
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from ...core.one_line import Parser
from ...nodes.processes import NODES, ros_env, start_nodes, stop_nodes

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def rss_mib(pid: int) -> float:
    """Resident set size of process ``pid`` in MiB (``VmRSS`` of ``/proc/<pid>/status``)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmRSS for process {pid}")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far (``/proc/<pid>/stat`` fields 14 and 15)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) "
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


class DiagnosticsProbe(Node):
    """Keeps the newest ``epoch`` that the belief filter (or, alone, the simulator) reports."""

    def __init__(self, context):
        super().__init__("soak_probe", context=context)
        self.epoch = 0
        self.lock = threading.Lock()
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name.startswith(("belief_filter", "target_simulator")):
                values = {kv.key: kv.value for kv in st.values}
                with self.lock:
                    self.epoch = max(self.epoch, int(values.get("epoch", 0)))


def growth(epochs: np.ndarray, times: np.ndarray, rss: np.ndarray) -> tuple[float, str, float]:
    """Least-squares slope of RSS: per 10 000 epochs if the loop advanced, else per minute; and the
    standard deviation of the residuals (MiB)."""
    x, unit = (epochs / 1e4, "MiB/10k epochs") if epochs[-1] > epochs[0] else (times / 60.0, "MiB/min")
    if len(x) < 2 or x[-1] == x[0]:
        return 0.0, unit, 0.0
    slope, intercept = np.polyfit(x, rss, 1)
    return float(slope), unit, float(np.std(rss - (slope * x + intercept)))


def run(model: str, step_period: float, epochs: int, minutes: float, sample: float, warmup: float,
        names: tuple[str, ...], time_budget: float | None = None, out=sys.stdout) -> int:
    domain_id = random.randint(1, 101)
    os.environ.update(ros_env(domain_id))
    log_dir = Path(tempfile.mkdtemp(prefix="pomdp_planner_soak_"))
    extra = {"target_simulator": ["-p", f"step_period:={step_period}"]}
    if time_budget is not None:
        extra["planner"] = ["-p", f"time_budget:={time_budget}"]
    ctx = Context()
    rclpy.init(context=ctx)
    probe = DiagnosticsProbe(ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(probe)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    procs = start_nodes(model, domain_id, log_dir, extra, names=names)
    mode = ("free running" if step_period == 0 else f"step_period {step_period:g} s") + (
        "" if time_budget is None else f", time_budget {time_budget:g} s")
    print(f"soak: {model}, {', '.join(names)} as processes, {mode}, until {epochs} epochs or {minutes:g} min, "
          f"a sample every {sample:g} s; load average {os.getloadavg()[0]:.1f}; logs in {log_dir}", file=out)
    header = f"{'t s':>7} {'epoch':>8} " + " ".join(f"{n + ' MiB':>22}" for n in names)
    print(header, file=out)
    rows = []
    start = time.monotonic()
    code = 0
    try:
        while True:
            now = time.monotonic() - start
            with probe.lock:
                epoch = probe.epoch
            rss = [rss_mib(p.pid) for p, _ in procs.values()]
            cpu = [cpu_seconds(p.pid) for p, _ in procs.values()]
            rows.append((now, epoch, rss, cpu))
            print(f"{now:>7.0f} {epoch:>8} " + " ".join(f"{r:>22.2f}" for r in rss), file=out, flush=True)
            if epoch >= epochs or now >= 60 * minutes:
                break
            dead = [n for n, (p, _) in procs.items() if p.poll() is not None]
            if dead:
                print(f"soak: {', '.join(dead)} exited; see {log_dir}", file=sys.stderr)
                code = 1
                break
            time.sleep(sample)
    finally:
        codes = stop_nodes(procs)
        executor.shutdown(timeout_sec=1.0)
        spin.join(timeout=2.0)
        probe.destroy_node()
        ctx.try_shutdown()
    measured = [r for r in rows if r[0] >= warmup * rows[-1][0]]
    if len(measured) < 2:
        print("soak: too short to measure", file=out)
        return 1
    t = np.array([r[0] for r in measured])
    ep = np.array([r[1] for r in measured], dtype=float)
    print(f"\nover {t[-1] - t[0]:.0f} s after the warm-up ({warmup:.0%} of the run), epochs "
          f"{int(ep[0])}..{int(ep[-1])} ({(ep[-1] - ep[0]) / max(t[-1] - t[0], 1e-9):.0f} per s):", file=out)
    print(f"{'process':>17} {'RSS start MiB':>13} {'RSS end MiB':>11} {'growth':>24} {'residual sd MiB':>15} "
          f"{'CPU % of a core':>15}", file=out)
    for k, name in enumerate(names):
        rss = np.array([r[2][k] for r in measured])
        slope, unit, sd = growth(ep, t, rss)
        cpu = 100.0 * (measured[-1][3][k] - measured[0][3][k]) / (t[-1] - t[0])
        print(f"{name:>17} {rss[0]:>13.2f} {rss[-1]:>11.2f} {slope:>+9.3f} {unit:<14} {sd:>15.3f} {cpu:>15.1f}",
              file=out)
    print(f"exit codes {codes}", file=out)
    return code or int(any(c != 0 for c in codes.values()))


def main(argv=None) -> int:
    p = Parser(prog="python -m pomdp_planner.bench.ros.soak", description=__doc__.split("\n")[0])
    p.add_argument("--model", choices=("s3", "s8"), default="s8")
    p.add_argument("--step-period", type=float, default=0.0, help="simulator step_period (0 = free running)")
    p.add_argument("--epochs", type=int, default=50_000, help="stop at this epoch (default 50 000)")
    p.add_argument("--minutes", type=float, default=10.0, help="or after this many minutes (default 10)")
    p.add_argument("--sample", type=float, default=10.0, help="seconds between samples (default 10)")
    p.add_argument("--warmup", type=float, default=0.2, help="fraction of the run left out of the fit (default 0.2)")
    p.add_argument("--nodes", nargs="+", choices=NODES, default=list(NODES), help="node processes to run")
    p.add_argument("--time-budget", type=float, default=None, help="planner time_budget (default: the file's)")
    args = p.parse_args(argv)
    if args.sample <= 0 or not 0 <= args.warmup < 1:
        p.error("--sample must be > 0 and --warmup in [0, 1)")
    return run(args.model, args.step_period, args.epochs, args.minutes, args.sample, args.warmup, tuple(args.nodes),
               args.time_budget)


if __name__ == "__main__":
    sys.exit(main())
