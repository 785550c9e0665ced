"""``pomdp-planner simulate MODEL --steps N --seed K [--policy NAME]``: closed-loop simulation.

Prints one line per step (true state, action as priority 1..A, observation, Shannon entropy
of the updated belief in nats, belief reward rho(b, a) and state reward r(s, a)) and a summary
(mean reward, discounted return). States and observations are shown by name when the model
names them, else by 0-based index. ``--json`` prints the same as data. For the planners
(``bnb``, ``exhaustive``, ``lower``, ``upper``) a header line (JSON: ``planner``) gives the
assumption gate's decision: pruning with valid bounds, exhaustive search and why, or pruning
without guarantee (``--option prune_without_guarantee=1``).
"""

from __future__ import annotations

import argparse

from ..core.model import ModelError
from ..core.policies import POLICIES, make_policy, policy_names
from ..core.simulate import simulate
from ._common import (
    add_belief_argument,
    add_json_argument,
    add_model_argument,
    emit_json,
    format_table,
    load_model_arg,
    parse_belief,
)


def _option(text: str) -> tuple[str, object]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    for conv in (int, float):
        try:
            return key, conv(value)
        except ValueError:
            pass
    return key, value


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("simulate", help="closed-loop simulation of a policy",
                              description=__doc__.split("\n\n")[0].replace("``", ""),
                              epilog="policies (--policy NAME):\n" + "\n".join(
                                  f"  {name:<11} {POLICIES[name].help}" for name in policy_names()),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_model_argument(p)
    p.add_argument("--steps", type=int, default=20, help="number of steps (default 20)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0); same seed, same run")
    p.add_argument("--policy", default="myopic",
                   help=f"policy name: {', '.join(policy_names())} (default myopic; see below)")
    p.add_argument("--option", type=_option, action="append", default=[], metavar="KEY=VALUE",
                   help="option passed to the policy factory (repeatable), e.g. --option depth=3")
    add_belief_argument(p, default="", help_text="initial belief: 'uniform' or p1,...,pS "
                        "(default: the model's start, else uniform)")
    p.add_argument("--initial-state", default=None, metavar="STATE",
                   help="true initial state: a state name or 0-based index (default: sampled from the belief)")
    add_json_argument(p)
    p.set_defaults(func=run)


def _initial_state(text: str | None, model) -> int | None:
    if text is None:
        return None
    if model.state_names is not None and text in model.state_names:
        return model.state_names.index(text)
    try:
        s = int(text)
    except ValueError:
        raise ModelError(f"--initial-state: {text!r} is neither a state name nor an index") from None
    if not 0 <= s < model.S:
        raise ModelError(f"--initial-state: index {s} out of range 0..{model.S - 1}")
    return s


def run(args: argparse.Namespace) -> int:
    model = load_model_arg(args)
    if args.steps < 0:
        raise ModelError(f"--steps: must be non-negative, got {args.steps}")
    if args.policy not in POLICIES:
        raise ModelError(f"--policy: unknown policy {args.policy!r} (known: {', '.join(policy_names())})")
    belief = parse_belief(args.belief, model) if args.belief else None
    # The same policy seed as simulate(model, name, seed=K) uses, so both give the same run.
    options = {"seed": args.seed + 1, **dict(args.option)}
    policy = make_policy(args.policy, model, **options)
    trace = simulate(model, policy, args.steps, seed=args.seed,
                     initial_state=_initial_state(args.initial_state, model), initial_belief=belief)
    data = trace.to_dict(model.state_names, model.observation_names)
    data["policy"] = args.policy
    setup = getattr(policy, "setup", None)  # the assumption gate's decision, for the planners
    if setup is not None:
        data["planner"] = {**setup.to_dict(), "certified_decisions": getattr(policy, "certified", None)}
    if args.json:
        emit_json(data)
        return 0

    def label(names, i):
        return names[i] if names is not None else int(i)

    rows = [[row["step"], label(model.state_names, row["state"]), row["priority"],
             label(model.observation_names, row["observation"]), row["entropy"], row["reward"],
             row["state_reward"]] for row in data["steps"]]
    print(f"# {model.describe()}  policy={args.policy} seed={args.seed} steps={args.steps}")
    if setup is not None:
        print(f"# planner: {setup.describe()}")
    print(format_table(["step", "state", "priority", "obs", "entropy", "reward", "r(s,a)"], rows))
    s = data["summary"]
    print(f"mean reward {s['mean_reward']:.4f}  discounted return {s['discounted_return']:.4f}  "
          f"(state reward: mean {s['mean_state_reward']:.4f}, discounted {s['discounted_state_return']:.4f})")
    if s["recovered_steps"]:
        print(f"warning: {s['recovered_steps']} observation(s) impossible under the belief; belief re-initialised "
              "from the observation likelihood")
    return 0
