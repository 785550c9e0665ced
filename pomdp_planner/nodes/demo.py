"""``make demo``: the three nodes as three processes, a live per-step table, a summary, a clean exit.

``python -m pomdp_planner.nodes.demo [--steps 30] [--model perimeter_s8] [--time-budget 0.1]`` starts
``target_simulator``, ``belief_filter`` and ``planner`` as separate processes (the installed
console scripts next to this Python if present, as ``ros2 run`` would start them, else
``python -m pomdp_planner.nodes.<name>``) with ``config/<node>_<model>.yaml``, on this machine only
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and a ROS domain of its own (``ROS_DOMAIN_ID``,
random unless ``--domain-id``). ``--model`` is one of the shipped parameter sets
(``processes.PARAMETER_SETS``): ``s3``, ``s8`` (the paper's tracking models) or ``perimeter_s3``,
``perimeter_s8`` (issue 12: greedy loses there and lookahead pays; the default, what ``make demo``
runs, because there the planner searches and differs from greedy). A monitor node prints one row
per decision epoch: step, true state, belief mode and Shannon entropy (nats), the action chosen
from that belief, the greedy action ``argmax_a rho(b, a)`` at the same belief (the core's
``myopic`` policy), depth reached, certified, decision latency. After ``--steps`` epochs it sends
SIGINT to the three processes, waits for them, and prints the mean reward
``r(s_t, a_t) - w_a f(b_t)`` (true state, the model's uncertainty function), the mean entropy, on
how many steps the planner chose other than greedy, and the deadline misses among the decisions
shown (each decision's ``plan_info.deadline_miss``: the planner's rule, latency >
``time_budget + deadline_slack``).
Exit code 0 if all three processes exited cleanly (code 0, no traceback).

The demo runs the loop free (``step_period`` 0, whatever the parameter files say: each action
steps the simulator at once, so each row pairs a belief with the action chosen from it), hundreds
of epochs per second on the shipped models, and discovery between processes can take seconds,
more than the writers' transient-local history (100 epochs) covers. So the monitor must have matched every writer
before the loop starts: the nodes are started filter, planner, simulator, each once the monitor
has the previous one's prior or has matched its writer, and the simulator gets
``min_subscribers`` 2: it takes its first step only when the filter and the monitor both
subscribe to its observations. If the monitor still misses the first epochs, the table starts
at the first complete one and says so (no hang).
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.io.model_yaml import load_model
from ..core.policies import MyopicPolicy
from ..core.uncertainty import SHANNON
from .messages import decode_belief, decode_observation, decode_plan_info, decode_true_state
from .processes import PARAMETER_SETS, parameter_set_model, ros_env, start_nodes, stop_nodes
from .qos import RECORDER_QOS


class Monitor:
    """Subscribes to the loop's topics (in its own rclpy context) and assembles per-epoch rows."""

    def __init__(self, model_path: Path):
        self.model = load_model(model_path)
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node("demo_monitor", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.beliefs: dict[int, object] = {}
        self.states: dict[int, int] = {}
        self.info: dict[int, dict] = {}
        self.observations: dict[int, tuple[int, int]] = {}
        self.observation_time: dict[int, float] = {}
        S = self.model.S
        self.node.create_subscription(Float64MultiArray, "belief",
                                      lambda msg: self._store(self.beliefs, decode_belief(msg, S)), RECORDER_QOS)
        self.node.create_subscription(Int64MultiArray, "true_state",
                                      lambda msg: self.states.__setitem__(*decode_true_state(msg)), RECORDER_QOS)
        self.subs = {
            "plan_info": self.node.create_subscription(Float64MultiArray, "plan_info", self._on_info,
                                                       RECORDER_QOS),
            "observation": self.node.create_subscription(Int64MultiArray, "observation", self._on_observation,
                                                         RECORDER_QOS),
        }

    @staticmethod
    def _store(d, bel):
        d[bel.epoch] = bel.belief

    def _on_info(self, msg):
        info = decode_plan_info(msg)
        self.info[int(info["epoch"])] = info

    def _on_observation(self, msg):
        obs = decode_observation(msg, self.model.A, self.model.Z)
        self.observations[obs.epoch] = (obs.priority, obs.observation)
        self.observation_time.setdefault(obs.epoch, time.monotonic())

    def matched(self, topic: str) -> bool:
        """Whether the monitor's subscription to ``topic`` has matched a publisher."""
        return self.subs[topic].get_publisher_count() > 0

    def spin_once(self, timeout: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    def first_complete_epoch(self) -> int | None:
        """The first epoch from which on belief, true state and next observation have all come (the
        earliest each writer delivered), or None before all three have delivered something."""
        if not (self.beliefs and self.states and self.observations):
            return None
        return max(min(self.beliefs), min(self.states), min(self.observations) - 1)

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
    domain_id = random.randint(1, 101) if domain_id is None else domain_id
    os.environ.update(ros_env(domain_id))
    model_path = parameter_set_model(model_key)
    # free running (step_period 0: one step per decision, so each row pairs a belief with the action
    # chosen from it); min_subscribers 2: the first step waits for the filter and this monitor (docstring)
    extra = {"target_simulator": ["-p", "step_period:=0.0", "-p", "min_subscribers:=2"]}
    if time_budget is not None:
        extra["planner"] = ["-p", f"time_budget:={time_budget}"]
    log_dir = Path(tempfile.mkdtemp(prefix="pomdp_planner_demo_"))
    monitor = Monitor(model_path)
    model = monitor.model
    greedy = MyopicPolicy(model)
    print(f"pomdp_planner demo: {model.describe()}; three processes on ROS_DOMAIN_ID={domain_id} "
          f"(localhost only); logs in {log_dir}", file=out)
    header = f"{'step':>4} {'true':>4} {'mode':>4} {'p(mode)':>7} {'entropy':>7} {'action':>6} {'greedy':>6} " \
             f"{'depth':>5} {'certified':>9} {'latency ms':>10}"
    rewards, entropies = [], []
    not_greedy = 0
    misses = decisions = 0
    t = 0
    code = 0
    procs: dict = {}
    try:
        # Start order (module docstring): filter, planner, simulator (which waits for its subscribers)
        for name, ready in (("belief_filter", lambda: 0 in monitor.beliefs),
                            ("planner", lambda: monitor.matched("plan_info")),
                            ("target_simulator", lambda: True)):
            procs.update(start_nodes(model_key, domain_id, log_dir, extra, names=(name,)))
            deadline = time.monotonic() + 30.0
            while not ready() and time.monotonic() < deadline and procs[name][0].poll() is None:
                monitor.spin_once()
        print(header, file=out)
        print("-" * len(header), file=out)
        last_progress = time.monotonic()
        t_end = steps
        while t < t_end:
            monitor.spin_once()
            first = monitor.first_complete_epoch() if not rewards else None
            if first is not None and first > t:  # epochs before the monitor matched a writer never come
                print(f"(the monitor matched the nodes late; the table starts at epoch {first})", file=out)
                t, t_end = first, first + steps
            while t < t_end and monitor.row_ready(t):
                b, s = monitor.beliefs[t], monitor.states[t]
                a = monitor.observations[t + 1][0] - 1
                info = monitor.info.get(t + 1)
                mode = int(b.argmax())
                h = float(SHANNON.value(b))
                rewards.append(float(model.r[s, a] - model.w[a] * model.uncertainty.value(b)))
                entropies.append(h)
                if info is None:  # plan_info not received (the monitor discovered the planner late)
                    extra_cols = f"{'-':>5} {'-':>9} {'-':>10}"
                else:
                    extra_cols = (f"{int(info['depth']):>5} {'yes' if info['certified'] else 'no':>9} "
                                  f"{1e3 * info['latency']:>10.1f}")
                    decisions += 1
                    misses += bool(info["deadline_miss"])
                g = greedy.act(b)
                not_greedy += g != a
                print(f"{t:>4} {s:>4} {mode:>4} {b[mode]:>7.3f} {h:>7.3f} {a + 1:>6} {g + 1:>6} {extra_cols}",
                      file=out, flush=True)
                t += 1
                last_progress = time.monotonic()
            dead = [n for n, (p, _) in procs.items() if p.poll() is not None]
            if dead or time.monotonic() - last_progress > 60.0:
                print(f"demo: {'process(es) ' + ', '.join(dead) + ' exited' if dead else 'no progress for 60 s'}; "
                      "stopping", file=sys.stderr)
                code = 1
                break
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
        print(f"\nsummary over {len(rewards)} steps: mean reward {sum(rewards) / len(rewards):.4f}, "
              f"mean entropy {sum(entropies) / len(entropies):.4f} nats, action other than greedy's on "
              f"{not_greedy} of {len(rewards)} steps, deadline misses "
              f"{misses} of {decisions} decisions shown (the planner's rule: latency > time_budget + "
              f"deadline_slack); "
              f"exit codes {codes}", file=out)
    return code


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pomdp_planner.nodes.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=30, help="decision epochs to run (default 30)")
    parser.add_argument("--model", choices=PARAMETER_SETS, default="perimeter_s8",
                        help="shipped parameter set config/<node>_<model>.yaml: s3, s8 (the paper's tracking "
                             "models), perimeter_s3, perimeter_s8 (models where lookahead pays; the default)")
    parser.add_argument("--time-budget", type=float, default=None, help="planner time_budget override (s)")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: random 1..101)")
    args = parser.parse_args(argv)
    if args.steps < 1:
        parser.error("--steps: must be at least 1")
    return run(args.steps, args.model, args.time_budget, args.domain_id)


if __name__ == "__main__":
    sys.exit(main())
