"""The budgeted multi-target planner: a price per unit of effort, per-target branch-and-bound,
an exact knapsack over the targets, and a dual bound on the joint lookahead optimum.

One decision (:meth:`MultiTargetPlanner.decide`) for the beliefs ``b_1..b_K`` of a
:class:`~.problem.MultiTargetProblem`, at search depth ``d`` (``d`` levels below the root, as in
``core/search.py``):

1. **Price.** For a price ``lambda >= 0`` every target becomes its own POMDP with the reward
   ``rho_k(b, a) - lambda e_k(a)`` (:meth:`~pomdp_planner.core.search.Planner.priced`). Its planner
   comes from the assumption gate (:func:`~pomdp_planner.core.gate.build_planner`), once per
   target model: a model that fails Assumption 1 is searched exhaustively and certifies nothing;
   one that passes prunes with the same ``g, h`` at every price (docs/THEORY.md, "Several targets").
   Each target's search returns ``Q_k^lambda(b_k, a)`` for **every** root action (the bounds prune
   below the root only: the budget may force a root action the bounds would skip).
2. **Joint action.** The exact multiple-choice knapsack (:mod:`.knapsack`) maximises
   ``sum_k [Q_k^lambda(b_k, a_k) + lambda e_k(a_k)]`` subject to ``sum_k e_k(a_k) <= B``: the root
   epoch's budget is kept exactly, so its effort is not priced again; later epochs are priced.
   The budget is never exceeded (integer arithmetic, :mod:`.problem`).
3. **Dual bound.** ``U(lambda)`` = the knapsack optimum + ``lambda B sum_{t=1}^{d} gamma^t``
   (:mod:`.dual`); ``lambda`` is chosen to minimise it (warm-started from the previous epoch, or
   from the previous depth of the same decision). ``L(lambda) = sum_k V_k^lambda(b_k) + lambda B
   sum_{t=0}^{d} gamma^t`` is reported too (``L >= U``).
4. **Gap.** A feasible joint policy that starts with the chosen joint action: from the next epoch
   on, target ``k`` keeps a fixed share ``beta_k`` of the budget (``sum_k beta_k <= B``) and uses
   only its actions with ``e_k(a) <= beta_k``, planned on its own. Its value decomposes over the
   targets: ``rho_k(b_k, a_k) + gamma sum_z eta W_k^{beta_k}(tau(b_k, a_k, z))``, with ``W`` the
   value of a depth ``d - 1`` search of the model restricted to those actions (unpriced; any
   search gives a policy's value, so pruning does not spoil it). The shares are chosen by a second
   knapsack over the share levels (each target's distinct efforts); ``lower_bound`` is its optimum
   and ``gap = dual_bound - lower_bound``. Cost: per target, one search of depth ``d - 1`` per
   share level and possible observation.

**What is guaranteed** (docs/THEORY.md, "What the decomposition guarantees"): the dual bound is
an upper bound on the depth-``d`` joint lookahead value (the exact expectimax over the product
belief and the joint actions within budget, every epoch) when every target's search is
exhaustive (``search="exhaustive"``, or a gate fallback for every target): ``bound_guaranteed``.
Then the chosen joint action's joint lookahead value is within ``gap`` of the best joint
action's. Branch-and-bound values are at most the exact depth-``d`` values (a max over a subset),
so with pruning the "dual bound" is an estimate that may fall below the joint optimum
(``bound_guaranteed=False``; the benchmark counts how often). Neither is a bound on the
infinite-horizon joint optimum.

**Budget that cannot bind** (``B >= sum_k max_a e_k(a)``): every joint action is within it, the
price is 0 (``U(lambda) >= U(0)`` for every ``lambda``, THEORY) and the decision is exactly that
of K independent single-target planners (the same searches, root pruning included), gap 0.

**Anytime.** ``time_budget`` seconds for the whole decision, all targets and all prices: the
depths ``1, 2, ..., max_depth`` are searched in turn for all targets, the deadline is checked
inside every search (before every chunk), an interrupted depth is discarded, and the deepest
completed depth is returned; the first depth ignores the deadline (a decision always comes back);
a depth predicted not to finish is not started (:func:`~pomdp_planner.core.search.next_depth_cannot_finish`).
Without a time budget one fixed ``depth`` is searched.

The call a sensor-manager node makes per epoch is :meth:`MultiTargetPlanner.decide`; it returns a
:class:`JointDecision` (joint action, price, dual bound, gap, budget use) and keeps the price
for the next epoch's warm start (:meth:`~MultiTargetPlanner.reset` forgets it).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from typing import Any

import numpy as np

from ..belief import ETA_MIN, check_belief_rows, posteriors_all
from ..bounds import DEFAULT_CONSTANT
from ..checks import check_choice, check_number
from ..errors import BeliefError, ModelError, OptionError
from ..gate import PlannerSetup, build_planner
from ..model import POMDP
from ..options import MAX_DEPTH_RANGE, TIME_BUDGET_RANGE, check_depth, check_time_budget
from ..policies import search_guards
from ..search import DEFAULT_MEMORY_BUDGET, DeadlineExceeded, next_depth_cannot_finish
from .dual import horizon_sum, lambda_ceiling, minimise_convex
from .knapsack import knapsack_optimum, near_optimal, solve_padded
from .problem import MultiTargetProblem

#: How the per-target searches run: branch-and-bound where the gate allows it, or exhaustive.
SEARCH_MODES = ("bnb", "exhaustive")
#: Prices a user may fix (``price``), inclusive.
PRICE_RANGE = (0.0, 1e9)
#: Most evaluations of ``U(lambda)`` (each one search per target) per depth, and the default.
MAX_EVALUATIONS_RANGE = (2, 200)
DEFAULT_EVALUATIONS = 12
#: The lookahead depth of every joint policy unless one is given (the planner, the fixed price, the
#: equal split and the exact joint planner alike, so their bounds and values compare like with like).
DEFAULT_JOINT_DEPTH = 2
#: How the joint action is chosen among the knapsack's near-ties at the chosen price (class docstring).
TIE_BREAKS = ("knapsack", "lower_bound")
DEFAULT_TIE_BREAK = "knapsack"
#: Joint actions within this much of the knapsack's optimum count as tied (``tie_break="lower_bound"``).
DEFAULT_TIE_TOLERANCE = 1e-3
TIE_TOLERANCE_RANGE = (0.0, 1e9)
#: Most tied joint actions whose lower bounds are compared.
TIE_CANDIDATES = 16


@dataclass(frozen=True)
class TargetDecision:
    """One target's part of a :class:`JointDecision` (0-based action).

    ``q_values[a] = Q_k^lambda(b_k, a) + lambda e_k(a)``: the knapsack's values (the root reward
    unpriced, the future priced; ``nan`` for root actions the bounds pruned, which only happens
    when the budget cannot bind). ``value = V_k^lambda(b_k)``; ``lower`` the value of the
    target's part of the fixed-share continuation (the gap's lower bound) and ``share`` the effort
    it may use per later epoch. ``guaranteed``: the gate proved the bounds valid for this
    target's model (valid at every price); ``pruned``: its searches pruned with them.
    ``root_bounds``: the priced myopic bounds at ``b_k`` (0-based, ``None`` without bounds).
    """

    action: int
    q_values: np.ndarray
    value: float
    lower: float
    share: Fraction
    guaranteed: bool
    pruned: bool
    root_bounds: tuple[int, int] | None

    def to_dict(self) -> dict[str, Any]:
        return {"priority": self.action + 1,
                "q_values": [None if not math.isfinite(x) else float(x) for x in self.q_values],
                "value": float(self.value), "lower": float(self.lower), "share": float(self.share),
                "guaranteed": bool(self.guaranteed),
                "pruned": bool(self.pruned),
                "root_bounds": None if self.root_bounds is None else [int(x) + 1 for x in self.root_bounds]}


@dataclass(frozen=True)
class JointDecision:
    """The outcome of one :meth:`MultiTargetPlanner.decide` (module docstring).

    ``actions`` (0-based; :attr:`priorities` ``1..A``), the price ``lam``, ``dual_bound`` =
    ``U(lam)``, ``lagrangian`` = ``L(lam)``, ``lower_bound`` and ``gap = dual_bound - lower_bound``;
    ``bound_guaranteed``: every target was searched exhaustively at ``depth``, so ``dual_bound`` is
    an upper bound on the depth-``depth`` joint lookahead value and ``gap`` bounds the chosen joint
    action's shortfall from the best one there. ``effort`` = ``sum_k e_k(a_k) <= budget`` (exact).
    ``prices``: every ``(lambda, U(lambda))`` evaluated at ``depth``.
    """

    actions: tuple[int, ...]
    lam: float
    dual_bound: float
    lagrangian: float
    lower_bound: float
    gap: float
    bound_guaranteed: bool
    budget: Fraction
    effort: Fraction
    budget_binds: bool
    depth: int
    targets: tuple[TargetDecision, ...]
    prices: tuple[tuple[float, float], ...] = ()
    time_used: float = 0.0
    deadline_hit: bool = False
    predicted_stop: bool = False
    depth_times: tuple[float, ...] = ()

    @property
    def priorities(self) -> tuple[int, ...]:
        return tuple(a + 1 for a in self.actions)

    @property
    def budget_use(self) -> float:
        """``effort / budget`` (1.0 for a zero budget)."""
        return float(self.effort / self.budget) if self.budget else 1.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; actions as priorities ``1..A``."""
        return {"priorities": list(self.priorities), "lambda": float(self.lam), "dual_bound": float(self.dual_bound),
                "lagrangian_bound": float(self.lagrangian), "lower_bound": float(self.lower_bound),
                "gap": float(self.gap), "bound_guaranteed": bool(self.bound_guaranteed),
                "budget": float(self.budget), "effort": float(self.effort), "budget_use": self.budget_use,
                "budget_binds": bool(self.budget_binds), "depth": int(self.depth),
                "price_evaluations": len(self.prices), "time_used": float(self.time_used),
                "deadline_hit": bool(self.deadline_hit), "predicted_stop": bool(self.predicted_stop),
                "targets": [t.to_dict() for t in self.targets]}


