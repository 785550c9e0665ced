"""``pomdp-planner bounds MODEL``: the vectors g, h of Theorem 2 and the myopic bound policies.

Prints g, h, feasibility, the belief-independent constant (which one, its value and why:
``--constant mlr``, the default, is exact for the MLR monotonicity Corollary 1 needs;
``--constant fosd`` asks for first-order dominance, Theorem 2's stronger route), the LP solve
time and, for each
belief (from ``--beliefs FILE.csv`` or ``--samples N`` reachable beliefs drawn with
``--seed K``), the lower and upper bound actions as tracking priorities 1..A and whether they
agree, plus the agreement rate.

The first line is the assumption gate's verdict (``core.gate.bounds_verdict``, the rule every
planner obeys): ``guaranteed: ...`` when Assumption 1 holds, the LP is feasible and (Shannon)
the guarantee covers a domain; then agreeing bounds certify the optimal action. Otherwise
``NOT GUARANTEED: <reason>``: the LP solution is still shown, as a diagnostic, and the
agreement column is labelled as certifying nothing (JSON: ``guaranteed``, ``reason``,
``covers`` starting with ``none``, ``certified`` false for every belief).

Exit code 0 when the bounds are guaranteed, 1 when they are not (the LP is infeasible, with the
most violated constraint reported; Assumption 1 fails or is unproven; or the Shannon guarantee
covers no domain), 2 on bad input.
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..core.bounds import (
    BOUND_CONSTANTS,
    BOUND_VARIANTS,
    DEFAULT_CONSTANT,
    BoundsSolution,
    sample_beliefs,
    solve_bounds,
)
from ..core.gate import BoundsVerdict, bounds_verdict
from ..core.io.file_text import read_model_text
from ..core.model import POMDP, ModelError, priority_of, short_repr
from ._common import (
    add_json_argument,
    add_model_argument,
    add_seed_argument,
    emit_json,
    format_table,
    int_in,
    load_model_arg,
)

#: Beliefs used to fit the "tight" variant (independent of the beliefs displayed).
FIT_SAMPLES = 400
#: Most beliefs evaluated (``--samples``, rows of ``--beliefs``): seconds of work and of output.
MAX_BELIEFS = 100_000
#: Largest ``--beliefs`` file read (bytes): 16 MiB, about 100 000 rows of 8 probabilities.
MAX_BELIEFS_FILE_BYTES = 16 * 2**20


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bounds", help="solve the Theorem 2 LP for g/h and show the myopic policy bounds",
        description=__doc__.split("\n\n", 1)[1].replace("``", "'"),
    )
    add_model_argument(p)
    p.add_argument("--variant", choices=BOUND_VARIANTS, default=BOUND_VARIANTS[0],
                   help="choice of g/h: 'tight' (default: the least g and greatest h where the transitions "
                        "prove them the tightest at every belief, else maximises agreement of the bounds on "
                        "sampled reachable beliefs) or 'feasible' (L1-minimal)")
    p.add_argument("--constant", choices=BOUND_CONSTANTS, default=DEFAULT_CONSTANT,
                   help="monotonicity the constraints guarantee: 'mlr' (default; steps >= 2|w_a| for Renyi "
                        "entropy, exact for what Corollary 1 needs) or 'fosd' (first-order dominance, the "
                        "stronger constant 2 C_S, C_S = (1 + sqrt(S-1))/2); Shannon and f = none: the same")
    p.add_argument("--beliefs", metavar="FILE.csv",
                   help="beliefs to evaluate, one per line, S comma-separated probabilities ('#' comments "
                        "and a non-numeric header line are skipped)")
    p.add_argument("--samples", type=int_in(1, MAX_BELIEFS), default=20, metavar="N",
                   help=f"number of sampled reachable beliefs to evaluate when --beliefs is not given, "
                        f"1..{MAX_BELIEFS:,} (default 20)")
    add_seed_argument(p, "seed for the sampled beliefs and for fitting the tight variant (default 0)")
    add_json_argument(p)
    p.set_defaults(func=run)


def read_beliefs_csv(path: str | Path, model: POMDP) -> np.ndarray:
    """Read beliefs (rows of S probabilities) from a CSV file; errors name file and line.

    The file is read as a model file is (``core.io.file_text``): a regular UTF-8 file of at most
    :data:`MAX_BELIEFS_FILE_BYTES`, with at most :data:`MAX_BELIEFS` beliefs.
    """
    path = Path(path)
    try:
        text = read_model_text(path, "beliefs file", MAX_BELIEFS_FILE_BYTES, "MAX_BELIEFS_FILE_BYTES")
    except ModelError as exc:
        raise ModelError(f"--beliefs: {exc}") from None
    rows = []
    for lineno, row in _csv_rows(text, path):
        cells = [c.strip() for c in row if c.strip() != ""]
        if not cells or cells[0].startswith("#"):
            continue
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if not rows and lineno == 1:  # a header line
                continue
            raise ModelError(f"--beliefs: {path}:{lineno}: not a row of numbers: "
                             f"{short_repr(','.join(cells))}") from None
        b = np.asarray(values)
        where = f"--beliefs: {path}:{lineno}"
        if b.size != model.S:
            raise ModelError(f"{where}: expected {model.S} probabilities (one per state), got {b.size}")
        if not np.all(np.isfinite(b)) or np.any(b < 0):
            raise ModelError(f"{where}: probabilities must be finite and non-negative")
        if abs(b.sum() - 1.0) > 1e-6:
            raise ModelError(f"{where}: probabilities sum to {b.sum():.9g}, not 1")
        rows.append(b / b.sum())
        if len(rows) > MAX_BELIEFS:
            raise ModelError(f"--beliefs: {path}: more than {MAX_BELIEFS:,} beliefs (MAX_BELIEFS)")
    if not rows:
        raise ModelError(f"--beliefs: {path} contains no beliefs")
    return np.array(rows)


def _csv_rows(text: str, path: Path) -> Iterator[tuple[int, list[str]]]:
    """``(line number, cells)`` of the CSV ``text``; the csv module's errors (a field over its
    size limit) as ``ModelError`` naming the line."""
    reader = csv.reader(text.splitlines())
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise ModelError(f"--beliefs: {path}:{reader.line_num}: {exc}") from None
        yield reader.line_num, row


def evaluate(sol: BoundsSolution, B: np.ndarray, guaranteed: bool) -> dict:
    """Per-belief lower/upper priorities, whether they agree and whether that certifies the action
    (agreeing *guaranteed* bounds, Proposition 1), and the agreement rate (None if infeasible)."""
    mb = sol.myopic
    if mb is None:
        return {"beliefs": [{"belief": b.tolist(), "lower": None, "upper": None, "agree": None, "certified": False}
                            for b in B], "agreement_rate": None}
    lo, up = mb.actions(B)
    items = [{"belief": b.tolist(), "lower": int(priority_of(lo_)), "upper": int(priority_of(up_)),
              "agree": bool(lo_ == up_), "certified": bool(guaranteed and lo_ == up_)}
             for b, lo_, up_ in zip(B, lo, up, strict=True)]
    return {"beliefs": items, "agreement_rate": float(np.mean(lo == up))}


def run(args: argparse.Namespace) -> int:
    model = load_model_arg(args)
    if args.beliefs is not None:
        B = read_beliefs_csv(args.beliefs, model)
        source = f"file {args.beliefs}"
    else:
        # displayed beliefs come from a different stream than the tight variant's fitting samples
        B = sample_beliefs(model, args.samples, seed=args.seed + 1)
        source = f"{args.samples} sampled reachable beliefs (seed {args.seed})"
    sol = solve_bounds(model, args.variant, constant=args.constant, samples=FIT_SAMPLES, seed=args.seed)
    verdict = bounds_verdict(model, sol)
    ev = evaluate(sol, B, verdict.guaranteed)
    if args.json:
        out = {"guaranteed": verdict.guaranteed, "reason": verdict.reason, **sol.to_dict(),
               "assumptions": dict(verdict.report.status), "belief_source": source, **ev}
        if not verdict.guaranteed:
            out["covers"] = f"none: not guaranteed ({verdict.reason})"
        emit_json(out)
    else:
        print(_text(model, sol, verdict, ev, source))
    return 0 if verdict.guaranteed else 1


def _vec(v: np.ndarray | None) -> str:
    return "-" if v is None else "[" + ", ".join(f"{x:.6g}" for x in v) + "]"


def _text(model: POMDP, sol: BoundsSolution, verdict: BoundsVerdict, ev: dict, source: str) -> str:
    c = sol.constants
    const = f"{c['constant']}, K_f = {c['K_f']:.6g}"
    if "C_used" in c:
        const += (f" (Renyi: steps >= 2 C |w_a| with C = {c['C_used']:.6g}; MLR-exact C = {c['C_mlr']:g}, "
                  f"FOSD C_S = {c['C_fosd']:.6g})")
    if "epsilon" in c:
        const += f" (Shannon on B_epsilon, epsilon = {c['epsilon']:g}; the paper uses -log eps = " \
                 f"{c['log_ratio_bound_paper']:.6g})"
    lines = [verdict.describe()]
    if not verdict.guaranteed and sol.feasible:
        lines.append("  the LP solution below is a diagnostic only: these bounds may exclude the optimal action, "
                     "and their agreement certifies nothing")
    lines += [
        model.describe(),
        f"variant: {sol.variant}   feasible: {'yes' if sol.feasible else 'NO'} "
        f"(g: {'yes' if sol.g_feasible else 'no'}, h: {'yes' if sol.h_feasible else 'no'})   "
        f"solve time: {sol.solve_time:.3f} s",
        f"constant: {const}",
        f"  why: {c['why']}",
        f"guarantee covers: {sol.covers if verdict.guaranteed else 'nothing (NOT GUARANTEED: see the first line)'}",
        f"g = {_vec(sol.g)}",
        f"h = {_vec(sol.h)}",
    ]
    if sol.message not in verdict.reason:  # an infeasible LP's message is the verdict's reason
        lines.append(sol.message)
    if not sol.feasible:
        for which, mv in (sol.most_violated or {}).items():
            if "violation" in mv:
                conf = ", ".join(f"(priority {x['priority']}, states {x['state_pair'][0]}-{x['state_pair'][1]})"
                                 for x in mv["conflicting"])
                lines.append(f"most violated ({which}): priority {mv['priority']}, states "
                             f"{mv['state_pair'][0]}-{mv['state_pair'][1]}, by {mv['violation']:.6g}; "
                             f"conflicting constraints: {conf}")
        lines.append("no myopic bounds: the planner must search all actions")
        return "\n".join(lines)
    rows = [[k + 1, ", ".join(f"{x:.4f}" for x in it["belief"]), it["lower"], it["upper"],
             "yes" if it["agree"] else "no"] for k, it in enumerate(ev["beliefs"])]
    agree, rate = ("agree (certified)", "agreement rate") if verdict.guaranteed else \
        ("agree (NOT GUARANTEED)", "agreement rate (NOT GUARANTEED: certifies nothing)")
    lines += ["", f"beliefs: {source}",
              format_table(["#", "belief", "lower", "upper", agree], rows),
              f"{rate}: {ev['agreement_rate']:.3f} "
              f"({sum(it['agree'] for it in ev['beliefs'])}/{len(ev['beliefs'])})"]
    return "\n".join(lines)
