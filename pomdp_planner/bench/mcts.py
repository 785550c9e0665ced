"""Benchmark of the belief-space MCTS (``core/belief_mcts.py``): speed, tuning, closed loop.

``python -m pomdp_planner.bench.mcts`` prints the throughput table: simulations per second of
:class:`~pomdp_planner.core.belief_mcts.BeliefMCTS` on the shipped ``S = 3`` and ``S = 8``
tracking models for each leaf evaluation (median over seeded random beliefs, a fixed number of
simulations per search, fresh tree each time), with the tree depth reached and the nodes
created per second.

``--tune`` measures decision quality at equal wall-clock time on the ``S = 3`` model against
a reference policy, the grid policy iteration of ``core/reference.py``
(:func:`~pomdp_planner.core.reference.reference_policy`): on grid beliefs where the reference
decides the action (its Q gap exceeds the measured tie margin), all those where greedy is
wrong plus a seeded sample of the others, the mean loss ``Q*(b, a*) - Q*(b, a_mcts)`` and the
share of optimal decisions, for each configuration (leaf evaluation, rollout depth,
exploration scale, maximum depth) and budget. The defaults of ``core/belief_mcts.py`` were
chosen from this table (one run: docs/benchmarks.md, "Belief-space MCTS").

``--closed-loop`` runs seeded closed-loop episodes (``core.simulate.simulate``, true belief
reward ``rho``) of the MCTS policy at each budget per decision and of greedy, and prints the
mean discounted return with a 95 % confidence interval (common random numbers: episode ``k``
has seed ``k`` for every policy).

Everything runs in this process; timings on a shared machine are noisy, compare figures of
one run.
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..core.belief_mcts import BeliefMCTS, BeliefMCTSPolicy, rho_range
from ..core.checks import integer, number
from ..core.io.model_yaml import load_model
from ..core.io.paths import resolve_path
from ..core.model import POMDP
from ..core.one_line import Parser
from ..core.policies import MyopicPolicy
from ..core.simulate import simulate
from .stats import mean_ci

DEFAULT_MODELS = ("tracking_s3_info", "tracking_s8_info")
#: Configurations of the throughput table: (label, BeliefMCTS keyword arguments).
THROUGHPUT_CONFIGS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("default (bellman, rollout 1, max depth 3)", {}),
    ("bellman, rho leaf, max depth 3", {"leaf": "rho"}),
    ("bellman, rollout 1, max depth 50", {"max_depth": 50}),
    ("bellman, rollout 3, max depth 50", {"max_depth": 50, "rollout_depth": 3}),
    ("bellman, rollout 10, max depth 50", {"max_depth": 50, "rollout_depth": 10}),
    ("mean, rollout 3, max depth 50", {"backup": "mean", "max_depth": 50, "rollout_depth": 3}),
)
#: Configurations compared by ``--tune``: (label, keyword arguments).
TUNE_CONFIGS: tuple[tuple[str, dict[str, Any]], ...] = (
    *((f"bellman, rollout 1, max depth {d}", {"backup": "bellman", "rollout_depth": 1, "max_depth": d})
      for d in (2, 3, 4, 6, 50)),
    *((f"bellman, rollout 1, max depth 3, c x{c:g}",
       {"backup": "bellman", "rollout_depth": 1, "max_depth": 3, "exploration_scale": c}) for c in (0.3, 3.0)),
    ("bellman, rollout 0, max depth 3", {"backup": "bellman", "rollout_depth": 0, "max_depth": 3}),
    ("bellman, rollout 3, max depth 3", {"backup": "bellman", "rollout_depth": 3, "max_depth": 3}),
    ("mean, rollout 1, max depth 3", {"backup": "mean", "rollout_depth": 1, "max_depth": 3}),
    ("mean, rollout 1, max depth 50", {"backup": "mean", "rollout_depth": 1, "max_depth": 50}),
    ("mean, rollout 3, max depth 50, c x3",
     {"backup": "mean", "rollout_depth": 3, "max_depth": 50, "exploration_scale": 3.0}),
)


def _model(name: str) -> POMDP:
    """A shipped model's name or a model file (``core.io.paths.resolve_path``)."""
    return load_model(resolve_path(name, "--model"))


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    cells = [[str(h) for h in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True)))
             for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


