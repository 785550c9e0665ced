"""``pomdp-planner plan MODEL --belief B [--depth D | --time-budget S] [--exhaustive] [--json]``.

Runs the branch-and-bound search of Algorithm 1 (paper Sec. V) from one belief and prints the
result: the chosen action as a tracking priority 1..A, the root Q values per priority (pruned
actions shown as ``-``/``null``), the depth searched (Table II convention: ``d`` action-
observation levels below the root), belief nodes in the tree and % pruned per depth, whether
the root bounds agree (certified optimal action) and the time used.

``--depth D`` searches exactly depth D; ``--time-budget S`` runs the anytime planner
(iterative deepening up to ``--max-depth``, stopped by the deadline, returning the deepest
completed depth). ``--exhaustive`` searches all actions (no bounds are solved). The bounds come
from the LP of Theorem 2 (``--variant``, ``--constant``) through the assumption gate
(:func:`pomdp_planner.core.gate.build_planner`): if the model fails Assumption 1, the LP is
infeasible or the Shannon guarantee covers no domain, the search is exhaustive and the output
says why; the text (``search:``) and JSON (``bounds``, ``gate``) outputs name the variant and
the constant the bounds were solved with. ``--prune-without-guarantee`` prunes anyway; the
output then says that no guarantee holds, and no decision is certified. Crossed root bounds
(lower > upper) are reported as such.

Resource guards (checked before the search starts; a refusal is exit code 2 with the figures):
a fixed depth whose complete tree has more than ``MAX_TREE_NODES`` (1e10) belief nodes is
refused unless ``--no-limit``; a depth whose memory estimate exceeds ``--memory-budget`` (MiB,
default 1024) is refused with the deepest depth that fits; the anytime search's
``--max-depth`` is capped at that depth instead, and the output says so.

Set-up (before the search, never part of ``--time-budget``): loading the model, the assumption
check, the bound LP and the planner's tables. The gate estimates its memory and time first and
refuses, with the figures, a set-up needing more memory than is available or expected to take more than
``MAX_SETUP_SECONDS`` (600 s; ``--no-limit`` lifts the time limit); a set-up expected to take
more than a few seconds is announced on stderr, with the expected time, before it starts.
"""

from __future__ import annotations

import argparse
import sys

from ..core.bounds import BOUND_CONSTANTS, BOUND_VARIANTS, DEFAULT_CONSTANT
from ..core.checks import integer
from ..core.gate import MAX_SETUP_SECONDS, build_planner
from ..core.search import (
    DEFAULT_MEMORY_BUDGET,
    MAX_DEPTH_RANGE,
    TIME_BUDGET_RANGE,
    check_depth,
    check_search_memory,
    check_time_budget,
    check_tree_size,
    deepest_depth_within_budget,
)
from ._common import (
    add_belief_argument,
    add_json_argument,
    add_model_argument,
    emit_json,
    float_in,
    load_model_arg,
    parse_belief,
)

