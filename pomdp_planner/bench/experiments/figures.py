"""Plots of the experiments (matplotlib, an optional extra: ``pip install .[experiments]``).

matplotlib is imported lazily inside each function with the non-interactive Agg backend,
so the rest of the package (and the experiments' numbers) never need it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .peer_policies import display_name

PRIORITY_COLOURS = ["#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02"]
UNDECIDED = "#bbbbbb"


def _plt():
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - exercised only without the extra
        raise ImportError("the experiments' plots need matplotlib: pip install 'pomdp_planner[experiments]'") from exc
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def ternary_xy(B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric -> 2-D: vertex s1 at (0, 0), s2 at (1, 0), s3 at (1/2, sqrt(3)/2)."""
    B = np.asarray(B, dtype=float)
    return B[:, 1] + 0.5 * B[:, 2], B[:, 2] * np.sqrt(3.0) / 2.0


def _simplex_axes(ax, title: str) -> None:
    ax.plot([0, 1, 0.5, 0], [0, 0, np.sqrt(3) / 2, 0], color="k", lw=0.8)
    for (x, y), lab, ha in (((0, 0), "$s_1$", "right"), ((1, 0), "$s_2$", "left"),
                            ((0.5, np.sqrt(3) / 2), "$s_3$", "center")):
        ax.annotate(lab, (x, y), ha=ha, va="bottom" if y > 0 else "top", fontsize=9)
    ax.set_title(title, fontsize=9)
    ax.set_aspect("equal")
    ax.axis("off")


