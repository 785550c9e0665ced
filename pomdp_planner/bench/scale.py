"""Scale benchmark: load, assumption check, bound LP, tables, memory and decisions, from S = 8 to 10 000.

``python -m pomdp_planner.bench.scale [--models SPEC ...] [--suite scale|setup] [--json FILE]``
(also ``pomdp-planner bench scale``)

Every model runs in a fresh process (so nothing is cached and the memory figure is that model's
own), one after the other, in one run:

* **load**: the model file, as a node reads it. ``tracking:S,A`` is the paper's 1-D tracking
  domain from the generator (``generator: {domain: tracking}``, the Sec. VI-B comparison reward,
  Renyi quadratic entropy with weight 0.5); ``grid:RxC`` is the shipped grid target search
  (``config/models/grid_10x10.yaml`` at that size) written as a ``.POMDP`` file with its
  ``# pomdp_planner:`` comment (element lines); any other spec is a model file;
* **set-up**: the assumption gate's estimate (:func:`~pomdp_planner.core.gate.estimate_setup`)
  beside what the gate then does (:func:`~pomdp_planner.core.gate.build_planner` with its
  defaults, each stage timed: assumption check, bound LP, planner tables) and their ratio; a set-up
  the gate refuses (expected over ``MAX_SETUP_SECONDS``, or the dense form of a sparse model too
  large for the search) shows why, and where only the search is refused the assumption check
  still runs and is timed;
* **peak RSS** of the process (after loading, setting up and deciding);
* **decisions**: a search of depth 1 from the uniform belief and of depth 2 from a point belief
  (the median of three), as the planner makes them.

``--suite setup`` runs the set-up part only over every model of the tests and benchmarks (the
shipped and test model files, the benchmarks' default models and sizes), for the estimate-vs-actual
table. Timings on a shared machine are noisy: only ratios measured in one run are meaningful; the
machine load (``/proc/loadavg``) is printed beside the table.
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .lp import add_json_argument, cell, print_rows

SCALE_MODELS = ("tracking:8,3", "tracking:32,3", "tracking:128,4", "tracking:256,4", "tracking:512,4",
                "tracking:1024,4", "grid:10x10", "grid:20x20", "grid:40x40", "grid:70x70", "grid:100x100")
#: Every model of the tests and benchmarks (shipped and test files, the benchmarks' defaults and sizes).
SETUP_MODELS = ("tracking_s2_info.yaml", "tracking_s3_info.yaml", "tracking_s8_info.yaml",
                "tracking_s8_natural.yaml", "perimeter_s3.yaml", "perimeter_s8.yaml", "grid_10x10.yaml",
                "grid_40x40.yaml", "test/models/birth_death_s2.yaml", "test/models/fails_assumption1_s3.yaml",
                "test/models/shannon_uncovered_s3.yaml", "test/models/finite_horizon_cost.POMDP",
                "comparison:64,16", "comparison:256,64", "perimeter:16", "perimeter:32", "perimeter:100",
                "random:6,3,4", "random:24,4,5", "random:40,12,30",
                *SCALE_MODELS)
DEPTHS = (1, 2)
#: A decision of depth 2 is not timed when depth 1 took longer than this (seconds).
SLOW_DEPTH1 = 5.0


def grid_document(rows: int, cols: int) -> dict:
    """The shipped grid model's document at ``rows x cols``."""
    from ..core.io.paths import resolve_path

    doc = yaml.safe_load(resolve_path("config/models/grid_10x10.yaml", "grid").read_text(encoding="utf-8"))
    doc["name"] = f"grid_{rows}x{cols}"
    doc["generator"].update(rows=rows, cols=cols)
    return doc


def model_file(spec: str, directory: Path) -> Path | str:
    """The file a spec loads from (module docstring), written into ``directory`` when generated."""
    from ..core.io.cassandra import save_pomdp_file
    from ..core.io.model_yaml import model_from_dict
    from ..core.io.paths import resolve_path

    if m := re.fullmatch(r"tracking:(\d+),(\d+)", spec):
        S, A = int(m.group(1)), int(m.group(2))
        doc = {"name": f"tracking_s{S}_a{A}", "discount": 0.95,
               "generator": {"domain": "tracking", "S": S, "A": A, "q": 0.8},
               "reward_generator": {"kind": "tracking_comparison"},
               "uncertainty": {"function": "renyi2", "weights": [0.5] * A}}
        path = directory / f"tracking_s{S}_a{A}.yaml"
        path.write_text(yaml.safe_dump(doc, default_flow_style=None), encoding="utf-8")
        return path
    if m := re.fullmatch(r"grid:(\d+)x(\d+)", spec):
        rows, cols = int(m.group(1)), int(m.group(2))
        path = directory / f"grid_{rows}x{cols}.POMDP"
        save_pomdp_file(model_from_dict(grid_document(rows, cols), spec), path)
        return path
    return resolve_path(spec, field="--models")


