"""The closed-loop policies, in one explicit table (``pomdp-planner simulate --policy NAME``).

A policy is a callable ``belief -> 0-based action`` or an object with ``.act(belief)``.
:data:`POLICIES` maps every name to a :class:`PolicyEntry`: ``factory(model, options) ->
policy``, a one-line help and the option names it accepts (``options`` a dict of keyword
options, e.g. ``{"seed": 1, "depth": 3}``; an unknown option is an error naming the known
ones). The planners are imported here, at the top: nothing registers itself at import time.

Policies: ``random`` (seeded uniform actions), ``myopic`` (greedy ``argmax_a rho(b, a)``,
Eq. 3), ``bnb`` (branch-and-bound search, Algorithm 1), ``exhaustive`` (the same search
without pruning), ``lower`` / ``upper`` (the myopic bound policies of Sec. IV, Theorem 2),
``mcts`` (information-aware MCTS on exact beliefs, :mod:`.belief_mcts`). The policies that use
the bounds (``bnb``, ``lower``, ``upper``) take ``variant`` (:data:`~.bounds.BOUND_VARIANTS`) and
``constant`` (:data:`~.bounds.BOUND_CONSTANTS`, default ``mlr``) and get them through the
assumption gate (:func:`~.gate.build_planner`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .belief_mcts import POLICY_OPTIONS as MCTS_OPTIONS
from .belief_mcts import make_belief_mcts_policy
from .bounds import BOUND_CONSTANTS, BOUND_VARIANTS, DEFAULT_CONSTANT, check_constant, check_variant
from .checks import check_choice, parse_flag
from .errors import OptionError, short_repr
from .gate import (
    MAX_SETUP_SECONDS,
    PlannerSetup,
    build_planner,
    check_setup_cost,
    estimate_setup,
    setup_notice,
)
from .model import POMDP
from .myopic import MyopicBounds
from .options import MAX_DEPTH_RANGE, TIME_BUDGET_RANGE, check_depth, check_seed, check_time_budget
from .options import SEED_RANGE as SEED_RANGE  # re-exported: the ranges live in options.py
from .search import Planner, SearchResult, check_tree_size


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


def search_guards(planner: Planner, depth: int, time_budget: float | None, max_depth: int, no_limit: bool,
                  prefix: str = "option ", hint: str = "use the option time_budget=S (anytime search), or no_limit=1"
                  ) -> tuple[int, str]:
    """The resource guards of a search request, applied once before the first decision: a fixed
    ``depth`` (no ``time_budget``) whose complete tree exceeds :data:`~.search.MAX_TREE_NODES` is
    refused unless ``no_limit`` (:func:`~.search.check_tree_size`, ``hint`` in the message), as is
    one over the planner's memory budget; under a time budget ``max_depth`` is capped at the
    deepest depth within the memory budget (refused if not even depth 1 fits). Returns the
    ``max_depth`` to use and a note (``""``, or what was capped). Fields are ``prefix + "depth"``."""
    m = planner.model
    if time_budget is None:
        if not no_limit:
            check_tree_size(m.A, m.Z, depth, f"{prefix}depth", hint=hint)
        planner.check_memory(depth, f"{prefix}depth")
        return max_depth, ""
    planner.check_memory(1, f"{prefix}max_depth")  # refused if not even depth 1 fits
    fits = planner.deepest_depth_within_budget(max_depth)
    if fits < max_depth:
        return fits, (f"max_depth capped at {fits}: deeper searches need more than the memory budget "
                      f"({max_depth} asked for)")
    return max_depth, ""


def table_entry(table: Mapping[str, Any], name: str, options: Mapping[str, Any], what: str = "policy") -> Any:
    """``table[name]`` (an entry with ``options``) after checking that the name is known and that
    every key of ``options`` is one of the entry's options; else an :class:`OptionError` naming the
    policy (``what``: how the table's entries are called, e.g. ``"joint policy"``)."""
    entry = table.get(name)
    if entry is None:
        raise OptionError(f"policy: unknown {what} {short_repr(name)} (known: {', '.join(sorted(table))})")
    unknown = sorted(set(options) - set(entry.options))
    if unknown:
        raise OptionError(f"policy {name}: unknown option {', '.join(short_repr(k) for k in unknown[:5])} "
                          f"(known: {', '.join(entry.options) or 'none'})")
    return entry


class SearchPolicy:
    """A closed-loop policy that plans every step (``--policy bnb`` / ``exhaustive``).

    ``setup`` is the assumption gate's decision (:func:`~.gate.build_planner`): its planner
    prunes only when the gate said so. ``depth``: fixed-depth search (default 3), or
    ``time_budget`` seconds of anytime search up to ``max_depth`` (default 10).

    The resource guards of the search are applied once, here, before the first step: a fixed
    depth whose complete tree exceeds :data:`~.search.MAX_TREE_NODES` is refused unless
    ``no_limit`` (:func:`~.search.check_tree_size`), as is one over the planner's memory budget
    (:class:`~.search.SearchMemoryError`); the anytime search's ``max_depth`` is capped at the
    deepest depth within the memory budget (``note`` says so; refused if not even depth 1 fits).
    """

    def __init__(self, setup: PlannerSetup, depth: int = 3, time_budget: float | None = None, max_depth: int = 10,
                 no_limit: bool = False):
        if setup.planner is None:
            raise OptionError(f"policy: no planner ({setup.reason})")
        self.setup = setup
        self.planner = planner = setup.planner
        self.depth = check_depth(depth, "option depth", MAX_DEPTH_RANGE)
        self.max_depth = check_depth(max_depth, "option max_depth", MAX_DEPTH_RANGE)
        self.time_budget = None if time_budget is None else check_time_budget(time_budget, "option time_budget",
                                                                              TIME_BUDGET_RANGE)
        self.max_depth, self.note = search_guards(planner, self.depth, self.time_budget, self.max_depth, no_limit)
        self.use_bounds = setup.pruning
        self.last: SearchResult | None = None
        self.decisions = self.certified = 0

    def act(self, belief: np.ndarray) -> int:
        if self.time_budget is None:
            self.last = self.planner.search(belief, self.depth, use_bounds=self.use_bounds)
        else:
            self.last = self.planner.plan(belief, self.max_depth, self.time_budget, use_bounds=self.use_bounds)
        self.decisions += 1
        self.certified += bool(self.last.certified)
        return self.last.action


class BoundPolicy:
    """The myopic lower or upper bound policy of Sec. IV (``--policy lower`` / ``upper``).

    ``setup`` (optional) is the gate's decision the bounds came from.
    """

    def __init__(self, bounds: MyopicBounds, which: str, setup: PlannerSetup | None = None):
        check_choice(which, ("lower", "upper"), "which")
        self.bounds = bounds
        self.which = which
        self.setup = setup

    def act(self, belief: np.ndarray) -> int:
        b = np.asarray(belief, dtype=float)[None, :]
        return int(getattr(self.bounds, self.which)(b)[0])


# ------------------------------------------------------------------------- factories
def _variant(opts: Mapping[str, Any]) -> str:
    """The option ``variant`` (the bound LP's vectors, ``tight`` by default)."""
    return check_variant(opts.get("variant", BOUND_VARIANTS[0]), "option variant")


def _constant(opts: Mapping[str, Any]) -> str:
    """The option ``constant`` (the bound LP's belief-independent constant, ``mlr`` by default)."""
    return check_constant(opts.get("constant", DEFAULT_CONSTANT), "option constant")


def _flag(opts: Mapping[str, Any], name: str) -> bool:
    """A yes/no option (:func:`~.checks.parse_flag`: 1/0, true/false, yes/no, on/off)."""
    return parse_flag(opts.get(name, False), f"option {name}")


OVERRIDE = "prune_without_guarantee"


#: How a ``simulate`` user lifts the set-up time limit (:func:`~.gate.check_setup_cost`).
_SETUP_HINT = "the option no_limit=1 lifts the limit (bnb, exhaustive)"


def _max_setup_seconds(opts: Mapping[str, Any]) -> float | None:
    return None if _flag(opts, "no_limit") else MAX_SETUP_SECONDS


def _setup(model: POMDP, opts: Mapping[str, Any], use_bounds: bool) -> PlannerSetup:
    variant, constant = (_variant(opts), _constant(opts)) if use_bounds else (BOUND_VARIANTS[0], DEFAULT_CONSTANT)
    return build_planner(model, use_bounds=use_bounds, variant=variant, constant=constant,
                         prune_without_guarantee=_flag(opts, OVERRIDE), override_name=f"the option {OVERRIDE}=1",
                         max_setup_seconds=_max_setup_seconds(opts), setup_hint=_SETUP_HINT)


def setup_notice_for(name: str, model: POMDP, options: Mapping[str, Any]) -> str | None:
    """The gate's announcement of a long planner set-up for policy ``name`` (:func:`~.gate.setup_notice`),
    ``None`` when it is short or the policy builds no planner; for an entry point to print before
    :func:`make_policy` (which then runs the set-up). A set-up the gate would refuse is refused
    here already (:class:`~.gate.SetupCostError`), so nothing is announced that will not run."""
    entry = POLICIES.get(name)
    if entry is None or entry.gate is None:
        return None
    variant = _variant(options) if entry.gate else BOUND_VARIANTS[0]
    est = estimate_setup(model, use_bounds=entry.gate, variant=variant)
    check_setup_cost(est, _max_setup_seconds(options), _SETUP_HINT)
    return setup_notice(est)


def _search_policy(model: POMDP, opts: Mapping[str, Any], use_bounds: bool) -> SearchPolicy:
    """``bnb`` (``use_bounds``) or ``exhaustive``: the gate decides whether ``bnb`` may prune;
    on a model failing Assumption 1 it searches exhaustively and says why (``policy.setup``)."""
    return SearchPolicy(_setup(model, opts, use_bounds), depth=opts.get("depth", 3),
                        time_budget=opts.get("time_budget"), max_depth=opts.get("max_depth", 10),
                        no_limit=_flag(opts, "no_limit"))


def _bound_policy(model: POMDP, opts: Mapping[str, Any], which: str) -> BoundPolicy:
    """``lower`` / ``upper``: they ARE the bounds, so without valid bounds they refuse with the
    gate's reason, unless ``prune_without_guarantee=1`` says to use them anyway."""
    setup = _setup(model, opts, True)
    if setup.myopic is None:
        hint = (f"; --option {OVERRIDE}=1 uses them anyway, without guarantee"
                if setup.bounds is None or (setup.bounds.feasible and not setup.guaranteed) else "")
        raise OptionError(f"policy {which}: no valid bounds: {setup.reason}{hint}")
    return BoundPolicy(setup.myopic, which, setup)


def _mcts_policy(model: POMDP, opts: Mapping[str, Any]) -> Policy:
    """``mcts``: the information-aware belief-space MCTS (``core/belief_mcts.py``); its option
    errors (:class:`~.errors.OptionError` naming the option) say which policy they are for."""
    try:
        return make_belief_mcts_policy(model, opts)
    except OptionError as exc:
        raise OptionError(f"policy mcts: option {exc}") from None


@dataclass(frozen=True)
class PolicyEntry:
    """One row of :data:`POLICIES`: the factory, a one-line help and the options it accepts."""

    factory: PolicyFactory
    help: str
    options: tuple[str, ...] = ("seed",)
    #: The policy builds a planner through the gate with the bounds (True: assumption check, LP,
    #: tables), without them (False: tables only), or none (None).
    gate: bool | None = None


_SEARCH_OPTIONS = ("seed", "depth", "time_budget", "max_depth", "no_limit")
_BOUND_OPTIONS = ("variant", "constant", OVERRIDE)
_CONSTANTS = "|".join(BOUND_CONSTANTS)

#: Every policy ``simulate`` knows: name -> :class:`PolicyEntry`.
POLICIES: dict[str, PolicyEntry] = {
    "random": PolicyEntry(lambda m, o: RandomPolicy(m, o.get("seed")), "uniformly random actions (seeded by --seed)"),
    "myopic": PolicyEntry(lambda m, o: MyopicPolicy(m), "greedy argmax_a rho(b, a) (Eq. 3)"),
    "bnb": PolicyEntry(lambda m, o: _search_policy(m, o, True),
                       "branch-and-bound search, Algorithm 1; exhaustive (and says why) where the bounds are not "
                       f"valid (options: depth=3 | time_budget=S, max_depth, no_limit=1, variant, "
                       f"constant={_CONSTANTS}, {OVERRIDE}=1)",
                       (*_SEARCH_OPTIONS, *_BOUND_OPTIONS), gate=True),
    "exhaustive": PolicyEntry(lambda m, o: _search_policy(m, o, False),
                              "exhaustive tree search (options: depth=3 | time_budget=S, max_depth, no_limit=1)",
                              _SEARCH_OPTIONS, gate=False),
    "lower": PolicyEntry(lambda m, o: _bound_policy(m, o, "lower"),
                         f"myopic lower-bound policy of Theorem 2; refused where the bounds are not valid (options: "
                         f"variant, constant={_CONSTANTS}, {OVERRIDE}=1)", ("seed", *_BOUND_OPTIONS), gate=True),
    "upper": PolicyEntry(lambda m, o: _bound_policy(m, o, "upper"),
                         f"myopic upper-bound policy of Theorem 2; refused where the bounds are not valid (options: "
                         f"variant, constant={_CONSTANTS}, {OVERRIDE}=1)", ("seed", *_BOUND_OPTIONS), gate=True),
    "mcts": PolicyEntry(_mcts_policy,
                        "UCT on exact Bayes beliefs with the true reward rho (options: time_budget=S | "
                        "simulations=N, max_depth, exploration, exploration_scale, leaf, rollout_depth, tail, "
                        "backup, reuse)", tuple(MCTS_OPTIONS)),
}


def policy_names() -> list[str]:
    """Names of all policies of :data:`POLICIES`, sorted."""
    return sorted(POLICIES)


def make_policy(name: str, model: POMDP, **options: Any) -> Policy:
    """Build policy ``name`` for ``model`` (``options`` go to its factory; unknown ones are errors)."""
    entry = table_entry(POLICIES, name, options)
    if options.get("seed") is not None:
        options = {**options, "seed": check_seed(options["seed"], "option seed")}
    return entry.factory(model, options)


def last_decision(policy: Policy, belief: np.ndarray) -> dict[str, Any]:
    """What a run record (:mod:`~.io.run_record`) keeps of the decision ``policy`` just made at ``belief``:
    ``bounds`` (lower, upper priorities ``1..A``, or ``None``), ``guaranteed``, ``depth``, ``certified``
    and ``latency`` (seconds of search), ``None`` where the policy has no such figure. A search policy
    reports its last search; a bound policy the bounds at ``belief``. ``guaranteed`` is the assumption
    gate's verdict on those bounds (:func:`~.gate.build_planner`: the planner's flag, or the bound
    policy's ``setup``; crossed root bounds are never guaranteed), so bounds used without the
    guarantee (``prune_without_guarantee``) are recorded as such."""
    out: dict[str, Any] = {"bounds": None, "guaranteed": False, "depth": None, "certified": False, "latency": None}
    last = getattr(policy, "last", None)
    if isinstance(last, SearchResult):
        rb = last.root_bounds
        out.update(bounds=None if rb is None else (rb[0] + 1, rb[1] + 1), depth=last.depth,
                   guaranteed=rb is not None and last.guaranteed and not last.crossed,
                   certified=last.certified and last.guaranteed, latency=last.time_used)
    elif isinstance(policy, BoundPolicy):
        lo, up = (int(x[0]) for x in policy.bounds.actions(np.asarray(belief, dtype=float)[None, :]))
        guaranteed = policy.setup is not None and policy.setup.guaranteed and lo <= up
        out.update(bounds=(lo + 1, up + 1), guaranteed=guaranteed, certified=guaranteed and lo == up)
    return out


def as_callable(policy: Policy) -> Callable[[np.ndarray], int]:
    """``policy.act`` for a policy object, the policy itself for a callable."""
    act = getattr(policy, "act", None)
    if callable(act):
        return act
    if callable(policy):
        return policy
    raise TypeError(f"policy: expected a callable belief -> action or an object with .act(), got {policy!r}")
