"""The joint policies of a multi-target problem, in one table (``simulate --targets ... --policy NAME``).

A joint policy maps the K beliefs to a joint action (0-based, one per target) within the budget;
``last`` holds the planner's last :class:`~.planner.JointDecision` where there is one.

* ``lagrangian``: :class:`~.planner.MultiTargetPlanner` (the price searched every epoch).
* ``fixed_price``: the same per-target searches and knapsack at one price fixed before the run
  (option ``price``; default: the planner's price at the initial beliefs, computed once).
* ``greedy``: the knapsack on the one-step rewards, ``max sum_k rho_k(b_k, a_k)`` within the
  budget: the multi-target analogue of a brute-force one-step sensor manager.
* ``equal_split``: every target gets a fixed share ``min_a e_k(a) + (B - sum_j min_a e_j(a)) / K``
  of the budget and plans alone (the gate's single-target search) with the priorities it affords.
* ``round_robin``: ignores the beliefs; each epoch the targets take turns, in a cyclic order
  starting one target later every epoch, to take the most effort the rest of the budget leaves
  (keeping every later target's least effort affordable).
* ``exact_joint``: the exact joint expectimax (:mod:`.joint_exact`; small problems only).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np

from ..belief import start_belief, uniform_belief
from ..bounds import BOUND_VARIANTS, DEFAULT_CONSTANT, check_constant, check_variant
from ..checks import check_choice, check_number, parse_flag
from ..options import MAX_DEPTH_RANGE, check_depth
from ..policies import table_entry
from .joint_exact import ExactJointPlanner
from .knapsack import solve_knapsack
from .planner import (
    DEFAULT_JOINT_DEPTH,
    DEFAULT_TIE_BREAK,
    DEFAULT_TIE_TOLERANCE,
    SEARCH_MODES,
    TIE_BREAKS,
    TIE_TOLERANCE_RANGE,
    JointDecision,
    MultiTargetPlanner,
    RestrictedPlanners,
)
from .problem import MultiTargetProblem


def initial_beliefs(problem: MultiTargetProblem) -> list[np.ndarray]:
    """Every target's model ``start`` belief, else uniform."""
    out = []
    for m in problem.models:
        b = start_belief(m)
        out.append(uniform_belief(m) if b is None else b)
    return out


class PlannerPolicy:
    """``lagrangian`` / ``fixed_price``: a :class:`~.planner.MultiTargetPlanner` per epoch."""

    def __init__(self, planner: MultiTargetPlanner):
        self.planner = planner
        self.last: JointDecision | None = None

    def act(self, beliefs: Sequence[np.ndarray]) -> tuple[int, ...]:
        self.last = self.planner.decide(beliefs)
        return self.last.actions


class GreedyPolicy:
    """``greedy``: ``max sum_k rho_k(b_k, a_k)`` within the budget (exact knapsack)."""

    def __init__(self, problem: MultiTargetProblem):
        self.problem = problem
        self.last = None

    def act(self, beliefs: Sequence[np.ndarray]) -> tuple[int, ...]:
        p = self.problem
        values = [m.rho(np.asarray(b, dtype=float)) for m, b in zip(p.models, beliefs, strict=True)]
        return solve_knapsack(values, p.units, p.knapsack_capacity)[1]


class EqualSplitPolicy:
    """``equal_split``: a fixed share of the budget per target, single-target search within it."""

    def __init__(self, problem: MultiTargetProblem, gate: dict[str, Any], depth: int):
        self.problem = problem
        self.depth = depth
        slack = (problem.budget - problem.least_effort) / problem.K
        self.shares = tuple(min(row) + slack for row in problem.efforts)
        planners = RestrictedPlanners(problem, gate, time.perf_counter)
        self.targets = [planners.get(k, share, units=False) for k, share in enumerate(self.shares)]
        self.last = None

    def act(self, beliefs: Sequence[np.ndarray]) -> tuple[int, ...]:
        out = []
        for (setup, keep), b in zip(self.targets, beliefs, strict=True):
            res = setup.planner.search(b, self.depth, use_bounds=setup.pruning)
            out.append(int(keep[res.action]))
        return tuple(out)


class RoundRobinPolicy:
    """``round_robin``: belief-blind turns (module docstring)."""

    def __init__(self, problem: MultiTargetProblem):
        self.problem = problem
        self.epoch = 0
        self.last = None

    def act(self, beliefs: Sequence[np.ndarray]) -> tuple[int, ...]:
        p = self.problem
        K = p.K
        order = [(self.epoch + i) % K for i in range(K)]
        self.epoch += 1
        least = [min(row) for row in p.efforts]
        left = p.budget
        actions = [0] * K
        for i, k in enumerate(order):
            reserve = sum((least[j] for j in order[i + 1:]), Fraction(0))
            row = p.efforts[k]
            afford = [a for a in range(len(row)) if row[a] <= left - reserve]
            top = max(row[a] for a in afford)
            actions[k] = min(a for a in afford if row[a] == top)
            left -= row[actions[k]]
        return tuple(actions)


class ExactJointPolicy:
    """``exact_joint``: the exact joint expectimax at ``depth``."""

    def __init__(self, problem: MultiTargetProblem, depth: int):
        self.planner = ExactJointPlanner(problem, depth)
        self.last = None

    def act(self, beliefs: Sequence[np.ndarray]) -> tuple[int, ...]:
        return self.planner.act([np.asarray(b, dtype=float) for b in beliefs])


