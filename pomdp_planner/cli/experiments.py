"""``pomdp-planner bench all``: every experiment of the paper, as RESULTS.md and img/*.png.

Runs every experiment of the paper (Figs. 1, 3, 4, Tables II, III) and the peer comparison,
writing ``DIR/RESULTS.md`` and ``DIR/img/*.png`` (``--output DIR``, default the current
directory; ``make experiments`` passes ``--output docs``). ``--quick`` runs toy
sizes (CI smoke test, about half a minute). Plots need the ``experiments`` extra (matplotlib), the
POUCT peer the ``bench`` extra (pomdp-py); without pomdp-py POUCT is left out and the report
says so.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ..bench.experiments.runner import CACHE_DIR, SECTIONS, run_all
from ..core.io.outputs import check_output_dir
from ..core.model import ModelError
from ._common import int_in

#: ``--jobs``: worker processes, at most one per CPU (the budgeted planners are timed).
MAX_JOBS = os.cpu_count() or 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", default=".", metavar="DIR",
                        help="directory for RESULTS.md and img/*.png (default: the current directory)")
    parser.add_argument("--quick", action="store_true", help="toy sizes, < 2 minutes (CI smoke test)")
    parser.add_argument("--only", nargs="+", choices=SECTIONS, metavar="SECTION",
                        help=f"run only these sections ({', '.join(SECTIONS)})")
    parser.add_argument("--report-only", action="store_true",
                        help="run nothing: rewrite RESULTS.md and the plots from DIR/.experiments-cache")
    parser.add_argument("--jobs", type=int_in(1, MAX_JOBS), default=1, metavar="N",
                        help=f"worker processes for the peer comparison, 1..{MAX_JOBS} (the CPUs; default 1; budgets "
                             "are CPU time, so load does not change the results, only the run time: use at most one "
                             "per core)")
    parser.add_argument("--resume", action="store_true",
                        help="peer comparison: reuse the chunks of episodes an interrupted run left in "
                             "DIR/.experiments-cache/peers-chunks instead of starting afresh")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:  # an optional extra, imported only to say clearly that it is missing
        import matplotlib  # noqa: F401
    except ImportError:
        print("pomdp-planner: error: the experiments need matplotlib: pip install 'pomdp_planner[experiments]'",
              file=sys.stderr)
        return 2
    output = check_output_dir(args.output, "--output")
    if args.report_only and not cached_sections(output):
        raise ModelError(f"--report-only: {output / CACHE_DIR} holds no results to report (run the experiments "
                         "first, without --report-only)")
    try:
        data = run_all(output, quick=args.quick, progress=not args.no_progress,
                       sections=() if args.report_only else tuple(args.only) if args.only else SECTIONS,
                       jobs=args.jobs, resume=args.resume)
    except OSError as exc:  # a file of the output folder could not be written (disk full, permissions)
        where = f" {exc.filename}" if exc.filename else ""
        raise ModelError(f"--output: cannot write{where}: {exc.strerror or exc}") from None
    mode = "report only" if args.report_only else "quick mode" if args.quick else "full mode"
    print(f"wrote {args.output}/RESULTS.md ({mode}; "
          + ", ".join(f"{k} {v:.0f} s" for k, v in data["timings"].items()) + ")")
    return 0


def cached_sections(output: Path) -> list[str]:
    """The sections with a cached result in ``output``'s cache folder (any file ``<section>.*``)."""
    cache = output / CACHE_DIR
    if not cache.is_dir():
        return []
    return [name for name in SECTIONS if any(cache.glob(f"{name}.*"))]
