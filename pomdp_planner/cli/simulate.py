"""``pomdp-planner simulate MODEL --steps N --seed K [--policy NAME]``: closed-loop simulation.

Prints one line per step (true state, action as priority 1..A, observation, Shannon entropy
of the updated belief in nats, belief reward rho(b, a) and state reward r(s, a)) and a summary
(mean reward, discounted return). States and observations are shown by name when the model
names them, else by 0-based index. ``--json`` prints the same as data. For the planners
(``bnb``, ``exhaustive``, ``lower``, ``upper``) a header line (JSON: ``planner``) gives the
assumption gate's decision: pruning with valid bounds, exhaustive search and why, or pruning
without guarantee (``--option prune_without_guarantee=1``).

``--record FILE`` also writes the run as a run record (``core/io/run_record.py``: one CSV row per
decision with the belief it was made from, the true state, the priority, the root bounds, the
depth, whether it was certified and the search time), streamed like the output; ``pomdp-planner
plot FILE`` draws it. A FILE ending in ``.mcap`` is a rosbag2 MCAP bag instead
(``core/io/run_bag.py``: the record and the loop's topics, with the readings, epoch ``t`` at
``t * 0.1`` s), for ``ros2 bag``, Foxglove, ``plot`` and ``replay``.

With ``--targets M1,M2,... --budget B`` (no ``MODEL``) it simulates K targets under one effort
budget per epoch and a joint policy (``cli/simulate_targets.py``, docs/multitarget.md).

The steps are streamed: each line (each JSON step) is printed as soon as the step is simulated
and then forgotten, and the summary comes from running sums (``core.simulate.Simulation``,
``RunningSummary``), so any ``--steps`` runs in constant memory and ``| head`` stops it at once.
The JSON output is still one object, with one step per line. Everything (model, options,
policy, the search guards) is checked before the first step is printed.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator, Sequence

from ..core.checks import option_value
from ..core.errors import OptionError
from ..core.io.outputs import check_output_file
from ..core.io.run_bag import open_run_output, simulated_clock, write_row
from ..core.io.run_record import RunRecordWriter
from ..core.model import POMDP, short_repr
from ..core.multitarget.policies import JOINT_POLICIES, joint_policy_names
from ..core.options import STEPS_RANGE
from ..core.policies import POLICIES, last_decision, make_policy, policy_names, setup_notice_for
from ..core.simulate import RunningSummary, Simulation, SimulationStep
from . import simulate_targets
from ._common import (
    add_belief_argument,
    add_json_argument,
    add_seed_argument,
    emit_json_stream,
    format_number,
    int_in,
    load_model_arg,
    parse_belief,
)


def _option(text: str) -> tuple[str, object]:
    """``KEY=VALUE``; the value as the core reads option text (:func:`~pomdp_planner.core.checks.option_value`:
    an int for plain ASCII digits, else a float, else the text); the policy checks it."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {short_repr(text)}")
    return key.strip(), option_value(value)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("simulate", help="closed-loop simulation of a policy",
                              description=__doc__.split("\n\n")[0].replace("``", ""),
                              epilog="policies (--policy NAME):\n" + "\n".join(
                                  f"  {name:<11} {POLICIES[name].help}" for name in policy_names())
                              + "\n\njoint policies (--targets ... --policy NAME):\n" + "\n".join(
                                  f"  {name:<11} {JOINT_POLICIES[name].help}" for name in joint_policy_names()),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", metavar="MODEL", nargs="?", default=None,
                   help="model file: YAML (see README) or Cassandra .POMDP, absolute, relative to the current "
                        "directory or to the installed share/pomdp_planner, or a shipped model's name "
                        "(e.g. tracking_s3_info); not with --targets")
    p.add_argument("--steps", type=int_in(*STEPS_RANGE), default=20, metavar="N",
                   help=f"number of steps, {STEPS_RANGE[0]}..{STEPS_RANGE[1]:.0e} (default 20); streamed in "
                   "constant memory")
    add_seed_argument(p, "random seed (default 0); same seed, same run")
    p.add_argument("--policy", default=None,
                   help=f"policy name: {', '.join(policy_names())} (default myopic; see below); with --targets "
                   f"one of {', '.join(joint_policy_names())} (default lagrangian)")
    p.add_argument("--option", type=_option, action="append", default=[], metavar="KEY=VALUE",
                   help="option passed to the policy factory (repeatable), e.g. --option depth=3")
    add_belief_argument(p, default="", help_text="initial belief: 'uniform' or p1,...,pS "
                        "(default: the model's start, else uniform)")
    p.add_argument("--initial-state", default=None, metavar="STATE",
                   help="true initial state: a state name or 0-based index (default: sampled from the belief)")
    p.add_argument("--record", default=None, metavar="FILE",
                   help="also write the run as a run-record CSV (one row per decision: belief, action, root "
                        "bounds, depth, certified, latency; docs/cli.md), e.g. for 'pomdp-planner plot'; a name "
                        "ending in .mcap writes a rosbag2 MCAP bag (also for 'pomdp-planner replay')")
    simulate_targets.add_arguments(p)
    add_json_argument(p)
    p.set_defaults(func=run)


def _initial_state(text: str | None, model: POMDP) -> int | None:
    if text is None:
        return None
    if model.state_names is not None and text in model.state_names:
        return model.state_names.index(text)
    t = text.strip()
    digits = t[1:] if t[:1] in "+-" else t
    if not (digits.isascii() and digits.isdigit() and len(digits) <= 30):
        raise OptionError(f"--initial-state: {short_repr(text)} is neither a state name nor an index")
    s = int(t)
    if not 0 <= s < model.S:
        raise OptionError(f"--initial-state: index {s} out of range 0..{model.S - 1}")
    return s