# ----------------------------------------------------------------------------- options
def _flag(opts: Mapping[str, Any], name: str) -> bool:
    return parse_flag(opts.get(name, False), f"option {name}")


def _search(opts: Mapping[str, Any]) -> str:
    return check_choice(opts.get("search", SEARCH_MODES[0]), SEARCH_MODES, "option search")


def _gate(opts: Mapping[str, Any]) -> dict[str, Any]:
    return {"variant": check_variant(opts.get("variant", BOUND_VARIANTS[0]), "option variant"),
            "constant": check_constant(opts.get("constant", DEFAULT_CONSTANT), "option constant"),
            "prune_without_guarantee": _flag(opts, "prune_without_guarantee")}


def _planner(problem: MultiTargetProblem, opts: Mapping[str, Any], price: float | None) -> MultiTargetPlanner:
    return MultiTargetPlanner(problem, search=_search(opts), depth=opts.get("depth", DEFAULT_JOINT_DEPTH),
                              time_budget=opts.get("time_budget"), max_depth=opts.get("max_depth", 10),
                              max_evaluations=opts.get("max_evaluations", 12), price=price,
                              no_limit=_flag(opts, "no_limit"), **_ties(opts), **_gate(opts))


def _ties(opts: Mapping[str, Any]) -> dict[str, Any]:
    return {"tie_break": check_choice(opts.get("tie_break", DEFAULT_TIE_BREAK), TIE_BREAKS, "option tie_break"),
            "tie_tolerance": check_number(opts.get("tie_tolerance", DEFAULT_TIE_TOLERANCE), "option tie_tolerance",
                                          *TIE_TOLERANCE_RANGE)}


def _fixed_price(problem: MultiTargetProblem, opts: Mapping[str, Any]) -> PlannerPolicy:
    price = opts.get("price")
    if price is None:  # a-priori: the planner's price at the initial beliefs, once
        probe = _planner(problem, {k: v for k, v in opts.items() if k != "price"}, None)
        price = probe.decide(initial_beliefs(problem)).lam
    return PlannerPolicy(_planner(problem, opts, price))


def _depth(opts: Mapping[str, Any]) -> int:
    return check_depth(opts.get("depth", DEFAULT_JOINT_DEPTH), "option depth", MAX_DEPTH_RANGE)


@dataclass(frozen=True)
class JointPolicyEntry:
    """One row of :data:`JOINT_POLICIES`: the factory, a one-line help and the options it accepts."""

    factory: Callable[[MultiTargetProblem, Mapping[str, Any]], Any]
    help: str
    options: tuple[str, ...] = ()


_PLANNER_OPTIONS = ("search", "depth", "time_budget", "max_depth", "max_evaluations", "no_limit", "variant",
                    "constant", "prune_without_guarantee", "tie_break", "tie_tolerance")

#: Every joint policy ``simulate --targets`` knows: name -> :class:`JointPolicyEntry`.
JOINT_POLICIES: dict[str, JointPolicyEntry] = {
    "lagrangian": JointPolicyEntry(
        lambda p, o: PlannerPolicy(_planner(p, o, None)),
        "per-target search at a price, exact knapsack, price minimising the dual bound (options: search=bnb|"
        f"exhaustive, depth={DEFAULT_JOINT_DEPTH} | time_budget=S, max_depth, max_evaluations, no_limit=1, variant, "
        "constant, prune_without_guarantee=1, tie_break=knapsack|lower_bound, tie_tolerance)", _PLANNER_OPTIONS),
    "fixed_price": JointPolicyEntry(
        _fixed_price, "as lagrangian, at one price fixed before the run (option price; default: lagrangian's "
        "price at the initial beliefs; and lagrangian's options)", (*_PLANNER_OPTIONS, "price")),
    "greedy": JointPolicyEntry(lambda p, o: GreedyPolicy(p), "max sum_k rho_k(b_k, a_k) within the budget"),
    "equal_split": JointPolicyEntry(
        lambda p, o: EqualSplitPolicy(p, {**_gate(o), "use_bounds": _search(o) == "bnb"}, _depth(o)),
        "a fixed equal share of the budget per target, each planned alone (options: search=bnb|exhaustive, "
        f"depth={DEFAULT_JOINT_DEPTH}, variant, constant, prune_without_guarantee=1)",
        ("search", "depth", "variant", "constant", "prune_without_guarantee")),
    "round_robin": JointPolicyEntry(lambda p, o: RoundRobinPolicy(p),
                                    "belief-blind turns: one target after another takes the most effort left"),
    "exact_joint": JointPolicyEntry(lambda p, o: ExactJointPolicy(p, _depth(o)),
                                    f"exact joint expectimax within the budget (small problems; option "
                                    f"depth={DEFAULT_JOINT_DEPTH})",
                                    ("depth",)),
}


def joint_policy_names() -> list[str]:
    """Names of all joint policies, sorted."""
    return sorted(JOINT_POLICIES)


def make_joint_policy(name: str, problem: MultiTargetProblem, **options: Any) -> Any:
    """Build joint policy ``name`` for ``problem`` (unknown names and options are errors)."""
    return table_entry(JOINT_POLICIES, name, options, "joint policy").factory(problem, options)