# ------------------------------------------------------------------ throughput
def throughput(models: Sequence[str], simulations: int = 5000, beliefs: int = 5, seed: int = 0,
               log: Callable[[str], None] = lambda s: None) -> list[dict[str, Any]]:
    """Simulations per second for each model and leaf configuration (median over beliefs)."""
    rows = []
    for name in models:
        model = _model(name)
        B = np.random.default_rng(seed).dirichlet(np.ones(model.S), size=beliefs)
        for label, kw in THROUGHPUT_CONFIGS:
            rates, depths, nodes = [], [], []
            for i, b in enumerate(B):
                planner = BeliefMCTS(model, seed=seed + i, **kw)
                res = planner.search(b, simulations=simulations)
                rates.append(res.simulations / res.time_used)
                depths.append(res.depth)
                nodes.append(res.nodes)
            row = {"model": model.name, "S": model.S, "config": label, "simulations": simulations,
                   "sims_per_s": statistics.median(rates), "depth": statistics.median(depths),
                   "nodes": statistics.median(nodes)}
            log(f"{model.name} {label}: {row['sims_per_s']:.0f} sims/s")
            rows.append(row)
    return rows


def throughput_table(rows: Sequence[dict[str, Any]]) -> str:
    return _table(("model", "configuration", "sims/s", "us/sim", "tree depth", "nodes created"),
                  [(r["model"], r["config"], f"{r['sims_per_s']:.0f}", f"{1e6 / r['sims_per_s']:.1f}",
                    f"{r['depth']:.0f}", f"{r['nodes']:.0f}") for r in rows])


