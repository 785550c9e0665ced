"""The planners of the peer comparison, each wrapped to record what the tables report.

Every peer is built by :func:`make_peer` from its name, the model, the budget per decision and
the plan; the table :data:`PEERS` says which are budgeted. Planners and policies come from the
core (the assumption gate ``core.gate.build_planner`` for B&B and exhaustive search, the
myopic bounds for the bound policies, ``core.reference`` for the optimal reference, the belief
MCTS of ``core.belief_mcts``) and from pomdp-py for POUCT (:mod:`.pouct`); this module only
times them and records depth, certification and simulations.

**Clock.** Every budget is measured on the CPU time of the deciding process
(``time.process_time``), injected into the planners (``Planner.clock``, ``BeliefMCTS.clock``,
the POUCT subclass of :mod:`.pouct`). On an idle core this equals wall-clock time; on a shared
machine a process waiting for a core is not charged, so a planner gets the same amount of
computation whatever else runs. ``process_time`` rather than ``thread_time``: it also counts any
helper thread (a multi-threaded BLAS call; the search itself avoids BLAS,
:mod:`~pomdp_planner.core.search`). Reading a CPU clock is a system call (2 us measured, against
0.14 us for ``perf_counter``), and the tree searches read their clock after every simulation
(6 us each for the belief MCTS on S = 3): the planners therefore get :data:`BUDGET_CLOCK`, the
process time re-read only when at least :data:`CLOCK_RESOLUTION` of wall time has passed since
the last reading (0.46 us per call measured). Its value is a true process-time reading at most
0.2 ms (of wall time, hence of CPU time) old, so a deadline is met to within 0.2 ms. Decision
times in the tables are exact ``process_time`` differences (:data:`DECISION_CLOCK`); each
decision's wall-clock time is recorded too.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...core.gate import PlannerSetup, build_planner
from ...core.gc_pause import paused_gc
from ...core.model import POMDP, model_digest
from ...core.policies import POLICIES, make_policy
from ...core.reference import ReferencePolicy, reference_policy
from ...core.search import complete_tree_nodes
from ..references import GridReferencePolicy
from .pouct import POUCTPolicy, POUCTSettings

#: The clock decision times are recorded on (module docstring).
DECISION_CLOCK: Callable[[], float] = time.process_time
#: Wall-clock seconds between two readings of the CPU clock in :data:`BUDGET_CLOCK`.
CLOCK_RESOLUTION = 2e-4


def coarse_cpu_clock(resolution: float = CLOCK_RESOLUTION) -> Callable[[], float]:
    """``time.process_time``, re-read only after ``resolution`` s of wall time (module docstring)."""
    perf, cpu = time.perf_counter, time.process_time
    state = [-math.inf, 0.0]  # wall time of the last reading, its process time

    def clock() -> float:
        w = perf()
        if w - state[0] >= resolution:
            state[0] = w
            state[1] = cpu()
        return state[1]

    return clock


#: The clock the planners' budgets run on (one per process; the harness is single-threaded).
BUDGET_CLOCK: Callable[[], float] = coarse_cpu_clock()
#: Budgeted planners: they get a time budget per decision.
BUDGETED = ("bnb", "exhaustive", "mcts", "pouct")
#: Planners without a budget; ``optimal`` only where the model has a reference.
UNBUDGETED = ("optimal", "greedy", "lower-bound", "upper-bound", "random")
#: How the report names a peer: the internal key ``optimal`` is the model's reference policy,
#: which is the optimum only where it is a certified grid solution (docs/RESULTS.md).
DISPLAY_NAMES = {"optimal": "reference"}


def display_name(planner: str) -> str:
    """The name a peer has in the report, the plots and the text (:data:`DISPLAY_NAMES`)."""
    return DISPLAY_NAMES.get(planner, planner)


#: What each peer is, for the report.
DESCRIPTIONS = {
    "bnb": "branch-and-bound (Algorithm 1, default `tight` bounds through the assumption gate), anytime iterative "
           "deepening under the budget; returns at once when the root bounds agree (a certified decision)",
    "exhaustive": "the same anytime search with the action filter off (gate with bounds disabled)",
    "mcts": "belief-space MCTS on exact Bayes beliefs with the true belief reward rho (`core/belief_mcts.py`, "
            "its default settings)",
    "pouct": "pomdp-py POUCT on the state reward, tuned (`bench/experiments/pouct.py`)",
    "optimal": "the reference policy of the model, which the models table names: grid policy iteration (its "
               "decisions certified optimal up to the grid's tie margin), or exhaustive search to a fixed depth at "
               "every decision, a finite lookahead of the same family as `bnb` and `exhaustive`, not the optimum",
    "greedy": "argmax_a rho(b, a) (depth-1 search)",
    "lower-bound": "the myopic lower-bound policy of Theorem 2 (no search)",
    "upper-bound": "the myopic upper-bound policy of Theorem 2 (no search)",
    "random": "uniformly random actions",
}


def mcts_available() -> bool:
    """Whether the belief MCTS is in the policy table (``core/policies.py``)."""
    return "mcts" in POLICIES


class TimedPolicy:
    """Wraps a decision function: per decision the CPU time, the wall time and, when the planner
    reports them, its depth, simulations and whether it was certified (an info value that is a
    function is a measurement, evaluated after the decision's clock has stopped)."""

    def __init__(self, name: str, decide: Callable[[np.ndarray], tuple[int, dict]], certifies: bool = False):
        self.name = name
        self._decide = decide
        self.certifies = certifies  # its decisions can be certified (B&B, the grid reference)
        self.cpu: list[float] = []
        self.wall: list[float] = []
        self.depths: list[int] = []
        self.sims: list[int] = []
        self.certified = 0

    def act(self, belief: np.ndarray) -> int:
        with paused_gc():  # a collection of the harness's own heap is no planner's cost (core/gc_pause.py)
            w0, c0 = time.perf_counter(), DECISION_CLOCK()
            action, info = self._decide(belief)
            self.cpu.append(DECISION_CLOCK() - c0)
            self.wall.append(time.perf_counter() - w0)
        info = {k: v() if callable(v) else v for k, v in info.items()}  # measurements, after the clock
        if "depth" in info:
            self.depths.append(int(info["depth"]))
        if "sims" in info:
            self.sims.append(int(info["sims"]))
        self.certified += int(bool(info.get("certified", False)))
        return int(action)


# ------------------------------------------------------------------ per-process caches
_CACHE: dict = {}


def _key(model: POMDP, *extra) -> tuple:
    """Cache key by model content (``core.model.model_digest``): each chunk brings its own copy of the model."""
    return (model_digest(model), *extra)


def gate_setup(model: POMDP, use_bounds: bool = True) -> PlannerSetup:
    """The assumption gate's planner for ``model`` (solved once per process and model), its
    deadlines on :data:`BUDGET_CLOCK`."""
    key = _key(model, "gate", use_bounds)
    if key not in _CACHE:
        setup = build_planner(model, use_bounds=use_bounds, variant="tight")
        if setup.planner is not None:
            setup.planner.clock = BUDGET_CLOCK
        _CACHE[key] = setup
    return _CACHE[key]


def grid_reference(model: POMDP, n: int) -> ReferencePolicy:
    """``core.reference.reference_policy(model, n)``, once per process and model."""
    key = _key(model, "grid", n)
    if key not in _CACHE:
        _CACHE[key] = reference_policy(model, n)
    return _CACHE[key]


# ------------------------------------------------------------------ the reference policy
@dataclass(frozen=True)
class ReferenceSpec:
    """How a model's reference policy acts.

    ``kind="grid"``: grid policy iteration (``core.reference.reference_policy`` at resolution
    ``param``, checked against ``2 param``); the action is the argmax of one exact Bellman
    backup of the fine grid's ``V`` at the belief, *certified* where its Q gap exceeds the
    measured tie margin. ``kind="search"``: exhaustive search to depth ``param`` at every
    decision (for S >= 8, where no grid is feasible): a finite lookahead, not the optimum.
    """

    kind: str
    param: int

    def __post_init__(self) -> None:
        if self.kind not in ("grid", "search"):
            raise ValueError(f"reference kind: expected 'grid' or 'search', got {self.kind!r}")

    def describe(self) -> str:
        if self.kind == "grid":
            return (f"grid policy iteration at resolution {self.param} (checked against {2 * self.param}; "
                    "one exact Bellman backup of the fine-grid V per decision)")
        return f"exhaustive search to depth {self.param} at every decision"


def _reference_decider(model: POMDP, spec: ReferenceSpec) -> Callable[[np.ndarray], tuple[int, dict]]:
    if spec.kind == "grid":
        pol = GridReferencePolicy(grid_reference(model, spec.param))

        def decide(b: np.ndarray) -> tuple[int, dict]:
            before = pol.certified
            a = pol.act(b)
            return a, {"certified": pol.certified > before}

        return decide
    planner = gate_setup(model, use_bounds=False).planner

    def search(b: np.ndarray) -> tuple[int, dict]:
        res = planner.search(b, spec.param, use_bounds=False)
        return res.action, {"depth": res.depth}

    return search


# ------------------------------------------------------------------ B&B and its probes
@dataclass(frozen=True)
class ProbeConfig:
    """B&B vs exhaustive search on the same beliefs (the "time to the same decision").

    In the first ``episodes`` episodes of every B&B cell, at the decisions ``steps``, the
    belief B&B just decided is searched again, untimed for the closed loop: (1) by exhaustive
    search at the depth B&B reached (fixed depth, skipped when the complete tree has more than
    ``max_nodes`` nodes), and (2) by the anytime exhaustive search at the same budget.
    """

    episodes: int = 20
    steps: tuple[int, ...] = (5, 25)
    max_nodes: int = 20_000_000


class SearchPeer(TimedPolicy):
    """``bnb`` / ``exhaustive``: ``Planner.plan`` under the budget (iterative deepening)."""

    def __init__(self, name: str, setup: PlannerSetup, budget: float, max_depth: int,
                 probes: ProbeConfig | None = None):
        self.planner = setup.planner
        self.use_bounds = name == "bnb" and setup.pruning
        self.budget, self.max_depth, self.probes = budget, max_depth, probes
        self.probe_records: list[dict] = []
        self._step = 0
        super().__init__(name, self._plan, certifies=self.use_bounds)

    def _plan(self, b: np.ndarray) -> tuple[int, dict]:
        res = self.planner.plan(b, self.max_depth, time_budget=self.budget, use_bounds=self.use_bounds)
        self._last = res
        return res.action, {"depth": res.depth, "certified": res.certified}

    def act(self, belief: np.ndarray) -> int:
        a = super().act(belief)
        if self.probes is not None and self._step in self.probes.steps:
            self.probe_records.append(self._probe(np.asarray(belief, dtype=float), self._last))
        self._step += 1
        return a

    def _probe(self, b: np.ndarray, res) -> dict:
        m = self.planner.model
        rec = {"step": self._step, "certified": bool(res.certified), "depth": int(res.depth),
               "bnb_time": float(self.cpu[-1]), "bnb_action": int(res.action), "fixed_time": None,
               "fixed_action": None}
        if complete_tree_nodes(m.A, m.Z, res.depth) <= self.probes.max_nodes:
            c0 = DECISION_CLOCK()
            fixed = self.planner.search(b, res.depth, use_bounds=False)
            rec.update(fixed_time=float(DECISION_CLOCK() - c0), fixed_action=int(fixed.action))
        c0 = DECISION_CLOCK()
        anytime = self.planner.plan(b, self.max_depth, time_budget=self.budget, use_bounds=False)
        rec.update(anytime_time=float(DECISION_CLOCK() - c0), anytime_action=int(anytime.action),
                   anytime_depth=int(anytime.depth))
        return rec


# ------------------------------------------------------------------ construction
def make_peer(name: str, model: POMDP, budget: float | None, *, max_depth: int, seed: int,
              reference: ReferenceSpec | None = None, pouct: POUCTSettings | None = None,
              probes: ProbeConfig | None = None) -> TimedPolicy:
    """A fresh peer for one episode (its randomness seeded by ``seed`` alone)."""
    if name in BUDGETED and budget is None:
        raise ValueError(f"planner {name}: needs a time budget")
    if name == "greedy":
        return TimedPolicy(name, lambda b: (int(np.argmax(model.rho(b))), {}))
    if name in ("lower-bound", "upper-bound"):
        setup = gate_setup(model)
        if setup.myopic is None or not setup.guaranteed:
            raise ValueError(f"planner {name} on {model.name}: no valid bounds: {setup.reason}")
        fn = setup.myopic.lower if name == "lower-bound" else setup.myopic.upper
        return TimedPolicy(name, lambda b: (int(fn(np.asarray(b)[None, :])[0]), {}))
    if name == "random":
        rng = np.random.default_rng([seed, 17])
        return TimedPolicy(name, lambda b: (int(rng.integers(model.A)), {}))
    if name == "optimal":
        if reference is None:
            raise ValueError(f"planner optimal on {model.name}: the model has no reference")
        return TimedPolicy(name, _reference_decider(model, reference), certifies=reference.kind == "grid")
    if name in ("bnb", "exhaustive"):
        setup = gate_setup(model, use_bounds=name == "bnb")
        return SearchPeer(name, setup, budget, max_depth, probes if name == "bnb" else None)
    if name == "mcts":
        pol = make_policy("mcts", model, time_budget=budget, seed=seed)  # its default settings
        pol.planner.clock = BUDGET_CLOCK

        def mcts(b: np.ndarray) -> tuple[int, dict]:
            a = pol.act(b)
            return a, {"depth": pol.last.depth, "sims": pol.last.simulations}

        return TimedPolicy(name, mcts)
    if name == "pouct":
        pol = POUCTPolicy(model, budget, pouct or POUCTSettings(), seed=seed, clock=BUDGET_CLOCK)

        def plan_pouct(b: np.ndarray) -> tuple[int, dict]:
            a = pol.act(b)
            return a, {"depth": pol.last_depth, "sims": pol.last_sims}  # the depth is counted untimed

        return TimedPolicy(name, plan_pouct)
    raise ValueError(f"planner: unknown peer {name!r}")
