"""Run every experiment of the paper and write ``RESULTS.md`` and ``img/*.png`` (``run_all``).

``quick=True`` shrinks every experiment (a CI smoke test, < 2 minutes); the report then says
so at the top. Sizes of both modes are in :data:`FULL` and :data:`QUICK` and are printed into
the report, so it always states exactly what was run.
"""

from __future__ import annotations

import platform
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ...core.bounds import BoundsSolution
from ...core.domains.comparison import Y_SPREAD, comparison_model
from ...core.gate import build_planner
from ...core.io.model_yaml import load_model
from ...core.io.paths import shipped_model_path
from ...core.model import POMDP, ModelError
from ...core.reference import alpha_vector_value_iteration, certified_actions, reference_policy
from ..search import BenchConfig, run_search_bench
from .datafile import CacheError, read_entry, write_entry
from .figures import plot_fig1, plot_fig3, plot_looseness, plot_peers
from .pbvi import pbvi, single_action_optimal
from .peer_policies import BUDGETED, UNBUDGETED, ProbeConfig, ReferenceSpec, gate_setup, grid_reference, mcts_available
from .peers import PeerPlan, compare_peers
from .pouct import exploration_constant, pouct_available, return_spread
from .progress import Progress
from .pruning import pruning_sweep
from .report import render_report, write_report
from .sampling import random_beliefs
from .sanity import run_sanity


@dataclass(frozen=True)
class ExperimentConfig:
    quick: bool
    fig1_grid: int  # Freudenthal resolution of the S = 3 reference (fine grid = 2x)
    fig1_plot_grid: int  # resolution of the plotted bound policies
    table2_beliefs: int
    table2_depths: tuple[int, ...]
    table2_depth6_beliefs: int  # beliefs counted at the deepest depth (costly), the rest one less
    model_check_states: tuple[int, ...]
    model_check_actions: int
    model_check_horizon: int  # exact alpha-vector horizon
    table3_states: tuple[int, ...]
    table3_actions: tuple[int, ...]
    table3_beliefs: int
    table3_variants: tuple[tuple[str, int], ...]  # (variant, largest S it is run for)
    looseness_max_states: int
    peers_models: tuple[str, ...]
    peers_budgets: tuple[float, ...]
    peers_cheap_episodes: int
    peers_episodes: tuple[int, ...]  # per budget
    peers_steps: int
    peers_max_depth: int
    peers_chunk: int = 10  # episodes per unit of work (parallel jobs, resumable cache)
    # (model, kind, param): the optimal reference of a model (peer_policies.ReferenceSpec)
    peers_references: tuple[tuple[str, str, int], ...] = ()
    peers_model_episodes: tuple[tuple[str, float, int], ...] = ()  # (model, budget, episodes) overrides
    peers_model_steps: tuple[tuple[str, int], ...] = ()  # (model, steps) overrides
    peers_probe_episodes: int = 20  # B&B vs exhaustive probes: first episodes of every B&B cell ...
    peers_probe_steps: tuple[int, ...] = (5, 25)  # ... at these decisions
    peers_sanity_models: tuple[str, ...] = ("tracking_s3_info", "perimeter_s3")
    peers_sanity_reachable: int = 12  # reachable check beliefs besides the vertices and the centre
    seed: int = 0


#: The models of the peer comparison: the paper's (old) ones and the ones where lookahead pays
#: (docs/MODEL_SEARCH.md). A model that is not shipped is skipped, and the report says so.
PEER_MODELS = ("tracking_s3_info", "tracking_s8_info", "perimeter_s3", "perimeter_s8")
#: Their optimal references (S = 3: grid policy iteration; S = 8: deep exhaustive search).
PEER_REFERENCES = (("tracking_s3_info", "grid", 40), ("tracking_s8_info", "search", 4),
                   ("perimeter_s3", "grid", 40), ("perimeter_s8", "search", 4))

