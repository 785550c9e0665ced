"""``make demo``: the three nodes as three processes, a live per-step table, a summary, a clean exit.

``python -m pomdp_planner.nodes.demo [--steps 30] [--model perimeter_s8] [--time-budget 0.1]
[--keep-logs] [--record FILE]`` starts ``target_simulator``, ``belief_filter`` and ``planner`` as separate
processes (the installed console scripts next to this Python if present, as ``ros2 run`` would
start them, else ``python -m pomdp_planner.nodes.<name>``) with ``config/<node>_<model>.yaml``, on
this machine only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) in the ROS domain ``--domain-id``,
else the exported ``ROS_DOMAIN_ID``, else a random one in 1..101 (:func:`choose_domain_id`).
``--model`` is one of the shipped parameter sets (``processes.PARAMETER_SETS``): ``s3``, ``s8``
(the paper's tracking models) or ``perimeter_s3``, ``perimeter_s8`` (greedy loses there and
lookahead pays; the default, what ``make demo`` runs, because there the planner searches and
differs from greedy).

A legend says what the columns mean on the model (its priorities, the bounds, "certified"). A
monitor node pairs the loop's topics into rows by the run recorder's rule
(``nodes/run_recorder.py``, the core's ``RecorderLoop``: row ``t`` is the belief and true state of
epoch ``t``, the action ``[t + 1, p]`` and the ``plan_info`` of that decision) and prints one row
per decision epoch: step, true state, belief mode and Shannon entropy (nats), the action chosen
from that belief, the root bound interval ``[lower, upper]`` of that decision (the myopic policy
bounds, Theorem 2, from ``plan_info``), the greedy action ``argmax_a rho(b, a)`` at the same
belief (the core's ``myopic`` policy), depth reached, certified (the bounds agree: Proposition 1),
decision latency (what a row shows and the sums below: the core's ``core/loop/run_summary.py``).
After ``--steps`` epochs it sends SIGINT to the three processes, waits for them,
and prints the mean reward ``r(s_t, a_t) - w_a f(b_t)`` (true state, the model's uncertainty
function), the mean entropy, on how many steps the planner chose other than greedy, the deadline
misses among the decisions shown (each decision's ``plan_info.deadline_miss``: the planner's rule,
latency > ``time_budget + deadline_slack``), how many decisions were certified, and the discounted
return ``sum_t gamma^t rho(b_t, a_t)`` of the planner's policy (the core's ``bnb`` with the
planner's parameters) beside greedy's over as many steps, both simulated by the core
(``core.simulate``) from the simulator's seed, so with the same random numbers. ``--record FILE``
writes the table's rows as a run record (``core/io/run_record.py``; ``pomdp-planner plot FILE -o
run.png`` draws it; a FILE ending in ``.mcap`` is a rosbag2 bag with the loop's topics and readings,
``core/io/run_bag.py``), and says where at the end. The nodes' logs go to a temporary directory,
removed at the end unless ``--keep-logs`` (which prints where they are, and records the run into
``run.csv`` there unless ``--record``). Exit code 0 if all three processes exited cleanly (code 0,
no traceback).

The demo runs the loop free (``step_period`` 0, whatever the parameter files say: each action
steps the simulator at once, so each row pairs a belief with the action chosen from it), hundreds
of epochs per second on the shipped models, and discovery between processes can take seconds,
more than the writers' transient-local history (100 epochs) covers. So the monitor must have matched every writer
before the loop starts: the nodes are started filter, planner, simulator, each once the monitor
has matched the previous one's writer, and the simulator gets
``min_subscribers`` 2: it takes its first step only when the filter and the monitor both
subscribe to its observations. If the monitor still misses the first epochs, the table starts
at the first row the rule gives and says so (no hang).
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Int64MultiArray

from ..core.errors import OptionError
from ..core.io.model_yaml import load_model
from ..core.io.outputs import check_output_file
from ..core.io.run_bag import RunBagWriter, open_run_output, write_row
from ..core.io.run_record import RunRecordError
from ..core.loop.recorder_loop import RecorderLoop, RecordRow
from ..core.loop.run_summary import RowFacts, RunSummary
from ..core.model import POMDP
from ..core.policies import make_policy
from ..core.simulate import simulate
from .messages import MessageError, decode_observation
from .processes import PARAMETER_SETS, parameter_set_model, parameter_set_values, ros_env, start_nodes, stop_nodes
from .qos import RECORDER_QOS
from .run_recorder import RunInputs

#: Readings waiting to be written into a bag (the oldest forgotten first; the demo writes them at once).
READINGS_KEPT = 1000
#: Seconds a row of the table waits for its plan_info or true state when their topic has not moved
#: past it (the first row waits for the simulator, started last, to publish its initial state).
ROW_TIMEOUT = 30.0


class Monitor:
    """Subscribes to the loop's topics (in its own rclpy context) and pairs them into rows: the run
    recorder's subscriptions and pairing rule (``nodes/run_recorder.RunInputs``, the core's
    ``RecorderLoop``), true states awaited from the start; and ``observation``, only so that the
    simulator (``min_subscribers`` 2) waits for this monitor too."""

    def __init__(self, model_path: Path):
        self.model = load_model(model_path)
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node("demo_monitor", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.rows: deque[RecordRow] = deque()
        self.loop = RecorderLoop(self.model.S, self.model.A, now=time.monotonic(), row_timeout=ROW_TIMEOUT,
                                 expect_true_state=True)
        self.inputs = RunInputs(self.node, self.loop, lambda out: self.rows.extend(out.rows))
        #: the loop's readings (epoch, priority, z) not yet written into a bag (--record x.mcap)
        self.observations: deque[tuple[int, int, int]] = deque(maxlen=READINGS_KEPT)
        self.subs = {**self.inputs.subscriptions,
                     "observation": self.node.create_subscription(Int64MultiArray, "observation",
                                                                  self._on_observation, RECORDER_QOS)}

    def _on_observation(self, msg: Int64MultiArray) -> None:
        try:
            obs = decode_observation(msg, self.model.A, self.model.Z)
        except MessageError:
            return
        self.observations.append((obs.epoch, obs.priority, obs.observation))

    def matched(self, topic: str) -> bool:
        """Whether the monitor's subscription to ``topic`` has matched a publisher."""
        return self.subs[topic].get_publisher_count() > 0

    def spin_once(self, timeout: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    def state(self) -> str:
        """One line for a run that stalls: the pairing's report and the topics no writer was matched on."""
        with self.inputs.lock:
            report = self.loop.report(time.monotonic())
        newest = ", ".join(f"{t} {self.loop.newest[t]}" for t in sorted(self.loop.newest)) or "none"
        unmatched = [t for t in self.subs if not self.matched(t)]
        return (f"monitor: {report.message}, {len(self.loop.pending)} rows waiting, newest row epoch per topic: "
                f"{newest}; no writer matched on: {', '.join(unmatched) or 'none'}")

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


def legend(model: POMDP, time_budget: float, max_depth: int) -> list[str]:
    """The lines before the table that say what its columns mean on ``model``."""
    names = model.action_names
    meaning = (", ".join(f"{k + 1} = {n}" for k, n in enumerate(names)) if names
               else model.metadata.get("description", ""))
    return [
        f"legend: action, bounds, greedy: priorities 1..{model.A}, the model's actions (1 = the greatest priority"
        f"{'; ' + meaning if meaning else ''})",
        "        bounds [lower, upper]: the myopic policy bounds at the belief (Theorem 2); the optimal action lies "
        "in between",
        "        certified yes: the bounds agree, so the action is optimal (Proposition 1) and the search stops at "
        "depth 1;",
        f"        no: they differ at this belief, so the planner searches the priorities in [lower, upper] to "
        f"depth {max_depth} in {time_budget:g} s",
    ]


def table_row(f: RowFacts) -> str:
    """One line of the table (``f``: what the core says of the row)."""
    bounds = "-" if f.bounds is None else f"[{f.bounds[0]}, {f.bounds[1]}]"
    if f.info is None:  # plan_info not received (the monitor discovered the planner late)
        extra_cols = f"{'-':>5} {'-':>9} {'-':>10}"
    else:
        extra_cols = f"{f.info.depth:>5} {'yes' if f.info.certified else 'no':>9} {1e3 * f.info.latency:>10.1f}"
    return (f"{f.epoch:>4} {'-' if f.true_state is None else f.true_state:>4} {f.mode:>4} {f.p_mode:>7.3f} "
            f"{f.entropy:>7.3f} {f.priority:>6} {bounds:>8} {f.greedy:>6} {extra_cols}")


def summary_lines(s: RunSummary, codes: dict) -> list[str]:
    """The summary after the table (``codes``: the processes' exit codes)."""
    widths = sorted(s.open_widths)
    open_ = (f"; where not, the bounds left {' or '.join(map(str, widths))} of the {s.model.A} priorities open"
             if widths else "")
    known = "" if len(s.rewards) == s.shown else f" (over the {len(s.rewards)} steps with the true state)"
    mean_reward = "-" if s.mean_reward is None else f"{s.mean_reward:.4f}"
    return [f"\nsummary over {s.shown} steps: mean reward {mean_reward}{known}, mean entropy {s.mean_entropy:.4f} "
            f"nats, action other than greedy's on {s.not_greedy} of {s.shown} steps, deadline misses {s.misses} of "
            f"{s.decisions} decisions shown (the planner's rule: latency > time_budget + deadline_slack); exit codes "
            f"{codes}",
            f"certified {s.certified} of {s.decisions} decisions shown (the bounds agreed){open_}"]


def compare_with_greedy(model: POMDP, planner: dict, steps: int, seed: int) -> str:
    """The discounted return of the planner (the core's policy with the planner node's settings)
    beside greedy's, both simulated by the core (``core.simulate``) from ``seed``: the same random
    numbers for both."""
    policy = make_policy("bnb" if planner["use_bounds"] else "exhaustive", model, time_budget=planner["time_budget"],
                         max_depth=planner["max_depth"],
                         **({"variant": planner["bound_variant"], "constant": planner["bound_constant"]}
                            if planner["use_bounds"] else {}))
    ours = simulate(model, policy, steps, seed=seed).discounted_return
    greedy = simulate(model, "myopic", steps, seed=seed).discounted_return
    return (f"discounted return over {steps} steps, simulated by the core from seed {seed} (the same random numbers "
            f"for both; one run, not an average): planner {ours:.4f}, greedy {greedy:.4f}")


#: ROS domain IDs a DDS participant may use (the ROS 2 docs' range for Linux).
DOMAIN_ID_RANGE = (0, 232)


def choose_domain_id(given: int | None, env: dict[str, str]) -> tuple[int, str]:
    """The demo's ROS domain and where it comes from: ``--domain-id`` (``given``), else the
    environment's ``ROS_DOMAIN_ID`` when set (non-empty), else a random one in 1..101 (a domain of
    its own, away from 0, the default of every other ROS program). A value outside
    :data:`DOMAIN_ID_RANGE` is an :class:`OptionError` naming where it came from."""
    lo, hi = DOMAIN_ID_RANGE
    if given is not None:
        value, source = given, "--domain-id"
    elif env.get("ROS_DOMAIN_ID", "").strip():
        text = env["ROS_DOMAIN_ID"].strip()
        if not text.isdigit():
            raise OptionError(f"ROS_DOMAIN_ID: must be an integer {lo}..{hi}, got {text!r}")
        value, source = int(text), "ROS_DOMAIN_ID"
    else:
        return random.randint(1, 101), "random"
    if not lo <= value <= hi:
        raise OptionError(f"{source}: must be an integer {lo}..{hi}, got {value}")
    return value, source


def run(steps: int, model_key: str, time_budget: float | None, domain_id: int | None, keep_logs: bool = False,
        out=sys.stdout, record: str | os.PathLike | None = None) -> int:
    """Run the demo (module docstring); node logs go to a temporary directory, removed at the end
    unless ``keep_logs``; the rows of the table go to the run record ``record`` (by default, with
    ``keep_logs``, ``run.csv`` in that directory)."""
    log_dir = Path(tempfile.mkdtemp(prefix="pomdp_planner_demo_"))
    path = Path(record) if record is not None else log_dir / "run.csv" if keep_logs else None
    written: list[int] = []
    try:
        return _run(steps, model_key, time_budget, domain_id, log_dir, keep_logs, out, path, written)
    finally:
        if path is not None and written:
            print(f"run record ({written[0]} rows) in {path}; draw it with: pomdp-planner plot {path} -o run.png",
                  file=out)
        if keep_logs:
            print(f"node logs kept in {log_dir}", file=out)
        else:
            shutil.rmtree(log_dir, ignore_errors=True)


def _run(steps: int, model_key: str, time_budget: float | None, domain_id: int | None, log_dir: Path,
         keep_logs: bool, out, record: Path | None, written: list[int]) -> int:
    domain_id, source = choose_domain_id(domain_id, dict(os.environ))
    os.environ.update(ros_env(domain_id))
    model_path = parameter_set_model(model_key)
    planner_params = dict(parameter_set_values(model_key, "planner"))
    # free running (step_period 0: one step per decision, so each row pairs a belief with the action
    # chosen from it); min_subscribers 2: the first step waits for the filter and this monitor (docstring)
    extra = {"target_simulator": ["-p", "step_period:=0.0", "-p", "min_subscribers:=2"]}
    if time_budget is not None:
        extra["planner"] = ["-p", f"time_budget:={time_budget}"]
        planner_params["time_budget"] = time_budget
    monitor = Monitor(model_path)
    model = monitor.model
    writer = None
    if record is not None:
        writer = open_run_output(record, "--record", model.name, model.S, model.A, planner_params["time_budget"])
        written.append(0)
    summary = RunSummary(model)
    where = {"random": "a random domain", "ROS_DOMAIN_ID": "from the environment", "--domain-id": "--domain-id"}
    print(f"pomdp_planner demo: {model.describe()}; three processes on ROS_DOMAIN_ID={domain_id} "
          f"({where[source]}; localhost only){f'; node logs in {log_dir}' if keep_logs else ''}", file=out)
    header = f"{'step':>4} {'true':>4} {'mode':>4} {'p(mode)':>7} {'entropy':>7} {'action':>6} {'bounds':>8} " \
             f"{'greedy':>6} {'depth':>5} {'certified':>9} {'latency ms':>10}"
    code = 0
    procs: dict = {}
    try:
        # Start order (module docstring): filter, planner, simulator (which waits for its subscribers)
        for name, ready in (("belief_filter", lambda: monitor.matched("belief")),
                            ("planner", lambda: monitor.matched("plan_info")),
                            ("target_simulator", lambda: True)):
            procs.update(start_nodes(model_key, domain_id, log_dir, extra, names=(name,)))
            deadline = time.monotonic() + 30.0
            while not ready() and time.monotonic() < deadline and procs[name][0].poll() is None:
                monitor.spin_once()
        for line in legend(model, planner_params["time_budget"], planner_params["max_depth"]):
            print(line, file=out)
        print(header, file=out)
        print("-" * len(header), file=out)
        last_progress = time.monotonic()
        while summary.shown < steps:
            monitor.spin_once()
            while summary.shown < steps and monitor.rows:
                row = monitor.rows.popleft()
                if summary.shown == 0 and row.epoch > 0:  # epochs before the monitor matched a writer never come
                    print(f"(the monitor matched the nodes late; the table starts at epoch {row.epoch})", file=out)
                print(table_row(summary.add(row)), file=out, flush=True)
                if writer is not None:
                    try:
                        write_row(writer, row.epoch, row.belief, row.priority, info=row.info, **row.record_fields())
                        written[0] += 1
                    except RunRecordError as exc:  # a full disk: the file ends on its last whole row
                        print(f"demo: {exc}; recording stopped", file=sys.stderr)
                        writer.close()
                        writer = None
                last_progress = time.monotonic()
            if isinstance(writer, RunBagWriter):  # a bag keeps the loop's readings as they come
                try:
                    while monitor.observations:
                        writer.observation(*monitor.observations.popleft())
                except RunRecordError as exc:
                    print(f"demo: {exc}; recording stopped", file=sys.stderr)
                    writer.close()
                    writer = None
            dead = [n for n, (p, _) in procs.items() if p.poll() is not None]
            if dead or time.monotonic() - last_progress > 60.0:
                print(f"demo: {'process(es) ' + ', '.join(dead) + ' exited' if dead else 'no progress for 60 s'}; "
                      f"stopping ({monitor.state()})", file=sys.stderr)
                code = 1
                break
    except KeyboardInterrupt:
        code = 130
    finally:
        codes = stop_nodes(procs)
        monitor.close()
        if writer is not None:
            writer.close()
    for name, c in codes.items():
        text = procs[name][1].read_text(errors="replace")
        if c != 0 or "Traceback" in text:
            code = code or 1
            print(f"demo: {name} exited with code {c}; last lines of its log:", file=sys.stderr)
            print("\n".join(text.splitlines()[-15:]), file=sys.stderr)
    if summary.shown:
        for line in summary_lines(summary, codes):
            print(line, file=out)
        if code == 0:
            seed = parameter_set_values(model_key, "target_simulator")["seed"]
            print(compare_with_greedy(model, planner_params, summary.shown, seed), file=out)
    return code


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pomdp_planner.nodes.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=30, help="decision epochs to run (default 30)")
    parser.add_argument("--model", choices=PARAMETER_SETS, default="perimeter_s8",
                        help="shipped parameter set config/<node>_<model>.yaml: s3, s8 (the paper's tracking "
                             "models), perimeter_s3, perimeter_s8 (models where lookahead pays; the default)")
    parser.add_argument("--time-budget", type=float, default=None, help="planner time_budget override (s)")
    parser.add_argument("--domain-id", type=int, default=None,
                        help="ROS_DOMAIN_ID (default: the exported ROS_DOMAIN_ID, else a random one in 1..101)")
    parser.add_argument("--keep-logs", action="store_true",
                        help="keep the nodes' log files and the run record run.csv (printed at the end; default: "
                             "removed with their directory)")
    parser.add_argument("--record", default=None, metavar="FILE",
                        help="write the table's rows as a run record (CSV; a name ending in .mcap: a rosbag2 MCAP "
                             "bag); pomdp-planner plot FILE draws it")
    args = parser.parse_args(argv)
    if args.steps < 1:
        parser.error("--steps: must be at least 1")
    try:
        choose_domain_id(args.domain_id, dict(os.environ))
        if args.record is not None:
            check_output_file(args.record, "--record", stdout=False)
    except OptionError as exc:
        parser.error(str(exc))
    return run(args.steps, args.model, args.time_budget, args.domain_id, args.keep_logs, record=args.record)


if __name__ == "__main__":
    sys.exit(main())
