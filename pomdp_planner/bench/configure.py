"""Configure benchmark: what the planner node's ``configure`` does, stage by stage, cold, in one run.

``python -m pomdp_planner.bench.configure [--models ...] [--no-old] [--json FILE]``
(also ``pomdp-planner bench configure``)

For every model, in this one process and cold (nothing cached for it), it runs what the planner
node's ``configure`` runs (``nodes/planner.py``): the model file is loaded
(:func:`~pomdp_planner.core.io.sensors.load_model_file`) and the node's loop is built
(:class:`~pomdp_planner.core.loop.PlannerLoop`: the assumption gate's set-up estimate, the
Assumption 1 check, the bound LP and the planner's tables, each stage timed by the gate:
:attr:`~pomdp_planner.core.gate.PlannerSetup.seconds`), with the node's default parameters.
``comparison:S,A`` (the Sec. VI-B comparison model, ``core.domains.comparison``; the default
``comparison:256,64`` is the largest case of the paper's comparison) is written as a generator
model file first (``generator`` with the model's ``y``, ``reward_generator``), so that loading it
is part of the figure, as for a node.

Then one decision per belief (the uniform one and ``--beliefs - 1`` random ones) as the node
makes it (anytime, ``--time-budget`` and ``--max-depth``: the node's defaults). Unless
``--no-old``, the same for the planner with the fused leaf table (``Planner(fused=True)``, the
only way before ``FUSED_TABLE_MAX_BYTES``; ``core/search.py``, "Leaf tables") where the planner
now does without it: its table time, the configure total with it, their ratio, its decisions,
and whether both give the same depth-1 action on every belief (``same``; exit code 1 if not).

Timings on a shared machine are noisy: only ratios measured in one run are meaningful. Exit code
0, 1 if some depth-1 action differs between the two, 2 for a bad option or model.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..core.bounds import BOUND_VARIANTS, DEFAULT_CONSTANT
from ..core.checks import integer, number
from ..core.domains.comparison import comparison_y
from ..core.gate import STAGES
from ..core.io.sensors import load_model_file
from ..core.loop import Liveness, PlanJob, PlannerLoop
from ..core.one_line import Parser
from ..core.search import Planner
from .lp import add_json_argument, cell, run_compared

DEFAULT_MODELS = ("comparison:256,64", "perimeter_s8.yaml", "tracking_s8_info.yaml")
#: The planner node's defaults (nodes/planner.py), as its configure reads them.
NODE_PARAMS = {"time_budget": 0.1, "max_depth": 3, "use_bounds": True, "bound_variant": BOUND_VARIANTS[0],
               "bound_constant": DEFAULT_CONSTANT, "deadline_slack": 0.02}
NODE_CHUNK_BYTES = 1024 * 1024


def comparison_file(S: int, A: int, directory: Path) -> Path:
    """The comparison model ``comparison_model(S, A)`` as a generator model file in ``directory``."""
    doc = {"name": f"comparison_s{S}_a{A}", "discount": 0.99,
           "generator": {"domain": "tracking", "S": S, "A": A, "q": 0.8, "y": comparison_y(S, A).tolist()},
           "reward_generator": {"kind": "tracking_comparison"}, "uncertainty": {"function": "none"}}
    path = directory / f"comparison_s{S}_a{A}.yaml"
    path.write_text(yaml.safe_dump(doc, default_flow_style=None), encoding="utf-8")
    return path


def model_path(spec: str, directory: Path) -> Path | str:
    """The model file of ``spec``: ``comparison:S,A`` written by :func:`comparison_file`, else ``spec``."""
    m = re.fullmatch(r"comparison:(\d+),(\d+)", spec.strip())
    if m is None:
        return spec
    S, A = int(m.group(1)), int(m.group(2))
    return comparison_file(S, A, directory)


def beliefs(S: int, n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [np.full(S, 1.0 / S)] + [rng.dirichlet(np.ones(S)) for _ in range(n - 1)]


def _decisions(loop: PlannerLoop, bs: Sequence[np.ndarray]) -> tuple[float, int, list[int]]:
    """Median seconds and depth of the loop's decisions on ``bs`` (as the node's planning side makes
    them: :meth:`PlannerLoop.search`), and the planner's depth-1 actions."""
    times, depths = [], []
    for k, b in enumerate(bs):
        t0 = time.perf_counter()
        r = loop.search(PlanJob(k, b, 0.0, dict(loop.params))).result
        times.append(time.perf_counter() - t0)
        depths.append(r.depth)
    return statistics.median(times), int(statistics.median(depths)), [loop.setup.planner.search(b, 1).action
                                                                       for b in bs]


def configure(path: Path | str, chunk_bytes: int = NODE_CHUNK_BYTES) -> tuple[PlannerLoop, float, float]:
    """What the planner node's configure runs: ``(loop, seconds to load the file, seconds in all)``."""
    t0 = time.perf_counter()
    model = load_model_file(str(path), "--models")
    t1 = time.perf_counter()
    loop = PlannerLoop(model, NODE_PARAMS, Liveness(), now=0.0, chunk_bytes=chunk_bytes, active=False)
    return loop, t1 - t0, time.perf_counter() - t0