FULL = ExperimentConfig(
    quick=False, fig1_grid=40, fig1_plot_grid=60, table2_beliefs=100, table2_depths=(2, 3, 4, 5, 6),
    table2_depth6_beliefs=20, model_check_states=(4, 5), model_check_actions=4, model_check_horizon=1500,
    table3_states=(4, 8, 16, 32, 64, 128, 256), table3_actions=(4, 8, 16, 32, 64), table3_beliefs=500,
    table3_variants=(("feasible", 256), ("tight", 256)), looseness_max_states=16,
    peers_models=PEER_MODELS, peers_budgets=(0.01, 0.05, 0.2, 1.0),
    peers_cheap_episodes=100, peers_episodes=(50, 50, 50, 20), peers_steps=50, peers_max_depth=12,
    peers_references=PEER_REFERENCES,
    # The compute plan (docs/benchmarks.md, "The peer comparison"): the 1 s cells are three quarters of
    # the cost, so they run 20 episodes on the perimeter models and 10 on the paper's, where lookahead
    # is worth nothing.
    peers_model_episodes=(("tracking_s3_info", 1.0, 10), ("tracking_s8_info", 1.0, 10)),
)

QUICK = ExperimentConfig(
    quick=True, fig1_grid=10, fig1_plot_grid=20, table2_beliefs=5, table2_depths=(2, 3, 4),
    table2_depth6_beliefs=2, model_check_states=(4,), model_check_actions=4, model_check_horizon=200,
    table3_states=(4, 8), table3_actions=(4, 8), table3_beliefs=50, table3_variants=(("feasible", 8), ("tight", 8)),
    looseness_max_states=4, peers_models=PEER_MODELS, peers_budgets=(0.01, 0.05),
    peers_cheap_episodes=3, peers_episodes=(2, 2), peers_steps=8, peers_max_depth=6, peers_chunk=2,
    peers_references=(("tracking_s3_info", "grid", 10), ("tracking_s8_info", "search", 2), ("perimeter_s3", "grid", 10),
                      ("perimeter_s8", "search", 2)),
    peers_probe_episodes=1, peers_probe_steps=(3,), peers_sanity_reachable=4,
    # perimeter_s3 has near-ties (Q gaps of 0.04) that a sampling planner misses now and then at
    # these budgets (a FAIL in the report): the smoke test's sanity model is the S = 3 tracking one
    peers_sanity_models=("tracking_s3_info",),
)


# ------------------------------------------------------------------------------ models
def shipped_model(name: str) -> POMDP:
    """A shipped model (``config/models/<name>.yaml``, installed share dir or source tree)."""
    return load_model(shipped_model_path(name))


def valid_bounds(model: POMDP, variant: str = "tight") -> BoundsSolution:
    """The LP solution of ``model`` once the assumption gate accepts its bounds (the figures plot
    bound policies, so a model without valid bounds is an error naming the gate's reason)."""
    setup = build_planner(model, variant=variant)
    if not (setup.pruning and setup.guaranteed):
        raise ValueError(f"{model.name}: {setup.describe()}")
    return setup.bounds


# ------------------------------------------------------------------------------ sections
def run_fig1(cfg: ExperimentConfig, img: Path) -> dict:
    """Fig. 1: bound policies and the grid-reference optimum on the S = 3 simplex."""
    model = shipped_model("tracking_s3_info")
    sol = valid_bounds(model)
    ref = reference_policy(model, cfg.fig1_grid)
    B = ref.beliefs
    lo, up = sol.myopic.actions(B)
    dec = ref.decided
    outside = dec & ((ref.actions < lo) | (ref.actions > up))
    path = plot_fig1(img / "fig1_policy_bounds_s3.png", B, lo, up, ref.actions, dec, model.A)
    return {
        "model": model.name, "variant": "tight", "lp_time": sol.solve_time, "g": sol.g, "h": sol.h,
        "grid_beliefs": len(B), "agree_fraction": float(np.mean(lo == up)),
        "decided_fraction": float(np.mean(dec)), "tie_margin": float(ref.tie_margin),
        "violations": int(outside.sum()), "optimal_actions": np.bincount(ref.actions, minlength=model.A).tolist(),
        "agree_and_correct": int(np.sum(dec & (lo == up) & (lo == ref.actions))),
        "agree_decided": int(np.sum(dec & (lo == up))), "image": path.name,
    }