def _spec_model(spec: str):
    """Models that are not files: ``comparison:S,A``, ``perimeter:S``, ``random:S,A,Z``."""
    from ..core.model import POMDP
    from .lp import load_bench_model

    if m := re.fullmatch(r"random:(\d+),(\d+),(\d+)", spec):
        S, A, Z = (int(x) for x in m.groups())
        rng = np.random.default_rng(0)
        return POMDP(P=rng.dirichlet(np.ones(S), size=(A, S)), O=rng.dirichlet(np.ones(Z), size=(A, S)),
                     r=rng.normal(size=(S, A)), gamma=0.9, uncertainty="renyi2", w=[0.1] * A, name=f"random_s{S}")
    if re.fullmatch(r"(comparison:\d+,\d+|perimeter:\d+)", spec):
        return load_bench_model(spec)
    return None


def _timed(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def measure(spec: str, path: str | None, decisions: bool) -> dict[str, Any]:
    """One model, in this process (the child's work): the row of the table."""
    from ..core.domains.comparison import comparison_model
    from ..core.gate import STAGES, assumption_report, build_planner, estimate_setup
    from ..core.io.sensors import load_model_file
    from ..core.model import ModelError
    from ..core.search import Planner

    build_planner(comparison_model(4, 3))  # the first set-up of a process pays for imports: not timed
    t0 = time.perf_counter()
    model = _spec_model(spec) if path is None else load_model_file(path, "--models")
    load = time.perf_counter() - t0 if path is not None else None
    row: dict[str, Any] = {"model": model.name, "S": model.S, "A": model.A, "Z": model.Z, "storage": model.storage,
                           "stored_bytes": model.stored_bytes, "load": load,
                           "file_bytes": Path(path).stat().st_size if path is not None else None}
    t0 = time.perf_counter()
    est = estimate_setup(model)
    row.update(estimate_time=time.perf_counter() - t0, est_check=est.check.seconds if est.check else 0.0,
               est_lp=est.lp_seconds, est_tables=est.table_seconds, est_total=est.seconds, est_bytes=est.bytes,
               no_lp=est.no_lp)
    cpu = time.process_time()
    try:
        setup = build_planner(model)
    except (ValueError, MemoryError) as exc:  # a set-up the gate refuses (its memory, the dense form)
        row.update(refused=str(exc).split(": ", 1)[-1][:160], mode=None)
        if "MAX_DENSE_BYTES" in str(exc):  # the search is refused; the assumption check still runs
            t0, cpu = time.perf_counter(), time.process_time()
            assumption_report(model)
            row.update(check=time.perf_counter() - t0, check_cpu=time.process_time() - cpu)
        row["rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        return row
    row["cpu"] = time.process_time() - cpu
    seconds = setup.seconds
    row.update(refused=None, mode=setup.mode, check=seconds.get("assumption check", 0.0),
               lp=seconds.get("bound LP", 0.0), tables=seconds.get("planner tables", 0.0),
               total=sum(seconds.get(s, 0.0) for s in STAGES[1:]))
    if decisions:
        planner: Planner = setup.planner
        uniform = np.full(model.S, 1.0 / model.S)
        point = np.zeros(model.S)
        point[model.S // 2] = 1.0
        for depth, belief in zip(DEPTHS, (uniform, point), strict=True):
            if depth > 1 and row.get("decide_1", 0.0) > SLOW_DEPTH1:
                row[f"decide_{depth}"] = None
                continue
            try:
                row[f"decide_{depth}"] = _timed(
                    lambda b=belief, d=depth: planner.search(b, d, use_bounds=setup.pruning))
            except (ValueError, ModelError) as exc:
                row[f"decide_{depth}"] = None
                row["decide_error"] = str(exc)[:160]
    row["rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return row


def run_scale_bench(models: Sequence[str], decisions: bool = True, log: Any = lambda s: None) -> list[dict[str, Any]]:
    """One row per model (module docstring), each measured in its own process."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_scale_") as tmp:
        for spec in models:
            path = model_file(spec, Path(tmp)) if _spec_model_kind(spec) == "file" else None
            cmd = [sys.executable, "-m", "pomdp_planner.bench.scale", "--child", spec, str(path or ""),
                   "1" if decisions else "0"]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                raise ValueError(f"{spec}: the measuring process failed: {proc.stderr.strip().splitlines()[-1:]}")
            row = json.loads(proc.stdout.strip().splitlines()[-1])
            row["spec"] = spec
            log(f"{row['model']}: set-up {cell(row.get('total'), '.2f')} s (estimate {row['est_total']:.2f} s)")
            rows.append(row)
    return rows


def _spec_model_kind(spec: str) -> str:
    return "spec" if re.fullmatch(r"(comparison:\d+,\d+|perimeter:\d+|random:\d+,\d+,\d+)", spec) else "file"


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{1000 * x:.1f}"


def _ratio(est: float, actual: float | None) -> str:
    if actual is None:
        return "-"
    return f"{est / max(actual, 1e-3):.2f}"


def format_table(rows: Sequence[dict[str, Any]], decisions: bool = True) -> str:
    head = (f"{'model':<22} {'S':>6} {'A':>3} {'Z':>6} {'stored':>9} {'file':>8} {'load':>6} | {'est chk':>7} "
            f"{'check':>7} {'est LP':>7} {'LP':>7} {'tables':>7} {'est':>7} {'set-up':>7} {'CPU':>7} {'est/CPU':>7} | "
            f"{'RSS':>6}" + (f" | {'d1 ms':>8} {'d2 ms':>8}" if decisions else ""))
    lines = [head, "-" * len(head)]
    for r in rows:
        stored = f"{r['stored_bytes'] / 2**20:.1f}M" + ("s" if r["storage"] == "sparse" else "d")
        file = "-" if r.get("file_bytes") is None else f"{r['file_bytes'] / 2**20:.1f}M"
        if r.get("refused"):
            tail = f"refused: {r['refused']}"
            lines.append(f"{r['model']:<22} {r['S']:>6} {r['A']:>3} {r['Z']:>6} {stored:>9} {file:>8} "
                         f"{cell(r['load'], '.2f'):>6} | {r['est_check']:>7.2f} {cell(r.get('check'), '.2f'):>7} "
                         f"{r['est_lp']:>7.2f} | {r['rss'] / 2**20:>5.0f}M | {tail}")
            continue
        lines.append(
            f"{r['model']:<22} {r['S']:>6} {r['A']:>3} {r['Z']:>6} {stored:>9} {file:>8} {cell(r['load'], '.2f'):>6} | "
            f"{r['est_check']:>7.2f} {r['check']:>7.2f} {r['est_lp']:>7.2f} {r['lp']:>7.2f} {r['tables']:>7.2f} "
            f"{r['est_total']:>7.2f} {r['total']:>7.2f} {r['cpu']:>7.2f} {_ratio(r['est_total'], r['cpu']):>7} | "
            f"{r['rss'] / 2**20:>5.0f}M" + (f" | {_ms(r.get('decide_1')):>8} {_ms(r.get('decide_2')):>8}"
                                           if decisions else ""))
    lines.append("Seconds, wall clock, cold, one process per model. stored: P, O and r as the model keeps them "
                 "(d dense, s sparse); load: the file (tracking: generator YAML, grid: .POMDP with the pomdp_planner "
                 "comment); est chk / check, est LP / LP: the gate's estimate and the stage as it ran (no LP where "
                 "Assumption 1 fails); tables: the planner's; est / set-up: estimate and actual of check + LP + "
                 "tables, CPU: the CPU time of that set-up (all threads), est/CPU their ratio (on a loaded machine the "
                 "wall clock exceeds the CPU time); RSS: peak of the process. d1: depth-1 decision from the uniform "
                 "belief, d2: depth 2 from a point belief (median of 3; exhaustive where Assumption 1 fails).")
    with open("/proc/loadavg") as fh:
        lines.append(f"Machine load (1, 5, 15 min) at the end: {' '.join(fh.read().split()[:3])}")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options (``pomdp-planner bench scale`` and ``python -m pomdp_planner.bench.scale``)."""
    parser.add_argument("--suite", choices=("scale", "setup"), default="scale",
                        help="scale: the scale table (default); setup: the set-up estimate against the set-up, "
                             "on every model of the tests and benchmarks (no decisions)")
    parser.add_argument("--models", nargs="+", metavar="SPEC", help="tracking:S,A, grid:RxC, comparison:S,A, "
                        "perimeter:S, random:S,A,Z or model files (default: the suite's)")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    add_json_argument(parser)


def run_from_args(args: argparse.Namespace, prog: str) -> int:
    if args.child:
        spec, path, decisions = args.child
        print(json.dumps(measure(spec, path or None, decisions == "1")))
        return 0
    decisions = args.suite == "scale"
    models = args.models or (SCALE_MODELS if decisions else SETUP_MODELS)
    try:
        rows = run_scale_bench(models, decisions, log=lambda s: print(s, file=sys.stderr, flush=True))
        print_rows(rows, format_table(rows, decisions), args.json)
    except (ValueError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    prog = "python -m pomdp_planner.bench.scale"
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run_from_args(parser.parse_args(argv), prog)


if __name__ == "__main__":
    sys.exit(main())
