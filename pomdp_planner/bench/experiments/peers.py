"""Closed-loop comparison of planners at equal time budgets (issues 6 and 12, "against peers").

Every planner acts on the exact Bayes-filter belief of :func:`pomdp_planner.core.simulate.simulate`
and every episode is scored with the TRUE belief reward: the discounted return
``sum_t gamma^t rho(b_t, a_t)`` (Eq. 3) over ``steps`` decisions, ``gamma`` the model's.

**Common random numbers.** Episode ``k`` of a model uses world seed ``seed + k`` for every
planner: the same initial state, and (``simulate`` draws transitions and observations from one
stream, inverse-CDF) the same trajectory for as long as the actions agree. Every cell of a model
runs episodes ``0 .. n - 1``, so any two cells are paired episode by episode.

**Regret** of a cell: the mean over its episodes of ``G_ref(k) - G(k)``, the return of the
model's optimal reference (the ``optimal`` peer, :class:`~.peer_policies.ReferenceSpec`) minus
the cell's, with the 95 % Student-t CI of that paired difference. The reference runs as many
episodes as the largest cell of its model.

The peers, the clock and the probes of B&B against exhaustive search are in
:mod:`.peer_policies`; POUCT's tuning in :mod:`.pouct`; the sanity check every peer passes
before its numbers are reported in :mod:`.sanity`.

**Work and cache.** A cell ``(model, planner, budget)`` is split into chunks of ``chunk``
episodes, the unit of parallel work (``jobs`` processes) and of the resumable cache: every
finished chunk is saved with its :meth:`PeerPlan.signature` (a JSON file, :mod:`.datafile`:
data only, never code), and a later run reuses a chunk only when the file is valid and the
signature matches; any other file is ignored with one line on stderr and the chunk recomputed.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ...core.model import POMDP
from ...core.simulate import simulate
from ..stats import mean_ci
from .datafile import CacheError, read_entry, register, write_entry
from .peer_policies import BUDGETED, UNBUDGETED, ProbeConfig, ReferenceSpec, SearchPeer, make_peer
from .pouct import TUNED, POUCTSettings, pouct_available, tree_depth

__all__ = ["PeerChunk", "PeerPlan", "PeerResult", "aggregate", "compare_peers", "mean_ci", "pouct_available",
           "run_chunk", "tree_depth"]


@register
@dataclass
class PeerResult:
    """One row of the comparison: a (model, planner, budget) cell.

    Decision times are CPU seconds of the deciding process (the budget clock) with the wall
    time beside them; ``mean_depth`` is the mean depth per decision (search: deepest completed
    depth; MCTS, POUCT: deepest tree level reached), ``max_depth`` the largest. ``regret`` is
    filled in by :func:`compare_peers` where the model has a reference.
    """

    model: str
    planner: str
    budget: float | None
    episodes: int
    steps: int
    mean: float
    ci: tuple[float, float]
    mean_state_return: float
    time_median: float
    time_p99: float
    wall_median: float
    wall_p99: float
    mean_depth: float | None
    max_depth: int | None
    certified_fraction: float | None
    mean_sims: float | None = None
    cpu_seconds: float = 0.0  # the cell's whole cost: episodes, simulator and probes (CPU / wall)
    wall_seconds: float = 0.0
    regret: float | None = None
    regret_ci: tuple[float, float] | None = None
    probes: list[dict] = field(default_factory=list)
    returns: list[float] = field(default_factory=list)
    state_returns: list[float] = field(default_factory=list)

    @property
    def mean_time(self) -> float:  # kept for older readers of the cache
        return self.time_median

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("returns", "state_returns", "probes"):
            d.pop(k)
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
        return f"{self.model}__{self.planner}__{b}__{self.start:04d}-{self.stop:04d}.json"


@dataclass
class PeerPlan:
    """What to run (every figure of it is printed in the report).

    ``planners``: the peers (budgeted ones at every budget of ``budgets``). Episodes: budgeted
    cells ``episodes_by_budget[budget]`` unless ``model_episodes[model][budget]`` says otherwise;
    unbudgeted cells ``episodes_cheap``; the reference the largest of its model's cells.
    ``steps``: decisions per episode (``model_steps[model]`` overrides). ``references``: the
    models' optimal references (absent: no ``optimal`` row and no regret).
    """

    budgets: tuple[float, ...] = (0.01, 0.05, 0.2, 1.0)
    planners: tuple[str, ...] = BUDGETED + UNBUDGETED
    episodes_cheap: int = 100
    episodes_by_budget: dict = field(default_factory=lambda: {0.01: 100, 0.05: 100, 0.2: 100, 1.0: 100})
    model_episodes: dict = field(default_factory=dict)
    steps: int = 50
    model_steps: dict = field(default_factory=dict)
    max_depth: int = 12
    seed: int = 1000
    references: dict = field(default_factory=dict)
    pouct: POUCTSettings = TUNED
    probes: ProbeConfig = field(default_factory=ProbeConfig)
    chunk: int = 10  # episodes per unit of work / cache file
    jobs: int = 1  # worker processes

    def steps_for(self, model: str) -> int:
        return int(self.model_steps.get(model, self.steps))

    def reference_for(self, model: str) -> ReferenceSpec | None:
        spec = self.references.get(model)
        return None if spec is None else spec if isinstance(spec, ReferenceSpec) else ReferenceSpec(*spec)

    def episodes_for(self, model: str, planner: str, budget: float | None) -> int:
        if planner == "optimal":
            return max(self.episodes_cheap, *(self.episodes_for(model, "bnb", b) for b in self.budgets))
        if budget is None:
            return self.episodes_cheap
        return int(self.model_episodes.get(model, {}).get(budget, self.episodes_by_budget[budget]))

    def cells(self, models: Sequence[str]) -> list[tuple[str, str, float | None, int]]:
        """``(model, planner, budget, episodes)``, cheapest first (so a cut-short run has whole cells)."""
        out = []
        for m in models:
            for p in self.planners:
                if p in UNBUDGETED and (p != "optimal" or self.reference_for(m) is not None):
                    out.append((m, p, None, self.episodes_for(m, p, None)))
        for b in sorted(self.budgets):
            out += [(m, p, b, self.episodes_for(m, p, b)) for m in models for p in self.planners if p in BUDGETED]
        return [c for c in out if c[3] > 0]

    def chunks(self, models: Sequence[str]) -> list[PeerChunk]:
        return [PeerChunk(m, p, b, k, min(k + self.chunk, n)) for m, p, b, n in self.cells(models)
                for k in range(0, n, self.chunk)]

    def signature(self, chunk: PeerChunk | None = None) -> dict:
        """What a cached chunk must match to be reused (what its episodes depend on)."""
        sig = {"steps": self.steps, "max_depth": self.max_depth, "seed": self.seed, "clock": "process_time"}
        if chunk is not None:
            sig["steps"] = self.steps_for(chunk.model)
            if chunk.planner == "pouct":
                sig["pouct"] = self.pouct.to_dict()
            if chunk.planner == "bnb":
                sig["probes"] = asdict(self.probes)
            if chunk.planner == "optimal":
                sig["reference"] = asdict(self.reference_for(chunk.model))
        return sig

    def total_units(self, models: Sequence[str]) -> int:
        return sum(n for *_, n in self.cells(list(models)))


def run_chunk(chunk: PeerChunk, model: POMDP, plan: PeerPlan) -> list[dict]:
    """Run the episodes of ``chunk``; one record per episode (episode ``k`` uses world seed ``seed + k``)."""
    records = []
    steps = plan.steps_for(chunk.model)
    for k in range(chunk.start, chunk.stop):
        c0, w0 = time.process_time(), time.perf_counter()
        probes = plan.probes if k < plan.probes.episodes else None
        pol = make_peer(chunk.planner, model, chunk.budget, max_depth=plan.max_depth, seed=plan.seed + 7919 * k,
                        reference=plan.reference_for(chunk.model), pouct=plan.pouct, probes=probes)
        tr = simulate(model, pol, steps, seed=plan.seed + k)
        records.append({"episode": k, "return": float(tr.discounted_return),
                        "state_return": float(tr.discounted_state_return), "cpu": list(pol.cpu),
                        "wall": list(pol.wall), "depths": list(pol.depths), "certified": int(pol.certified),
                        "sims": list(pol.sims), "certifies": bool(pol.certifies),
                        "probes": list(pol.probe_records) if isinstance(pol, SearchPeer) else [],
                        "episode_cpu": time.process_time() - c0, "episode_wall": time.perf_counter() - w0})
    return records


def aggregate(model_label: str, planner_label: str, budget: float | None, steps: int,
              records: Sequence[dict]) -> PeerResult:
    """One table row from the episode records of a cell."""
    records = sorted(records, key=lambda r: r["episode"])
    returns = np.array([r["return"] for r in records])
    cpu = np.array([t for r in records for t in r.get("cpu", r.get("times", []))])
    wall = np.array([t for r in records for t in r.get("wall", r.get("times", []))])
    depths = [d for r in records for d in r["depths"]]
    sims = [x for r in records for x in r.get("sims", [])]
    certified = sum(r["certified"] for r in records)
    m, ci = mean_ci(returns)
    certifies = any(r.get("certifies", planner_label == "bnb") for r in records)
    return PeerResult(
        model=model_label, planner=planner_label, budget=budget, episodes=len(records), steps=steps, mean=m, ci=ci,
        mean_state_return=float(np.mean([r["state_return"] for r in records])),
        time_median=float(np.median(cpu)), time_p99=float(np.percentile(cpu, 99)),
        wall_median=float(np.median(wall)), wall_p99=float(np.percentile(wall, 99)),
        mean_depth=float(np.mean(depths)) if depths else None, max_depth=int(max(depths)) if depths else None,
        certified_fraction=certified / max(cpu.size, 1) if certifies else None,
        mean_sims=float(np.mean(sims)) if sims else None,
        cpu_seconds=float(sum(r.get("episode_cpu", 0.0) for r in records)),
        wall_seconds=float(sum(r.get("episode_wall", 0.0) for r in records)),
        probes=[p for r in records for p in r.get("probes", [])],
        returns=[float(x) for x in returns], state_returns=[float(r["state_return"]) for r in records])


def add_regret(results: Sequence[PeerResult]) -> None:
    """Fill in every row's paired regret against its model's ``optimal`` row (module docstring)."""
    refs = {r.model: r for r in results if r.planner == "optimal"}
    for r in results:
        ref = refs.get(r.model)
        if ref is None:
            continue
        n = min(len(r.returns), len(ref.returns))
        r.regret, r.regret_ci = mean_ci(np.asarray(ref.returns[:n]) - np.asarray(r.returns[:n]))


def summarise_probes(probes: Sequence[dict]) -> dict:
    """B&B against exhaustive search on the probed beliefs (``ProbeConfig``).

    ``uncertified``: decisions B&B had to search; per probe the exhaustive search at B&B's
    depth (time ratio exhaustive / B&B, median, and the share of equal actions).
    ``certified``: decisions B&B proved optimal at the root; the anytime exhaustive search at the
    same budget: its median time and how often it found the proven action.
    """
    unc = [p for p in probes if not p["certified"]]
    run = [p for p in unc if p["fixed_time"] is not None]
    cert = [p for p in probes if p["certified"]]
    out = {"probes": len(probes), "uncertified": len(unc), "fixed_run": len(run), "certified": len(cert)}
    if run:
        out.update(depth=float(np.mean([p["depth"] for p in run])),
                   bnb_time=float(np.median([p["bnb_time"] for p in run])),
                   fixed_time=float(np.median([p["fixed_time"] for p in run])),
                   ratio=float(np.median([p["fixed_time"] / max(p["bnb_time"], 1e-9) for p in run])),
                   fixed_agree=float(np.mean([p["fixed_action"] == p["bnb_action"] for p in run])))
    if cert:
        out.update(cert_bnb_time=float(np.median([p["bnb_time"] for p in cert])),
                   cert_anytime_time=float(np.median([p["anytime_time"] for p in cert])),
                   cert_anytime_depth=float(np.mean([p["anytime_depth"] for p in cert])),
                   cert_anytime_agree=float(np.mean([p["anytime_action"] == p["bnb_action"] for p in cert])))
    return out


#: The keys of an episode record (:func:`run_chunk`).
RECORD_KEYS = frozenset({"episode", "return", "state_return", "cpu", "wall", "depths", "certified", "sims",
                         "certifies", "probes", "episode_cpu", "episode_wall"})


def _numbers_only(x) -> bool:
    """``x`` holds only numbers, booleans and ``None`` (in lists and string-keyed dicts)."""
    if x is None or isinstance(x, (bool, int, float)):
        return True
    if isinstance(x, list):
        return all(_numbers_only(v) for v in x)
    return isinstance(x, dict) and all(isinstance(k, str) and _numbers_only(v) for k, v in x.items())


def check_records(records, chunk: PeerChunk, plan: PeerPlan) -> None:
    """Raise :class:`~.datafile.CacheError` unless ``records`` are episode records of ``chunk``
    that the comparison can aggregate (a cached chunk's validation)."""
    if not isinstance(records, list) or not all(isinstance(r, dict) and set(r) == RECORD_KEYS for r in records):
        raise CacheError("not a list of episode records")
    if [r["episode"] for r in records] != list(range(chunk.start, chunk.stop)):
        raise CacheError(f"episodes are not {chunk.start}..{chunk.stop - 1}")
    if not _numbers_only(records):
        raise CacheError("an episode record holds something other than numbers")
    aggregate(chunk.model, chunk.planner, chunk.budget, plan.steps_for(chunk.model), records)
    summarise_probes([p for r in records for p in r["probes"]])


def _load_chunk(path: Path, plan: PeerPlan, chunk: PeerChunk) -> list[dict] | None:
    """The records of a valid cached chunk made by ``plan``, else ``None`` (one stderr line if a file was there)."""
    return read_entry(path, [plan.signature(chunk)], lambda rec: check_records(rec, chunk, plan),
                      then="its episodes are run again")


def _save_chunk(path: Path, plan: PeerPlan, chunk: PeerChunk, records: list[dict]) -> None:
    write_entry(path, plan.signature(chunk), records, meta={"chunk": asdict(chunk)})


#: Worker processes compute single-threaded: two jobs on two cores must not oversubscribe them
#: (and a BLAS helper thread would be charged to the budget clock anyway).
_SINGLE_THREAD_ENV = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


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
            rec = _load_chunk(cache_dir / c.filename, plan, c)
            if rec is not None:
                done[c] = rec
                if progress is not None:
                    progress.advance(c.stop - c.start, note="cached")
    todo = [c for c in chunks if c not in done]

    def finish(c: PeerChunk, rec: list[dict]) -> None:
        done[c] = rec
        if cache_dir is not None:
            _save_chunk(cache_dir / c.filename, plan, c, rec)
        if progress is not None:
            progress.advance(c.stop - c.start, note=f"{c.model} {c.planner} {'' if c.budget is None else c.budget}")

    if plan.jobs <= 1:
        for c in todo:
            finish(c, run_chunk(c, models[c.model], plan))
    elif todo:
        ctx = multiprocessing.get_context("spawn")  # no forked BLAS/ROS state in the workers
        saved = {k: os.environ.get(k) for k in _SINGLE_THREAD_ENV}
        os.environ.update(_SINGLE_THREAD_ENV)  # inherited by the spawned workers
        try:
            with ProcessPoolExecutor(max_workers=plan.jobs, mp_context=ctx) as pool:
                futures = {pool.submit(run_chunk, c, models[c.model], plan): c for c in todo}
                for f in as_completed(futures):
                    finish(futures[f], f.result())
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    results = []
    for m, p, b, _ in plan.cells(list(models)):
        rec = [r for c in chunks if (c.model, c.planner, c.budget) == (m, p, b) for r in done[c]]
        results.append(aggregate(m, p, b, plan.steps_for(m), rec))
    add_regret(results)
    return results
