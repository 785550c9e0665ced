"""``pomdp-planner simulate --targets M1,M2,... --budget B [--policy NAME]``: K targets, one budget.

Each target is a model file (resolved like every model argument, ``core/io/paths.py``: a path,
or a shipped model's name); the same file may be given several times. Every epoch the joint
policy gives each target a priority within the effort budget ``B`` (``--efforts``: one list of
efforts per priority ``1..A``, for every target or one per target separated by ``;``; default
``A - p`` for priority ``p``). The run (``core/multitarget/simulate.py``) draws every target's
randomness from its own stream (common random numbers: the same ``--seed`` gives every policy
the same luck). Printed per step: the priorities, the effort used, the joint reward and, for the
planners, the lookahead depth the numbers refer to, the price ``lambda``, the dual bound and the
gap; then the summary, with the number of epochs over budget (0 for every policy of the package).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

from ..core.checks import check_number, option_value
from ..core.errors import OptionError, short_repr
from ..core.io.sensors import load_model_file
from ..core.multitarget.planner import MultiTargetPlanner
from ..core.multitarget.policies import JOINT_POLICIES, joint_policy_names, make_joint_policy
from ..core.multitarget.problem import MultiTargetProblem, format_effort, make_problem
from ..core.multitarget.simulate import JointRunningSummary, JointSimulation, JointStep
from ._common import emit_json_stream, format_number


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The multi-target options of ``simulate``."""
    g = p.add_argument_group("several targets, one budget (docs/multitarget.md)")
    g.add_argument("--targets", default=None, metavar="M1,M2,...",
                   help="comma-separated target models (files or shipped names; repeats allowed); replaces MODEL")
    g.add_argument("--budget", default=None, metavar="B",
                   help="effort budget per epoch: a number >= 0 (exact: 1.5, 3/2)")
    g.add_argument("--efforts", default=None, metavar="E",
                   help="efforts per priority 1..A: 'e1,...,eA' for every target, or one list per target "
                   "separated by ';' (empty = the default A - p)")
    g.add_argument("--discount", default=None, metavar="G",
                   help="the joint discount (replaces every model's; needed when the models' discounts differ)")


def check_single_target(args: argparse.Namespace) -> None:
    """A single-target run needs ``MODEL`` and none of the multi-target options."""
    if args.model is None:
        raise OptionError("MODEL: give a model file, or --targets M1,M2,... for several targets")
    for name in ("budget", "efforts", "discount"):
        if getattr(args, name) is not None:
            raise OptionError(f"--{name}: only with --targets")


def _efforts(text: str | None, K: int) -> list | None:
    if text is None:
        return None
    rows = [r.strip() for r in text.split(";")]
    if len(rows) == 1:
        rows = rows * K
    if len(rows) != K:
        raise OptionError(f"--efforts: {len(rows)} lists for {K} targets (give one list, or one per target)")
    return [None if not r else [x.strip() for x in r.split(",")] for r in rows]


#: The options that give :func:`make_problem`'s fields (its errors name them).
CLI_FIELDS = {"targets": "--targets", "efforts": "--efforts", "budget": "--budget", "discount": "--discount"}


def load_problem(args: argparse.Namespace) -> MultiTargetProblem:
    """The problem of ``--targets``, ``--budget``, ``--efforts`` and ``--discount``."""
    if args.model is not None:
        raise OptionError("MODEL: not with --targets (give every target in --targets)")
    for name in ("belief", "initial_state", "record"):
        if getattr(args, name, None):
            raise OptionError(f"--{name.replace('_', '-')}: not available with --targets (every target starts from "
                             "its model's start belief, else uniform)")
    names = [t.strip() for t in args.targets.split(",")]
    if not all(names):
        raise OptionError(f"--targets: an empty entry in {short_repr(args.targets)}")
    if args.budget is None:
        raise OptionError("--budget: required with --targets")
    loaded: dict[str, object] = {}
    models = []
    for k, name in enumerate(names):
        if name not in loaded:
            loaded[name] = load_model_file(name, f"--targets[{k}]")
        models.append(loaded[name])
    discount = None if args.discount is None else check_number(option_value(args.discount), "--discount", 0.0, 1.0)
    return make_problem(models, budget=args.budget, efforts=_efforts(args.efforts, len(models)),
                        discount=discount, fields=CLI_FIELDS)