@dataclass(frozen=True)
class _Evaluation:
    """Every target searched at one price: the knapsack's values ``V`` (``K x max_k A_k``, row ``k``
    = target ``k``'s ``Q_k + lambda e_k``, ``-inf`` past its actions), ``V_k^lambda(b_k)`` per target,
    the knapsack's optimum and both bounds. The joint action is found for the chosen price only
    (:meth:`MultiTargetPlanner._joint`)."""

    lam: float
    values: np.ndarray
    target_values: np.ndarray
    knapsack: float
    upper: float
    lagrangian: float


def sub_model(model: POMDP, keep: np.ndarray) -> POMDP:
    """``model`` with only the actions ``keep`` (0-based, increasing), in their order."""
    names = None if model.action_names is None else [model.action_names[a] for a in keep]
    return POMDP(model.P[keep], model.O[keep], model.r[:, keep], model.gamma, model.uncertainty, model.w[keep],
                 model.epsilon, f"{model.name}[priorities {','.join(str(a + 1) for a in keep)}]",
                 model.state_names, names, model.observation_names)


class RestrictedPlanners:
    """The gate's planners for a problem's models restricted to the actions within an effort
    level, built once per (model, action set). ``gate``: the keyword arguments of
    :func:`~pomdp_planner.core.gate.build_planner`; ``clock`` is given to every planner."""

    def __init__(self, problem: MultiTargetProblem, gate: dict[str, Any], clock: Callable[[], float],
                 full: Sequence[PlannerSetup] | None = None):
        self.problem = problem
        self.gate = gate
        self.clock = clock
        self.full = full
        self._cache: dict[tuple[int, tuple[int, ...]], tuple[PlannerSetup, np.ndarray]] = {}

    def get(self, k: int, level: Fraction | int, units: bool = True) -> tuple[PlannerSetup, np.ndarray]:
        """Target ``k``'s planner for the actions of effort at most ``level`` (in the problem's
        integer units if ``units``, else an effort) and those actions (0-based)."""
        p = self.problem
        keep = np.flatnonzero(p.units[k] <= level) if units else \
            np.array([a for a, e in enumerate(p.efforts[k]) if e <= level], dtype=int)
        if keep.size == 0:
            raise OptionError(f"efforts[{k}]: no priority of {p.names[k]} costs at most {level}")
        model = p.models[k]
        key = (id(model), tuple(int(x) for x in keep))
        hit = self._cache.get(key)
        if hit is None:
            if keep.size == model.A and self.full is not None:
                hit = (self.full[k], keep)
            else:
                restricted = model if keep.size == model.A else sub_model(model, keep)
                setup = build_planner(restricted, **self.gate)
                if setup.planner is None:
                    raise ModelError(f"targets: no planner for {restricted.name} ({setup.reason})")
                setup.planner.clock = self.clock
                hit = (setup, keep)
            self._cache[key] = hit
        return hit


