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

The record is a run-record CSV or a bag (``core/io/run_bag.py``: a ``.mcap`` file written with
``--record x.mcap``, or a bag of a running loop recorded with ``ros2 bag record``, a directory or a
``.mcap``/``.db3`` file; ``--namespace`` picks the run's topics when the bag has several).
``--epochs A:B`` draws the rows of epochs ``A <= t < B`` only (either end may be left out). More
than :data:`MAX_COLUMNS` rows are drawn in blocks of ``k`` consecutive epochs (the fewest that
fit): the belief's mean over the block, the priorities' mean with their range, the bounds' range,
the certified share and the latencies' median and largest value per block, so a long run stays
readable; the title says ``k``.

The picture is ``--width`` x ``--height`` inches at ``--dpi`` dots per inch (default 10 x 7 at
100: 1000 x 700 pixels); the format follows the output's suffix (``.png``, ``.svg``, ``.pdf``).
matplotlib is an optional extra (``pip install '.[plot]'``; also in the ``experiments`` extra): without
it the command says so in one line (exit code 2). A malformed record is refused in one line
naming the line and the column (exit code 2); a last row without its line end (still being
written, or cut off) is left out with one warning naming its line.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

import numpy as np

from ..core.errors import OptionError
from ..core.io.outputs import check_output_file
from ..core.io.run_bag import read_run_output
from ..core.io.run_record import RunRecord
from ._common import float_in

#: The most columns (epochs, or blocks of epochs) a picture draws (module docstring).
MAX_COLUMNS = 200

#: Output formats (by suffix) the command writes.
FORMATS = (".png", ".svg", ".pdf")
INSTALL_HINT = "matplotlib is not installed: pip install matplotlib (or, in the source tree, pip install '.[plot]')"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plot", help="draw a run record (belief heat map, actions and bounds, latency)",
                              description=__doc__.split("\n\n")[0].replace("``", ""))
    p.add_argument("record", metavar="RUN",
                   help="a run record (simulate --record FILE, the run_recorder node, the demo's --record): a CSV "
                        "file or a rosbag2 bag (.mcap, or a ros2 bag record bag of the loop)")
    p.add_argument("--epochs", default=None, metavar="A:B", help="draw epochs A <= t < B only (A: or :B: open)")
    p.add_argument("--namespace", default=None, metavar="NS",
                   help="a bag with the topics of several runs: the namespace of the one to draw")
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
    rec = read_run_output(args.record, namespace=args.namespace)
    if args.epochs is not None:
        rec = select_epochs(rec, args.epochs)
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


def parse_epochs(spec: str) -> tuple[int | None, int | None]:
    """``A:B`` as ``(A, B)``, either ``None`` where left out; one :class:`OptionError` line otherwise."""
    head, sep, tail = spec.partition(":")
    try:
        lo = int(head) if head.strip() else None
        hi = int(tail) if tail.strip() else None
    except ValueError:
        lo = hi = -1
    if not sep or (lo is not None and lo < 0) or (hi is not None and hi < 0) or \
            (lo is not None and hi is not None and hi <= lo):
        raise OptionError(f"--epochs: expected A:B with integers 0 <= A < B (either may be left out), got {spec!r}")
    return lo, hi


def select_epochs(rec: RunRecord, spec: str) -> RunRecord:
    """The rows of ``rec`` with ``A <= epoch < B`` (``spec``: ``A:B``); none is one line."""
    lo, hi = parse_epochs(spec)
    keep = np.ones(len(rec.epoch), dtype=bool)
    if lo is not None:
        keep &= rec.epoch >= lo
    if hi is not None:
        keep &= rec.epoch < hi
    if not keep.any():
        raise OptionError(f"--epochs: no row of the record in {spec} (its epochs: {rec.epoch[0]}..{rec.epoch[-1]})")
    arrays = {f.name: getattr(rec, f.name)[keep] for f in dataclasses.fields(rec)
              if isinstance(getattr(rec, f.name), np.ndarray)}
    return dataclasses.replace(rec, **arrays)


def block_size(n: int, columns: int = MAX_COLUMNS) -> int:
    """Epochs per drawn column: the fewest that fit ``n`` rows into ``columns``."""
    return max(1, math.ceil(n / columns))


