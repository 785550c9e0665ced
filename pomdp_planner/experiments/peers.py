"""Closed-loop comparison of planners at equal time budgets (issue 6, "against peers").

Every planner acts on the exact Bayes-filter belief of :func:`pomdp_planner.core.simulate.simulate`
and every episode is scored with the TRUE belief reward: the discounted return
``sum_t gamma^t rho(b_t, a_t)`` (Eq. 3), ``gamma`` the model's. Episodes are seeded
(episode ``k`` uses seed ``base + k`` for the world, the same for every planner: common
random numbers for the initial state and, as long as the actions agree, the trajectory).

Planners
--------
* ``bnb``: Algorithm 1 with the myopic bounds (``Planner.plan``, anytime iterative deepening
  under the budget; returns at once when the root bounds agree, a certified decision).
* ``exhaustive``: the same planner with the action filter off (``use_bounds=False``).
* ``greedy``: ``argmax_a rho(b, a)`` (depth-1 search; no budget).
* ``lower-bound``: the myopic lower-bound policy alone (no search).
* ``random``: uniform random actions.
* ``pouct``: pomdp-py's POUCT (optional ``bench`` extra). It plans with sampled states and
  STATE rewards only, so it is given ``r(s, a)``: it cannot see the uncertainty term
  ``-w_a f(b)`` of ``rho``. It gets the exact belief as a histogram at every step, a fresh
  tree per decision, random rollouts, ``max_depth`` 20 and the model's discount.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.stats import t as student_t

from ..core.model import POMDP
from ..core.simulate import simulate


def mean_ci(x: np.ndarray) -> tuple[float, tuple[float, float]]:
    """Mean and 95 % Student-t confidence interval."""
    x = np.asarray(x, dtype=float)
    m = float(np.mean(x))
    if x.size < 2:
        return m, (m, m)
    half = float(student_t.ppf(0.975, x.size - 1)) * float(np.std(x, ddof=1)) / math.sqrt(x.size)
    return m, (m - half, m + half)


class _Timed:
    """Wraps a policy: records per-decision wall time and (when available) search depth."""

    def __init__(self, name: str):
        self.name = name
        self.times: list[float] = []
        self.depths: list[int] = []
        self.certified = 0

    def act(self, belief: np.ndarray) -> int:
        t0 = time.perf_counter()
        a = self._act(belief)
        self.times.append(time.perf_counter() - t0)
        return int(a)

    def _act(self, belief: np.ndarray) -> int:  # pragma: no cover - abstract
        raise NotImplementedError


class SearchPolicy(_Timed):
    def __init__(self, name: str, planner, budget: float, max_depth: int, use_bounds: bool):
        super().__init__(name)
        self.planner, self.budget, self.max_depth, self.use_bounds = planner, budget, max_depth, use_bounds

    def _act(self, belief: np.ndarray) -> int:
        res = self.planner.plan(belief, self.max_depth, time_budget=self.budget, use_bounds=self.use_bounds)
        self.depths.append(res.depth)
        self.certified += int(res.certified)
        return res.action


class FunctionPolicy(_Timed):
    def __init__(self, name: str, fn):
        super().__init__(name)
        self.fn = fn

    def _act(self, belief: np.ndarray) -> int:
        return self.fn(belief)


class POUCTPolicy(_Timed):
    """pomdp-py POUCT on the model's STATE reward (it cannot plan with ``rho``)."""

    def __init__(self, model: POMDP, budget: float, max_depth: int = 20, seed: int = 0):
        super().__init__("pouct")
        import pomdp_py  # optional extra 'bench'

        self.pomdp_py = pomdp_py
        self.model, self.budget, self.max_depth = model, budget, max_depth
        self.rng = random.Random(seed)
        self.agent = _pomdp_py_agent(pomdp_py, model, self.rng)

    def _act(self, belief: np.ndarray) -> int:
        pp = self.pomdp_py
        hist = pp.Histogram({self._states[i]: float(p) for i, p in enumerate(belief) if p > 0})
        self.agent.set_belief(hist, prior=True)
        self.agent.tree = None  # fresh tree each decision
        planner = pp.POUCT(max_depth=self.max_depth, planning_time=self.budget, discount_factor=self.model.gamma,
                           rollout_policy=self.agent.policy_model, show_progress=False)
        random.seed(self.rng.random())  # pomdp-py samples with the global `random`
        action = planner.plan(self.agent)
        self.depths.append(self.max_depth)
        return int(action.index)

    @property
    def _states(self):
        return self.agent._pp_states


def _pomdp_py_agent(pp, model: POMDP, rng: random.Random):
    """Build a pomdp-py Agent for ``model`` (state reward only)."""
    S, A, Z = model.S, model.A, model.Z
    P, O, r = np.asarray(model.P), np.asarray(model.O), np.asarray(model.r)
    cP, cO = np.cumsum(P, axis=-1), np.cumsum(O, axis=-1)

    class _Indexed:
        """Equality and hashing by index, shared by the state, action and observation classes."""

        def __init__(self, i):
            self.index = i

        def __hash__(self):
            return self.index

        def __eq__(self, other):
            return type(other) is type(self) and other.index == self.index

    class St(_Indexed, pp.State):
        pass

    class Ac(_Indexed, pp.Action):
        pass

    class Ob(_Indexed, pp.Observation):
        pass

    states = [St(i) for i in range(S)]
    actions = [Ac(a) for a in range(A)]
    observations = [Ob(z) for z in range(Z)]

    def draw(c):
        return min(int(np.searchsorted(c, random.random() * c[-1], side="right")), c.size - 1)

    class T(pp.TransitionModel):
        def probability(self, ns, s, a):
            return float(P[a.index, s.index, ns.index])

        def sample(self, s, a):
            return states[draw(cP[a.index, s.index])]

        def get_all_states(self):
            return states

    class Om(pp.ObservationModel):
        def probability(self, o, ns, a):
            return float(O[a.index, ns.index, o.index])

        def sample(self, ns, a):
            return observations[draw(cO[a.index, ns.index])]

        def get_all_observations(self):
            return observations

    class R(pp.RewardModel):
        def sample(self, s, a, ns):
            return float(r[s.index, a.index])

    class Pol(pp.RolloutPolicy):
        def sample(self, s):
            return actions[random.randrange(A)]

        def rollout(self, s, history=None):
            return actions[random.randrange(A)]

        def get_all_actions(self, state=None, history=None):
            return actions

    init = pp.Histogram({s: 1.0 / S for s in states})
    agent = pp.Agent(init, Pol(), T(), Om(), R())
    agent._pp_states = states
    return agent