def run_fig3(cfg: ExperimentConfig, img: Path) -> dict:
    """The paper's reward figure on our S = 2 model (config/models/tracking_s2_info.yaml)."""
    model = shipped_model("tracking_s2_info")
    sol = valid_bounds(model)
    b1 = np.linspace(0.0, 1.0, 401)
    B = np.stack([1.0 - b1, b1], axis=1)
    rho = model.rho(B)
    rl, ru = sol.myopic.transformed_rewards(B, rho)
    lo, up = sol.myopic.actions(B, rho)
    path = plot_fig3(img / "fig3_rewards_s2.png", b1, rho, rl, ru, lo, up)
    ref = reference_policy(model, 4 * cfg.fig1_grid)
    rlo, rup = sol.myopic.actions(ref.beliefs)
    viol = int(np.sum(ref.decided & ((ref.actions < rlo) | (ref.actions > rup))))
    mono_lower = bool(np.all(np.diff(rl, axis=0) >= -1e-9))
    mono_upper = bool(np.all(np.diff(ru, axis=0) <= 1e-9))
    return {"model": model.name, "agree_fraction": float(np.mean(lo == up)),
            "agree_a1": float(np.mean((lo == up) & (lo == 0))), "agree_a2": float(np.mean((lo == up) & (lo == 1))),
            "lower_increasing": mono_lower, "upper_decreasing": mono_upper, "violations": viol,
            "g": sol.g, "h": sol.h, "image": path.name}


def run_table2(cfg: ExperimentConfig, progress: bool) -> dict:
    """Table II and search timings: the search helper's benchmark (``pomdp-planner bench search``)."""
    if cfg.quick:
        bc = BenchConfig(beliefs=cfg.table2_beliefs, deep_beliefs=cfg.table2_depth6_beliefs, timed=2,
                         depths=cfg.table2_depths, timed_max_depth=max(cfg.table2_depths) - 1, seed=cfg.seed,
                         engines=False)
    else:  # the engine comparison is `bench search`'s own (docs/benchmarks.md), not an experiment of the paper
        bc = BenchConfig(beliefs=cfg.table2_beliefs, deep_beliefs=cfg.table2_depth6_beliefs, depths=cfg.table2_depths,
                         seed=cfg.seed, engines=False)

    def log(msg: str) -> None:
        if progress:
            print(f"  table II: {msg}", file=sys.stderr, flush=True)

    return run_search_bench(config=bc, log=log)


def run_model_check(cfg: ExperimentConfig, progress: bool) -> dict:
    """Natural vs our Sec. VI-B sequences: which actions the optimal policy uses (exact)."""
    rows = []
    rng = np.random.default_rng([cfg.seed, 3])
    with Progress("model check", 2 * len(cfg.model_check_states), enabled=progress) as bar:
        for S in cfg.model_check_states:
            A = cfg.model_check_actions
            B = random_beliefs(S, 500, rng)
            for natural in (True, False):
                m = comparison_model(S, A, natural=natural)
                single = single_action_optimal(m)
                t0 = time.perf_counter()
                sol = alpha_vector_value_iteration(m, cfg.model_check_horizon)
                act, cert, _ = certified_actions(sol, B)
                pol = pbvi(m, np.vstack([np.eye(S), B]), tol=1e-6)
                pb = pol.actions(B)
                rows.append({"S": S, "A": A, "natural": natural,
                             "single_action": None if single is None else single + 1,
                             "exact_counts": np.bincount(act, minlength=A).tolist(), "certified": float(np.mean(cert)),
                             "error_bound": float(sol.error_bound), "horizon": cfg.model_check_horizon,
                             "pbvi_counts": np.bincount(pb, minlength=A).tolist(),
                             "pbvi_agrees_exact": float(np.mean(pb == act)), "time": time.perf_counter() - t0})
                bar.advance()
    # The exact single-action certificate is cheap: run it on every Table III size too.
    sweep = []
    for S in cfg.table3_states:
        for A in cfg.table3_actions:
            nat = single_action_optimal(comparison_model(S, A, natural=True))
            ours = single_action_optimal(comparison_model(S, A))
            sweep.append({"S": S, "A": A, "natural": None if nat is None else nat + 1,
                          "ours": None if ours is None else ours + 1})
    return {"rows": rows, "sweep": sweep, "y_spread": Y_SPREAD}


