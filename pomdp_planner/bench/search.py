"""Search benchmark: the paper's Table II (pruning by depth), timings, agreement and throughput.

Reproduces Sec. VI-A of the paper: for the ``S = Z = 8, A = 3`` tracking problem (the paper
does not publish it; primary reading ``config/models/tracking_s8_natural.yaml``, the S = 3
problem stretched with the generator's defaults, and a second one with a steeper kernel,
``tracking_s8_info.yaml``) and the ``S = 3`` problem, over seeded random initial beliefs
(uniform on the simplex):

* **Pruning** (depths 2..6): belief nodes of the complete tree (the formula
  ``sum_{i<=d} (A Z)^i``), nodes of the branch-and-bound tree (mean) and the percentage
  pruned ``100 (1 - bnb / complete)`` (mean, min, max), next to the paper's Table II row.
  Counts come from :meth:`Planner.count_nodes` (the B&B tree is built, its leaves are not
  valued; exhaustive counts are the formula). The depth-``D`` tree contains every smaller
  depth's tree, so one count per belief gives all depths. The deepest depth, the expensive
  one, is counted on the first ``deep_beliefs`` beliefs only (all with ``--full``).
* **Timing** (depths 2..5, first ``timed`` beliefs): the median over beliefs of the wall-clock
  time of B&B and of exhaustive search (each the best of a few repetitions when a run takes
  under 50 ms), the speed-up (ratio of the medians), how often both choose the same action,
  and throughput in belief nodes per second (tree nodes / median time).

The bounds are solved with ``--variant`` and ``--constant`` (default ``tight``, ``mlr``; the report
and the JSON name both). The planner comes from the assumption gate
(:func:`pomdp_planner.core.gate.build_planner`): a
model whose bounds are not valid (Assumption 1 fails, LP infeasible, Shannon guarantee covering
no domain) is skipped with the gate's reason, unless ``--prune-without-guarantee`` asks to
measure pruning anyway; the report then says that no guarantee holds and that agreeing root
bounds certify nothing.

* **Engines** (:mod:`.engines`; depths 2..5 on ``tracking_s8_info``, ``tracking_s8_natural``,
  ``perimeter_s8``, ``perimeter_s3``): nodes/s of the compiled kernel and of the numpy reference
  side by side, exhaustive and branch-and-bound, the B&B efficiency of each, and the kernel against
  an optimised standalone C implementation of the same exhaustive expectimax compiled for the
  machine (thread CPU time, interleaved rounds; ``--no-engines`` leaves it out).

Everything runs in this process on one core (the planner avoids BLAS threads). Timings on a
shared machine are noisy: compare ratios measured in one run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..core.bounds import BOUND_CONSTANTS, BOUND_VARIANTS, DEFAULT_CONSTANT
from ..core.checks import integer
from ..core.gate import build_planner
from ..core.io.model_yaml import load_model
from ..core.io.outputs import check_output_file, is_stdout, write_text_file
from ..core.io.paths import resolve_path
from ..core.model import POMDP
from ..core.policies import check_seed
from ..core.search import complete_tree_nodes
from .engines import ENGINE_DEPTHS, ENGINE_MODELS, format_engines, run_engines
from .paper import PAPER_TABLE_II

#: Table II's models: the primary one (the paper's S = 3 problem stretched naturally to S = 8 with
#: the generator's defaults), the second S = 8 reading (x = 1..8, a steeper kernel) and the
#: paper's fully specified S = 3 problem.
DEFAULT_MODELS = ("tracking_s8_natural.yaml", "tracking_s8_info.yaml", "tracking_s3_info.yaml")
#: Most random beliefs of the pruning table (``--beliefs``): the default is 100; each one counts
#: the B&B tree to depth 6 on the S = 8 model.
MAX_BELIEFS = 10_000


@dataclass(frozen=True)
class BenchConfig:
    """What the benchmark measures (defaults: the issue's full table)."""

    beliefs: int = 100
    deep_beliefs: int = 20
    timed: int = 10
    depths: tuple[int, ...] = (2, 3, 4, 5, 6)
    timed_max_depth: int = 5
    seed: int = 0
    variant: str = "tight"
    constant: str = DEFAULT_CONSTANT  # the bound LP's belief-independent constant (core.bounds.BOUND_CONSTANTS)
    prune_without_guarantee: bool = False  # measure pruning on a model whose bounds are not valid (said so)
    engines: bool = True  # the engine comparison (module docstring)
    engine_models: tuple[str, ...] = ENGINE_MODELS
    engine_depths: tuple[int, ...] = ENGINE_DEPTHS
    engine_beliefs: int = 3
    engine_rounds: int = 5

    @classmethod
    def quick(cls) -> BenchConfig:
        return cls(beliefs=20, deep_beliefs=3, timed=3, depths=(2, 3, 4, 5, 6), timed_max_depth=4,
                   engine_depths=(2, 3, 4), engine_beliefs=2, engine_rounds=3)


def _timed(fn: Callable[[], Any], clock: Callable[[], float] = time.perf_counter) -> tuple[float, Any]:
    """Best time of a few calls of ``fn`` (more calls when it is fast), and its result."""
    t0 = clock()
    out = fn()
    best = clock() - t0
    reps = 0 if best > 0.05 else min(10, int(0.05 / max(best, 1e-6)))
    for _ in range(reps):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best, out


def bench_model(model: POMDP, config: BenchConfig, log: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Pruning and timing figures for one model (a JSON-ready dict)."""
    A, Z, S = model.A, model.Z, model.S
    t0 = time.perf_counter()
    setup = build_planner(model, variant=config.variant, constant=config.constant,
                          prune_without_guarantee=config.prune_without_guarantee,
                          override_name="--prune-without-guarantee")
    gate_time = time.perf_counter() - t0
    sol = setup.bounds
    out: dict[str, Any] = {
        "model": model.name, "S": S, "A": A, "Z": Z, "uncertainty": model.uncertainty.name,
        "variant": config.variant, "constant": config.constant,
        "bounds_feasible": bool(sol is not None and sol.feasible),
        "bounds_message": setup.reason if sol is None else sol.message,
        "bounds_solve_time": None if sol is None else sol.solve_time, "gate_time": gate_time,
        "gate": setup.to_dict(), "beliefs": config.beliefs, "seed": config.seed,
    }
    if not setup.pruning:
        log(f"{model.name}: {setup.describe()}; skipped")
        return out
    if not setup.guaranteed:
        log(f"{model.name}: {setup.describe()}")
    planner = setup.planner
    beliefs = np.random.default_rng(config.seed).dirichlet(np.ones(S), size=config.beliefs)
    dmax = max(config.depths)
    expanded: dict[int, list[int]] = {d: [] for d in config.depths}
    certified = 0
    t0 = time.perf_counter()
    for i, b in enumerate(beliefs):
        depth = dmax if i < config.deep_beliefs else dmax - 1
        sizes = np.cumsum(planner.count_nodes(b, depth))
        for d in config.depths:
            if d <= depth:
                expanded[d].append(int(sizes[d]))
        lo, up = planner.root_bounds(b)
        certified += lo == up
    log(f"{model.name}: node counts for {config.beliefs} beliefs in {time.perf_counter() - t0:.1f} s")
    pruning = []
    for d in config.depths:
        complete = complete_tree_nodes(A, Z, d)
        pct = [100.0 * (1.0 - e / complete) for e in expanded[d]]
        pruning.append({
            "depth": d, "beliefs": len(pct), "complete_nodes": complete,
            "bnb_nodes_mean": float(np.mean(expanded[d])) if pct else None,
            "percent_pruned_mean": float(np.mean(pct)) if pct else None,
            "percent_pruned_min": float(np.min(pct)) if pct else None,
            "percent_pruned_max": float(np.max(pct)) if pct else None,
            "paper_table_ii": PAPER_TABLE_II.get(d) if (S, A, Z) == (8, 3, 8) else None,
        })
    out["pruning"] = pruning
    out["root_bounds_agree"] = certified / config.beliefs
    timing = []
    tdepths = [d for d in config.depths if d <= config.timed_max_depth]
    for d in tdepths:
        t_b, t_e, agree, n_b = [], [], 0, []
        for i, b in enumerate(beliefs[: config.timed]):
            runs = [("bnb", True), ("exh", False)]
            if i % 2:
                runs.reverse()  # alternate the order: neither search always runs on a warm cache
            res = {}
            for name, use in runs:
                t, r = _timed(lambda b=b, use=use, d=d: planner.search(b, d, use_bounds=use))
                res[name] = (t, r)
            t_b.append(res["bnb"][0])
            t_e.append(res["exh"][0])
            n_b.append(res["bnb"][1].nodes_expanded[-1])
            agree += res["bnb"][1].action == res["exh"][1].action
        mb, me = statistics.median(t_b), statistics.median(t_e)
        complete = complete_tree_nodes(A, Z, d)
        timing.append({
            "depth": d, "beliefs": len(t_b), "bnb_time_median": mb, "exhaustive_time_median": me,
            "speedup": me / mb, "agreement": agree / len(t_b),
            "bnb_nodes_per_s": float(np.mean(n_b)) / mb, "exhaustive_nodes_per_s": complete / me,
            "bnb_percent_pruned": 100.0 * (1.0 - float(np.mean(n_b)) / complete),
        })
        log(f"{model.name}: timed depth {d}: bnb {mb * 1e3:.1f} ms, exhaustive {me * 1e3:.1f} ms")
    out["timing"] = timing
    out["targets"] = _targets(out)
    return out


def _targets(res: dict[str, Any]) -> dict[str, Any]:
    """The issue's speed targets, evaluated on this model's figures (``None``: not applicable)."""
    timing = res.get("timing", [])
    thr = [t["exhaustive_nodes_per_s"] for t in timing if t["depth"] >= 4]
    faster = [t["speedup"] > 1.0 for t in timing if t["depth"] >= 3 and t["bnb_percent_pruned"] >= 20.0]
    d5 = [t["bnb_time_median"] for t in timing if t["depth"] == 5]
    big = res["S"] == 8
    return {
        "exhaustive_5M_nodes_per_s_depth_ge_4": (min(thr) >= 5e6) if (thr and big) else None,
        "bnb_faster_where_pruning_ge_20pct_depth_ge_3": all(faster) if faster else None,
        "bnb_depth5_within_1s": (d5[0] <= 1.0) if (d5 and big) else None,
    }


def run_search_bench(models: Sequence[str] = DEFAULT_MODELS, config: BenchConfig | None = None,
                     log: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """The whole benchmark: one :func:`bench_model` entry per model file."""
    config = config or BenchConfig()
    t0 = time.perf_counter()
    loaded = [load_model(resolve_path(m, "--model")) for m in models]  # every file checked before the first run
    engine_models = [load_model(resolve_path(m, "--engine-model")) for m in config.engine_models] \
        if config.engines else []
    results = [bench_model(model, config, log) for model in loaded]
    out = {"benchmark": "search", "config": asdict(config), "models": results,
           "python": sys.version.split()[0], "numpy": np.__version__, "cpu_count": os.cpu_count()}
    if engine_models:
        out["engines"] = run_engines(engine_models, config.engine_depths, config.engine_beliefs,
                                     config.engine_rounds, config.seed, log)
    out["total_time"] = time.perf_counter() - t0
    return out


def _fmt(x: Any, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def format_report(result: dict[str, Any]) -> str:
    """Plain-text tables of :func:`run_search_bench`'s result."""
    lines = []
    cfg = result["config"]
    for m in result["models"]:
        gate = m.get("gate", {})
        solved = "not solved" if m["bounds_solve_time"] is None else f"solved in {m['bounds_solve_time']:.2f} s"
        lines.append(f"== {m['model']} (S={m['S']}, A={m['A']}, Z={m['Z']}, {m['uncertainty']}), "
                     f"bounds: {m['variant']}, constant {m.get('constant', DEFAULT_CONSTANT)}, {solved}, "
                     f"{cfg['beliefs']} beliefs (seed {cfg['seed']})")
        if "pruning" not in m:
            lines.append(f"   skipped: {gate.get('reason', m['bounds_message'])}")
            continue
        agree = f"{100 * m['root_bounds_agree']:.0f}% of the beliefs"
        if gate.get("guaranteed", True):
            lines.append(f"   root bounds agree (action certified) on {agree}")
        else:
            lines.append(f"   WITHOUT GUARANTEE: {gate['reason']}")
            lines.append(f"   root bounds agree (certifying nothing) on {agree}")
        lines.append("   depth  beliefs  complete nodes  B&B nodes (mean)  % pruned mean [min, max]  paper Table II")
        for p in m["pruning"]:
            paper = f"{p['paper_table_ii']:.1f}%" if p["paper_table_ii"] is not None else "-"
            lines.append(f"   {p['depth']:>5}  {p['beliefs']:>7}  {p['complete_nodes']:>14,}  "
                         f"{_fmt(p['bnb_nodes_mean'], '>16,.0f')}  "
                         f"{_fmt(p['percent_pruned_mean'], '>5.1f')} [{_fmt(p['percent_pruned_min'], '.1f')}, "
                         f"{_fmt(p['percent_pruned_max'], '.1f')}]{'':>6}  {paper:>14}")
        lines.append(f"   timing over {cfg['timed']} beliefs (median wall clock; nodes/s = tree nodes / median time)")
        lines.append("   depth  B&B time  exhaustive time  speed-up  same action  B&B nodes/s  exhaustive nodes/s")
        for t in m["timing"]:
            lines.append(f"   {t['depth']:>5}  {_ms(t['bnb_time_median']):>8}  {_ms(t['exhaustive_time_median']):>15}  "
                         f"{t['speedup']:>7.2f}x  {100 * t['agreement']:>10.0f}%  {t['bnb_nodes_per_s'] / 1e6:>9.1f} M"
                         f"  {t['exhaustive_nodes_per_s'] / 1e6:>16.1f} M")
        tg = m["targets"]
        lines.append("   targets: " + ", ".join(f"{k} = {v}" for k, v in tg.items() if v is not None))
        lines.append("")
    if "engines" in result:
        lines += [*format_engines(result["engines"]), ""]
    lines.append(f"total {result['total_time']:.0f} s (python {result['python']}, numpy {result['numpy']}, "
                 f"{result['cpu_count']} CPUs)")
    return "\n".join(lines)


def _ms(t: float) -> str:
    return f"{t * 1e3:.1f} ms" if t < 1.0 else f"{t:.2f} s"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The benchmark's options (``pomdp-planner bench search`` and ``python -m pomdp_planner.bench.search``)."""
    p.add_argument("--json", metavar="FILE", default=None,
                   help="also write the results as JSON to FILE (a regular file, checked before the run); '-': the "
                        "JSON on stdout, the text report on stderr")
    p.add_argument("--quick", action="store_true",
                   help="a smoke run in seconds (20 beliefs, 3 timed, deepest depth on 3 beliefs, timing to depth 4)")
    p.add_argument("--full", action="store_true", help="count the deepest depth on every belief (slower)")
    p.add_argument("--beliefs", type=integer, default=None, help="random initial beliefs for the pruning table (100)")
    p.add_argument("--timed", type=integer, default=None, help="beliefs timed per depth (10)")
    p.add_argument("--seed", type=integer, default=0, help="seed of the random beliefs (0)")
    p.add_argument("--variant", default=BOUND_VARIANTS[0], choices=BOUND_VARIANTS,
                   help=f"bound variant ({BOUND_VARIANTS[0]})")
    p.add_argument("--constant", default=DEFAULT_CONSTANT, choices=BOUND_CONSTANTS,
                   help=f"belief-independent constant of the bound LP ({DEFAULT_CONSTANT}; fosd: the first-order "
                        "dominance constant C_S)")
    p.add_argument("--prune-without-guarantee", action="store_true",
                   help="measure pruning also on a model whose bounds the gate finds not valid (NO GUARANTEE; "
                        "the report says so)")
    p.add_argument("--model", action="append", default=None, metavar="MODEL",
                   help="model file (repeatable; default: the shipped S = 8 tracking models, natural and "
                        "steeper, and S = 3)")
    p.add_argument("--engine-model", action="append", default=None, metavar="MODEL",
                   help="model file of the engine comparison (repeatable; default: the --model files, else "
                        "tracking_s8_info, tracking_s8_natural, perimeter_s8, perimeter_s3)")
    p.add_argument("--no-engines", action="store_true",
                   help="leave out the engine comparison (kernel, numpy reference, C yardstick)")


def config_from_args(args: argparse.Namespace) -> BenchConfig:
    cfg = BenchConfig.quick() if args.quick else BenchConfig()
    changes: dict[str, Any] = {"seed": check_seed(args.seed, "--seed"), "variant": args.variant,
                               "constant": args.constant,
                               "prune_without_guarantee": args.prune_without_guarantee,
                               "engines": not args.no_engines}
    if args.engine_model or args.model:  # the engines measure the models asked for
        changes["engine_models"] = tuple(args.engine_model or args.model)
    if args.beliefs is not None:
        if not 1 <= args.beliefs <= MAX_BELIEFS:
            raise ValueError(f"--beliefs: must be in 1..{MAX_BELIEFS}, got {args.beliefs}")
        changes["beliefs"] = args.beliefs
    if args.timed is not None:
        if args.timed < 1:
            raise ValueError(f"--timed: must be >= 1, got {args.timed}")
        changes["timed"] = args.timed
    beliefs = changes.get("beliefs", cfg.beliefs)
    changes["timed"] = min(changes.get("timed", cfg.timed), beliefs)
    changes["deep_beliefs"] = beliefs if args.full else min(cfg.deep_beliefs, beliefs)
    return BenchConfig(**{**asdict(cfg), **changes})


def run_from_args(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    if args.json is not None:  # before the run, not after minutes of it
        check_output_file(args.json, "--json")
    result = run_search_bench(args.model or DEFAULT_MODELS, config,
                              log=lambda s: print(s, file=sys.stderr, flush=True))
    print(format_report(result), file=sys.stderr if args.json is not None and is_stdout(args.json) else sys.stdout)
    if args.json is not None:
        write_text_file(args.json, json.dumps(result, indent=2) + "\n", "--json")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pomdp_planner.bench.search",
                                     description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    try:
        return run_from_args(parser.parse_args(argv))
    except (ValueError, OSError) as exc:  # ModelError included: a bad option or model file; an unwritable --json
        print(f"search bench: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
