"""Closed-loop comparison of planners at equal time budgets (issue 6, "against peers").

Every planner acts on the exact Bayes-filter belief of :func:`pomdp_planner.core.simulate.simulate`
and every episode is scored with the TRUE belief reward: the discounted return
``sum_t gamma^t rho(b_t, a_t)`` (Eq. 3), ``gamma`` the model's. Episodes are seeded
(episode ``k`` uses seed ``base + k`` for the world, the same for every planner: common
random numbers for the initial state and, as long as the actions agree, the trajectory).

Planners
--------
* ``bnb``: Algorithm 1 with the myopic bounds (``Planner.plan``, anytime iterative deepening
  under the budget; returns at once when the root bounds agree, a certified decision). The
  planner comes from the assumption gate (``core.gate.build_planner``): on a model whose bounds
  are not valid it would be exhaustive search; the shipped models pass.
* ``exhaustive``: the same planner with the action filter off (``use_bounds=False``).
* ``greedy``: ``argmax_a rho(b, a)`` (depth-1 search; no budget).
* ``lower-bound``: the myopic lower-bound policy alone (no search).
* ``random``: uniform random actions.
* ``pouct``: pomdp-py's POUCT (optional ``bench`` extra). It plans with sampled states and
  STATE rewards only, so it is given ``r(s, a)``: it cannot see the uncertainty term
  ``-w_a f(b)`` of ``rho``. It gets the exact belief as a histogram at every step, a fresh
  tree per decision, random rollouts, ``max_depth`` 20 and the model's discount. Its "depth" is
  the deepest level its sampled tree reached (:func:`tree_depth`), with the simulations per decision.
"""

from __future__ import annotations

import math
import multiprocessing
import pickle
import random
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.stats import t as student_t

from ...core.gate import PlannerSetup, build_planner
from ...core.model import POMDP
from ...core.simulate import simulate


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
        self.sims: list[int] = []

    def _act(self, belief: np.ndarray) -> int:
        pp = self.pomdp_py
        hist = pp.Histogram({self._states[i]: float(p) for i, p in enumerate(belief) if p > 0})
        self.agent.set_belief(hist, prior=True)
        self.agent.tree = None  # fresh tree each decision
        planner = pp.POUCT(max_depth=self.max_depth, planning_time=self.budget, discount_factor=self.model.gamma,
                           rollout_policy=self.agent.policy_model, show_progress=False)
        random.seed(self.rng.random())  # pomdp-py samples with the global `random`
        action = planner.plan(self.agent)
        self._planner = planner
        return int(action.index)

    def act(self, belief: np.ndarray) -> int:
        a = super().act(belief)  # timed: the planning only
        self.depths.append(tree_depth(self.agent.tree))
        self.sims.append(int(self._planner.last_num_sims))
        return a

    @property
    def _states(self):
        return self.agent._pp_states


def tree_depth(root) -> int:
    """Depth of a pomdp-py search tree in action-observation levels (root 0): the deepest
    belief node the sampled tree reached (not a complete tree of that depth)."""
    best, stack = 0, [(root, 0)]
    while stack:
        v, d = stack.pop()
        best = max(best, d)
        stack.extend((child, d + 1) for q in v.children.values() for child in q.children.values())
    return best


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
    try:  # the optional extra 'bench'
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
    mean_sims: float | None = None  # POUCT: simulations per decision
    returns: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("returns")
        return d


@dataclass(frozen=True)
class PeerChunk:
    """Episodes ``start .. stop - 1`` of one (model, planner, budget) cell: the unit of work,
    of parallelism (``jobs``) and of the resumable cache (``cache_dir``)."""

    model: str
    planner: str
    budget: float | None
    start: int
    stop: int

    @property
    def filename(self) -> str:
        b = "none" if self.budget is None else f"{self.budget:g}"
        return f"{self.model}__{self.planner}__{b}__{self.start:04d}-{self.stop:04d}.pickle"