DEFAULT_DEPTH = 3
DEFAULT_MAX_DEPTH = 10
MIB = 2**20
#: ``--memory-budget`` in MiB: at least 1 MiB, at most 1 TiB.
MEMORY_BUDGET_RANGE_MIB = (1.0, float(2**20))


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plan", help="choose an action from a belief by branch-and-bound search",
                              description=__doc__.split("\n\n")[0].replace("``", ""))
    add_model_argument(p)
    add_belief_argument(p)
    g = p.add_mutually_exclusive_group()
    depths, budgets = "..".join(map(str, MAX_DEPTH_RANGE)), "..".join(f"{x:g}" for x in TIME_BUDGET_RANGE)
    g.add_argument("--depth", type=integer, default=None, metavar="D",
                   help=f"search exactly this depth, {depths} (default {DEFAULT_DEPTH} unless --time-budget is given)")
    g.add_argument("--time-budget", type=float_in(*TIME_BUDGET_RANGE, " of seconds"), default=None, metavar="S",
                   help=f"anytime search: iterative deepening for at most S seconds, {budgets}; bounds the search "
                        "of the decision only, not the set-up before it (model, assumption check, LP, tables), "
                        "which is announced when expected to take long")
    p.add_argument("--max-depth", type=integer, default=DEFAULT_MAX_DEPTH, metavar="D",
                   help=f"deepest depth of the anytime search, {depths} (default {DEFAULT_MAX_DEPTH})")
    p.add_argument("--exhaustive", action="store_true", help="search all actions (no myopic bounds)")
    lo, hi = MEMORY_BUDGET_RANGE_MIB
    p.add_argument("--memory-budget", type=float_in(lo, hi, " of MiB"), default=DEFAULT_MEMORY_BUDGET / MIB,
                   metavar="MIB", help=f"memory the search may use, in MiB ({lo:g}..{hi:g}, default "
                   f"{DEFAULT_MEMORY_BUDGET / MIB:g}): a deeper fixed depth is refused, the anytime search's "
                   "--max-depth capped")
    p.add_argument("--no-limit", action="store_true",
                   help="run a fixed depth whose complete tree exceeds MAX_TREE_NODES (1e10 belief nodes; "
                        "refused by default: it would take minutes to hours), and a set-up expected to take more "
                        f"than MAX_SETUP_SECONDS ({MAX_SETUP_SECONDS:g} s)")
    p.add_argument("--variant", default=BOUND_VARIANTS[0], choices=BOUND_VARIANTS,
                   help=f"bound variant of the LP (default {BOUND_VARIANTS[0]})")
    p.add_argument("--constant", default=DEFAULT_CONSTANT, choices=BOUND_CONSTANTS,
                   help=f"belief-independent constant of the LP (default {DEFAULT_CONSTANT}): 'mlr' is exact for the "
                        "MLR monotonicity Corollary 1 needs, 'fosd' the stronger first-order dominance constant C_S "
                        "(see 'pomdp-planner bounds --help')")
    p.add_argument("--prune-without-guarantee", action="store_true",
                   help="prune with the bounds even where the gate finds them not valid (Assumption 1 fails or "
                        "is unproven, or the Shannon guarantee covers no domain): NO GUARANTEE, nothing certified")
    add_json_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    model = load_model_arg(args)
    belief = parse_belief(args.belief, model)
    depth = DEFAULT_DEPTH if args.depth is None else check_depth(args.depth, "--depth", MAX_DEPTH_RANGE)
    max_depth = check_depth(args.max_depth, "--max-depth", MAX_DEPTH_RANGE)
    budget = None if args.time_budget is None else check_time_budget(args.time_budget, "--time-budget",
                                                                       TIME_BUDGET_RANGE)
    # The resource guards, before the gate (whose assumption check and LP take long on large models).
    S, A, Z = model.S, model.A, model.Z
    memory = int(args.memory_budget * MIB)
    capped = None  # the anytime search's max depth, when the memory budget lowers it
    if budget is None:
        if not args.no_limit:
            check_tree_size(A, Z, depth, "--depth", hint="use --time-budget S (anytime search, stopped in time) "
                            "or --no-limit")
        check_search_memory(S, A, Z, depth, memory, "--depth")
    else:
        check_search_memory(S, A, Z, 1, memory, "--max-depth")  # refused if not even depth 1 fits
        fits = deepest_depth_within_budget(S, A, Z, max_depth, memory)
        if fits < max_depth:
            capped, max_depth = max_depth, fits
            cap_note = (f"--max-depth capped at {fits} (asked {capped}): a deeper search needs more than the "
                        f"memory budget of {args.memory_budget:g} MiB")
    setup = build_planner(model, use_bounds=not args.exhaustive, variant=args.variant, constant=args.constant,
                          prune_without_guarantee=args.prune_without_guarantee,
                          override_name="--prune-without-guarantee", memory_budget=memory,
                          max_setup_seconds=None if args.no_limit else MAX_SETUP_SECONDS,
                          setup_hint="--no-limit lifts the limit, --exhaustive skips the assumption check and "
                                     "the LP",
                          progress=lambda note: print(f"pomdp-planner plan: {note}", file=sys.stderr, flush=True))
    planner = setup.planner
    assert planner is not None  # the gate refuses only when asked to (on_assumption_failure="refuse")
    sol = setup.bounds
    bounds_info = None if sol is None else {"variant": sol.variant, "constant": sol.constant,
                                            "feasible": bool(sol.feasible), "message": sol.message,
                                            "why": sol.constants.get("why")}
    if args.json and not args.exhaustive and not setup.guaranteed:  # the text output has a "search:" line
        print(f"pomdp-planner plan: {setup.describe()}", file=sys.stderr)
    use_bounds = setup.pruning
    if budget is not None:
        res = planner.plan(belief, max_depth=max_depth, time_budget=budget, use_bounds=use_bounds)
    else:
        res = planner.search(belief, depth, use_bounds=use_bounds)
    if args.json:
        if capped is not None:
            print(f"pomdp-planner plan: {cap_note}", file=sys.stderr)
        emit_json({"model": model.name, "belief": belief, "mode": "anytime" if budget is not None
                   else "fixed-depth", "bounds": bounds_info, "gate": setup.to_dict(),
                   "max_depth": max_depth if budget is not None else None, "max_depth_capped_from": capped,
                   "memory_budget_bytes": planner.memory_budget, **res.to_dict()})
        return 0
    d = res.to_dict()
    q = ", ".join(f"{i + 1}: {'-' if v is None else f'{v:.6g}'}" for i, v in enumerate(d["q_values"]))
    rbs = d["root_bounds"]
    if rbs is None:
        rb = "none (exhaustive search)"
    elif res.crossed:
        rb = (f"crossed bounds: no guarantee (lower priority {rbs[0]} > upper priority {rbs[1]}; "
              "every action searched)")
    else:
        rb = f"priorities {rbs[0]}..{rbs[1]}" + (
            "" if res.guaranteed else " (bounds without guarantee: they certify nothing)")
    lines = [
        f"action: priority {d['action']}" + ("  (certified: the root bounds agree)" if d["certified"] else ""),
        f"search: {setup.describe()}",
        f"Q values by priority: {q}",
        f"root bounds: {rb}",
        f"depth: {d['depth']}" + ("  (next depth predicted not to finish in time: not started)"
                                  if d.get("predicted_stop") else
                                  f"  (deadline hit inside depth 1: {sum(x is not None for x in d['q_values'])} root "
                                  "action(s) searched, the best of them chosen)" if d.get("partial") else
                                  "  (deadline hit; deeper depth discarded)" if d["deadline_hit"] else ""),
        "nodes per depth: " + ", ".join(f"d={i + 1}: {n:,} ({p:.1f}% pruned)" for i, (n, p) in
                                        enumerate(zip(d["nodes_expanded"], d["percent_pruned"], strict=True))),
        f"time: {d['time_used'] * 1e3:.1f} ms",
    ]
    if capped is not None:
        lines.insert(5, f"max depth: {cap_note}")
    print("\n".join(lines))
    return 0
