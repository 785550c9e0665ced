"""``pomdp-planner check MODEL [--json]``: validate a model and check Assumption 1 (paper Sec. III).

Prints the model summary (name, sizes, discount, uncertainty function and weights), then the
(A1)-(A3) report of :func:`pomdp_planner.core.structure.check_assumptions`. Exit codes:
0 = Assumption 1 holds, 1 = it fails or could not be proven, 2 = the model is malformed
(the error names the field and the problem). A check expected to take more than a few seconds
(:func:`pomdp_planner.core.structure.estimate_check`) is announced on stderr, with the expected
time, before it starts.
"""

from __future__ import annotations

import argparse
import sys

from ..core.gate import check_notice
from ..core.model import POMDP, infinite_horizon_refusal
from ..core.structure import EXACT_MAX_STATES, SDP_MAX_STATES, check_assumptions, estimate_check
from ._common import (
    add_json_argument,
    add_model_argument,
    add_seed_argument,
    emit_json,
    float_in,
    int_in,
    load_model_arg,
)

#: ``--tol``: the tolerances are relative (core/structure.py); above 1e-3 a test would accept
#: violations a thousand times larger than rounding, and a negative one would refuse exact zeros.
TOL_RANGE = (0.0, 1e-3)


def model_summary(model: POMDP) -> dict:
    """Name, sizes, discount and reward parameters (weights per priority 1..A)."""
    return {
        "name": model.name, "S": model.S, "A": model.A, "Z": model.Z, "gamma": model.gamma,
        "uncertainty": model.uncertainty.name, "weights": [float(w) for w in model.w],
        "epsilon": model.epsilon,
    }


def _text(model: POMDP, report) -> str:
    s = model_summary(model)
    weights = ", ".join(f"{w:g}" for w in s["weights"])
    lines = [
        f"model: {s['name']}",
        f"  S={s['S']} states, A={s['A']} actions (priorities 1..{s['A']}), Z={s['Z']} observations, "
        f"gamma={s['gamma']:g}",
        f"  uncertainty: {s['uncertainty']}, weights per priority [{weights}]",
        "  validation: OK (shapes, probabilities, rows sum to 1, 0 <= gamma <= 1)",
    ]
    horizon = infinite_horizon_refusal(model, "the bound LP (Theorem 2)")
    if horizon:
        lines.append(f"  {horizon}; plan and simulate search exhaustively")
    lines += [
        "",
        report.summary(),
    ]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    model = load_model_arg(args)
    notice = check_notice(estimate_check(model, sdp_max_states=args.sdp_max_states,
                                         exact_max_states=args.exact_max_states), model)
    if notice is not None:
        print(f"pomdp-planner check: {notice}", file=sys.stderr, flush=True)
    report = check_assumptions(model, tol=args.tol, sdp_max_states=args.sdp_max_states, seed=args.seed,
                               exact_max_states=args.exact_max_states)
    if args.json:
        emit_json({"model": model_summary(model), "valid": True, "assumptions": report.to_dict()})
    else:
        print(_text(model, report))
    return 0 if report.holds else 1


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "check", help="validate a model and check the structural assumptions (A1)-(A3)",
        description="Validate MODEL and check Assumption 1 of the paper: (A1) TP2 transitions and "
        "observations, (A2) copositivity of every D^(j,a,z), (A3) first-order dominance of the "
        "predicted observation. Exit code 0 if it holds, 1 if it fails or is not proven, 2 if "
        "the model is malformed.",
    )
    add_model_argument(p)
    add_json_argument(p)
    p.add_argument("--tol", type=float_in(*TOL_RANGE), default=1e-9, metavar="TOL",
                   help=f"tolerance of every test, {TOL_RANGE[0]:g}..{TOL_RANGE[1]:g} (default 1e-9; relative, "
                        "see core/structure.py)")
    p.add_argument("--sdp-max-states", type=int_in(0, None), default=SDP_MAX_STATES, metavar="N",
                   help=f"attempt the (A2) SDP certificate only for S <= N, N >= 0 (default {SDP_MAX_STATES})")
    p.add_argument("--exact-max-states", type=int_in(0, None), default=EXACT_MAX_STATES, metavar="N",
                   help=f"exact (A2) small-support test only for S <= N, N >= 0 (default {EXACT_MAX_STATES})")
    add_seed_argument(p, "seed of the counterexample search (default 0)")
    p.set_defaults(func=run)