@dataclass
class PeerPlan:
    """What to run: budgets and episodes per budget (stated in the report)."""

    budgets: tuple[float, ...] = (0.05, 0.2, 1.0)
    episodes_cheap: int = 100
    episodes_by_budget: dict = field(default_factory=lambda: {0.05: 100, 0.2: 100, 1.0: 100})
    steps: int = 50
    max_depth: int = 12
    seed: int = 1000
    with_pouct: bool = True
    chunk: int = 10  # episodes per unit of work / cache file
    jobs: int = 1  # worker processes

    def cells(self, models: Sequence[str]) -> list[tuple[str, str, float | None, int]]:
        """``(model, planner, budget, episodes)``, cheapest first (so a cut-short run has whole cells)."""
        out = [(m, p, None, self.episodes_cheap) for m in models for p in CHEAP_PLANNERS]
        budgeted = ("bnb", "exhaustive") + (("pouct",) if self.with_pouct else ())
        for b in sorted(self.budgets):
            out += [(m, p, b, self.episodes_by_budget[b]) for m in models for p in budgeted]
        return out

    def chunks(self, models: Sequence[str]) -> list[PeerChunk]:
        return [PeerChunk(m, p, b, k, min(k + self.chunk, n)) for m, p, b, n in self.cells(models)
                for k in range(0, n, self.chunk)]

    def signature(self) -> dict:
        """What a cached chunk must match to be reused."""
        return {"steps": self.steps, "max_depth": self.max_depth, "seed": self.seed}

    def total_units(self, n_models: int) -> int:
        return sum(n for *_, n in self.cells([str(i) for i in range(n_models)]))


CHEAP_PLANNERS = ("greedy", "lower-bound", "random")

_PLANNERS: dict = {}  # per process: (label, pickled model) -> PlannerSetup; the LP is solved once per model


def _planner_for(label: str, model: POMDP) -> PlannerSetup:
    """The assumption gate's planner for ``model`` (``bnb`` prunes only with valid bounds, else it
    is exhaustive search and the gate's reason is in the setup). Each chunk brings its own
    unpickled copy of the model, so the cache is keyed by the model's content (its pickle)."""
    key = (label, pickle.dumps(model))
    if key not in _PLANNERS:
        _PLANNERS[key] = build_planner(model, variant="tight")
    return _PLANNERS[key]


def _policy(chunk: PeerChunk, model: POMDP, plan: PeerPlan, k: int) -> _Timed:
    """A fresh policy for episode ``k`` of ``chunk`` (its randomness seeded by ``k`` alone)."""
    name, budget = chunk.planner, chunk.budget
    if name == "greedy":
        return FunctionPolicy(name, lambda b: int(np.argmax(model.rho(b))))
    if name == "lower-bound":
        setup = _planner_for(chunk.model, model)
        if setup.myopic is None or not setup.guaranteed:
            raise ValueError(f"peer lower-bound on {chunk.model}: no valid bounds: {setup.reason}")
        lower = setup.myopic.lower
        return FunctionPolicy(name, lambda b: int(lower(b[None, :])[0]))
    if name == "random":
        rng = np.random.default_rng([plan.seed, k])
        return FunctionPolicy(name, lambda b: int(rng.integers(model.A)))
    if name in ("bnb", "exhaustive"):
        setup = _planner_for(chunk.model, model)
        return SearchPolicy(name, setup.planner, budget, plan.max_depth, name == "bnb" and setup.pruning)
    if name == "pouct":
        return POUCTPolicy(model, budget, seed=plan.seed + 7919 * k)
    raise ValueError(f"planner: unknown peer {name!r}")


def run_chunk(chunk: PeerChunk, model: POMDP, plan: PeerPlan) -> list[dict]:
    """Run the episodes of ``chunk``; one record per episode (episode ``k`` uses world seed ``seed + k``)."""
    records = []
    for k in range(chunk.start, chunk.stop):
        pol = _policy(chunk, model, plan, k)
        tr = simulate(model, pol, plan.steps, seed=plan.seed + k)
        records.append({"episode": k, "return": float(tr.discounted_return),
                        "state_return": float(tr.discounted_state_return), "times": list(pol.times),
                        "depths": list(getattr(pol, "depths", [])), "certified": int(getattr(pol, "certified", 0)),
                        "sims": list(getattr(pol, "sims", []))})
    return records