def plot_fig1(path: Path, B: np.ndarray, lower: np.ndarray, upper: np.ndarray, optimal: np.ndarray,
              optimal_decided: np.ndarray, A: int) -> Path:
    """Fig. 1: lower / upper bound policies, where they agree, and the reference optimum."""
    plt = _plt()
    x, y = ternary_xy(B)
    fig, axes = plt.subplots(1, 4, figsize=(12, 3.4))
    panels = [
        ("lower bound policy", lower, np.ones(len(B), bool)),
        ("upper bound policy", upper, np.ones(len(B), bool)),
        ("bounds agree (grey: they differ)", lower, lower == upper),
        ("optimal (grid reference; grey: near-tie)", optimal, optimal_decided),
    ]
    for ax, (title, act, mask) in zip(axes, panels, strict=True):
        _simplex_axes(ax, title)
        c = [PRIORITY_COLOURS[a % len(PRIORITY_COLOURS)] if m else UNDECIDED for a, m in zip(act, mask, strict=True)]
        ax.scatter(x, y, c=c, s=max(4.0, 8000.0 / len(B)), marker="s", linewidths=0)
    handles = [plt.Line2D([], [], marker="s", ls="", color=PRIORITY_COLOURS[a % len(PRIORITY_COLOURS)],
                          label=f"priority {a + 1}") for a in range(A)]
    fig.legend(handles=handles, loc="lower center", ncol=A, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_fig3(path: Path, b1: np.ndarray, rho: np.ndarray, rho_lower: np.ndarray, rho_upper: np.ndarray,
              lower: np.ndarray, upper: np.ndarray) -> Path:
    """The paper's reward figure (S = 2): original rewards (left), transformed (right).

    ``b1`` is ``b(s_2)`` on the x axis (MLR order on S = 2 is the order of ``b(s_2)``).
    """
    plt = _plt()
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 3.6))
    styles = ["-", "--", ":", "-."]
    for a in range(rho.shape[1]):
        ax0.plot(b1, rho[:, a], "k" + styles[a % 4], label=f"$\\rho(b, a_{a + 1})$")
        ax1.plot(b1, rho_lower[:, a], color="tab:blue", ls=styles[a % 4], label=f"$\\underline{{\\rho}}(b, a_{a + 1})$")
        ax1.plot(b1, rho_upper[:, a], color="tab:red", ls=styles[a % 4], label=f"$\\overline{{\\rho}}(b, a_{a + 1})$")
    ax0.set_xlabel("$b(s_2)$")
    ax0.set_title("original expected rewards", fontsize=9)
    ax0.legend(fontsize=8)
    ax1.set_xlabel("$b(s_2)$")
    ax1.set_title("transformed rewards (blue: MLR increasing, red: MLR decreasing)", fontsize=9)
    # where the bounds agree, mark the segment at the bottom, one line style per action
    lo_y = ax1.get_ylim()[0]
    agree = lower == upper
    for a in range(rho.shape[1]):
        m = agree & (lower == a)
        if np.any(m):
            xs = np.where(m, b1, np.nan)
            ax1.plot(xs, np.full_like(b1, lo_y), "k" + styles[a % 4], lw=2.5, marker="o", markevery=[
                int(np.nanargmin(xs)), int(np.nanargmax(xs))], label=f"bounds agree: $a_{a + 1}$")
    ax1.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_looseness(path: Path, cells: Sequence, A_values: Sequence[int]) -> Path:
    """Fig. 4: mean (upper - optimal) and (upper - lower) against S, one colour per A."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for i, A in enumerate(A_values):
        col = plt.cm.viridis(i / max(len(A_values) - 1, 1))
        rows = sorted([c for c in cells if c.A == A and c.feasible], key=lambda c: c.S)
        if not rows:
            continue
        ax.plot([c.S for c in rows], [c.mean_width for c in rows], ls="--", marker=".", color=col)
        opt = [c for c in rows if c.upper_minus_opt is not None]
        if opt:
            ax.plot([c.S for c in opt], [c.upper_minus_opt for c in opt], ls="-", marker="o", color=col, label=f"A={A}")
        else:
            ax.plot([], [], ls="-", marker="o", color=col, label=f"A={A}")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("S (number of states)")
    ax.set_ylabel("mean distance in actions")
    ax.set_title("solid: upper - optimal (PBVI reference); dashed: upper - lower", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


PEER_STYLE = {"bnb": ("o", "C0"), "exhaustive": ("s", "C1"), "mcts": ("D", "C2"), "pouct": ("^", "C3"),
              "optimal": ("", "k"), "greedy": ("", "C4"), "lower-bound": ("", "C5"), "upper-bound": ("", "C6"),
              "random": ("", "C7")}
#: Budgeted planners are drawn side by side (x offsets), not on top of each other.
PEER_OFFSETS = {"bnb": 0.92, "exhaustive": 0.97, "mcts": 1.03, "pouct": 1.08}


def plot_peers(path: Path, results: Sequence, models: Sequence[str]) -> Path:
    """Return (top row) and regret against the reference policy (bottom row) against the time
    budget per decision, one column per model, log x axis; 95 % CI error bars. Planners without a
    budget are horizontal lines (dotted) with their CI as a band. Random is left out of the regret
    row (its regret dwarfs the others)."""
    plt = _plt()
    cols = max(len(models), 1)
    fig, axes = plt.subplots(2, cols, figsize=(4.6 * cols, 7.2), squeeze=False)
    for j, mname in enumerate(models):
        rows = [r for r in results if r.model == mname]
        budgets = sorted({r.budget for r in rows if r.budget is not None})
        for i, (metric, label) in enumerate((("return", "mean discounted return (true $\\rho$)"),
                                              ("regret", "regret vs. reference policy"))):
            ax = axes[i][j]
            has_regret = any(r.regret is not None for r in rows)
            if metric == "regret" and not has_regret:
                ax.text(0.5, 0.5, "no reference policy\nfor this model", ha="center", va="center",
                        transform=ax.transAxes, fontsize=9)
                ax.set_axis_off()
                continue
            for planner in dict.fromkeys(r.planner for r in rows):
                if metric == "regret" and planner in ("random", "optimal"):
                    continue
                pr = sorted([r for r in rows if r.planner == planner], key=lambda r: r.budget or 0)
                marker, col = PEER_STYLE.get(planner, ("o", "C9"))
                mean = [r.mean if metric == "return" else r.regret for r in pr]
                ci = [r.ci if metric == "return" else r.regret_ci for r in pr]
                if pr[0].budget is None:
                    if budgets:
                        ax.axhline(mean[0], color=col, ls=":", lw=1.2, label=display_name(planner))
                        ax.axhspan(ci[0][0], ci[0][1], color=col, alpha=0.12, lw=0)
                    continue
                xs = [r.budget * PEER_OFFSETS.get(planner, 1.0) for r in pr]
                pairs = list(zip(mean, ci, strict=True))
                err = [[m - c[0] for m, c in pairs], [c[1] - m for m, c in pairs]]
                ax.errorbar(xs, mean, yerr=err, marker=marker, capsize=3, color=col, label=display_name(planner))
            if budgets:
                ax.set_xscale("log")
                ax.set_xticks(budgets, [f"{b:g}" for b in budgets])
                ax.set_xticks([], minor=True)
            ax.set_xlabel("time budget per decision (s, CPU)")
            ax.set_ylabel(label)
            ax.set_title(mname, fontsize=9)
            ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