def run_table3(cfg: ExperimentConfig, progress: bool) -> dict:
    """Table III and the looseness figure's data, for each bound variant of the config."""
    sweep = pruning_sweep(cfg.table3_states, cfg.table3_actions, tuple(cfg.table3_variants), n=cfg.table3_beliefs,
                          seed=cfg.seed, exact_max_S=cfg.looseness_max_states, progress=progress)
    return {variant: {"cells": sweep[variant], "time": float(sum(c.extra["cell_time"] for c in sweep[variant])),
                      "max_S": max_S} for variant, max_S in cfg.table3_variants}


def peer_plan(cfg: ExperimentConfig, jobs: int = 1, with_pouct: bool = True, with_mcts: bool = True) -> PeerPlan:
    """The :class:`PeerPlan` of a configuration (POUCT / MCTS left out when not available)."""
    planners = tuple(p for p in BUDGETED + UNBUDGETED
                     if (p != "pouct" or with_pouct) and (p != "mcts" or with_mcts))
    model_episodes: dict = {}
    for m, b, n in cfg.peers_model_episodes:
        model_episodes.setdefault(m, {})[b] = n
    return PeerPlan(budgets=cfg.peers_budgets, planners=planners, episodes_cheap=cfg.peers_cheap_episodes,
                    episodes_by_budget=dict(zip(cfg.peers_budgets, cfg.peers_episodes, strict=True)),
                    model_episodes=model_episodes, steps=cfg.peers_steps, model_steps=dict(cfg.peers_model_steps),
                    max_depth=cfg.peers_max_depth, seed=1000 + cfg.seed,
                    references={m: ReferenceSpec(kind, n) for m, kind, n in cfg.peers_references},
                    probes=ProbeConfig(episodes=cfg.peers_probe_episodes, steps=cfg.peers_probe_steps),
                    chunk=cfg.peers_chunk, jobs=jobs)


def available_models(names: tuple[str, ...]) -> tuple[dict[str, POMDP], list[str]]:
    """The shipped models among ``names`` and the names that are not shipped (yet)."""
    found, missing = {}, []
    for name in names:
        try:
            found[name] = shipped_model(name)
        except ModelError:
            missing.append(name)
    return found, missing


def model_facts(model: POMDP, steps: int, reference: ReferenceSpec | None) -> dict:
    """What the report states per model: size, discount, rho range, the truncation of the
    ``steps``-step return and, with a grid reference, the range of ``V*`` over the simplex."""
    B = np.vstack([np.eye(model.S), random_beliefs(model.S, 2000, np.random.default_rng(0))])
    rho = model.rho(B)
    facts = {"S": model.S, "A": model.A, "Z": model.Z, "gamma": model.gamma, "steps": steps,
             "rho_min": float(rho.min()), "rho_max": float(rho.max()), "tail": float(model.gamma ** steps),
             "value_range_bound": float((rho.max() - rho.min()) / (1 - model.gamma)), "v_range": None,
             "reference": None if reference is None else reference.describe()}
    if reference is not None and reference.kind == "grid":
        V = grid_reference(model, reference.param).fine.V
        facts["v_range"] = float(V.max() - V.min())
    return facts