def run(args: argparse.Namespace) -> int:
    if args.targets is not None:
        return simulate_targets.run(args)
    simulate_targets.check_single_target(args)
    args.policy = "myopic" if args.policy is None else args.policy
    if args.record is not None:  # before any work: not after a long run
        check_output_file(args.record, "--record", stdout=False)  # the steps go to stdout
    model = load_model_arg(args)
    if args.policy not in POLICIES:
        raise OptionError(f"--policy: unknown policy {short_repr(args.policy)} (known: {', '.join(policy_names())})")
    belief = parse_belief(args.belief, model) if args.belief else None
    initial_state = _initial_state(args.initial_state, model)
    # The same policy seed as simulate(model, name, seed=K) uses, so both give the same run.
    options = {"seed": args.seed + 1, **dict(args.option)}
    notice = setup_notice_for(args.policy, model, options)
    if notice is not None:
        print(f"pomdp-planner simulate: {notice}", file=sys.stderr, flush=True)
    policy = make_policy(args.policy, model, **options)
    sim = Simulation(model, policy, args.steps, seed=args.seed, initial_state=initial_state, initial_belief=belief)
    setup = getattr(policy, "setup", None)  # the assumption gate's decision, for the planners
    note = getattr(policy, "note", "")  # e.g. the anytime search's max_depth capped by the memory budget
    summary = RunningSummary(model.gamma)
    record = None if args.record is None else _open_record(args.record, model, policy)

    clock = simulated_clock()  # a bag's row times: epoch t at t * 0.1 s from now

    def steps() -> Iterator[SimulationStep]:
        belief = sim.initial_belief  # the belief each decision is made from
        reading = None  # the (priority, observation) that made it
        try:
            for st in sim:
                summary.add(st)
                if record is not None:
                    write_row(record, st.t, belief, st.action + 1, true_state=st.state, observation=reading,
                              stamp_ns=clock(st.t), **last_decision(policy, belief))
                belief, reading = st.belief, (st.action + 1, st.observation)
                yield st
        finally:  # also when the reader stops early (| head)
            if record is not None:
                record.close()

    if args.json:
        head = {"model": model.name, "policy": args.policy, "seed": args.seed, "gamma": model.gamma,
                "initial_belief": sim.initial_belief}
        if note:
            head["policy_note"] = note

        def tail() -> dict:
            out: dict = {"summary": summary.summary()}
            if setup is not None:
                out["planner"] = {**setup.to_dict(), "certified_decisions": getattr(policy, "certified", None)}
            return out

        rows = (st.to_dict(model.state_names, model.observation_names) for st in steps())
        emit_json_stream(head, "steps", rows, tail)
        return 0
    print(f"# {model.describe()}  policy={args.policy} seed={args.seed} steps={args.steps}")
    if setup is not None:
        print(f"# planner: {setup.describe()}")
    if note:
        print(f"# policy: {note}")
    table = StepTable(model, args.steps)
    print(table.header)
    for st in steps():
        print(table.line(st))
    s = summary.summary()
    print(f"mean reward {s['mean_reward']:.4f}  discounted return {s['discounted_return']:.4f}  "
          f"(state reward: mean {s['mean_state_reward']:.4f}, discounted {s['discounted_state_return']:.4f})")
    if s["recovered_steps"]:
        print(f"warning: {s['recovered_steps']} observation(s) impossible under the belief; belief re-initialised "
              "from the observation likelihood")
    return 0


def _open_record(path: str, model: POMDP, policy: object) -> RunRecordWriter:
    """The ``--record`` writer: a CSV run record (every row is flushed as written) or, for a
    ``.mcap`` name, a bag (``core/io/run_bag.py``); closed after the last step."""
    return open_run_output(path, "--record", model.name, model.S, model.A, getattr(policy, "time_budget", None))


class StepTable:
    """One table line per step, with the column widths fixed in advance (the rows are streamed,
    so they cannot be measured first): integer columns by their largest value, names by the
    longest name (left-aligned), numbers at least 9 characters (a wider value widens its line only)."""

    HEADERS = ("step", "state", "priority", "obs", "entropy", "reward", "r(s,a)")

    def __init__(self, model: POMDP, steps: int):
        def width(names: Sequence[str] | None, count: int) -> int:
            return max(len(n) for n in names) if names is not None else len(str(count - 1))

        self.states, self.observations = model.state_names, model.observation_names
        cols = [len(str(max(steps - 1, 0))), width(self.states, model.S), len(str(model.A)),
                width(self.observations, model.Z), 9, 9, 9]
        self.widths = [max(w, len(h)) for w, h in zip(cols, self.HEADERS, strict=True)]
        self.left = [False, self.states is not None, False, self.observations is not None, False, False, False]
        self.header = self._line(self.HEADERS) + "\n" + "  ".join("-" * w for w in self.widths)

    def _line(self, cells: Sequence[str]) -> str:
        return "  ".join(c.ljust(w) if left else c.rjust(w)
                         for c, w, left in zip(cells, self.widths, self.left, strict=True)).rstrip()

    def line(self, st: SimulationStep) -> str:
        """The table line of one step."""
        state = self.states[st.state] if self.states is not None else str(st.state)
        obs = self.observations[st.observation] if self.observations is not None else str(st.observation)
        return self._line([str(st.t), state, str(st.action + 1), obs, format_number(st.entropy),
                           format_number(st.reward), format_number(st.state_reward)])
