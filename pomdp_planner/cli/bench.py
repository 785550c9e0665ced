"""``pomdp-planner bench search|structure|configure|scale|multitarget|all``: benchmarks and experiments.

``bench search [--json FILE] [--quick]`` is the search benchmark (paper Table II, timings,
throughput; ``pomdp_planner/bench/search.py``, also ``python -m pomdp_planner.bench.search``).
``bench structure`` times the Assumption 1 check, fast path against the previous one
(``pomdp_planner/bench/structure.py``).
``bench configure`` times what the planner node's configure runs, stage by stage
(``pomdp_planner/bench/configure.py``).
``bench scale [--suite scale|setup] [--models ...]`` times loading, the set-up (estimate beside the
stages) and decisions from S = 8 to a 100 x 100 grid, one process per model
(``pomdp_planner/bench/scale.py``).
``bench multitarget [--quick] [--json FILE] [--plot FILE]`` is the multi-target benchmark (dual
bound against the exact joint lookahead, closed-loop regret, decision time against K;
``pomdp_planner/bench/multitarget.py``).
``bench all`` writes every experiment into ``--output DIR`` (``RESULTS.md``, ``img/*.png``;
``pomdp_planner/bench/experiments/``, through ``pomdp_planner/cli/experiments.py``).
"""

from __future__ import annotations

import argparse
import sys

from ..bench import configure as configure_bench
from ..bench import multitarget as multitarget_bench
from ..bench import scale as scale_bench
from ..bench import search as search_bench
from ..bench import structure as structure_bench
from . import experiments


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
    t = sub.add_parser("structure", help="the Assumption 1 check: fast path against the previous one",
                       description=structure_bench.__doc__.split("\n\n")[0])
    structure_bench.add_arguments(t)
    t.set_defaults(func=lambda args: structure_bench.run_from_args(args, "pomdp-planner bench structure"))
    c = sub.add_parser("configure", help="the planner node's configure, stage by stage, cold",
                       description=configure_bench.__doc__.split("\n\n")[0])
    configure_bench.add_arguments(c)
    c.set_defaults(func=lambda args: configure_bench.run_from_args(args, "pomdp-planner bench configure"))
    sc = sub.add_parser("scale", help="load, set-up (estimate and stages), memory and decisions from S = 8 to 10 000",
                        description=scale_bench.__doc__.split("\n\n")[0])
    scale_bench.add_arguments(sc)
    sc.set_defaults(func=lambda args: scale_bench.run_from_args(args, "pomdp-planner bench scale"))
    m = sub.add_parser("multitarget", help="several targets, one budget: dual bound, regret, scaling",
                       description=multitarget_bench.__doc__.split("\n\n")[0])
    multitarget_bench.add_arguments(m)
    m.set_defaults(func=_run_multitarget)
    experiments.add_arguments(sub.add_parser("all", help="all experiments: RESULTS.md and img/*.png in --output DIR",
                                             description=experiments.__doc__.split("\n\n")[0]))


def _run_multitarget(args: argparse.Namespace) -> int:
    try:
        return multitarget_bench.run_from_args(args)
    except (ValueError, OSError) as exc:  # a bad option; an unwritable --json or --plot
        print(f"pomdp-planner bench multitarget: error: {exc}", file=sys.stderr)
        return 2


def _run_search(args: argparse.Namespace) -> int:
    try:
        return search_bench.run_from_args(args)
    except (ValueError, OSError) as exc:  # ModelError included: a bad option or model file; an unwritable --json
        print(f"pomdp-planner bench search: error: {exc}", file=sys.stderr)
        return 2
