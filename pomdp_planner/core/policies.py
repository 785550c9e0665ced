"""The closed-loop policies, in one explicit table (``pomdp-planner simulate --policy NAME``).

A policy is a callable ``belief -> 0-based action`` or an object with ``.act(belief)``.
:data:`POLICIES` maps every name to a :class:`PolicyEntry`: ``factory(model, options) ->
policy``, a one-line help and the option names it accepts (``options`` a dict of keyword
options, e.g. ``{"seed": 1, "depth": 3}``; an unknown option is an error naming the known
ones). The planners are imported here, at the top: nothing registers itself at import time.

Policies: ``random`` (seeded uniform actions), ``myopic`` (greedy ``argmax_a rho(b, a)``,
Eq. 3), ``bnb`` (branch-and-bound search, Algorithm 1), ``exhaustive`` (the same search
without pruning), ``lower`` / ``upper`` (the myopic bound policies of Sec. IV, Theorem 2).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .bounds import BOUND_VARIANTS, solve_bounds
from .model import POMDP, ModelError
from .myopic import MyopicBounds
from .search import Planner, SearchResult


class PolicyObject(Protocol):
    def act(self, belief: np.ndarray) -> int: ...


Policy = Callable[[np.ndarray], int] | PolicyObject
PolicyFactory = Callable[[POMDP, Mapping[str, Any]], Policy]


# ------------------------------------------------------------------------- policies
class RandomPolicy:
    """Uniformly random actions from its own seeded generator (ignores the belief)."""

    def __init__(self, model: POMDP, seed: int | None = None):
        self.num_actions = model.A
        self.rng = np.random.default_rng(seed)

    def act(self, belief: np.ndarray) -> int:
        return int(self.rng.integers(self.num_actions))


class MyopicPolicy:
    """Greedy one-step policy ``argmax_a rho(b, a)`` (Eq. 3; ties: smallest index = priority)."""

    def __init__(self, model: POMDP):
        self.model = model

    def act(self, belief: np.ndarray) -> int:
        return int(np.argmax(self.model.rho(belief)))


class SearchPolicy:
    """A closed-loop policy that plans every step (``--policy bnb`` / ``exhaustive``).

    ``depth``: fixed-depth search (default 3), or ``time_budget`` seconds of anytime search up
    to ``max_depth`` (default 10).
    """

    def __init__(self, planner: Planner, depth: int = 3, time_budget: float | None = None, max_depth: int = 10,
                 use_bounds: bool = True):
        self.planner = planner
        self.depth = Planner._check_depth(depth, "depth")
        self.max_depth = Planner._check_depth(max_depth, "max_depth")
        self.time_budget = None if time_budget is None else float(time_budget)
        self.use_bounds = use_bounds and planner.has_bounds
        self.last: SearchResult | None = None

    def act(self, belief: np.ndarray) -> int:
        if self.time_budget is None:
            self.last = self.planner.search(belief, self.depth, use_bounds=self.use_bounds)
        else:
            self.last = self.planner.plan(belief, self.max_depth, self.time_budget, use_bounds=self.use_bounds)
        return self.last.action


class BoundPolicy:
    """The myopic lower or upper bound policy of Sec. IV (``--policy lower`` / ``upper``)."""

    def __init__(self, bounds: MyopicBounds, which: str):
        if which not in ("lower", "upper"):
            raise ValueError(f"which: expected 'lower' or 'upper', got {which!r}")
        self.bounds = bounds
        self.which = which

    def act(self, belief: np.ndarray) -> int:
        b = np.asarray(belief, dtype=float)[None, :]
        return int(getattr(self.bounds, self.which)(b)[0])


# ------------------------------------------------------------------------- factories
def _variant(opts: Mapping[str, Any]) -> str:
    variant = str(opts.get("variant", BOUND_VARIANTS[0]))
    if variant not in BOUND_VARIANTS:
        raise ModelError(f"option variant: expected one of {', '.join(BOUND_VARIANTS)}, got {variant!r}")
    return variant


def _search_policy(model: POMDP, opts: Mapping[str, Any], use_bounds: bool) -> SearchPolicy:
    variant = _variant(opts) if use_bounds else None
    planner = Planner.from_model(model, variant=variant)
    if use_bounds and not planner.has_bounds:
        raise ModelError(f"policy bnb: the bound LP ({variant}) is infeasible for this model: "
                         f"{planner.bounds_solution.message}; use --policy exhaustive")
    tb = opts.get("time_budget")
    return SearchPolicy(planner, depth=int(opts.get("depth", 3)), time_budget=None if tb is None else float(tb),
                        max_depth=int(opts.get("max_depth", 10)), use_bounds=use_bounds)


def _bound_policy(model: POMDP, opts: Mapping[str, Any], which: str) -> BoundPolicy:
    variant = _variant(opts)
    sol = solve_bounds(model, variant=variant)
    if not sol.feasible or sol.myopic is None:
        raise ModelError(f"policy {which}: the bound LP ({variant}) is infeasible for this model: {sol.message}")
    return BoundPolicy(sol.myopic, which)


@dataclass(frozen=True)
class PolicyEntry:
    """One row of :data:`POLICIES`: the factory, a one-line help and the options it accepts."""

    factory: PolicyFactory
    help: str
    options: tuple[str, ...] = ("seed",)


_SEARCH_OPTIONS = ("seed", "depth", "time_budget", "max_depth")

#: Every policy ``simulate`` knows: name -> :class:`PolicyEntry`.
POLICIES: dict[str, PolicyEntry] = {
    "random": PolicyEntry(lambda m, o: RandomPolicy(m, o.get("seed")), "uniformly random actions (seeded by --seed)"),
    "myopic": PolicyEntry(lambda m, o: MyopicPolicy(m), "greedy argmax_a rho(b, a) (Eq. 3)"),
    "bnb": PolicyEntry(lambda m, o: _search_policy(m, o, True),
                       "branch-and-bound search, Algorithm 1 (options: depth=3 | time_budget=S, max_depth, variant)",
                       (*_SEARCH_OPTIONS, "variant")),
    "exhaustive": PolicyEntry(lambda m, o: _search_policy(m, o, False),
                              "exhaustive tree search (options: depth=3 | time_budget=S, max_depth)", _SEARCH_OPTIONS),
    "lower": PolicyEntry(lambda m, o: _bound_policy(m, o, "lower"),
                         "myopic lower-bound policy of Theorem 2 (option: variant)", ("seed", "variant")),
    "upper": PolicyEntry(lambda m, o: _bound_policy(m, o, "upper"),
                         "myopic upper-bound policy of Theorem 2 (option: variant)", ("seed", "variant")),
}


def policy_names() -> list[str]:
    """Names of all policies of :data:`POLICIES`, sorted."""
    return sorted(POLICIES)


def make_policy(name: str, model: POMDP, **options: Any) -> Policy:
    """Build policy ``name`` for ``model`` (``options`` go to its factory; unknown ones are errors)."""
    entry = POLICIES.get(name)
    if entry is None:
        raise ModelError(f"policy: unknown policy {name!r} (known: {', '.join(policy_names())})")
    unknown = sorted(set(options) - set(entry.options))
    if unknown:
        raise ModelError(f"policy {name}: unknown option {', '.join(map(repr, unknown))} "
                         f"(known: {', '.join(entry.options)})")
    return entry.factory(model, options)


def as_callable(policy: Policy) -> Callable[[np.ndarray], int]:
    """``policy.act`` for a policy object, the policy itself for a callable."""
    act = getattr(policy, "act", None)
    if callable(act):
        return act
    if callable(policy):
        return policy
    raise TypeError(f"policy: expected a callable belief -> action or an object with .act(), got {policy!r}")
