"""``make demo``: the three nodes as three processes, a live per-step table, a summary, a clean exit.

``python -m pomdp_planner.nodes.demo [--steps 30] [--model s8] [--time-budget 0.1]`` starts
``target_simulator``, ``belief_filter`` and ``planner`` as separate processes (the installed
console scripts next to this Python if present, as ``ros2 run`` would start them, else
``python -m pomdp_planner.nodes.<name>``) with ``config/<node>_<model>.yaml``, on this machine only
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and a ROS domain of its own (``ROS_DOMAIN_ID``,
random unless ``--domain-id``). A monitor node prints one row per decision epoch: step, true
state, belief mode and Shannon entropy (nats), the action chosen from that belief, depth reached,
certified, decision latency. After ``--steps`` epochs it sends SIGINT to the three processes,
waits for them, and prints the mean reward ``r(s_t, a_t) - w_a f(b_t)`` (true state, the model's
uncertainty function), the mean entropy and the planner's deadline misses. Exit code 0 if all
three processes exited cleanly (code 0, no traceback).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

NODES = ("target_simulator", "belief_filter", "planner")


def node_command(name: str) -> list[str]:
    """How ``ros2 run pomdp_planner <name>`` would start the node: the installed console script if
    it sits next to this interpreter (a venv's ``bin``), else ``python -m pomdp_planner.nodes.<name>``."""
    script = Path(sys.executable).parent / name
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-m", f"pomdp_planner.nodes.{name}"]


def ros_env(domain_id: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1")
    return env


def start_nodes(model: str, domain_id: int, log_dir: Path, extra: dict[str, list[str]] | None = None,
                names=NODES) -> dict[str, tuple[subprocess.Popen, Path]]:
    """Start node processes with ``config/<name>_<model>.yaml``; output goes to ``log_dir/<name>.log``."""
    from .common import resolve_path

    procs = {}
    env = ros_env(domain_id)
    for name in names:
        params = resolve_path(f"config/{name}_{model}.yaml", "params file")
        cmd = [*node_command(name), "--ros-args", "--params-file", str(params), *(extra or {}).get(name, [])]
        log = log_dir / f"{name}.log"
        with open(log, "wb") as fh:
            procs[name] = (subprocess.Popen(cmd, env=env, stdout=fh, stderr=subprocess.STDOUT), log)
    return procs


def stop_nodes(procs: dict[str, tuple[subprocess.Popen, Path]], timeout: float = 10.0) -> dict[str, int]:
    """SIGINT every process (as Ctrl-C would), wait, SIGKILL stragglers; returns the exit codes."""
    for p, _ in procs.values():
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    codes = {}
    deadline = time.monotonic() + timeout
    for name, (p, _) in procs.items():
        try:
            codes[name] = p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            codes[name] = p.wait()
    return codes


class Monitor:
    """Subscribes to the loop's topics (in its own rclpy context) and assembles per-epoch rows."""

    def __init__(self, model_path: Path):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64MultiArray, Int64MultiArray

        from ..core.io.model_yaml import load_model
        from . import messages as m

        self.model = load_model(model_path)
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = Node("demo_monitor", context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.beliefs: dict[int, object] = {}
        self.states: dict[int, int] = {}
        self.info: dict[int, dict] = {}
        self.observations: dict[int, tuple[int, int]] = {}
        self.observation_time: dict[int, float] = {}
        self.planner_diag: dict[str, str] = {}
        S = self.model.S
        self.node.create_subscription(Float64MultiArray, "belief",
                                      lambda msg: self._store(self.beliefs, m.decode_belief(msg, S)), deep)
        self.node.create_subscription(Int64MultiArray, "true_state",
                                      lambda msg: self.states.__setitem__(*m.decode_true_state(msg)), deep)
        self.node.create_subscription(Float64MultiArray, "plan_info", self._on_info, deep)
        self.node.create_subscription(Int64MultiArray, "observation", self._on_observation, deep)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)
        self._m = m

    @staticmethod
    def _store(d, bel):
        d[bel.epoch] = bel.belief

    def _on_info(self, msg):
        info = self._m.decode_plan_info(msg)
        self.info[int(info["epoch"])] = info

    def _on_observation(self, msg):
        obs = self._m.decode_observation(msg, self.model.A, self.model.Z)
        self.observations[obs.epoch] = (obs.priority, obs.observation)
        self.observation_time.setdefault(obs.epoch, time.monotonic())

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name.startswith("planner"):
                self.planner_diag = {kv.key: kv.value for kv in st.values}

    def spin_once(self, timeout: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    def row_ready(self, t: int, info_wait: float = 1.0) -> bool:
        """Belief and true state of epoch ``t``, the observation of ``t + 1`` (it carries the action
        chosen from that belief) and the planner's ``plan_info`` of ``t + 1``, or, if that has not
        come ``info_wait`` s after the observation (missed before discovery), the row without it."""
        if not (t in self.beliefs and t in self.states and (t + 1) in self.observations):
            return False
        return (t + 1) in self.info or time.monotonic() - self.observation_time[t + 1] > info_wait

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


def run(steps: int, model_key: str, time_budget: float | None, domain_id: int | None, out=sys.stdout) -> int:
    from .common import resolve_path, shannon_entropy

    domain_id = random.randint(1, 101) if domain_id is None else domain_id
    os.environ.update(ros_env(domain_id))
    model_path = resolve_path(f"config/models/tracking_{model_key}_info.yaml")
    extra = {"planner": ["-p", f"time_budget:={time_budget}"]} if time_budget is not None else None
    log_dir = Path(tempfile.mkdtemp(prefix="pomdp_planner_demo_"))
    monitor = Monitor(model_path)
    model = monitor.model
    print(f"pomdp_planner demo: {model.describe()}; three processes on ROS_DOMAIN_ID={domain_id} "
          f"(localhost only); logs in {log_dir}", file=out)
    header = f"{'step':>4} {'true':>4} {'mode':>4} {'p(mode)':>7} {'entropy':>7} {'action':>6} {'depth':>5} " \
             f"{'certified':>9} {'latency ms':>10}"
    rewards, entropies = [], []
    t = 0
    code = 0
    procs: dict = {}
    try:
        # The planner starts once the monitor has the prior and the initial state, so no row is missed.
        procs.update(start_nodes(model_key, domain_id, log_dir, extra, names=NODES[:2]))
        deadline = time.monotonic() + 30.0
        while not (0 in monitor.beliefs and 0 in monitor.states) and time.monotonic() < deadline:
            monitor.spin_once()
        procs.update(start_nodes(model_key, domain_id, log_dir, extra, names=NODES[2:]))
        print(header, file=out)
        print("-" * len(header), file=out)
        last_progress = time.monotonic()
        while t < steps:
            monitor.spin_once()
            while t < steps and monitor.row_ready(t):
                b, s = monitor.beliefs[t], monitor.states[t]
                a = monitor.observations[t + 1][0] - 1
                info = monitor.info.get(t + 1)
                mode = int(b.argmax())
                h = shannon_entropy(b)
                rewards.append(float(model.r[s, a] - model.w[a] * model.uncertainty.value(b)))
                entropies.append(h)
                if info is None:  # plan_info not received (the monitor discovered the planner late)
                    extra_cols = f"{'-':>5} {'-':>9} {'-':>10}"
                else:
                    extra_cols = (f"{int(info['depth']):>5} {'yes' if info['certified'] else 'no':>9} "
                                  f"{1e3 * info['latency']:>10.1f}")
                print(f"{t:>4} {s:>4} {mode:>4} {b[mode]:>7.3f} {h:>7.3f} {a + 1:>6} {extra_cols}",
                      file=out, flush=True)
                t += 1
                last_progress = time.monotonic()
            dead = [n for n, (p, _) in procs.items() if p.poll() is not None]
            if dead or time.monotonic() - last_progress > 60.0:
                print(f"demo: {'process(es) ' + ', '.join(dead) + ' exited' if dead else 'no progress for 60 s'}; "
                      "stopping", file=sys.stderr)
                code = 1
                break
        # the planner's diagnostics (about 1 Hz) after the last step, for the deadline misses
        n_diag = monitor.planner_diag.get("decisions")
        wait_until = time.monotonic() + 2.5
        while time.monotonic() < wait_until and (not monitor.planner_diag
                                                  or monitor.planner_diag.get("decisions") == n_diag):
            monitor.spin_once()
    except KeyboardInterrupt:
        code = 130
    finally:
        codes = stop_nodes(procs)
        monitor.close()
    for name, c in codes.items():
        text = procs[name][1].read_text(errors="replace")
        if c != 0 or "Traceback" in text:
            code = code or 1
            print(f"demo: {name} exited with code {c}; last lines of {procs[name][1]}:", file=sys.stderr)
            print("\n".join(text.splitlines()[-15:]), file=sys.stderr)
    if rewards:
        d = monitor.planner_diag
        print(f"\nsummary over {len(rewards)} steps: mean reward {sum(rewards) / len(rewards):.4f}, "
              f"mean entropy {sum(entropies) / len(entropies):.4f} nats, deadline misses "
              f"{d.get('deadline_misses', '?')} of {d.get('decisions', '?')} decisions "
              f"(budget {d.get('param.time_budget', '?')} s + slack {d.get('param.deadline_slack', '?')} s); "
              f"exit codes {codes}", file=out)
    return code


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pomdp_planner.nodes.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=30, help="decision epochs to run (default 30)")
    parser.add_argument("--model", choices=("s3", "s8"), default="s8", help="shipped model (default s8)")
    parser.add_argument("--time-budget", type=float, default=None, help="planner time_budget override (s)")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: random 1..101)")
    args = parser.parse_args(argv)
    if args.steps < 1:
        parser.error("--steps: must be at least 1")
    return run(args.steps, args.model, args.time_budget, args.domain_id)


if __name__ == "__main__":
    sys.exit(main())