# ------------------------------------------------------------------ tuning
def tuning_beliefs(model: POMDP, n: int = 30, count: int = 100, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """Decided reference beliefs (module docstring) and the reference Q* there.

    Returns ``(beliefs, Q*, tie_margin)``: every decided grid belief where greedy is not optimal,
    then a seeded sample of the other decided ones, ``count`` in all.
    """
    from ..core.reference import reference_policy

    ref = reference_policy(model, n)
    greedy = np.argmax(model.rho(ref.beliefs), axis=1)
    decided = np.flatnonzero(ref.decided)
    wrong = decided[greedy[decided] != ref.actions[decided]]
    right = decided[greedy[decided] == ref.actions[decided]]
    rng = np.random.default_rng(seed)
    take = rng.choice(right, size=max(0, min(right.size, count - wrong.size)), replace=False)
    idx = np.concatenate([wrong, np.sort(take)])[:count]
    return ref.beliefs[idx], ref.Q[idx], float(ref.tie_margin)


def tune(model_name: str = "tracking_s3_info", budgets: Sequence[float] = (0.01, 0.05, 0.2), count: int = 100,
         configs: Sequence[tuple[str, dict[str, Any]]] = TUNE_CONFIGS, seed: int = 0,
         log: Callable[[str], None] = lambda s: None) -> list[dict[str, Any]]:
    """Mean Q* loss and share of optimal decisions of each configuration at each budget."""
    model = _model(model_name)
    B, Q, margin = tuning_beliefs(model, count=count, seed=seed)
    best = Q.max(axis=1)
    greedy = np.argmax(model.rho(B), axis=1)
    rows = [{"config": "greedy", "budget": 0.0, "loss": float(np.mean(best - Q[np.arange(len(B)), greedy])),
             "optimal": float(np.mean(Q[np.arange(len(B)), greedy] >= best - margin)), "sims": 0.0}]
    log(f"{len(B)} beliefs, tie margin {margin:.2e}, greedy loss {rows[0]['loss']:.4f}")
    for label, kw in configs:
        for budget in budgets:
            planner = BeliefMCTS(model, seed=seed, **kw)
            acts, sims = [], []
            for b in B:
                res = planner.search(b, time_budget=budget)
                acts.append(res.action)
                sims.append(res.simulations)
            q = Q[np.arange(len(B)), acts]
            rows.append({"config": label, "budget": budget, "loss": float(np.mean(best - q)),
                         "optimal": float(np.mean(q >= best - margin)), "sims": float(np.median(sims))})
            log(f"{label} @ {budget:g} s: loss {rows[-1]['loss']:.4f}, optimal {rows[-1]['optimal']:.2f}")
    return rows


def tune_table(rows: Sequence[dict[str, Any]]) -> str:
    return _table(("configuration", "budget s", "mean Q* loss", "optimal", "median sims"),
                  [(r["config"], f"{r['budget']:g}", f"{r['loss']:.4f}", f"{100 * r['optimal']:.0f} %",
                    f"{r['sims']:.0f}") for r in rows])


# ------------------------------------------------------------------ closed loop
def _mean_ci(x: Sequence[float]) -> tuple[float, float]:
    """Mean and half-width of its 95 % Student-t interval (:func:`.stats.mean_ci`)."""
    m, (lo, hi) = mean_ci(np.asarray(x, dtype=float))
    return m, (hi - lo) / 2.0


def closed_loop(model_name: str = "tracking_s3_info", budgets: Sequence[float] = (0.01, 0.05, 0.2, 1.0),
                episodes: int = 20, steps: int = 50, options: dict[str, Any] | None = None,
                log: Callable[[str], None] = lambda s: None) -> list[dict[str, Any]]:
    """Mean discounted return (95 % CI) of greedy and of the MCTS policy at each budget."""
    model = _model(model_name)
    rows = []
    greedy = [simulate(model, MyopicPolicy(model), steps, seed=k).discounted_return for k in range(episodes)]
    m, h = _mean_ci(greedy)
    rows.append({"policy": "greedy", "budget": 0.0, "mean": m, "ci": h, "sims": 0.0, "depth": 0.0,
                 "agree": 1.0, "diff": 0.0, "diff_ci": 0.0})
    log(f"greedy: {m:.3f} +- {h:.3f}")
    for budget in budgets:
        returns, sims, depths, agree = [], [], [], []
        for k in range(episodes):
            policy = BeliefMCTSPolicy(BeliefMCTS(model, seed=k, **(options or {})), time_budget=budget)
            stats: list[tuple[int, int, int]] = []

            def act(b: np.ndarray, policy: BeliefMCTSPolicy = policy, stats: list = stats) -> int:
                a = policy.act(b)
                stats.append((policy.last.simulations, policy.last.depth, int(a == int(np.argmax(model.rho(b))))))
                return a

            returns.append(simulate(model, act, steps, seed=k).discounted_return)
            sims += [s[0] for s in stats]
            depths += [s[1] for s in stats]
            agree += [s[2] for s in stats]
        m, h = _mean_ci(returns)
        dm, dh = _mean_ci(np.asarray(returns) - np.asarray(greedy))
        rows.append({"policy": "mcts", "budget": budget, "mean": m, "ci": h, "sims": float(np.median(sims)),
                     "depth": float(np.median(depths)), "agree": float(np.mean(agree)), "diff": dm, "diff_ci": dh})
        log(f"mcts @ {budget:g} s: {m:.3f} +- {h:.3f} (vs greedy {dm:+.3f} +- {dh:.3f})")
    return rows


def closed_loop_table(rows: Sequence[dict[str, Any]]) -> str:
    return _table(("policy", "budget s", "mean return", "95 % CI", "minus greedy (paired)", "median sims",
                   "median depth", "same action as greedy"),
                  [(r["policy"], f"{r['budget']:g}", f"{r['mean']:.3f}", f"+-{r['ci']:.3f}",
                    f"{r['diff']:+.3f} +-{r['diff_ci']:.3f}", f"{r['sims']:.0f}", f"{r['depth']:.0f}",
                    f"{100 * r['agree']:.1f} %") for r in rows])


# ------------------------------------------------------------------ command line
def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m pomdp_planner.bench.mcts", description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", action="append", default=None,
                        help="shipped model name or model file (repeatable)")
    parser.add_argument("--simulations", type=integer, default=5000, help="simulations per timed search (5000)")
    parser.add_argument("--beliefs", type=integer, default=5, help="random beliefs per throughput row (5)")
    parser.add_argument("--tune", action="store_true", help="decision quality against the S = 3 grid optimum")
    parser.add_argument("--closed-loop", action="store_true", help="closed-loop returns against greedy")
    parser.add_argument("--budgets", type=number, nargs="+", default=None, help="seconds per decision")
    parser.add_argument("--episodes", type=integer, default=20, help="closed-loop episodes (20)")
    parser.add_argument("--steps", type=integer, default=50, help="closed-loop steps per episode (50)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = parser.parse_args(argv)
    for name, value in (("simulations", args.simulations), ("beliefs", args.beliefs), ("episodes", args.episodes),
                        ("steps", args.steps)):
        if value < 1:
            parser.error(f"--{name}: must be >= 1, got {value}")
    if args.budgets is not None and any(not (b > 0.0 and math.isfinite(b)) for b in args.budgets):
        parser.error(f"--budgets: must be positive numbers of seconds, got {args.budgets}")
    log = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    models = args.model or list(DEFAULT_MODELS)
    try:  # every name found before the first run
        for name in models:
            resolve_path(name, "--model")
    except ValueError as exc:
        parser.error(str(exc))
    t0 = time.perf_counter()
    if args.tune:
        budgets = args.budgets or (0.01, 0.05, 0.2)
        print(tune_table(tune(models[0], budgets, log=log)))
    elif args.closed_loop:
        budgets = args.budgets or (0.01, 0.05, 0.2, 1.0)
        for name in models:
            print(f"\n{name}: {args.episodes} episodes x {args.steps} steps, discounted return of rho")
            print(closed_loop_table(closed_loop(name, budgets, args.episodes, args.steps, log=log)))
    else:
        print(throughput_table(throughput(models, args.simulations, args.beliefs, log=log)))
        for name in models:
            model = _model(name)
            print(f"{model.name}: rho range {rho_range(model):.3f} (UCB1 constant c = scale x range)")
    log(f"done in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
