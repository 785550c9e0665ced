"""``pomdp-planner bench search|all``: benchmarks and experiments.

``bench search [--json FILE] [--quick]`` is the search benchmark (paper Table II, timings,
throughput), the same as ``python bench/search_bench.py`` (``pomdp_planner/bench/search_bench.py``).
``bench all`` regenerates docs/RESULTS.md (``pomdp_planner/cli/experiments.py``, issue 6).
"""

from __future__ import annotations

import argparse
import sys

from ..bench import search_bench


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("bench", help="benchmarks (search: pruning, timings, throughput)",
                              description="Benchmarks. 'bench search' reproduces the paper's Table II "
                              "and measures the speed of branch-and-bound and exhaustive search.")
    sub = p.add_subparsers(dest="bench", metavar="BENCH")
    sub.required = True
    s = sub.add_parser("search", help="Table II pruning, timings, agreement and throughput of the search",
                       description=search_bench.__doc__.split("\n\n")[0])
    search_bench.add_arguments(s)
    s.set_defaults(func=_run_search)
    from . import experiments  # issue 6: every experiment -> docs/RESULTS.md (cli/experiments.py)

    experiments.add_arguments(sub.add_parser("all", help="all experiments: docs/RESULTS.md and docs/img/*.png",
                                             description=experiments.__doc__.split("\n\n")[0]))


def _run_search(args: argparse.Namespace) -> int:
    try:
        return search_bench.run_from_args(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"pomdp-planner bench search: error: {exc}", file=sys.stderr)
        return 2
