"""Multi-target benchmark: the dual bound against the exact joint lookahead, closed-loop regret of
the planner and the baselines, and decision time against the number of targets.

``pomdp-planner bench multitarget [--quick] [--json FILE] [--plot FILE]`` (also
``python -m pomdp_planner.bench.multitarget``). Four parts, all seeded:

1. **Bounds** (K = 2, 3 targets on the S = 3 perimeter and tracking models, budgets that bind):
   random beliefs (Dirichlet with a random concentration), prices 0, random ones and the
   planner's own; every per-target search exhaustive, so the dual bound must be an upper bound on
   the exact joint lookahead value ``V*`` (``core/multitarget/joint_exact.py``). Counted:
   ``dual_bound_violations`` (``U < V*``), ``lagrangian_violations`` (``L < U``),
   ``lower_bound_violations`` (the reported lower bound above the chosen joint action's exact
   value ``Q*(a)``) and ``gap_violations`` (``V* - Q*(a)`` above the reported gap). Also measured:
   the decision regret ``V* - Q*(a)``, the bound excess ``U - V*`` and the reported gap, and with
   branch-and-bound values how often the estimate falls below ``V*`` (no guarantee there).
2. **Sanity** (before any number counts): (a) a budget that admits one joint action only: every
   policy has the same return in every episode; (b) a budget that cannot bind, identical targets:
   the planner, the fixed-price planner, the equal split and the exact joint planner all take the
   K independent exhaustive decisions at every step; (c) greedy equals the exact joint planner at
   depth 0. A policy whose check fails is reported as such and its regret is not shown.
3. **Regret** (closed loop, common random numbers: ``core/multitarget/simulate.py``): per episode
   ``return(exact joint) - return(policy)`` at the same depth, mean and 95 % Student-t interval
   (``bench/stats.py``), on mixes where the budget binds and lookahead pays.
4. **Scaling** (S = 8: ``perimeter_s8`` and ``tracking_s8_natural`` alternating, discount 0.95,
   budget K, default efforts): the median decision time at a fixed depth for K = 2 ... 64
   (growing linearly in K: the per-target searches are independent), and the depth one time
   budget reaches.

``budget_violations`` counts the epochs of every closed-loop run (every policy) and every decision
of part 1 whose effort exceeds the budget. Timings on a shared machine are noisy: compare the
ratios of one run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from ..core.io.model_yaml import load_model
from ..core.io.outputs import check_output_file, write_text_file
from ..core.io.paths import shipped_model_path
from ..core.model import POMDP
from ..core.multitarget.joint_exact import ExactJointPlanner
from ..core.multitarget.planner import MultiTargetPlanner
from ..core.multitarget.policies import make_joint_policy
from ..core.multitarget.problem import MultiTargetProblem, make_problem
from ..core.multitarget.simulate import simulate_targets
from ..core.search import Planner
from .stats import mean_ci

#: The policies of the regret table, with their options (depth filled in per case).
POLICIES = (
    ("exact_joint", "exact_joint", {}),
    ("lagrangian (exhaustive)", "lagrangian", {"search": "exhaustive"}),
    ("lagrangian (bnb)", "lagrangian", {"search": "bnb"}),
    ("lagrangian (lower-bound ties)", "lagrangian", {"search": "exhaustive", "tie_break": "lower_bound"}),
    ("fixed_price", "fixed_price", {"search": "bnb"}),
    ("greedy", "greedy", None),
    ("equal_split", "equal_split", {"search": "bnb"}),
    ("round_robin", "round_robin", None),
)

#: The paired differences of the return the regret part reports per case (first minus second).
PAIRS = (
    ("fixed_price", "lagrangian (exhaustive)"),
    ("lagrangian (lower-bound ties)", "lagrangian (exhaustive)"),
    ("lagrangian (lower-bound ties)", "fixed_price"),
)


@dataclass(frozen=True)
class Case:
    """A problem of the benchmark: shipped model names, budget and the lookahead depth(s)."""

    name: str
    models: tuple[str, ...]
    budget: str
    depths: tuple[int, ...]


BOUND_CASES = (
    Case("perimeter x2, B=2", ("perimeter_s3", "perimeter_s3"), "2", (1, 2, 3)),
    Case("perimeter + tracking, B=1", ("perimeter_s3", "tracking_s3_info"), "1", (1, 2, 3)),
    Case("perimeter x2 + tracking, B=2", ("perimeter_s3", "perimeter_s3", "tracking_s3_info"), "2", (1, 2)),
)
REGRET_CASES = (
    Case("perimeter x2, B=2", ("perimeter_s3", "perimeter_s3"), "2", (2,)),
    Case("perimeter + tracking, B=1", ("perimeter_s3", "tracking_s3_info"), "1", (2,)),
    Case("perimeter x2 + tracking, B=2", ("perimeter_s3", "perimeter_s3", "tracking_s3_info"), "2", (1,)),
)
SCALING_MODELS = ("perimeter_s8", "tracking_s8_natural")
#: The parts a run may be limited to (``--only``): the bound check, sanity and regret, scaling.
PARTS = ("bounds", "regret", "scaling")


@dataclass(frozen=True)
class MultiBenchConfig:
    """What the benchmark measures (defaults: the full run; :meth:`quick`: a smoke run)."""

    bound_beliefs: int = 100
    bound_prices: int = 3
    episodes: int = 100
    steps: int = 60
    scaling_targets: tuple[int, ...] = (2, 4, 8, 16, 32, 64, 128, 256)
    scaling_depth: int = 2
    scaling_decisions: int = 7
    tie_episodes: int = 20
    time_budget: float = 0.5
    discount: float = 0.95
    seed: int = 0
    bound_cases: tuple[Case, ...] = field(default=BOUND_CASES)
    regret_cases: tuple[Case, ...] = field(default=REGRET_CASES)

    @classmethod
    def quick(cls) -> MultiBenchConfig:
        return cls(bound_beliefs=12, bound_prices=2, episodes=6, steps=15, scaling_targets=(2, 4, 8, 16),
                   tie_episodes=2, scaling_decisions=2, time_budget=0.2, bound_cases=BOUND_CASES[:2],
                   regret_cases=REGRET_CASES[:2])


_MODELS: dict[str, POMDP] = {}


def _model(name: str) -> POMDP:
    if name not in _MODELS:
        _MODELS[name] = load_model(shipped_model_path(name))
    return _MODELS[name]


def _problem(names: Sequence[str], budget: str, discount: float) -> MultiTargetProblem:
    return make_problem([_model(n) for n in names], budget=budget, discount=discount)


def _stat(x: Sequence[float]) -> dict[str, Any]:
    m, (lo, hi) = mean_ci(np.asarray(x, dtype=float))
    return {"mean": m, "ci": [lo, hi], "n": len(x)}


# ----------------------------------------------------------------------------- 1. bounds
def bench_bounds(config: MultiBenchConfig, log: Callable[[str], None]) -> dict[str, Any]:
    """Part 1 (module docstring)."""
    counts = {"checks": 0, "dual_bound_violations": 0, "lagrangian_violations": 0, "lower_bound_violations": 0,
              "gap_violations": 0, "budget_violations": 0, "bnb_estimates": 0, "bnb_estimates_below_exact": 0}
    rows = []
    rng = np.random.default_rng(config.seed)

    def above(upper: float, value: float) -> bool:
        return upper >= value - 1e-9 * max(1.0, abs(value))

    for case in config.bound_cases:
        problem = _problem(case.models, case.budget, config.discount)
        for depth in case.depths:
            t0 = time.perf_counter()
            exact = MultiTargetPlanner(problem, search="exhaustive", depth=depth)
            bnb = MultiTargetPlanner(problem, search="bnb", depth=depth)
            joint = ExactJointPlanner(problem, depth)
            regret, excess, gaps = [], [], []
            for _ in range(config.bound_beliefs):
                bs = [rng.dirichlet(np.ones(m.S) * rng.choice([0.3, 1.0, 3.0])) for m in problem.models]
                q = joint.q_values(bs)
                v = float(q.max())
                dec = exact.decide(bs)
                for lam in (0.0, dec.lam, *rng.exponential(max(dec.lam, 0.05) * 2, config.bound_prices)):
                    ev = exact.evaluate(bs, float(lam), depth)
                    counts["checks"] += 1
                    counts["dual_bound_violations"] += not above(ev.dual_bound, v)
                    counts["lagrangian_violations"] += not above(ev.lagrangian, ev.dual_bound)
                    counts["budget_violations"] += not problem.within_budget(ev.actions)
                q_a = float(q[joint.actions.index(dec.actions)])
                counts["lower_bound_violations"] += not above(q_a, dec.lower_bound)
                counts["gap_violations"] += not above(dec.gap, v - q_a)
                counts["budget_violations"] += not problem.within_budget(dec.actions)
                regret.append(v - q_a)
                excess.append(dec.dual_bound - v)
                gaps.append(dec.gap)
                est = bnb.decide(bs)
                counts["bnb_estimates"] += 1
                counts["bnb_estimates_below_exact"] += not above(est.dual_bound, v)
                counts["budget_violations"] += not problem.within_budget(est.actions)
            row = {"case": case.name, "K": problem.K, "depth": depth, "beliefs": config.bound_beliefs,
                   "decision_regret": _stat(regret), "decision_regret_max": float(max(regret)),
                   "optimal_share": float(np.mean(np.asarray(regret) <= 1e-9)),
                   "bound_excess": _stat(excess), "reported_gap": _stat(gaps),
                   "value_scale": float(np.mean(np.abs([joint.value([rng.dirichlet(np.ones(m.S))
                                                                     for m in problem.models])
                                                        for _ in range(5)])))}
            rows.append(row)
            log(f"bounds {case.name} depth {depth}: {time.perf_counter() - t0:.1f} s")
    return {**counts, "rows": rows}


# ----------------------------------------------------------------------------- 2. sanity
def _decisions_match(problem: MultiTargetProblem, policy: Any, reference: Callable[[list[np.ndarray]], tuple],
                     steps: int, seed: int) -> bool:
    class Checked:
        ok = True
        last = None

        def act(self, beliefs):
            a = policy.act(beliefs)
            self.ok &= tuple(a) == tuple(reference(beliefs))
            return a

    checked = Checked()
    simulate_targets(problem, checked, steps, seed)
    return checked.ok


def bench_sanity(config: MultiBenchConfig, log: Callable[[str], None]) -> dict[str, Any]:
    """Part 2 (module docstring): which policies pass the known-optimum checks."""
    checks: dict[str, dict[str, bool]] = {}
    steps, episodes = min(config.steps, 15), min(config.episodes, 3)
    # (a) one feasible joint action: efforts 0 only at the lowest priority, budget 0.
    one = _problem(("perimeter_s3", "tracking_s3_info"), "0", config.discount)
    returns = {}
    for label, name, opts in POLICIES:
        kw = {} if opts is None else {**opts, "depth": 1}
        returns[label] = [simulate_targets(one, make_joint_policy(name, one, **kw), steps, seed)[1]["discounted_return"]
                          for seed in range(episodes)]
    first = next(iter(returns.values()))
    for label, r in returns.items():
        checks.setdefault(label, {})["single_joint_action"] = bool(np.allclose(r, first, rtol=0, atol=1e-12))
    # (b) a budget that cannot bind, identical targets: K independent exhaustive decisions.
    free = _problem(("perimeter_s3", "perimeter_s3"), "4", config.discount)
    singles = [Planner(m) for m in free.models]
    depth = 2

    def independent(bs):
        return tuple(p.search(b, depth, use_bounds=False).action for p, b in zip(singles, bs, strict=True))

    for label, name, opts in POLICIES:
        if opts is None:  # greedy, round_robin: no lookahead, no depth-d optimum to find
            continue
        # Pruning may choose another action than the depth-d optimum (docs/THEORY.md), so the check runs
        # the policy's own code with exhaustive searches.
        kw = {**opts, "depth": depth, **({"search": "exhaustive"} if "search" in opts else {})}
        policy = make_joint_policy(name, free, **kw)
        checks[label]["independent_optimum"] = _decisions_match(free, policy, independent, steps, config.seed)
    # (c) greedy = the exact joint planner at depth 0 (the best joint action for sum rho within the budget).
    tight = _problem(("perimeter_s3", "tracking_s3_info"), "1", config.discount)
    zero = ExactJointPlanner(tight, 0)
    checks["greedy"]["one_step_optimum"] = _decisions_match(tight, make_joint_policy("greedy", tight),
                                                            lambda bs: zero.act(bs), steps, config.seed)
    passed = {label: all(c.values()) for label, c in checks.items()}
    log(f"sanity: {sum(passed.values())} of {len(passed)} policies pass")
    return {"checks": checks, "passed": passed}


# ----------------------------------------------------------------------------- 3. regret
def bench_regret(config: MultiBenchConfig, log: Callable[[str], None]) -> dict[str, Any]:
    """Part 3 (module docstring): per case and policy, the regret against the exact joint planner."""
    out = []
    violations = 0
    for case in config.regret_cases:
        problem = _problem(case.models, case.budget, config.discount)
        depth = case.depths[0]
        returns: dict[str, np.ndarray] = {}
        times: dict[str, float] = {}
        for label, name, opts in POLICIES:
            kw = {} if opts is None else {**opts, "depth": depth}
            t0 = time.perf_counter()
            r = []
            for ep in range(config.episodes):
                _, summary = simulate_targets(problem, make_joint_policy(name, problem, **kw), config.steps,
                                                  config.seed + ep)
                violations += summary["budget_violations"]
                r.append(summary["discounted_return"])
            returns[label] = np.asarray(r)
            times[label] = (time.perf_counter() - t0) / (config.episodes * max(config.steps, 1))
            log(f"regret {case.name} {label}: {time.perf_counter() - t0:.1f} s")
        ref = returns["exact_joint"]
        rows = {label: {"return": _stat(r), "regret_vs_exact": _stat(ref - r), "ms_per_step": 1e3 * times[label]}
                for label, r in returns.items()}
        paired = [{"first": a, "second": b, "difference": _stat(returns[a] - returns[b])} for a, b in PAIRS]
        out.append({"case": case.name, "K": problem.K, "budget": case.budget, "depth": depth,
                    "episodes": config.episodes, "steps": config.steps, "policies": rows, "paired": paired,
                    "ties": bench_ties(case.name, problem, depth, config, log)})
    return {"cases": out, "budget_violations": violations}


def bench_ties(name: str, problem: MultiTargetProblem, depth: int, config: MultiBenchConfig,
               log: Callable[[str], None]) -> dict[str, Any]:
    """Where the price that minimises the bound and the fixed price choose differently: along the
    planner's own closed-loop runs (``config.tie_episodes`` episodes, exhaustive search), at every
    decision, the fixed-price planner's choice at the same beliefs, the knapsack's values of every
    joint action within the budget at the planner's price, and the exact joint lookahead value
    ``Q*`` of each (``core/multitarget/joint_exact.py``). Reported over the decisions where the two
    choices differ: the knapsack's margin between its best and its runner-up, the difference of
    their exact values, which of the two choices is better, and how often the lower bounds order
    the two choices as ``Q*`` does."""
    joint = ExactJointPlanner(problem, depth)
    feasible = list(joint.actions)
    planner = make_joint_policy("lagrangian", problem, search="exhaustive", depth=depth)
    fixed = make_joint_policy("fixed_price", problem, search="exhaustive", depth=depth)
    records: list[tuple[float, float, bool]] = []
    decisions = 0

    class Probe:
        last = None

        def act(self, beliefs):
            nonlocal decisions
            dec = planner.planner.decide(beliefs)
            self.last = dec
            decisions += 1
            other = fixed.planner.decide(beliefs)
            if other.actions != dec.actions:
                values = np.array([sum(dec.targets[k].q_values[a] for k, a in enumerate(joint_action))
                                   for joint_action in feasible])
                top = np.sort(values)[::-1]
                q = joint.q_values([np.asarray(b, dtype=float) for b in beliefs])
                mine, theirs = q[feasible.index(dec.actions)], q[feasible.index(other.actions)]
                records.append((float(top[0] - top[1]), float(theirs - mine),
                                bool(other.lower_bound > dec.lower_bound) == bool(theirs > mine)))
            return dec.actions

    t0 = time.perf_counter()
    for ep in range(config.tie_episodes):
        planner.planner.reset()
        simulate_targets(problem, Probe(), config.steps, config.seed + ep)
    log(f"ties {name}: {time.perf_counter() - t0:.1f} s")
    if not records:
        return {"decisions": decisions, "differing": 0}
    margin, better, lb_agrees = (np.array(x) for x in zip(*records, strict=True))
    return {"decisions": decisions, "differing": len(records), "episodes": config.tie_episodes,
            "margin_range": [float(margin.min()), float(margin.max())],
            "margin_median": float(np.median(margin)),
            "value_difference_range": [float(np.abs(better).min()), float(np.abs(better).max())],
            "fixed_better": int(np.sum(better > 1e-12)), "planner_better": int(np.sum(better < -1e-12)),
            "lower_bound_orders_like_exact": int(np.sum(lb_agrees))}


# ----------------------------------------------------------------------------- 4. scaling
def machine() -> dict[str, Any]:
    """The machine the timings come from: processor, cores and the load average (1, 5, 15 min)."""
    name = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            name = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), name)
    except OSError:
        pass
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {"processor": name, "cores": os.cpu_count(), "load_average": load,
            "python": f"{platform.python_implementation()} {platform.python_version()}", "numpy": np.__version__}


def bench_scaling(config: MultiBenchConfig, log: Callable[[str], None]) -> dict[str, Any]:
    """Part 4 (module docstring): decision time against K at a fixed depth, and the depth reached
    within one time budget. The decisions of all K are interleaved (round ``r`` takes decision
    ``r`` of every K in turn), so a change of the machine's load falls on every K alike; the time of
    a decision is the CPU time of the process (``time.process_time``) and the wall time."""
    rng = np.random.default_rng(config.seed + 1)
    runs = []
    for K in config.scaling_targets:
        names = [SCALING_MODELS[k % 2] for k in range(K)]
        problem = _problem(names, str(K), config.discount)
        fixed = MultiTargetPlanner(problem, depth=config.scaling_depth)
        anytime = MultiTargetPlanner(problem, time_budget=config.time_budget, max_depth=6)
        beliefs = [[rng.dirichlet(np.ones(m.S)) for m in problem.models] for _ in range(config.scaling_decisions + 1)]
        fixed.decide(beliefs[0])  # the restricted models' gate calls, once
        anytime.decide(beliefs[0])
        runs.append({"K": K, "fixed": fixed, "anytime": anytime, "beliefs": beliefs[1:], "cpu": [], "wall": [],
                     "evals": [], "depths": [], "any_wall": []})
    before = machine()
    for r in range(config.scaling_decisions):
        for run in runs:
            bs = run["beliefs"][r]
            c0, w0 = time.process_time(), time.perf_counter()
            d = run["fixed"].decide(bs)
            run["cpu"].append(time.process_time() - c0)
            run["wall"].append(time.perf_counter() - w0)
            run["evals"].append(len(d.prices))
            a = run["anytime"].decide(bs)
            run["depths"].append(a.depth)
            run["any_wall"].append(a.time_used)
    rows = []
    for run in runs:
        K = run["K"]
        cpu = 1e3 * statistics.median(run["cpu"])
        rows.append({"K": K, "depth": config.scaling_depth, "decision_cpu_ms": cpu, "decision_ms": cpu,
                     "decision_wall_ms": 1e3 * statistics.median(run["wall"]), "cpu_ms_per_target": cpu / K,
                     "price_evaluations": statistics.median(run["evals"]), "time_budget": config.time_budget,
                     "anytime_depth": statistics.median(run["depths"]),
                     "anytime_ms": 1e3 * statistics.median(run["any_wall"])})
        log(f"scaling K={K}: {cpu:.1f} ms CPU at depth {config.scaling_depth}; "
            f"anytime depth {rows[-1]['anytime_depth']}")
    return {"rows": rows, "machine": before, "load_after": machine()["load_average"]}


# ----------------------------------------------------------------------------- run and report
def run_multitarget_bench(config: MultiBenchConfig, log: Callable[[str], None] = lambda s: None,
                          parts: Sequence[str] = PARTS) -> dict[str, Any]:
    """The parts of the module docstring (``parts``: :data:`PARTS`, all by default); a JSON-ready
    dict with the keys of the module docstring (those of the parts run)."""
    t0 = time.perf_counter()
    out: dict[str, Any] = {"config": asdict(config), "parts": list(parts)}
    violations = 0
    if "bounds" in parts:
        bounds = bench_bounds(config, log)
        violations += bounds["budget_violations"]
        out.update({"dual_bound_violations": bounds["dual_bound_violations"],
                    "lagrangian_violations": bounds["lagrangian_violations"],
                    "lower_bound_violations": bounds["lower_bound_violations"],
                    "gap_violations": bounds["gap_violations"], "bound_checks": bounds["checks"],
                    "bnb_estimates": bounds["bnb_estimates"],
                    "bnb_estimates_below_exact": bounds["bnb_estimates_below_exact"], "bounds": bounds["rows"]})
    if "regret" in parts:
        sanity = bench_sanity(config, log)
        regret = bench_regret(config, log)
        violations += regret["budget_violations"]
        out.update({"sanity": sanity, "regret": regret["cases"],
                    "regret_vs_exact": {c["case"]: {label: (row["regret_vs_exact"] if sanity["passed"].get(label, True)
                                                            else None) for label, row in c["policies"].items()}
                                        for c in regret["cases"]}})
    if "bounds" in parts or "regret" in parts:
        out["budget_violations"] = violations
    if "scaling" in parts:
        scaling = bench_scaling(config, log)
        out.update({"scaling": scaling["rows"], "machine": scaling["machine"], "load_after": scaling["load_after"],
                    "decision_ms": {str(r["K"]): r["decision_cpu_ms"] for r in scaling["rows"]}})
    out["seconds"] = time.perf_counter() - t0
    return out


def _ci(s: dict[str, Any] | None, digits: int = 3) -> str:
    if s is None:
        return "n/a (sanity check failed)"
    return f"{s['mean']:.{digits}f} [{s['ci'][0]:.{digits}f}, {s['ci'][1]:.{digits}f}]"


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    return "\n".join(lines + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows])


def format_report(result: dict[str, Any]) -> str:
    """The report of the parts run: violations, the bound table, sanity, the regret tables with
    their paired differences, and the scaling table (markdown)."""
    out: list[str] = []
    if "budget_violations" in result:
        out.append(f"budget violations: {result['budget_violations']}")
    if "bounds" in result:
        out += [f"dual bound violations: {result['dual_bound_violations']} of {result['bound_checks']} checks "
                f"(exhaustive per-target searches); L < U: {result['lagrangian_violations']}; lower bound above the "
                f"chosen action's value: {result['lower_bound_violations']}; gap below the shortfall: "
                f"{result['gap_violations']}",
                f"branch-and-bound estimates below the exact joint value: {result['bnb_estimates_below_exact']} of "
                f"{result['bnb_estimates']} (no guarantee with pruning)", ""]
        out.append(markdown_table(
            ["case", "depth", "decisions", "optimal share", "regret V* - Q*(a)", "max", "U - V*", "reported gap"],
            [[r["case"], r["depth"], r["beliefs"], f"{r['optimal_share']:.2f}", _ci(r["decision_regret"], 4),
              f"{r['decision_regret_max']:.4f}", _ci(r["bound_excess"]), _ci(r["reported_gap"])]
             for r in result["bounds"]]))
    if "regret" in result:
        failed = [label for label, ok in result["sanity"]["passed"].items() if not ok]
        out += ["", "sanity checks: " + ("all passed" if not failed else f"FAILED for {', '.join(failed)}")]
        for c in result["regret"]:
            out += ["", f"{c['case']} (K = {c['K']}, depth {c['depth']}, {c['episodes']} episodes x {c['steps']} "
                    "steps, common random numbers):", ""]
            out.append(markdown_table(
                ["policy", "discounted return", "regret vs exact joint", "ms/step"],
                [[label, _ci(row["return"]), _ci(result["regret_vs_exact"][c["case"]][label]),
                  f"{row['ms_per_step']:.1f}"] for label, row in c["policies"].items()]))
            if c.get("paired"):
                out += ["", "paired differences of the return (first minus second, per episode):", ""]
                out.append(markdown_table(["first", "second", "difference"],
                                          [[p["first"], p["second"], _ci(p["difference"])] for p in c["paired"]]))
            t = c.get("ties")
            if t and t["differing"]:
                out += ["", f"where the fixed price chose differently ({t['differing']} of {t['decisions']} decisions "
                        f"of the planner's own runs, {t['episodes']} episodes): the knapsack's best and runner-up "
                        f"joint actions at the planner's price differ by {t['margin_range'][0]:.2g} to "
                        f"{t['margin_range'][1]:.2g} (median {t['margin_median']:.2g}); the two choices' exact "
                        f"lookahead values by {t['value_difference_range'][0]:.2g} to "
                        f"{t['value_difference_range'][1]:.2g}; the fixed price's was better in {t['fixed_better']}, "
                        f"the planner's in {t['planner_better']}; the lower bounds ordered them like the exact values "
                        f"in {t['lower_bound_orders_like_exact']}"]
    if "scaling" in result:
        m = result["machine"]
        out += ["", f"scaling (S = 8, {' / '.join(SCALING_MODELS)} alternating, budget K, depth "
                f"{result['config']['scaling_depth']}, median of {result['config']['scaling_decisions']} decisions "
                f"per K, the K interleaved; CPU time of the process):",
                f"machine: {m['processor']}, {m['cores']} cores, {m['python']}, numpy {m['numpy']}; load average "
                f"(1, 5, 15 min) {m['load_average']} before, {result['load_after']} after", ""]
        first = result["scaling"][0]
        out.append(markdown_table(
            ["K", "CPU ms", "CPU ms per target", "per target / K = " + str(first["K"]), "wall ms",
             "price evaluations", "anytime depth", f"anytime ms (budget {result['config']['time_budget']:g} s)"],
            [[r["K"], f"{r['decision_cpu_ms']:.1f}", f"{r['cpu_ms_per_target']:.2f}",
              f"{r['cpu_ms_per_target'] / first['cpu_ms_per_target']:.2f}", f"{r['decision_wall_ms']:.1f}",
              r["price_evaluations"], r["anytime_depth"], f"{r['anytime_ms']:.0f}"] for r in result["scaling"]]))
    return "\n".join(out)


def plot_scaling(result: dict[str, Any], path: str) -> None:
    """Decision time against K (log-log) with the linear reference through K = 2 (needs matplotlib)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    K = np.array([r["K"] for r in result["scaling"]], dtype=float)
    ms = np.array([r["decision_cpu_ms"] for r in result["scaling"]])
    fig, ax = plt.subplots(figsize=(5, 3.4))
    ax.loglog(K, ms, "o-", label=f"decision, depth {result['scaling'][0]['depth']}")
    ax.loglog(K, ms[0] * K / K[0], "k--", lw=0.8, label="linear in K (through K = 2)")
    ax.set_xscale("log", base=2)
    ax.minorticks_off()
    ax.set_xticks(K, [str(int(k)) for k in K])
    ax.set_xlabel("targets K")
    ax.set_ylabel("decision CPU time (ms)")
    ax.legend(fontsize=8)
    ax.set_title("multi-target planner: one decision, S = 8 targets (median)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The benchmark's options (``pomdp-planner bench multitarget``)."""
    p.add_argument("--quick", action="store_true",
                   help="a smoke run (about a minute): fewer beliefs, episodes, K <= 16")
    p.add_argument("--only", default=None, metavar="PARTS",
                   help=f"run only these parts, comma-separated: {', '.join(PARTS)} (default: all; "
                   "'--only scaling' is the decision time against K, a few minutes)")
    p.add_argument("--json", metavar="FILE", default=None, help="also write the results as JSON to FILE")
    p.add_argument("--plot", metavar="FILE", default=None,
                   help="also plot decision time against K to FILE (matplotlib)")
    p.add_argument("--episodes", type=int, default=None, help="closed-loop episodes per policy and case (100)")
    p.add_argument("--seed", type=int, default=0, help="seed of beliefs and episodes (0)")


def run_from_args(args: argparse.Namespace) -> int:
    config = MultiBenchConfig.quick() if args.quick else MultiBenchConfig()
    if args.episodes is not None:
        if args.episodes < 2:
            raise ValueError(f"--episodes: must be at least 2, got {args.episodes}")
        config = replace(config, episodes=args.episodes)
    if args.seed < 0:
        raise ValueError(f"--seed: must be >= 0, got {args.seed}")
    config = replace(config, seed=args.seed)
    for path, name in ((args.json, "--json"), (args.plot, "--plot")):
        if path is not None:
            check_output_file(path, name)
    parts = PARTS if args.only is None else tuple(x.strip() for x in args.only.split(","))
    unknown = [x for x in parts if x not in PARTS]
    if unknown or not parts:
        raise ValueError(f"--only: expected some of {', '.join(PARTS)}, got {args.only!r}")
    if args.plot is not None and "scaling" not in parts:
        raise ValueError("--plot: draws the scaling part, which --only leaves out")
    result = run_multitarget_bench(config, log=lambda s: print(s, file=sys.stderr, flush=True), parts=parts)
    print(format_report(result))
    if args.json is not None:
        write_text_file(args.json, json.dumps(result, indent=2) + "\n", "--json")
    if args.plot is not None:
        plot_scaling(result, args.plot)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pomdp_planner.bench.multitarget",
                                     description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    try:
        return run_from_args(parser.parse_args(argv))
    except (ValueError, OSError) as exc:
        print(f"multitarget bench: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