def run_configure_bench(models: Sequence[str] = DEFAULT_MODELS, old: bool = True, n_beliefs: int = 3,
                        time_budget: float = NODE_PARAMS["time_budget"], max_depth: int = NODE_PARAMS["max_depth"],
                        log: Any = lambda s: None) -> list[dict[str, Any]]:
    """One row per model (module docstring)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_configure_") as tmp:
        configure(model_path("comparison:4,3", Path(tmp)))  # the first call pays for imports: not timed
        for spec in models:
            path = model_path(spec, Path(tmp))
            loop, load_s, total = configure(path)
            m, setup = loop.model, loop.setup
            bs = beliefs(m.S, n_beliefs)
            loop.set_params({"time_budget": time_budget, "max_depth": max_depth})
            dec_s, depth, actions = _decisions(loop, bs)
            row: dict[str, Any] = {
                "model": m.name, "S": m.S, "A": m.A, "Z": m.Z, "load": load_s,
                **{stage: setup.seconds.get(stage) for stage in STAGES}, "total": total, "mode": setup.mode,
                "fused": setup.planner.fused, "decision": dec_s, "depth": depth,
                "old_tables": None, "old_total": None, "old_decision": None, "old_depth": None, "same": None,
            }
            if old and not setup.planner.fused:
                t0 = time.perf_counter()
                fused = Planner(m, setup.myopic, chunk_bytes=NODE_CHUNK_BYTES, guaranteed=setup.guaranteed,
                                fused=True)
                old_tables = time.perf_counter() - t0
                loop.setup = replace(setup, planner=fused)  # the node's loop with the old planner
                old_dec, old_depth, old_actions = _decisions(loop, bs)
                loop.setup = setup
                del fused
                row.update(old_tables=old_tables, old_total=total - setup.seconds["planner tables"] + old_tables,
                           old_decision=old_dec, old_depth=old_depth, same=old_actions == actions)
            log(f"{m.name}: configure {total:.2f} s")
            rows.append(row)
    return rows


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    head = (f"{'model':<20} {'S':>4} {'A':>3} {'Z':>4} {'load':>6} {'est.':>6} {'check':>6} {'LP':>6} "
            f"{'tables':>7} {'total':>7} {'decide':>7} {'d':>2} | {'old tbl':>7} {'old tot':>7} {'old/new':>7} "
            f"{'old dec':>7} {'d':>2} {'same':<4}")
    lines = [head, "-" * len(head)]
    for r in rows:
        ratio = None if r["old_total"] is None else r["old_total"] / r["total"]
        same = "-" if r["same"] is None else ("yes" if r["same"] else "NO")
        stage = [f"{cell(r[s], '.2f'):>6}" for s in ("estimate", "assumption check", "bound LP")]
        lines.append(f"{r['model']:<20} {r['S']:>4} {r['A']:>3} {r['Z']:>4} {r['load']:>6.2f} {' '.join(stage)} "
                     f"{cell(r['planner tables'], '.2f'):>7} {r['total']:>7.2f} {r['decision']:>7.3f} "
                     f"{r['depth']:>2} | "
                     f"{cell(r['old_tables'], '.2f'):>7} {cell(r['old_total'], '.2f'):>7} "
                     f"{cell(ratio, '.1f') + ('x' if ratio else ''):>7} {cell(r['old_decision'], '.3f'):>7} "
                     f"{cell(r['old_depth'], 'd'):>2} {same:<4}")
    lines.append("Seconds, wall clock, cold, one process. load: the model file; est., check, LP, tables: the gate's "
                 "stages (estimate, Assumption 1, bound LP, planner tables); total: load + loop (what the planner "
                 "node's configure runs); decide: median anytime decision (d: its median depth). old: with the fused "
                 "leaf table (only where the planner now does without it); same: equal depth-1 actions.")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options (``pomdp-planner bench configure`` and ``python -m pomdp_planner.bench.configure``)."""
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS), metavar="MODEL",
                        help="'comparison:S,A' or model files (default: %(default)s)")
    parser.add_argument("--no-old", action="store_true", help="do not time the planner with the fused leaf table")
    parser.add_argument("--beliefs", type=integer, default=3, metavar="N", help="decisions per model (3)")
    parser.add_argument("--time-budget", type=number, default=NODE_PARAMS["time_budget"], metavar="S",
                        help="seconds per decision (the node's default, %(default)s)")
    parser.add_argument("--max-depth", type=integer, default=NODE_PARAMS["max_depth"], metavar="D",
                        help="deepest search of a decision (the node's default, %(default)s)")
    add_json_argument(parser)


def run_from_args(args: argparse.Namespace, prog: str) -> int:
    for name, value, low in (("--beliefs", args.beliefs, 1), ("--max-depth", args.max_depth, 1)):
        if value < low:
            print(f"{prog}: error: {name}: must be >= {low}, got {value}", file=sys.stderr)
            return 2
    if not args.time_budget > 0:
        print(f"{prog}: error: --time-budget: must be > 0, got {args.time_budget}", file=sys.stderr)
        return 2
    return run_compared(prog, args.json, lambda log: run_configure_bench(
        args.models, not args.no_old, args.beliefs, args.time_budget, args.max_depth, log=log), format_table)


def main(argv: Sequence[str] | None = None) -> int:
    prog = "python -m pomdp_planner.bench.configure"
    parser = Parser(prog=prog, description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run_from_args(parser.parse_args(argv), prog)


if __name__ == "__main__":
    sys.exit(main())
