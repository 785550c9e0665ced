"""Assumption 1 benchmark: ``check_assumptions`` on the fast path against the previous one, in one run.

``python -m pomdp_planner.bench.structure [--models ...] [--repeat N] [--no-old] [--json FILE]``
(also ``pomdp-planner bench structure``)

For every model it times :func:`~pomdp_planner.core.structure.check_assumptions` cold (no
cache: the gate's cache is not involved) with ``reduce=True`` (the default: the separable ratio
bound before the exact (A2') ratio, dominance over the observations of one ``(j, a)``) and with
``reduce=False`` (the previous path: every ratio exact, every ``D`` that fails (A2') classified
alone), prints S, A, Z, both times and their ratio, the prediction of
:func:`~pomdp_planner.core.structure.estimate_check`, the verdicts (A1/A2/A3) of both and
whether every matrix got the same verdict (proven / refuted / unknown) from both. The default
models: the paper's Sec. VI-B comparison case S = 256, A = 64 (``core.domains.comparison``, the
planner's slowest start-up before), a perimeter model at S = 32 (one sensor for all priorities:
dominance does the work), and the shipped models.

Timings on a shared machine are noisy: each figure is the best of ``--repeat`` runs, and only
the ratio measured in one run is meaningful. Exit code 0, or 1 if some matrix got different
verdicts from the two paths, 2 for a bad option or model.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.checks import integer
from ..core.model import POMDP
from ..core.one_line import Parser
from ..core.structure import REFUTED, AssumptionReport, check_assumptions, estimate_check, is_proven
from .lp import add_json_argument, cell, load_bench_model, old_over_new, run_compared

DEFAULT_MODELS = ("comparison:256,64", "perimeter:32", "perimeter_s8.yaml", "tracking_s8_natural.yaml",
                  "tracking_s3_info.yaml")


def _best_of(model: POMDP, reduce: bool, repeat: int) -> tuple[float, AssumptionReport]:
    best, rep = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        rep = check_assumptions(model, reduce=reduce)
        best = min(best, time.perf_counter() - t0)
    assert rep is not None
    return best, rep


def same_verdicts(a: AssumptionReport, b: AssumptionReport) -> bool:
    """Every ``D^{j,a,z}`` proven, refuted or unknown in both, and the same (A1)/(A3) status."""
    ca, cb = a.copositivity.codes, b.copositivity.codes
    return bool(a.status == b.status and np.array_equal(is_proven(ca), is_proven(cb))
                and np.array_equal(ca == REFUTED, cb == REFUTED))


def _verdict(rep: AssumptionReport) -> str:
    return "/".join(rep.status[k] for k in ("A1", "A2", "A3"))


def run_structure_bench(models: Sequence[str] = DEFAULT_MODELS, repeat: int = 1, old: bool = True,
                        log: Any = lambda s: None) -> list[dict[str, Any]]:
    """One row per model (module docstring)."""
    check_assumptions(load_bench_model("comparison:4,3"))  # first call pays for imports: not timed
    rows = []
    for spec in models:
        model = load_bench_model(spec)
        est = estimate_check(model)
        t_new, r_new = _best_of(model, True, repeat)
        row: dict[str, Any] = {
            "model": model.name, "S": model.S, "A": model.A, "Z": model.Z, "new_time": t_new,
            "estimate": est.seconds, "estimate_max": est.seconds_max, "new_verdict": _verdict(r_new),
            "new_counts": r_new.copositivity.counts(), "old_time": None, "old_verdict": None, "same": None,
        }
        if old:
            t_old, r_old = _best_of(model, False, repeat)
            row.update(old_time=t_old, old_verdict=_verdict(r_old), same=same_verdicts(r_new, r_old))
        log(f"{model.name}: new {t_new:.3f} s" + (f", old {row['old_time']:.3f} s" if old else ""))
        rows.append(row)
    return rows


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    head = (f"{'model':<22} {'S':>4} {'A':>3} {'Z':>4} {'old s':>8} {'new s':>8} {'old/new':>8} {'est. s':>8} "
            f"{'verdict old':<17} {'verdict new':<17} {'same':<4}")
    lines = [head, "-" * len(head)]
    for r in rows:
        ratio = old_over_new(r)
        same = "-" if r["same"] is None else ("yes" if r["same"] else "NO")
        lines.append(f"{r['model']:<22} {r['S']:>4} {r['A']:>3} {r['Z']:>4} {cell(r['old_time'], '>8.3f')} "
                     f"{r['new_time']:>8.3f} {cell(ratio, '>7.1f') + 'x':>8} {r['estimate']:>8.2f} "
                     f"{r['old_verdict'] or '-':<17} {r['new_verdict']:<17} {same:<4}")
    lines.append("new: check_assumptions (separable ratio bound, dominance); old: reduce=False (the previous path). "
                 "Times: best of the repeats, wall clock, cold. est.: estimate_check's prediction. same: every "
                 "D^(j,a,z) proven / refuted / unknown in both, same A1/A3.")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options (``pomdp-planner bench structure`` and ``python -m pomdp_planner.bench.structure``)."""
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS), metavar="MODEL",
                        help="'comparison:S,A', 'perimeter:S' or model files (default: %(default)s)")
    parser.add_argument("--repeat", type=integer, default=1, metavar="N", help="best of N runs per cell (1)")
    parser.add_argument("--no-old", action="store_true", help="time the fast path only")
    add_json_argument(parser)


def run_from_args(args: argparse.Namespace, prog: str) -> int:
    if args.repeat < 1:
        print(f"{prog}: error: --repeat: must be >= 1, got {args.repeat}", file=sys.stderr)
        return 2
    return run_compared(prog, args.json, lambda log: run_structure_bench(args.models, args.repeat, not args.no_old,
                                                                         log=log), format_table)


def main(argv: Sequence[str] | None = None) -> int:
    prog = "python -m pomdp_planner.bench.structure"
    parser = Parser(prog=prog, description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run_from_args(parser.parse_args(argv), prog)


if __name__ == "__main__":
    sys.exit(main())