def run_peers(cfg: ExperimentConfig, progress: bool, cache: Path, jobs: int = 1, resume: bool = False) -> dict:
    """The sanity check and the peer comparison; finished chunks of episodes go to
    ``cache/peers-chunks`` and are reused only with ``resume`` (otherwise that folder is emptied first)."""
    with_pouct, with_mcts = pouct_available(), mcts_available()
    plan = peer_plan(cfg, jobs, with_pouct, with_mcts)
    chunk_dir = cache / "peers-chunks"
    if not resume and chunk_dir.is_dir():
        for f in (*chunk_dir.glob("*.json"), *chunk_dir.glob("*.pickle")):
            f.unlink()
    _warn_pickles(chunk_dir)
    models, missing = available_models(cfg.peers_models)
    t0 = time.perf_counter()
    sanity_models, _ = available_models(cfg.peers_sanity_models)
    if progress:
        print(f"  peers: sanity check on {', '.join(sanity_models)} ...", file=sys.stderr, flush=True)
    sanity = run_sanity(sanity_models, plan.planners, plan.budgets, max_depth=plan.max_depth,
                        reachable=cfg.peers_sanity_reachable, seed=cfg.seed,
                        references={m: plan.reference_for(m) for m in sanity_models}, pouct=plan.pouct,
                        pouct_defaults=with_pouct)
    sanity_time = time.perf_counter() - t0
    with Progress("peers", plan.total_units(list(models)), enabled=progress) as bar:
        results = compare_peers(models, plan, progress=bar, cache_dir=chunk_dir)
    facts = {m: model_facts(models[m], plan.steps_for(m), plan.reference_for(m)) for m in models}
    for m, f in facts.items():
        f["pouct_c"] = exploration_constant(models[m], plan.pouct)
        f["pouct_spread"] = return_spread(models[m], plan.pouct.rollout)
        gate = gate_setup(models[m])
        f["gate"] = gate.describe()
    return {"results": results, "plan": asdict(plan), "pouct": with_pouct, "mcts": with_mcts, "missing": missing,
            "sanity": sanity, "sanity_time": sanity_time, "facts": facts, "models": list(models),
            "time": time.perf_counter() - t0}


SECTIONS = ("fig1", "fig3", "table2", "model_check", "table3", "peers")


CACHE_DIR = ".experiments-cache"
#: The layout version of each section's cached data: bump it when the data a section returns
#: changes shape, and cache files of the older layout are ignored (the section is rerun or
#: reported missing) instead of breaking the report. table2 2: the natural S = 8 model added
#: (search.DEFAULT_MODELS); table3 2: degenerate cells and the mean interval width.
SECTION_SCHEMAS = {"fig1": 1, "fig3": 1, "table2": 2, "model_check": 1, "table3": 2, "peers": 1}
#: The configuration fields (names or name prefixes) each section's results depend on, besides
#: ``quick`` and ``seed``; a cached section is reused only under the same values.
SECTION_FIELDS = {"fig1": ("fig1_",), "fig3": ("fig1_grid",), "table2": ("table2_",),
                  "model_check": ("model_check_", "table3_states", "table3_actions"),
                  "table3": ("table3_", "looseness_"), "peers": ("peers_",)}


def section_signature(cfg: ExperimentConfig | dict, name: str) -> dict:
    """What a cached section must carry to be reused: its name, data layout and plan (the
    configuration fields it depends on, :data:`SECTION_FIELDS`)."""
    c = cfg if isinstance(cfg, dict) else asdict(cfg)
    plan = {k: v for k, v in c.items() if k in ("quick", "seed") or k.startswith(SECTION_FIELDS[name])}
    return {"section": name, "schema": SECTION_SCHEMAS[name], "plan": plan}


def _cache_dir(output: Path) -> Path:
    d = output / CACHE_DIR
    d.mkdir(parents=True, exist_ok=True)
    (d / ".gitignore").write_text("*\n")  # never committed
    return d


def _warn_pickles(directory: Path) -> None:
    """One stderr line when ``directory`` holds cache files of the old pickle format (never loaded)."""
    old = sorted(directory.glob("*.pickle")) if directory.is_dir() else []
    if old:
        names = ", ".join(f.name for f in old[:3]) + (", ..." if len(old) > 3 else "")
        print(f"pomdp-planner: ignoring {len(old)} old *.pickle cache file(s) in {directory} ({names}): never "
              "loaded (unpickling can run code); delete them", file=sys.stderr, flush=True)


def _header(cfg: ExperimentConfig) -> dict:
    return {"config": asdict(cfg), "configs": {}, "timings": {}, "modes": {},
            "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
            "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}"}


def _add_section(data: dict, name: str, entry: dict) -> None:
    data[name] = entry["data"]
    data["configs"][name] = entry["config"]
    data["timings"][name] = entry["time"]
    data["modes"][name] = ("quick" if entry["config"]["quick"] else "full") + f", {entry['finished']}"