def aggregate(model_label: str, planner_label: str, budget: float | None, steps: int,
              records: Sequence[dict]) -> PeerResult:
    """One table row from the episode records of a cell."""
    records = sorted(records, key=lambda r: r["episode"])
    returns = np.array([r["return"] for r in records])
    times = [t for r in records for t in r["times"]]
    depths = [d for r in records for d in r["depths"]]
    certified = sum(r["certified"] for r in records)
    sims = [x for r in records for x in r.get("sims", [])]
    m, ci = mean_ci(returns)
    return PeerResult(model=model_label, planner=planner_label, budget=budget, episodes=len(records), steps=steps,
                      mean=m, ci=ci, mean_state_return=float(np.mean([r["state_return"] for r in records])),
                      mean_depth=float(np.mean(depths)) if depths else None,
                      mean_time=float(np.mean(times)), max_time=float(np.max(times)),
                      certified_fraction=certified / max(len(times), 1) if planner_label == "bnb" else None,
                      mean_sims=float(np.mean(sims)) if sims else None, returns=[float(x) for x in returns])


def _load_chunk(path: Path, plan: PeerPlan) -> list[dict] | None:
    if not path.is_file():
        return None
    with open(path, "rb") as fh:
        entry = pickle.load(fh)  # our own file, written by _save_chunk
    return entry["records"] if entry.get("signature") == plan.signature() else None


def _save_chunk(path: Path, plan: PeerPlan, records: list[dict]) -> None:
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump({"signature": plan.signature(), "records": records,
                     "finished": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}, fh)
    tmp.replace(path)  # atomic: a run killed mid-write leaves no half file


def compare_peers(models: dict[str, POMDP], plan: PeerPlan, progress=None,
                  cache_dir: Path | None = None) -> list[PeerResult]:
    """Run every planner on every model (``models[label] = model``), ``plan.jobs`` processes.

    With ``cache_dir`` every finished chunk of episodes is saved there and chunks already
    there (same :meth:`PeerPlan.signature`) are reused, so a long run killed half-way resumes.
    """
    chunks = plan.chunks(list(models))
    done: dict[PeerChunk, list[dict]] = {}
    if cache_dir is not None:
        cache_dir.mkdir(parents=True, exist_ok=True)
        for c in chunks:
            rec = _load_chunk(cache_dir / c.filename, plan)
            if rec is not None:
                done[c] = rec
                if progress is not None:
                    progress.advance(c.stop - c.start, note="cached")
    todo = [c for c in chunks if c not in done]

    def finish(c: PeerChunk, rec: list[dict]) -> None:
        done[c] = rec
        if cache_dir is not None:
            _save_chunk(cache_dir / c.filename, plan, rec)
        if progress is not None:
            progress.advance(c.stop - c.start, note=f"{c.model} {c.planner} {'' if c.budget is None else c.budget}")

    if plan.jobs <= 1:
        for c in todo:
            finish(c, run_chunk(c, models[c.model], plan))
    else:
        ctx = multiprocessing.get_context("spawn")  # no forked BLAS/ROS state in the workers
        with ProcessPoolExecutor(max_workers=plan.jobs, mp_context=ctx) as pool:
            futures = {pool.submit(run_chunk, c, models[c.model], plan): c for c in todo}
            for f in as_completed(futures):
                finish(futures[f], f.result())
    results = []
    for m, p, b, _ in plan.cells(list(models)):
        rec = [r for c in chunks if (c.model, c.planner, c.budget) == (m, p, b) for r in done[c]]
        results.append(aggregate(m, p, b, plan.steps, rec))
    return results