def run(args: argparse.Namespace) -> int:
    problem = load_problem(args)
    name = "lagrangian" if args.policy is None else args.policy
    if name not in JOINT_POLICIES:
        raise OptionError(f"--policy: unknown joint policy {short_repr(name)} "
                         f"(known: {', '.join(joint_policy_names())})")
    policy = make_joint_policy(name, problem, **dict(args.option))
    sim = JointSimulation(problem, policy, args.steps, seed=args.seed)
    summary = JointRunningSummary(problem.gamma)
    planner: MultiTargetPlanner | None = getattr(policy, "planner", None)
    if not isinstance(planner, MultiTargetPlanner):
        planner = None

    def steps() -> Iterator[JointStep]:
        for st in sim:
            summary.add(st)
            yield st

    if args.json:
        head = {"targets": list(problem.names), "efforts": [[float(e) for e in row] for row in problem.efforts],
                "budget": float(problem.budget), "gamma": problem.gamma, "policy": name, "seed": args.seed}
        if planner is not None:
            head["planner"] = {"search": planner.search_mode, "bound_guaranteed": planner.bound_guaranteed,
                               "targets": [s.to_dict() for s in planner.setups]}

        def tail() -> dict:
            return {"summary": summary.summary()}

        emit_json_stream(head, "steps", (st.to_dict() for st in steps()), tail)
        return 0
    print(f"# {problem.describe()}  policy={name} seed={args.seed} steps={args.steps}")
    if planner is not None:
        print(f"# planner: {planner.describe()}")
        print(f"# {bound_line(planner)}")
        if planner.note:
            print(f"# planner: {planner.note}")
    cells = _Row(problem, args.steps)
    print(cells.header)
    for st in steps():
        print(cells.line(st))
    s = summary.summary()
    line = (f"discounted return {format_number(s['discounted_return'])}  "
            f"mean reward {format_number(s['mean_reward'])}  "
            f"mean effort {format_number(s['mean_effort'])}  epochs over budget {s['budget_violations']}")
    if s["mean_lambda"] is not None:
        line += f"  mean lambda {format_number(s['mean_lambda'])}  mean gap {format_number(s['mean_gap'])}"
    print(line)
    return 0


def bound_line(planner: MultiTargetPlanner) -> str:
    """What the dual bound of each row is, and which lookahead it refers to (the ``depth`` column)."""
    if planner.time_budget is None:
        depth = f"the depth-{planner.depth} joint lookahead ({planner.depth + 1} decisions; the depth column)"
    else:
        depth = (f"the joint lookahead of the row's depth (the depth column: the deepest depth completed within "
                 f"the time budget of {planner.time_budget:g} s, up to {planner.max_depth})")
    if planner.bound_guaranteed:
        return f"dual bound: an upper bound on the optimal value of {depth}; every target searched exhaustively"
    return (f"dual bound: ESTIMATE, not a bound, of the optimal value of {depth}; branch-and-bound values "
            "(--option search=exhaustive makes it one)")


class _Row:
    """One fixed-width line per step (the steps are streamed, so widths are fixed in advance)."""

    HEADERS = ("step", "priorities", "effort", "reward", "depth", "lambda", "dual_bound", "gap")

    def __init__(self, problem: MultiTargetProblem, steps: int):
        self.problem = problem
        budget = format_effort(problem.budget)
        widths = [len(str(max(steps - 1, 0))), 2 * problem.K - 1, 2 * len(budget) + 6, 9, 5, 9, 10, 9]
        self.widths = [max(w, len(h)) for w, h in zip(widths, self.HEADERS, strict=True)]
        self.header = self._join(self.HEADERS) + "\n" + "  ".join("-" * w for w in self.widths)

    def _join(self, cells) -> str:
        return "  ".join(c.rjust(w) for c, w in zip(cells, self.widths, strict=True)).rstrip()

    def line(self, st: JointStep) -> str:
        d = st.decision
        effort = f"{format_effort(st.effort)}/{format_effort(self.problem.budget)}"
        effort += "" if st.within_budget else " OVER"
        nums = ["-"] * 4 if d is None else [str(d.depth), format_number(d.lam), format_number(d.dual_bound),
                                            format_number(d.gap)]
        return self._join([str(st.t), " ".join(str(a + 1) for a in st.actions), effort,
                           format_number(st.reward), *nums])