def pouct_available() -> bool:
    try:
        import pomdp_py  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass
class PeerResult:
    model: str
    planner: str
    budget: float | None
    episodes: int
    steps: int
    mean: float
    ci: tuple[float, float]
    mean_state_return: float
    mean_depth: float | None
    mean_time: float
    max_time: float
    certified_fraction: float | None
    returns: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("returns")
        return d


def run_planner(model: POMDP, make_policy, episodes: int, steps: int, seed: int, model_label: str,
                planner_label: str, budget: float | None, progress=None) -> PeerResult:
    """``episodes`` closed-loop runs of a fresh policy from ``make_policy(episode)``."""
    returns, state_returns, times, depths, certified = [], [], [], [], 0
    for k in range(episodes):
        pol = make_policy(k)
        tr = simulate(model, pol, steps, seed=seed + k)
        returns.append(tr.discounted_return)
        state_returns.append(tr.discounted_state_return)
        times.extend(pol.times)
        depths.extend(getattr(pol, "depths", []))
        certified += getattr(pol, "certified", 0)
        if progress is not None:
            progress.advance(note=f"{model_label} {planner_label} {'' if budget is None else budget}")
    m, ci = mean_ci(np.array(returns))
    n_dec = max(len(times), 1)
    is_search = planner_label in ("bnb", "exhaustive")
    return PeerResult(model=model_label, planner=planner_label, budget=budget, episodes=episodes, steps=steps,
                      mean=m, ci=ci, mean_state_return=float(np.mean(state_returns)),
                      mean_depth=float(np.mean(depths)) if depths and planner_label != "pouct" else None,
                      mean_time=float(np.mean(times)), max_time=float(np.max(times)),
                      certified_fraction=certified / n_dec if is_search and planner_label == "bnb" else None,
                      returns=[float(x) for x in returns])


@dataclass
class PeerPlan:
    """What to run: budgets, and episodes per budget (fewer at big budgets; stated in the report)."""

    budgets: tuple[float, ...] = (0.05, 0.2, 1.0)
    episodes_cheap: int = 100
    episodes_by_budget: dict = field(default_factory=lambda: {0.05: 40, 0.2: 10, 1.0: 3})
    steps: int = 50
    max_depth: int = 12
    seed: int = 1000
    with_pouct: bool = True

    def total_units(self, n_models: int) -> int:
        n_budgeted = 3 if self.with_pouct else 2
        per = 3 * self.episodes_cheap + n_budgeted * sum(self.episodes_by_budget[b] for b in self.budgets)
        return n_models * per


def _cheap_factories(model: POMDP, planner, seed: int) -> list:
    rho, lower = model.rho, planner.bounds.lower
    rng_random = np.random.default_rng(seed)

    def greedy(k: int) -> FunctionPolicy:
        return FunctionPolicy("greedy", lambda b: int(np.argmax(rho(b))))

    def lower_bound(k: int) -> FunctionPolicy:
        return FunctionPolicy("lower-bound", lambda b: int(lower(b[None, :])[0]))

    def uniform(k: int) -> FunctionPolicy:
        return FunctionPolicy("random", lambda b: int(rng_random.integers(model.A)))

    return [("greedy", greedy), ("lower-bound", lower_bound), ("random", uniform)]


def _search_factory(name: str, planner, budget: float, max_depth: int, use_bounds: bool):
    return lambda k: SearchPolicy(name, planner, budget, max_depth, use_bounds)


def _pouct_factory(model: POMDP, budget: float, seed: int):
    return lambda k: POUCTPolicy(model, budget, seed=seed + 7919 * k)


def compare_peers(models: dict[str, tuple[POMDP, object]], plan: PeerPlan, progress=None) -> list[PeerResult]:
    """Run every planner on every model. ``models[label] = (model, planner_with_bounds)``."""
    results = []
    for label, (model, planner) in models.items():
        for name, factory in _cheap_factories(model, planner, plan.seed):
            results.append(run_planner(model, factory, plan.episodes_cheap, plan.steps, plan.seed, label, name,
                                       None, progress))
        for budget in plan.budgets:
            n_ep = plan.episodes_by_budget[budget]
            for name, use_bounds in (("bnb", True), ("exhaustive", False)):
                factory = _search_factory(name, planner, budget, plan.max_depth, use_bounds)
                results.append(run_planner(model, factory, n_ep, plan.steps, plan.seed, label, name, budget, progress))
            if plan.with_pouct:
                factory = _pouct_factory(model, budget, plan.seed)
                results.append(run_planner(model, factory, n_ep, plan.steps, plan.seed, label, "pouct", budget,
                                           progress))
    return results
