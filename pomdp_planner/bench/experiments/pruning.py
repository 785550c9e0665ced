"""Table III (actions pruned by the myopic bounds) and the looseness figure (paper Fig. 4).

For each ``(S, A)`` the Sec. VI-B model (our non-trivial ``y``, see
:mod:`pomdp_planner.core.domains.comparison`) gets its bounds through the assumption gate
(:func:`pomdp_planner.core.gate.build_planner`: Assumption 1 checked once per model, then the
LP of each variant); a cell whose bounds the gate does not accept is reported with its reason
instead of figures. At ``n`` random reachable beliefs the lower and upper myopic actions are
evaluated in one vectorised call.

Percentage formula. The issue (and our reading of the paper) uses
``pruned = 100 (1 - (upper - lower) / A)``. It is the only reading consistent with the
paper's Table III: its A = 4 entries are multiples of 25 and reach 100 (S = 4), which needs
``upper = lower`` to give 100 %. The literal count of actions the search skips,
``A - (upper - lower + 1)``, gives ``100 (1 - (upper - lower + 1) / A)``, at most
``100 (A - 1) / A`` (75 % for A = 4), so it cannot produce the paper's 100. We report the
paper's formula in Table III and the literal count beside it (same granularity ``100/A``,
exactly ``100/A`` lower).

Degenerate cells: a cell where one action is provably optimal measures nothing about how the
bounds prune a real choice. Two exact tests flag it: (i) **reward-dominant**: the reward is
linear in the belief (f = none or all weights 0, as in the Sec. VI-B model) and the
blind-policy certificate :func:`~.pbvi.single_action_optimal` proves one action optimal at
*every* belief (its value vector ``alpha = (I - gamma P_a)^-1 r_a`` satisfies
``r_a' + gamma P_a' alpha <= alpha`` for every ``a'``); (ii) **bounds-degenerate**: the lower
and upper bound agree, on the same action, at *every* sampled belief, so the bounds alone
prove that action optimal wherever the cell was measured (Corollary 1). Both are reported per
cell; the mean interval width ``mean(upper - lower + 1)`` (actions the search still has to
consider) is reported beside the percentages.

Looseness: the optimal action at the same beliefs comes from the point-based reference
(:mod:`pomdp_planner.bench.experiments.pbvi`) run on those very beliefs, for ``S <= exact_max_S``;
larger cells report only ``upper - lower``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ...core.domains.comparison import comparison_model
from ...core.gate import build_planner
from ...core.model import POMDP
from .datafile import register
from .pbvi import pbvi, single_action_optimal
from .progress import Progress
from .sampling import reachable_beliefs


@register
@dataclass
class PruningCell:
    S: int
    A: int
    feasible: bool
    message: str = ""
    lp_time: float = float("nan")
    n: int = 0
    pct: tuple[float, float, float] | None = None  # paper formula (min, avg, max)
    pct_count: tuple[float, float, float] | None = None  # literal count (min, avg, max)
    mean_width: float = float("nan")  # mean (upper - lower)
    mean_interval: float = float("nan")  # mean (upper - lower + 1): actions left in [lower, upper]
    crossed: int = 0  # beliefs with lower > upper (must be 0)
    # degenerate cells (module docstring): priorities, None where the cell is not degenerate that way
    single_action: int | None = None  # optimal at every belief, proven by the blind-policy certificate
    bounds_single: int | None = None  # lower == upper == this priority at every sampled belief
    # looseness against the reference optimal policy (None where not computed)
    opt_method: str | None = None
    upper_minus_opt: float | None = None
    opt_minus_lower: float | None = None
    opt_outside: int | None = None  # beliefs where the optimum is outside [lower, upper]
    opt_decided: int | None = None  # beliefs where the reference is not a near-tie
    ref_time: float | None = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def degenerate(self) -> str | None:
        """Why one action is provably optimal in this cell, or ``None`` (module docstring)."""
        why = []
        if self.single_action is not None:
            why.append(f"priority {self.single_action} optimal at every belief (blind-policy certificate)")
        if self.bounds_single is not None:
            why.append(f"lower = upper = priority {self.bounds_single} at all {self.n} sampled beliefs")
        return "; ".join(why) or None


def pruned_percentages(lower: np.ndarray, upper: np.ndarray, A: int) -> tuple[np.ndarray, np.ndarray]:
    """``(paper, count)`` percentages per belief (see the module docstring)."""
    width = np.asarray(upper) - np.asarray(lower)
    return 100.0 * (1.0 - width / A), 100.0 * (1.0 - (width + 1) / A)


def _mma(x: np.ndarray) -> tuple[float, float, float]:
    return float(np.min(x)), float(np.mean(x)), float(np.max(x))


def reference_actions(model, B: np.ndarray, tol: float = 1e-6, tie: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """PBVI optimal actions at ``B`` (points = ``B`` plus the vertices) and the decided mask."""
    pts = np.vstack([np.eye(model.S), B])
    pol = pbvi(model, pts, tol=tol)
    Q = pol.q_values(B)
    srt = np.sort(Q, axis=1)
    gap = srt[:, -1] - srt[:, -2]
    return np.argmax(Q, axis=1), gap > tie


def pruning_cell(S: int, A: int, n: int, seed: int, variant: str = "tight", exact_max_S: int = 0,
                 ref_max_actions: int = 64, model: POMDP | None = None) -> PruningCell:
    """One cell of Table III (and of the looseness figure when ``S <= exact_max_S``);
    ``model`` defaults to ``comparison_model(S, A)``."""
    model = comparison_model(S, A) if model is None else model
    t0 = time.perf_counter()
    setup = build_planner(model, variant=variant)
    sol = setup.bounds
    cell = PruningCell(S=S, A=A, feasible=setup.pruning, message=sol.message if setup.pruning else setup.reason,
                       lp_time=float(sol.solve_time) if sol is not None else float("nan"))
    cell.extra["gate_time"] = time.perf_counter() - t0
    if not setup.pruning:
        return cell
    assert setup.guaranteed  # the gate prunes without the guarantee only when told to, and we never tell it
    rng = np.random.default_rng([seed, S, A])
    B = reachable_beliefs(model, n, rng)
    lo, up = setup.myopic.actions(B)
    paper, count = pruned_percentages(lo, up, A)
    cell.n = n
    cell.pct = _mma(paper)
    cell.pct_count = _mma(count)
    cell.mean_width = float(np.mean(up - lo))
    cell.mean_interval = float(np.mean(up - lo + 1))
    cell.crossed = int(np.sum(lo > up))
    if model.uncertainty.name == "none" or not np.any(model.w):
        a_star = single_action_optimal(model)
        cell.single_action = None if a_star is None else a_star + 1
    if np.all(lo == up) and np.all(lo == lo[0]):
        cell.bounds_single = int(lo[0]) + 1
    if S <= exact_max_S and A <= ref_max_actions:
        t0 = time.perf_counter()
        opt, decided = reference_actions(model, B)
        cell.ref_time = time.perf_counter() - t0
        cell.opt_method = "pbvi"
        cell.upper_minus_opt = float(np.mean(up - opt))
        cell.opt_minus_lower = float(np.mean(opt - lo))
        cell.opt_outside = int(np.sum(decided & ((opt < lo) | (opt > up))))
        cell.opt_decided = int(np.sum(decided))
    return cell


def pruning_sweep(S_values, A_values, variants: tuple[tuple[str, int], ...] = (("tight", 1 << 30),), n: int = 500,
                  seed: int = 0, exact_max_S: int = 8, progress: bool = True) -> dict[str, list[PruningCell]]:
    """All cells of Table III, smallest first, for each ``(variant, largest S)`` of ``variants``:
    one model per ``(S, A)`` for all variants (so Assumption 1 is checked once per model). LP or
    solver failures become ``feasible=False`` cells."""
    out: dict[str, list[PruningCell]] = {v: [] for v, _ in variants}
    total = sum(1 for S in S_values for _ in A_values for _, m in variants if S <= m)
    with Progress("table III", total, enabled=progress) as bar:
        for S in S_values:
            for A in A_values:
                todo = [v for v, max_S in variants if S <= max_S]
                model = comparison_model(S, A) if todo else None
                for variant in todo:
                    t0 = time.perf_counter()
                    try:
                        cell = pruning_cell(S, A, n, seed, variant, exact_max_S, model=model)
                    except Exception as exc:  # a solver failure must not kill the whole sweep
                        cell = PruningCell(S=S, A=A, feasible=False, message=f"error: {type(exc).__name__}: {exc}")
                    cell.extra["cell_time"] = time.perf_counter() - t0
                    out[variant].append(cell)
                    bar.advance(note=f"S={S} A={A} {variant}")
    return out
