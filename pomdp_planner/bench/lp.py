"""Bound LP benchmark: ``solve_bounds`` on the new path against the previous one, in one run.

``python -m pomdp_planner.bench.lp [--models ...] [--repeat N] [--no-old] [--json FILE]``

For every model, variant and constant it times :func:`~pomdp_planner.core.bounds.solve_bounds`
with ``solver="structured"`` (the default: least element where it is certified, HiGHS dual
simplex otherwise) and with ``solver="clarabel"`` (the previous path: Clarabel interior point
for every LP, row generation over whole actions, hinge-LP tightening), and prints the wall
times, their ratio and both solutions' worst constraint margins (``>= 0`` means every exact
constraint holds; both are post-checked by ``solve_bounds`` itself), the agreement of the lower
and upper bound on the LP's fitting samples and whether the bounds are guaranteed for the model
(the assumption gate's :func:`~pomdp_planner.core.gate.bounds_verdict`, untimed; where they are
not, the agreement is a diagnostic that certifies nothing, and the JSON row gives the reason). The default models are
the paper's Sec. VI-B comparison case S = 256, A = 64 (``core.domains.comparison``; f = none,
so both constants coincide there) and the shipped Renyi models under both constants.

Timings on a shared machine are noisy: each figure is the best of ``--repeat`` runs, and
only the ratio measured in one run is meaningful.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from ..core.bounds import BOUND_CONSTANTS, BOUND_SOLVERS, BOUND_VARIANTS, solve_bounds
from ..core.checks import integer
from ..core.domains.comparison import comparison_model
from ..core.domains.perimeter import PRESETS, perimeter_model
from ..core.gate import bounds_verdict
from ..core.io.model_yaml import load_model
from ..core.io.outputs import check_output_file, is_stdout, write_text_file
from ..core.io.paths import resolve_path
from ..core.model import POMDP
from ..core.one_line import Parser

#: ``comparison:S,A`` (the Sec. VI-B model) or a model file name / path.
DEFAULT_MODELS = ("comparison:256,64", "tracking_s8_natural.yaml", "tracking_s3_info.yaml")
NEW, OLD = BOUND_SOLVERS  # "structured", "clarabel"


def load_bench_model(spec: str) -> POMDP:
    """``comparison:S,A`` (the Sec. VI-B model), ``perimeter:S`` (the shipped perimeter physics at
    ``S`` bands) or a model file (shipped name or path)."""
    m = re.fullmatch(r"comparison:(\d+),(\d+)", spec.strip())
    if m:
        return comparison_model(int(m.group(1)), int(m.group(2)))
    m = re.fullmatch(r"perimeter:(\d+)", spec.strip())
    if m:
        return perimeter_model(**(PRESETS["perimeter_s8"] | {"S": int(m.group(1))}), name=f"perimeter_s{m.group(1)}")
    return load_model(resolve_path(spec, field="--models"))


def _best_of(model: POMDP, variant: str, constant: str, solver: str, repeat: int) -> tuple[float, Any]:
    best, sol = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        sol = solve_bounds(model, variant, constant=constant, solver=solver)
        best = min(best, time.perf_counter() - t0)
    return best, sol


def _worst_margin(sol: Any) -> float | None:
    vals = [v for v in sol.min_margin.values() if v is not None]
    return min(vals) if vals else None


def run_lp_bench(models: Sequence[str] = DEFAULT_MODELS, repeat: int = 1, old: bool = True,
                 log: Any = lambda s: None) -> list[dict[str, Any]]:
    """One row per (model, variant, constant); constants are deduplicated where they coincide."""
    warm = comparison_model(4, 3)  # first calls pay for imports and solver set-up: not timed
    for solver in BOUND_SOLVERS:
        solve_bounds(warm, "tight", solver=solver, samples=20)
    rows = []
    for spec in models:
        model = load_bench_model(spec)
        constants = BOUND_CONSTANTS if model.uncertainty.name == "renyi2" else BOUND_CONSTANTS[:1]
        for variant in BOUND_VARIANTS:
            for constant in constants:
                t_new, s_new = _best_of(model, variant, constant, NEW, repeat)
                verdict = bounds_verdict(model, s_new)
                row: dict[str, Any] = {
                    "model": model.name, "S": model.S, "A": model.A, "uncertainty": model.uncertainty.name,
                    "variant": variant, "constant": constant, "new_time": t_new, "new_feasible": s_new.feasible,
                    "new_worst_margin": _worst_margin(s_new), "new_agreement": s_new.sample_agreement,
                    "old_time": None, "old_feasible": None, "old_worst_margin": None, "old_agreement": None,
                    "guaranteed": verdict.guaranteed, "reason": verdict.reason,
                }
                if old:
                    t_old, s_old = _best_of(model, variant, constant, OLD, repeat)
                    row.update(old_time=t_old, old_feasible=s_old.feasible, old_worst_margin=_worst_margin(s_old),
                               old_agreement=s_old.sample_agreement)
                log(f"{model.name} {variant} {constant}: new {t_new:.3f} s"
                    + (f", old {row['old_time']:.3f} s" if old else ""))
                rows.append(row)
    return rows


def cell(x: Any, spec: str) -> str:
    """``x`` formatted with ``spec``, ``-`` for ``None`` (a figure not measured)."""
    return "-" if x is None else format(x, spec)


def print_rows(rows: Sequence[dict[str, Any]], table: str, json_path: str | None) -> None:
    """A benchmark's output: ``table`` on stdout (on stderr when the rows go to stdout: ``--json -``),
    then the rows as JSON to ``json_path`` if given."""
    print(table, file=sys.stderr if json_path is not None and is_stdout(json_path) else sys.stdout)
    if json_path is not None:
        write_text_file(json_path, json.dumps(rows, indent=2) + "\n", "--json")


def add_json_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--json FILE`` option of the benchmarks (:func:`print_rows`, checked first by :func:`run_compared`)."""
    parser.add_argument("--json", metavar="FILE", help="also write the rows as JSON (a regular file, checked before "
                        "the run; '-': the JSON on stdout, the table on stderr)")