def blocks(values: np.ndarray, k: int, how=np.mean) -> np.ndarray:
    """``how`` over consecutive blocks of ``k`` rows of ``values`` (the last block may be shorter),
    NaNs left out (a block of NaNs gives NaN)."""
    values = np.asarray(values, dtype=float)
    out = []
    for start in range(0, len(values), k):
        chunk = values[start:start + k]
        finite = chunk[~np.isnan(chunk)] if chunk.ndim == 1 else chunk
        out.append(how(finite, axis=0) if len(finite) else np.nan)
    return np.array(out)


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
    """The figure of :mod:`this module <pomdp_planner.cli.plot>` for ``rec`` (``plt``: ``matplotlib.pyplot``);
    more than :data:`MAX_COLUMNS` rows in blocks (module docstring)."""
    n = len(rec.epoch)
    k = block_size(n)
    x = blocks(rec.epoch, k)  # each column's epoch: the block's mean epoch
    fig, (ax_b, ax_a, ax_t) = plt.subplots(3, 1, figsize=size, sharex=True, constrained_layout=True,
                                           gridspec_kw={"height_ratios": [3.0, 1.5, 1.2]})
    mesh = ax_b.pcolormesh(_edges(x), np.arange(rec.S + 1) - 0.5, blocks(rec.beliefs, k).T, cmap="viridis",
                           vmin=0.0, vmax=1.0, shading="flat")
    fig.colorbar(mesh, ax=ax_b, label="belief" if k == 1 else f"belief (mean of {k} epochs)", pad=0.01)
    known = rec.true_state >= 0
    if known.any():
        ax_b.plot(rec.epoch[known], rec.true_state[known], "o", color="white", markersize=3 if k == 1 else 1,
                  label="true state")
        ax_b.legend(loc="upper right", fontsize="small", framealpha=0.6)
    ax_b.set_ylabel("state")
    ax_b.set_ylim(-0.5, rec.S - 0.5)
    shown = f"epochs {rec.epoch[0]}..{rec.epoch[-1]}" + (f", {k} epochs per column" if k > 1 else "")
    ax_b.set_title(title or f"{rec.model}: {n} decisions (S={rec.S}, A={rec.A}; {shown})")

    for rows, style in ((rec.has_bounds & rec.guaranteed, {"color": "tab:orange", "alpha": 0.3,
                                                            "label": "root bounds [lower, upper]"}),
                        (rec.unguaranteed_bounds, {"facecolor": "none", "edgecolor": "tab:gray", "hatch": "////",
                                                   "label": "root bounds NOT GUARANTEED"})):
        if rows.any():
            lo = blocks(np.where(rows, np.minimum(rec.lower, rec.upper), np.nan), k, np.min)
            up = blocks(np.where(rows, np.maximum(rec.lower, rec.upper), np.nan), k, np.max)
            ax_a.fill_between(x, lo - 0.3, up + 0.3, step="mid", linewidth=0, **style)
    if k == 1:
        ax_a.step(x, rec.action, where="mid", color="tab:blue", linewidth=1.2, label="priority chosen")
    else:
        ax_a.fill_between(x, blocks(rec.action, k, np.min), blocks(rec.action, k, np.max), step="mid",
                          color="tab:blue", alpha=0.15, linewidth=0, label="priorities chosen (range)")
        ax_a.plot(x, blocks(rec.action, k), color="tab:blue", linewidth=1.0, label="priority chosen (mean)")
    if rec.certified.any():
        share = blocks(rec.certified, k)
        marked = share > 0
        ax_a.plot(x[marked], blocks(rec.action, k)[marked], "s", color="tab:green", markersize=3,
                  label="certified" if k == 1 else "certified (in the block)")
    ax_a.set_ylabel("priority")
    ax_a.set_ylim(rec.A + 0.7, 0.3)  # priority 1 (the greatest) on top
    ax_a.set_yticks(range(1, rec.A + 1))
    ax_a.legend(**_LEGEND)

    ms = rec.latency * 1e3
    measured = np.isfinite(ms)
    if measured.any():
        mid, top = blocks(ms, k, np.median), blocks(ms, k, np.max)
        has = np.isfinite(mid)
        ax_t.plot(x[has], mid[has], ".", color="tab:blue", markersize=3,
                  label="decision latency" if k == 1 else "decision latency (median)")
        if k > 1:
            ax_t.plot(x[has], top[has], "_", color="tab:purple", markersize=4, label="largest")
    if rec.time_budget is not None:
        budget = rec.time_budget * 1e3
        ax_t.axhline(budget, color="black", linestyle="--", linewidth=1, label=f"budget {budget:g} ms")
        over = measured & (ms > budget)
        if over.any():
            ax_t.plot(rec.epoch[over], ms[over], "x", color="tab:red", markersize=4,
                      label=f"over budget ({over.sum()})")
    if not measured.any():
        ax_t.text(0.5, 0.5, "no latency in this record", transform=ax_t.transAxes, ha="center", va="center")
    ax_t.set_ylabel("ms")
    ax_t.set_xlabel("epoch")
    ax_t.set_ylim(bottom=0)
    if measured.any() or rec.time_budget is not None:
        ax_t.legend(**_LEGEND)
    return fig
