"""The sensor manager's parameters as the core checks them: the targets' namespaces, the efforts
as one flat list (a parameter cannot be a list of lists), the problem they make, and the
parameters that may change at run time (the loop: :mod:`.manager_loop`; the node's descriptors
state the ranges, these checks are the core's behind them)."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from fractions import Fraction
from typing import Any

from ..checks import check_int, check_number
from ..errors import OptionError, kind_of, short_repr
from ..model import POMDP
from ..multitarget.problem import MultiTargetProblem, as_rational, make_problem
from ..options import MAX_DEPTH_RANGE, TIME_BUDGET_RANGE

#: Parameters that may change while the loop runs (in force from the next decision).
TUNABLE = ("time_budget", "max_depth", "gather_timeout", "deadline_slack")
#: Their ranges, inclusive (seconds but ``max_depth``): the planners' (:mod:`~pomdp_planner.core.options`),
#: ``gather_timeout`` up to a minute, ``deadline_slack`` as the planner node's.
RANGES = {"time_budget": TIME_BUDGET_RANGE, "max_depth": MAX_DEPTH_RANGE, "gather_timeout": (0.0, 60.0),
          "deadline_slack": (0.0, 10.0)}
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def check_targets(values: Sequence[Any], field: str = "targets") -> tuple[str, ...]:
    """The targets' namespaces: at least one, each a relative or absolute name of tokens (letters,
    digits, ``_``; not starting with a digit) separated by ``/``, no two the same."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise OptionError(f"{field}: must be a list of namespaces, got {kind_of(values)}")
    if not values:
        raise OptionError(f"{field}: give at least one target namespace, e.g. [target1, target2]")
    names: list[str] = []
    for k, v in enumerate(values):
        text = v if isinstance(v, str) else None
        body = None if text is None else text[1:] if text.startswith("/") else text
        if not body or not all(_TOKEN.fullmatch(t) for t in body.split("/")):
            raise OptionError(f"{field}[{k}]: {short_repr(v)} is not a namespace (tokens of letters, digits and _, "
                              "not starting with a digit, separated by /)")
        if text in names:
            raise OptionError(f"{field}[{k}]: {short_repr(v)} is given twice (one namespace per target)")
        names.append(text)
    return tuple(names)


def split_efforts(values: Sequence[float] | None, models: Sequence[POMDP],
                  field: str = "efforts") -> list[list[Fraction]] | None:
    """One flat list of efforts as one list per target: ``A`` values (in priority order ``1..A``)
    for every target (all targets with ``A`` priorities), or ``sum_k A_k`` values, target after
    target; ``None`` or empty: every target's default (:func:`~..multitarget.problem.default_efforts`).
    Each value is an exact non-negative rational (:func:`~..multitarget.problem.as_rational`; an
    error names its place in the flat list)."""
    if not values:
        return None
    values = [as_rational(x, f"{field}[{i}]") for i, x in enumerate(values)]
    sizes = [m.A for m in models]
    if len(set(sizes)) == 1 and len(values) == sizes[0]:
        return [values] * len(models)
    if len(values) == sum(sizes):
        out, i = [], 0
        for a in sizes:
            out.append(values[i:i + a])
            i += a
        return out
    shared = f"{sizes[0]} (one per priority, for every target) or " if len(set(sizes)) == 1 else ""
    raise OptionError(f"{field}: {len(values)} values; expected {shared}{sum(sizes)} (every target's priorities, "
                      f"target after target: {', '.join(map(str, sizes))})")


def manager_problem(targets: Sequence[str], models: Sequence[POMDP], budget: Any,
                    efforts: Sequence[float] | None = None, discount: float | None = None) -> MultiTargetProblem:
    """The multi-target problem of the manager's parameters (``effort_budget``, ``efforts``,
    ``discount``; ``discount`` ``None``: the models' common one); errors name the parameter."""
    if len(models) != len(targets):
        raise OptionError(f"model_files: {len(models)} model files for {len(targets)} targets (one per target)")
    rows = split_efforts(efforts, models)
    return make_problem(models, budget=budget, efforts=rows, discount=discount, names=targets,
                        fields={"budget": "effort_budget"})


def check_params(values: Mapping[str, Any]) -> str:
    """Why ``values`` (some of :data:`TUNABLE`) cannot be used, or ``""``: each within its range
    (:data:`RANGES`; the node's descriptors state the same ones, which rclpy enforces first)."""
    try:
        for name, (lo, hi) in RANGES.items():
            if name not in values:
                continue
            check = check_int if name == "max_depth" else check_number
            check(values[name], name, lo, hi)
    except OptionError as exc:
        return str(exc)
    return ""