def run_compared(prog: str, json_path: str | None, run: Callable[[Callable[[str], None]], list[dict[str, Any]]],
                 table: Callable[[Sequence[dict[str, Any]]], str]) -> int:
    """Run a benchmark that compares a new path with the old one: ``--json`` checked first, ``run(log)``
    (progress lines on stderr), :func:`print_rows`. Exit code 0, 1 if a row's ``same`` is false, 2
    (one line) for a bad model spec or file or an unwritable ``--json``."""
    try:
        if json_path is not None:  # before the run, not after minutes of it
            check_output_file(json_path, "--json")
        rows = run(lambda s: print(s, file=sys.stderr, flush=True))
        print_rows(rows, table(rows), json_path)
    except (ValueError, OSError) as exc:  # InputError included
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    return 0 if all(r["same"] is not False for r in rows) else 1


def old_over_new(row: dict[str, Any]) -> float | None:
    """The speed-up of a row with ``old_time`` and ``new_time`` (``None`` without the old path)."""
    return row["old_time"] / row["new_time"] if row["old_time"] is not None and row["new_time"] > 0 else None


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    head = (f"{'model':<22} {'S':>4} {'A':>3} {'variant':<8} {'const':<5} {'new s':>8} {'old s':>8} "
            f"{'old/new':>8} {'new margin':>11} {'old margin':>11} {'agree new':>9} {'agree old':>9} guaranteed")
    lines = [head, "-" * len(head)]
    for r in rows:
        ratio = old_over_new(r)
        lines.append(f"{r['model']:<22} {r['S']:>4} {r['A']:>3} {r['variant']:<8} {r['constant']:<5} "
                     f"{r['new_time']:>8.3f} {cell(r['old_time'], '>8.3f')} {cell(ratio, '>7.1f') + 'x':>8} "
                     f"{cell(r['new_worst_margin'], '>11.2e')} {cell(r['old_worst_margin'], '>11.2e')} "
                     f"{cell(r['new_agreement'], '>9.3f')} {cell(r['old_agreement'], '>9.3f')} "
                     f"{'yes' if r['guaranteed'] else 'NO'}")
    lines.append("new: solver='structured' (least element / HiGHS); old: solver='clarabel' (the previous path). "
                 "Times: best of the repeats, wall clock. Margins: worst exact constraint margin of g and h "
                 "(>= 0: feasible). Agreement: lower == upper on the 400 fitting samples. Guaranteed: the assumption "
                 "gate's verdict for the model; NO: the bounds are not valid and their agreement certifies nothing.")
    lines += [f"{m}: NOT GUARANTEED: {why}" for m, why in
              dict.fromkeys((r["model"], r["reason"]) for r in rows if not r["guaranteed"])]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m pomdp_planner.bench.lp", description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS), metavar="MODEL",
                        help="'comparison:S,A' or model files (default: %(default)s)")
    parser.add_argument("--repeat", type=integer, default=1, metavar="N", help="best of N runs per cell (1)")
    parser.add_argument("--no-old", action="store_true", help="time the new path only")
    add_json_argument(parser)
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat: must be >= 1, got {args.repeat}")
    try:
        if args.json is not None:
            check_output_file(args.json, "--json")
        rows = run_lp_bench(args.models, args.repeat, not args.no_old,
                            log=lambda s: print(s, file=sys.stderr, flush=True))
        print_rows(rows, format_table(rows), args.json)
    except (ValueError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
