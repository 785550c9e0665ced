"""The price ``lambda`` and the dual bound (docs/THEORY.md, "Several targets").

For a depth-``d`` lookahead (the search convention of ``core/search.py``: ``d`` action-observation
levels below the root, so ``d + 1`` decisions, ``t = 0..d``) and a price ``lambda >= 0``:

* ``L(lambda) = sum_k V_k^lambda(b_k) + lambda B sum_{t=0}^{d} gamma^t`` (weak duality; every
  epoch's budget is priced), and
* ``U(lambda) = max_{a within B} sum_k [Q_k^lambda(b_k, a_k) + lambda e_k(a_k)] + lambda B sum_{t=1}^{d} gamma^t``
  (the root epoch's budget kept exactly by the knapsack, only the later epochs priced);

``V* <= U(lambda) <= L(lambda)`` for the depth-``d`` joint lookahead value ``V*`` whenever the
per-target values are the exact depth-``d`` values of the priced problems (exhaustive search);
then both are also convex in ``lambda`` (maxima of functions affine in ``lambda``). With
branch-and-bound values (a maximum over the actions the bounds keep, which change with the
price) ``U`` is an estimate: it may fall below ``V*`` and need not be convex. The planner
minimises ``U``.

**The search for lambda** (:func:`minimise_convex`): warm-started at the previous epoch's (or the
previous depth's) price ``x0``; a bracket is found by stepping from ``x0`` (step ``x0 / 4``, at
least the ceiling / 1024; from 0, :func:`lambda_ceiling` / 32) and doubling the step while ``U``
decreases; then golden-section search inside the bracket. It returns the least value it has
evaluated (ties: the smallest price), also when its evaluation budget stops it early: with exact
values every evaluation is a valid bound (weak duality holds at every ``lambda >= 0``), so that
is the best bound found, and on a convex ``U`` the bracket holds a minimiser. With
branch-and-bound estimates the search is a heuristic: it returns the least estimate it has seen,
which need not be near a minimiser of a non-convex ``U``. The price never needs to exceed
:func:`lambda_ceiling`: above it every target's priced optimum uses its least effort at every
node below the root, so the exact ``U`` no longer decreases (docs/THEORY.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..model import POMDP

#: Golden-section fraction ``(3 - sqrt 5) / 2``.
GOLDEN = (3.0 - math.sqrt(5.0)) / 2.0
#: The bracket search stops when its width is below this share of the ceiling.
LAMBDA_XTOL = 1e-6


def horizon_sum(gamma: float, first: int, last: int) -> float:
    """``sum_{t=first}^{last} gamma^t`` (0 if ``last < first``)."""
    return float(sum(gamma ** t for t in range(first, last + 1)))


def reward_range_bound(model: POMDP) -> float:
    """An upper bound on ``sup rho - inf rho`` over beliefs and actions (Eq. 3): ``rho(b, a) =
    b . r_a - w_a f(b)`` with ``0 <= f <= log S`` (Shannon and Renyi quadratic entropy; ``f = 0``
    for ``none``)."""
    fmax = 0.0 if model.uncertainty.name == "none" else math.log(model.S)
    w = np.asarray(model.w, dtype=float)
    hi = float(model.r.max()) + fmax * float(np.maximum(-w, 0.0).max())
    lo = float(model.r.min()) - fmax * float(np.maximum(w, 0.0).max())
    return hi - lo


def lambda_ceiling(models: list[POMDP] | tuple[POMDP, ...], efforts: list[np.ndarray], depth: int) -> float:
    """A price above which ``U`` does not decrease: ``max_k R_k sum_{t=0}^{d} gamma^t / delta_k``,
    ``R_k`` :func:`reward_range_bound`, ``delta_k`` the least positive effort step of target ``k``
    above its least effort (targets whose efforts are all equal do not count); 0 if none count."""
    ceiling = 0.0
    for m, e in zip(models, efforts, strict=True):
        e = np.asarray(e, dtype=float)
        steps = e[e > e.min()] - e.min()
        if steps.size:
            ceiling = max(ceiling, reward_range_bound(m) * horizon_sum(m.gamma, 0, depth) / float(steps.min()))
    return ceiling


@dataclass(frozen=True)
class PriceSearch:
    """The outcome of :func:`minimise_convex`: the best price, its value, every ``(lambda, value)``
    evaluated (in order) and the final bracket."""

    x: float
    value: float
    evaluations: tuple[tuple[float, float], ...]
    bracket: tuple[float, float]


def minimise_convex(f: Callable[[float], float], ceiling: float, x0: float, max_evals: int) -> PriceSearch:
    """Minimise a convex ``f`` on ``[0, ceiling]`` with at most ``max_evals`` evaluations (>= 2),
    warm-started at ``x0`` (module docstring). Exceptions of ``f`` propagate (a deadline)."""
    seen: dict[float, float] = {}
    order: list[tuple[float, float]] = []

    def ev(x: float) -> float:
        x = float(min(max(x, 0.0), ceiling))
        if x not in seen:
            seen[x] = float(f(x))
            order.append((x, seen[x]))
        return seen[x]

    def result(lo: float, hi: float) -> PriceSearch:
        best = min(seen.values())
        x = min(k for k, v in seen.items() if v <= best)
        return PriceSearch(x, seen[x], tuple(order), (lo, hi))

    x0 = float(min(max(x0, 0.0), ceiling))
    if ceiling <= 0.0:
        ev(0.0)
        return result(0.0, 0.0)
    step = max(x0 / 4.0, ceiling / 1024.0) if x0 > 0.0 else ceiling / 32.0
    # Bracket (a, b, c): f(b) <= f(a), f(b) <= f(c), so a minimiser lies in [a, c] (convexity).
    b = x0
    fb = ev(b)
    c = min(b + step, ceiling)
    fc = ev(c)
    if fc < fb:  # descend to the right, doubling the step
        a, b, fb = b, c, fc
        while True:
            if len(seen) >= max_evals or b >= ceiling:
                return result(a, b) if b >= ceiling else result(a, min(b + step, ceiling))
            step *= 2.0
            c = min(b + step, ceiling)
            fc = ev(c)
            if fc >= fb:
                break
            a, b, fb = b, c, fc
    elif b > 0.0:
        a = max(b - step, 0.0)
        fa = ev(a)
        if fa < fb:  # descend to the left
            c, b, fb = b, a, fa
            while b > 0.0:
                if len(seen) >= max_evals:
                    return result(max(b - step, 0.0), c)
                step *= 2.0
                a = max(b - step, 0.0)
                fa = ev(a)
                if fa >= fb:
                    break
                c, b, fb = b, a, fa
            if b == 0.0:
                a = 0.0
    else:
        a = 0.0
    xtol = LAMBDA_XTOL * ceiling
    while len(seen) < max_evals and c - a > xtol:
        x = b + GOLDEN * (c - b) if c - b >= b - a else b - GOLDEN * (b - a)
        if x in seen:
            break
        fx = ev(x)
        if fx < fb:
            if x > b:
                a = b
            else:
                c = b
            b, fb = x, fx
        elif x > b:
            c = x
        else:
            a = x
    return result(a, c)
