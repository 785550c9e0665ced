"""``pomdp-planner replay BAG [--model M] [--policy NAME] [--option KEY=VALUE]``: the filter and a
planner run again, offline, on a recorded run's readings, and where their beliefs and decisions
differ from the recorded ones, with entropy and return.

BAG is a bag with the run's readings (``observation``) and rows: ``simulate --record x.mcap``,
the demo's ``--record x.mcap``, the ``run_recorder`` node writing a ``.mcap``, or a bag of a
running loop recorded with ``ros2 bag record`` (a directory or a file; ``--namespace`` when it has
several runs). ``--model`` replaces the run's model (default: the one its record names; a bag
without a record needs ``--model``); ``--policy`` (default ``bnb``, the planner node's) and
``--option KEY=VALUE`` (``time_budget``, ``max_depth``, ...; default ``time_budget``: the run's)
the planner. The rules are the core's (``core/loop/replay.py``): beliefs by the L1 distance
(``--tol``), decisions by priority; the readings stay the recorded ones. Prints a summary and
the first ``--show`` epochs that differ; ``--json`` all of it per epoch. Exit code 0 (also when
they differ: that is the answer), 2 for a bad bag or option.
"""

from __future__ import annotations

import argparse

from ..core.errors import OptionError
from ..core.io.run_bag import read_run_bag
from ..core.io.sensors import load_model_file
from ..core.loop.replay import DEFAULT_TOL, replay
from ..core.policies import as_callable, make_policy, policy_names
from ._common import add_json_argument, emit_json, float_in, int_in
from .simulate import _option


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("replay", help="re-run filter and planner offline on a recorded bag and compare",
                              description=__doc__.split("\n\n")[0].replace("``", ""))
    p.add_argument("bag", metavar="BAG", help="a bag with the run's readings: a .mcap file or a rosbag2 directory")
    p.add_argument("--model", default=None, metavar="M",
                   help="the model to replay with (default: the one the bag's record names)")
    p.add_argument("--policy", default="bnb", help=f"the replay's planner: {', '.join(policy_names())} (bnb)")
    p.add_argument("--option", type=_option, action="append", default=[], metavar="KEY=VALUE",
                   help="option of the planner (repeatable), e.g. --option max_depth=4 (default time_budget: the "
                        "run's)")
    p.add_argument("--namespace", default=None, metavar="NS", help="the run's namespace in a bag of several")
    p.add_argument("--tol", type=float_in(0.0, 2.0), default=DEFAULT_TOL, metavar="X",
                   help=f"beliefs further apart than this (L1) differ ({DEFAULT_TOL:g})")
    p.add_argument("--show", type=int_in(0, 10**6), default=10, metavar="N",
                   help="list the first N epochs that differ (10)")
    add_json_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    bag = read_run_bag(args.bag, namespace=args.namespace)
    rec = bag.record
    if args.model is None and rec.model == "unknown":
        raise OptionError("--model: the bag has no run record naming its model: give --model")
    model = load_model_file(args.model or rec.model, "--model")
    if model.S != rec.S:
        raise OptionError(f"--model: {model.name} has {model.S} states, the bag's beliefs {rec.S}")
    if not bag.observations:
        raise OptionError(f"{args.bag}: no observation topic with the run's readings: nothing to replay")
    options = dict(args.option)
    if rec.time_budget is not None and args.policy in ("bnb", "exhaustive"):
        options.setdefault("time_budget", rec.time_budget)
    policy = make_policy(args.policy, model, **options)
    report = replay(model, rec, bag.observations, as_callable(policy), tol=args.tol)
    sums = report.sums(model)
    beliefs, decisions = report.belief_differences, report.decision_differences
    if args.json:
        emit_json({"bag": str(args.bag), "model": model.name, "policy": args.policy, "options": options,
                   "epochs": len(report.steps), "readings": report.readings, "gaps": report.gaps, "tol": args.tol,
                   "belief_differences": beliefs, "decision_differences": decisions,
                   "largest_distance": report.largest_distance, **sums, "notes": bag.notes,
                   "steps": [{"epoch": s.epoch, "distance": s.distance, "recorded_priority": s.recorded_priority,
                              "replayed_priority": s.replayed_priority, "true_state": s.true_state, "how": s.how,
                              "recorded": s.recorded.tolist(), "replayed": s.replayed.tolist()}
                             for s in report.steps]})
        return 0
    steps = report.steps
    n = len(steps)
    opts = ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in options.items())
    print(f"replay of {args.bag}: model {model.name} (the run's: {rec.model}), {n} epochs "
          f"({steps[0].epoch}..{steps[-1].epoch}), {report.readings} readings"
          f"{f', {len(report.gaps)} epochs without one (predicted)' if report.gaps else ''}; "
          f"policy {args.policy}{f' ({opts})' if opts else ''}")
    for note in bag.notes:
        print(f"note: {note}")
    print(f"beliefs: {n - len(beliefs)} of {n} epochs equal to the recorded ones within {args.tol:g} (L1); "
          f"largest difference {report.largest_distance:.3g}"
          + (f"; first differing epoch {beliefs[0]}" if beliefs else ""))
    print(f"decisions: {len(decisions)} of {n} differ from the recorded ones")
    rec_s, rep_s = sums["recorded"], sums["replayed"]
    print(f"entropy (Shannon, nats), mean: recorded {rec_s['mean_entropy']:.4f}, replayed {rep_s['mean_entropy']:.4f}")
    print(f"discounted return sum gamma^k rho(b_k, a_k) (gamma {model.gamma:g}): recorded "
          f"{rec_s['discounted_return']:.4f}, replayed {rep_s['discounted_return']:.4f}")
    if rec_s["discounted_state_return"] is not None:
        print(f"discounted state reward with the true state: recorded {rec_s['discounted_state_return']:.4f}, "
              f"replayed {rep_s['discounted_state_return']:.4f}")
    differing = [s for s in steps if s.distance > args.tol or s.recorded_priority != s.replayed_priority]
    if differing and args.show:
        print(f"{'epoch':>6} {'recorded':>8} {'replayed':>8} {'L1':>10}  how")
        for s in differing[:args.show]:
            print(f"{s.epoch:>6} {s.recorded_priority:>8} {s.replayed_priority:>8} {s.distance:>10.3g}  {s.how}")
        if len(differing) > args.show:
            print(f"... and {len(differing) - args.show} more (--show N, or --json)")
    return 0
