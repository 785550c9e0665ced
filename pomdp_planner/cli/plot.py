"""``pomdp-planner plot RUN.csv -o run.png``: a picture of one run record.

Reads a run record (``core/io/run_record.py``: ``simulate --record FILE`` writes one) and draws,
against the epoch:

1. the belief as a heat map (states upwards, probability as colour) with the true state, where
   the record knows it, as white dots;
2. the chosen priority, the root bound interval ``[lower, upper]`` as a band where the decision
   had bounds (hatched grey and labelled "NOT GUARANTEED" where the record says they are not
   guaranteed), and the certified decisions (agreeing guaranteed bounds, Proposition 1) marked;
3. the decision latency in milliseconds against the run's time budget (dashed), decisions over
   the budget marked.

The picture is ``--width`` x ``--height`` inches at ``--dpi`` dots per inch (default 10 x 7 at
100: 1000 x 700 pixels); the format follows the output's suffix (``.png``, ``.svg``, ``.pdf``).
matplotlib is an optional extra (``pip install '.[plot]'``; also in the ``experiments`` extra): without
it the command says so in one line (exit code 2). A malformed record is refused in one line
naming the line and the column (exit code 2); a last row without its line end (still being
written, or cut off) is left out with one warning naming its line.
"""

from __future__ import annotations

import argparse

import numpy as np

from ..core.errors import OptionError
from ..core.io.outputs import check_output_file
from ..core.io.run_record import RunRecord, read_run_record
from ._common import float_in

#: Output formats (by suffix) the command writes.
FORMATS = (".png", ".svg", ".pdf")
INSTALL_HINT = "matplotlib is not installed: pip install matplotlib (or, in the source tree, pip install '.[plot]')"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plot", help="draw a run record (belief heat map, actions and bounds, latency)",
                              description=__doc__.split("\n\n")[0].replace("``", ""))
    p.add_argument("record", metavar="RUN.csv",
                   help="a run record (simulate --record FILE, the run_recorder node, the demo's --record)")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help=f"the picture: {', '.join(FORMATS)}")
    p.add_argument("--dpi", type=float_in(20, 600), default=100.0, metavar="N", help="dots per inch, 20..600 (100)")
    p.add_argument("--width", type=float_in(3, 40, " of inches"), default=10.0, metavar="IN",
                   help="width in inches, 3..40 (10)")
    p.add_argument("--height", type=float_in(3, 40, " of inches"), default=7.0, metavar="IN",
                   help="height in inches, 3..40 (7)")
    p.add_argument("--title", default=None, help="title (default: the model and the number of decisions)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = check_output_file(args.output, "--output", stdout=False)
    if out.suffix.lower() not in FORMATS:
        raise OptionError(f"--output: the suffix must be one of {', '.join(FORMATS)}, got {out.name!r}")
    rec = read_run_record(args.record)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise OptionError(INSTALL_HINT) from None
    fig = draw(plt, rec, (args.width, args.height), args.title)
    try:
        fig.savefig(out, dpi=args.dpi, format=out.suffix.lower().lstrip("."))
    except OSError as exc:
        raise OptionError(f"--output: cannot write {out}: {exc.strerror or type(exc).__name__}") from None
    finally:
        plt.close(fig)
    print(f"wrote {out} ({len(rec.epoch)} decisions of {rec.model})")
    return 0


#: Legends of the lower panels: one row just above the panel, clear of the data.
_LEGEND = {"loc": "lower right", "bbox_to_anchor": (1.0, 1.0), "ncol": 4, "fontsize": "small", "frameon": False,
           "borderaxespad": 0.1}


def _edges(x: np.ndarray) -> np.ndarray:
    """Cell edges around the epochs (half-way between neighbours, half a step at the ends)."""
    if x.size == 1:
        return np.array([x[0] - 0.5, x[0] + 0.5])
    mid = (x[1:] + x[:-1]) / 2.0
    return np.concatenate([[x[0] - (mid[0] - x[0])], mid, [x[-1] + (x[-1] - mid[-1])]])


def draw(plt, rec: RunRecord, size: tuple[float, float], title: str | None):
    """The figure of :mod:`this module <pomdp_planner.cli.plot>` for ``rec`` (``plt``: ``matplotlib.pyplot``)."""
    x = rec.epoch.astype(float)
    fig, (ax_b, ax_a, ax_t) = plt.subplots(3, 1, figsize=size, sharex=True, constrained_layout=True,
                                           gridspec_kw={"height_ratios": [3.0, 1.5, 1.2]})
    mesh = ax_b.pcolormesh(_edges(x), np.arange(rec.S + 1) - 0.5, rec.beliefs.T, cmap="viridis", vmin=0.0, vmax=1.0,
                           shading="flat")
    fig.colorbar(mesh, ax=ax_b, label="belief", pad=0.01)
    known = rec.true_state >= 0
    if known.any():
        ax_b.plot(x[known], rec.true_state[known], "o", color="white", markersize=3, label="true state")
        ax_b.legend(loc="upper right", fontsize="small", framealpha=0.6)
    ax_b.set_ylabel("state")
    ax_b.set_ylim(-0.5, rec.S - 0.5)
    ax_b.set_title(title or f"{rec.model}: {len(x)} decisions (S={rec.S}, A={rec.A})")

    for rows, style in ((rec.has_bounds & rec.guaranteed, {"color": "tab:orange", "alpha": 0.3,
                                                            "label": "root bounds [lower, upper]"}),
                        (rec.unguaranteed_bounds, {"facecolor": "none", "edgecolor": "tab:gray", "hatch": "////",
                                                   "label": "root bounds NOT GUARANTEED"})):
        if rows.any():
            lo = np.where(rows, np.minimum(rec.lower, rec.upper), np.nan).astype(float)
            up = np.where(rows, np.maximum(rec.lower, rec.upper), np.nan).astype(float)
            ax_a.fill_between(x, lo - 0.3, up + 0.3, step="mid", linewidth=0, **style)
    ax_a.step(x, rec.action, where="mid", color="tab:blue", linewidth=1.2, label="priority chosen")
    if rec.certified.any():
        ax_a.plot(x[rec.certified], rec.action[rec.certified], "s", color="tab:green", markersize=3,
                  label="certified")
    ax_a.set_ylabel("priority")
    ax_a.set_ylim(rec.A + 0.7, 0.3)  # priority 1 (the greatest) on top
    ax_a.set_yticks(range(1, rec.A + 1))
    ax_a.legend(**_LEGEND)

    ms = rec.latency * 1e3
    measured = np.isfinite(ms)
    if measured.any():
        ax_t.plot(x[measured], ms[measured], ".", color="tab:blue", markersize=3, label="decision latency")
    if rec.time_budget is not None:
        budget = rec.time_budget * 1e3
        ax_t.axhline(budget, color="black", linestyle="--", linewidth=1, label=f"budget {budget:g} ms")
        over = measured & (ms > budget)
        if over.any():
            ax_t.plot(x[over], ms[over], "x", color="tab:red", markersize=4, label=f"over budget ({over.sum()})")
    if not measured.any():
        ax_t.text(0.5, 0.5, "no latency in this record", transform=ax_t.transAxes, ha="center", va="center")
    ax_t.set_ylabel("ms")
    ax_t.set_xlabel("epoch")
    ax_t.set_ylim(bottom=0)
    if measured.any() or rec.time_budget is not None:
        ax_t.legend(**_LEGEND)
    return fig