def _plots(data: dict, img: Path) -> None:
    """The plots made from several sections' data (looseness, peers), and their names in ``data``."""
    if "table3" in data:
        t3 = data["table3"].get("tight") or next(iter(data["table3"].values()))
        data["looseness_variant"] = "tight" if "tight" in data["table3"] else next(iter(data["table3"]))
        data["looseness_image"] = plot_looseness(img / "fig4_looseness.png", t3["cells"],
                                                 data["configs"]["table3"]["table3_actions"]).name
    if "peers" in data:
        data["peers_image"] = plot_peers(img / "peers_return_regret.png", data["peers"]["results"],
                                         data["peers"]["models"]).name


def check_cached_section(name: str, entry: object, accept: list[dict]) -> None:
    """Raise unless ``entry`` (a decoded cache file) is a section entry the report can be written
    from: the right fields, a configuration whose signature is in ``accept``, and the section's
    report and plots render from it alone (in a scratch directory)."""
    if not isinstance(entry, dict) or set(entry) != {"data", "config", "time", "finished"}:
        raise CacheError("not a section entry")
    config = entry["config"]
    if not isinstance(config, dict) or section_signature(config, name) not in accept:
        raise CacheError("its configuration does not match its signature")
    if not isinstance(config.get("quick"), bool) or not isinstance(entry["finished"], str):
        raise CacheError("bad configuration")
    if not isinstance(entry["time"], (int, float)) or isinstance(entry["time"], bool):
        raise CacheError("bad run time")
    data = _header(QUICK)
    _add_section(data, name, entry)
    with tempfile.TemporaryDirectory() as tmp:
        _plots(data, Path(tmp))
    render_report(data)


def load_section(cache: Path, name: str, then: str = "the section is left out of the report") -> dict | None:
    """The cached entry of section ``name`` made under the FULL or the QUICK plan, or ``None``
    (with one stderr line when a file was there but is not usable)."""
    accept = [section_signature(FULL, name), section_signature(QUICK, name)]
    return read_entry(cache / f"{name}.json", accept, lambda e: check_cached_section(name, e, accept), then=then)


def run_all(output: str | Path = ".", quick: bool = False, progress: bool = True,
            sections: tuple[str, ...] = SECTIONS, jobs: int = 1, resume: bool = False) -> dict:
    """Run the experiments and write ``output/RESULTS.md`` and ``output/img/*.png``.

    Each section's data is also saved as JSON in ``output/.experiments-cache/<section>.json``
    (git-ignored; :mod:`.datafile`: data only, never code, with the section's plan as
    signature, :func:`section_signature`). When only some ``sections`` are run, the other
    sections are taken from that cache if a valid file made under the FULL or QUICK plan is
    there (anything else is ignored with one line on stderr), so a long run can be done in
    pieces; the report states each section's mode. The peer comparison runs in ``jobs``
    processes and, with ``resume``, reuses the chunks of episodes an earlier, interrupted run
    left in ``output/.experiments-cache/peers-chunks``.
    """
    cfg = QUICK if quick else FULL
    output = Path(output)
    img = output / "img"
    img.mkdir(parents=True, exist_ok=True)
    cache = _cache_dir(output)
    _warn_pickles(cache)
    runners = {"fig1": lambda: run_fig1(cfg, img), "fig3": lambda: run_fig3(cfg, img),
               "table2": lambda: run_table2(cfg, progress), "model_check": lambda: run_model_check(cfg, progress),
               "table3": lambda: run_table3(cfg, progress),
               "peers": lambda: run_peers(cfg, progress, cache, jobs, resume)}
    data = _header(cfg)
    for name in SECTIONS:
        if name in sections:
            t0 = time.perf_counter()
            if progress:
                print(f"[experiments] {name} ...", file=sys.stderr, flush=True)
            entry = {"data": runners[name](), "config": asdict(cfg), "time": time.perf_counter() - t0,
                     "finished": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
            try:
                write_entry(cache / f"{name}.json", section_signature(cfg, name), entry)
            except (CacheError, OSError) as exc:  # the report is still written from memory
                print(f"pomdp-planner: could not cache section {name}: {exc}", file=sys.stderr, flush=True)
        else:
            entry = load_section(cache, name)
            if entry is None:
                continue
        _add_section(data, name, entry)
    _plots(data, img)
    write_report(output / "RESULTS.md", data)
    return data


__all__ = ["FULL", "QUICK", "SECTIONS", "ExperimentConfig", "load_section", "run_all", "section_signature",
           "shipped_model"]