class MultiTargetPlanner:
    """Per-epoch decisions for a :class:`~.problem.MultiTargetProblem` (module docstring).

    ``search``: :data:`SEARCH_MODES` (``"bnb"``: prune where the gate allows, ``"exhaustive"``:
    never prune; only then is the dual bound guaranteed). ``depth``: the fixed depth (default
    :data:`DEFAULT_JOINT_DEPTH`), or ``time_budget`` seconds for the anytime search up to
    ``max_depth``. ``max_evaluations``: evaluations of ``U(lambda)`` per depth. ``price``: a fixed
    price (no search for it; the baseline "per-target search at an a-priori price"). ``variant``,
    ``constant``, ``prune_without_guarantee`` go to the gate; ``no_limit`` lifts the tree-size
    guard of a fixed depth; ``memory_budget`` per search; ``clock`` for deadlines (injectable).

    ``tie_break``: :data:`TIE_BREAKS`. ``"knapsack"``: the knapsack's optimum at the chosen price
    (its tie rule, :mod:`.knapsack`). ``"lower_bound"``: of the joint actions whose knapsack value
    is within ``tie_tolerance`` of the optimum (at most :data:`TIE_CANDIDATES`), the one with the
    greatest lower bound (the value of its fixed-share continuation; ties: the knapsack's).
    At the price that minimises the bound the knapsack's best joint actions can be near-ties (the
    price sits where the relaxed problem is indifferent between them), and their true values can
    differ far more than their knapsack values. Neither rule changes the dual bound; the gap
    is always that of the joint action chosen (``dual_bound - lower_bound``).
    """

    def __init__(self, problem: MultiTargetProblem, *, search: str = "bnb", depth: int = DEFAULT_JOINT_DEPTH,
                 time_budget: float | None = None, max_depth: int = 10,
                 max_evaluations: int = DEFAULT_EVALUATIONS, price: float | None = None,
                 variant: str = "tight", constant: str = DEFAULT_CONSTANT, prune_without_guarantee: bool = False,
                 no_limit: bool = False, memory_budget: int = DEFAULT_MEMORY_BUDGET,
                 clock: Callable[[], float] = time.perf_counter, tie_break: str = DEFAULT_TIE_BREAK,
                 tie_tolerance: float = DEFAULT_TIE_TOLERANCE):
        check_choice(search, SEARCH_MODES, "search")
        self.tie_break = check_choice(tie_break, TIE_BREAKS, "tie_break")
        self.tie_tolerance = check_number(tie_tolerance, "tie_tolerance", *TIE_TOLERANCE_RANGE)
        self.problem = problem
        self.search_mode = search
        self.clock = clock
        self.depth = check_depth(depth, "depth", MAX_DEPTH_RANGE)
        self.max_depth = check_depth(max_depth, "max_depth", MAX_DEPTH_RANGE)
        self.time_budget = None if time_budget is None else check_time_budget(time_budget, "time_budget",
                                                                              TIME_BUDGET_RANGE)
        self.max_evaluations = check_depth(max_evaluations, "max_evaluations", MAX_EVALUATIONS_RANGE)
        self.fixed_price = None if price is None else check_number(price, "price", *PRICE_RANGE)
        self._gate = {"variant": variant, "constant": constant, "prune_without_guarantee": prune_without_guarantee,
                      "memory_budget": memory_budget, "use_bounds": search == "bnb"}
        self._setups: dict[int, PlannerSetup] = {}
        self.setups = tuple(self._setup(m) for m in problem.models)
        self._planners = tuple(s.planner for s in self.setups)
        self.efforts = tuple(u.astype(float) / problem.scale for u in problem.units)
        self._restricted = RestrictedPlanners(problem, self._gate, clock, self.setups)
        groups: dict[tuple[int, bytes], list[int]] = {}
        for k, (m, u) in enumerate(zip(problem.models, problem.units, strict=True)):
            groups.setdefault((id(m), u.tobytes()), []).append(k)
        self._groups = tuple(tuple(g) for g in groups.values())
        self._members = tuple(np.array(g, dtype=np.intp) for g in self._groups)
        # Every target's efforts as one K x max_k A_k table (the knapsack's), integer units and effort.
        width = max(m.A for m in problem.models)
        self._capacity = problem.knapsack_capacity
        self._binds = problem.budget_binds
        self._ceilings: dict[int, float] = {}  # per depth
        self._units = np.zeros((problem.K, width), dtype=np.int64)
        self._effort_table = np.zeros((problem.K, width))
        for k, (u, e) in enumerate(zip(problem.units, self.efforts, strict=True)):
            self._units[k, :u.size] = u
            self._effort_table[k, :e.size] = e
        self.note = ""
        self._check_resources(no_limit)
        self._lam = 0.0 if price is None else price

    # ----------------------------------------------------------------- set-up
    def _setup(self, model: POMDP) -> PlannerSetup:
        """The gate's decision for ``model`` (one per model object: K copies of one file share it)."""
        setup = self._setups.get(id(model))
        if setup is None:
            setup = build_planner(model, **self._gate)
            if setup.planner is None:
                raise ModelError(f"targets: no planner for {model.name} ({setup.reason})")
            setup.planner.clock = self.clock
            self._setups[id(model)] = setup
        return setup

    def _check_resources(self, no_limit: bool) -> None:
        """The search guards of ``core/policies.py`` (:func:`~pomdp_planner.core.policies.search_guards`),
        per distinct model; under a time budget ``max_depth`` is capped for the deepest-limited model."""
        for setup in self._setups.values():
            fits, note = search_guards(setup.planner, self.depth, self.time_budget, self.max_depth, no_limit,
                                       prefix="", hint="use time_budget (anytime search), or no_limit")
            if fits < self.max_depth:
                self.max_depth, self.note = fits, note

    @property
    def guaranteed_targets(self) -> tuple[bool, ...]:
        """Per target: the gate proved its bounds valid (valid at every price)."""
        return tuple(s.guaranteed for s in self.setups)

    @property
    def bound_guaranteed(self) -> bool:
        """Every target is searched exhaustively, so the dual bound is guaranteed (module docstring)."""
        return not any(s.pruning for s in self.setups)

    @property
    def price(self) -> float:
        """The price the next decision starts from (the last decision's, or the fixed price)."""
        return self._lam

    def reset(self) -> None:
        """Forget the warm start: the next decision searches the price from 0 (or the fixed price)."""
        self._lam = 0.0 if self.fixed_price is None else self.fixed_price

    def describe(self) -> str:
        """One line per distinct model: the gate's decision."""
        return "; ".join(f"{s.planner.model.name}: {s.describe()}" for s in self._setups.values())

    # --------------------------------------------------------------- decisions
    def check_beliefs(self, beliefs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """The K beliefs, each checked against its target's model (``BeliefError`` naming ``beliefs[k]``)."""
        return self._split(self._stacks(beliefs))

    def _stacks(self, beliefs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """The beliefs validated once, at the boundary (the searches do not validate them again),
        as one ``n x S`` array per group of targets with the same model and efforts."""
        if len(beliefs) != self.problem.K:
            raise BeliefError(f"beliefs: {len(beliefs)} beliefs for {self.problem.K} targets")
        return [check_belief_rows(self.problem.models[g[0]], [beliefs[k] for k in g], [f"beliefs[{k}]" for k in g])
                for g in self._groups]

    def _split(self, stacks: list[np.ndarray]) -> list[np.ndarray]:
        """Per target, its row of :meth:`_stacks`."""
        out: list[np.ndarray] = [np.empty(0)] * self.problem.K
        for stack, members in zip(stacks, self._groups, strict=True):
            for i, k in enumerate(members):
                out[k] = stack[i]
        return out

    def decide(self, beliefs: Sequence[np.ndarray], started_at: float | None = None) -> JointDecision:
        """The joint action for ``beliefs`` (module docstring). ``started_at``: the :attr:`clock`
        reading the time budget counts from (default: now), e.g. when the beliefs arrived."""
        stacks = self._stacks(beliefs)
        t0 = self.clock() if started_at is None else float(started_at)
        deadline = None if self.time_budget is None else t0 + self.time_budget
        depths = [self.depth] if self.time_budget is None else list(range(1, self.max_depth + 1))
        lam0 = self._lam
        best: JointDecision | None = None
        times: list[float] = []
        hit = predicted = False
        for i, d in enumerate(depths):
            ts = self.clock()
            try:
                dec = self._decide_at(stacks, d, lam0, None if i == 0 else deadline)
            except DeadlineExceeded:
                hit = True
                break
            best, lam0 = dec, dec.lam
            now = self.clock()
            times.append(now - ts)
            if deadline is None or i == len(depths) - 1:
                continue
            if now >= deadline:
                hit = True
                break
            if next_depth_cannot_finish(times, deadline - now):
                hit = predicted = True
                break
        assert best is not None  # the first depth runs without a deadline
        if self.fixed_price is None:
            self._lam = best.lam
        return replace(best, time_used=self.clock() - t0, deadline_hit=hit, predicted_stop=predicted,
                       depth_times=tuple(times))

    def evaluate(self, beliefs: Sequence[np.ndarray], lam: float, depth: int) -> JointDecision:
        """The decision at the price ``lam`` and ``depth`` (no search for the price, no warm start
        kept): what :meth:`decide` computes for one price. ``dual_bound`` is ``U(lam)``."""
        stacks = self._stacks(beliefs)
        depth = check_depth(depth)
        lam = check_number(lam, "lam", *PRICE_RANGE)
        ev = self._evaluate(stacks, lam, depth, None)
        return self._joint(stacks, ev, depth, ((ev.lam, ev.upper),), None)

    def _decide_at(self, stacks: list[np.ndarray], depth: int, lam0: float, deadline: float | None) -> JointDecision:
        if not self._binds:
            return self._independent(stacks, depth, deadline)
        if self.fixed_price is not None:
            ev = self._evaluate(stacks, self.fixed_price, depth, deadline)
            return self._joint(stacks, ev, depth, ((ev.lam, ev.upper),), deadline)
        seen: dict[float, _Evaluation] = {}

        def upper(lam: float) -> float:
            seen[lam] = self._evaluate(stacks, lam, depth, deadline)
            return seen[lam].upper

        ceiling = self._ceilings.get(depth)
        if ceiling is None:  # one term per group of targets with one model and one list of efforts
            ceiling = self._ceilings[depth] = lambda_ceiling([self.problem.models[g[0]] for g in self._groups],
                                                             [self.efforts[g[0]] for g in self._groups], depth)
        found = minimise_convex(upper, ceiling, lam0, self.max_evaluations)
        return self._joint(stacks, seen[found.x], depth, found.evaluations, deadline)

    def _priced(self, k: int, lam: float):
        """Target ``k``'s planner at the price ``lam`` (the gate's planner itself at 0)."""
        return self._planners[k] if lam == 0.0 else self._planners[k].priced(lam * self.efforts[k])

    def _evaluate(self, stacks: list[np.ndarray], lam: float, depth: int, deadline: float | None) -> _Evaluation:
        """Every target's priced search at ``lam`` (all root actions), the knapsack's optimum and both
        bounds. Targets with the same model and efforts are searched in one batch
        (``Planner.q_values_batch``), their beliefs not validated again."""
        p = self.problem
        V = np.full(self._units.shape, -np.inf)
        top = np.empty(p.K)  # V_k^lambda(b_k)
        for stack, members, idx in zip(stacks, self._groups, self._members, strict=True):
            k0 = members[0]
            Q = self._priced(k0, lam).q_values_batch(stack, depth, self.setups[k0].pruning, deadline=deadline,
                                                     checked=True)
            V[idx, :Q.shape[1]] = Q + lam * self.efforts[k0]
            top[idx] = Q.max(axis=1)
        knap = knapsack_optimum(V, self._units, self._capacity)
        B, g = float(p.budget), p.gamma
        upper = knap + lam * B * horizon_sum(g, 1, depth)
        lagrangian = float(sum(top.tolist())) + lam * B * horizon_sum(g, 0, depth)
        return _Evaluation(lam, V, top, knap, upper, lagrangian)

    def _joint(self, stacks: list[np.ndarray], ev: _Evaluation, depth: int, prices: tuple[tuple[float, float], ...],
               deadline: float | None) -> JointDecision:
        """The decision of one evaluation: its joint action (the knapsack's, ties as
        :mod:`.knapsack` breaks them), with the lower bound of that joint action."""
        _, actions = solve_padded(ev.values, self._units, self._capacity)
        candidates = [actions]
        if self.tie_break == "lower_bound" and self.tie_tolerance > 0.0:
            candidates += [a for a in near_optimal(ev.values, self._units, self._capacity, self.tie_tolerance,
                                                   TIE_CANDIDATES) if a != actions]
        best, lower, shares = self._lower_bounds(stacks, candidates, depth, deadline)
        actions = candidates[best]
        scale = self.problem.scale
        bounds: list[tuple[int, int] | None] = [None] * self.problem.K
        for stack, members in zip(stacks, self._groups, strict=True):
            k0 = members[0]
            if self.setups[k0].pruning:
                priced = self._priced(k0, ev.lam)
                lo, up = priced.bounds.actions(stack, priced.q_values_batch(stack, 0, checked=True))
                for i, k in enumerate(members):
                    bounds[k] = (int(lo[i]), int(up[i]))
        targets = tuple(TargetDecision(a, ev.values[k, :self.problem.models[k].A].copy(), float(ev.target_values[k]),
                                       lower[k], Fraction(int(shares[k]), scale), s.guaranteed, s.pruning, bounds[k])
                        for k, (a, s) in enumerate(zip(actions, self.setups, strict=True)))
        total = float(sum(lower))
        return JointDecision(actions, ev.lam, ev.upper, ev.lagrangian, total, ev.upper - total,
                             self.bound_guaranteed, self.problem.budget, self._effort(actions),
                             self._binds, depth, targets, tuple(prices))

    def _effort(self, actions: Sequence[int]) -> Fraction:
        """``sum_k e_k(a_k)``, exactly (integer units over the common denominator)."""
        return Fraction(int(self._units[np.arange(self.problem.K), np.asarray(actions)].sum()), self.problem.scale)

    def _independent(self, stacks: list[np.ndarray], depth: int, deadline: float | None) -> JointDecision:
        """A budget that cannot bind: K independent searches, price 0, gap 0 (module docstring)."""
        bs = self._split(stacks)
        results = [self._planners[k].search(b, depth, use_bounds=self.setups[k].pruning, deadline=deadline,
                                            checked=True) for k, b in enumerate(bs)]
        actions = tuple(r.action for r in results)
        total = float(sum(r.value for r in results))
        targets = tuple(TargetDecision(r.action, np.asarray(r.q_values, dtype=float), float(r.value), float(r.value),
                                       max(row), s.guaranteed, s.pruning, r.root_bounds)
                        for r, s, row in zip(results, self.setups, self.problem.efforts, strict=True))
        return JointDecision(actions, 0.0, total, total, total, 0.0, self.bound_guaranteed, self.problem.budget,
                             self.problem.effort_of(actions), False, depth, targets, ((0.0, total),))

    def _lower_bounds(self, stacks: list[np.ndarray], candidates: Sequence[tuple[int, ...]], depth: int,
                      deadline: float | None) -> tuple[int, list[float], np.ndarray]:
        """The value of the best fixed-share continuation after each candidate joint action (module
        docstring): per target, action and share level ``beta`` (an effort of the target), the root
        action followed by the target's own depth ``d - 1`` search on its model restricted to
        ``e_k <= beta`` (the children of every target of a group, for every action some candidate
        gives it, in one batch); the shares by a knapsack (``sum_k beta_k <= B``). Returns the index
        of the candidate with the greatest value (ties: the first), and its per-target values and
        shares (in units)."""
        p = self.problem
        chosen = np.asarray(candidates, dtype=np.intp).reshape(len(candidates), p.K)
        width = max(np.unique(u).size for u in p.units)
        items = np.full((len(candidates), p.K, width), -np.inf)
        levels = np.zeros((p.K, width), dtype=np.int64)
        for stack, members, idx in zip(stacks, self._groups, self._members, strict=True):
            model = p.models[members[0]]
            n = len(members)
            keys, pair = np.unique(np.arange(n)[None, :] * model.A + chosen[:, idx], return_inverse=True)
            rows, acts = keys // model.A, keys % model.A  # every (target, action) some candidate needs
            tau, eta = posteriors_all(model, stack)  # (n, A, Z, S), (n, A, Z)
            tau, eta = tau[rows, acts], eta[rows, acts]  # their branches
            possible = eta > ETA_MIN
            children, weights = tau[possible], eta[possible]  # in (pair, observation) order
            owner = np.repeat(np.arange(keys.size), possible.sum(axis=1))
            heads = model.rho(stack)[rows, acts]
            group_levels = np.unique(p.units[members[0]])
            values = np.empty((keys.size, group_levels.size))
            for j, level in enumerate(group_levels):
                setup, _ = self._restricted.get(members[0], int(level))
                cont = setup.planner.q_values_batch(children, depth - 1, setup.pruning, deadline=deadline,
                                                    checked=True).max(axis=1)
                values[:, j] = heads + model.gamma * np.bincount(owner, weights=weights * cont, minlength=keys.size)
            items[:, idx, :group_levels.size] = values[pair.reshape(len(candidates), n)]
            levels[idx, :group_levels.size] = group_levels
        target_rows = np.arange(p.K)
        best: tuple[float, int, list[float], np.ndarray] | None = None
        for i in range(len(candidates)):
            _, choice = solve_padded(items[i], levels, self._capacity, ties=False)  # any best shares
            lower = items[i, target_rows, choice].tolist()
            total = float(sum(lower))
            if best is None or total > best[0]:
                best = (total, i, lower, levels[target_rows, choice])
        assert best is not None
        return best[1], best[2], best[3]
