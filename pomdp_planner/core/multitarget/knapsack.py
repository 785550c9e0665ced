"""The exact multiple-choice knapsack that chooses the joint action.

Given, for every target ``k`` and action ``a``, a value ``v_k(a)`` and an integer weight
``w_k(a) >= 0`` (the effort in the units of :attr:`~.problem.MultiTargetProblem.scale`), and an
integer capacity ``C``, find

    max_{a_1..a_K} sum_k v_k(a_k)   subject to   sum_k w_k(a_k) <= C,

one action per target. Dynamic programming over the capacity: ``T_0(c) = 0`` and
``T_k(c) = max_{a: w_k(a) <= c} T_{k-1}(c - w_k(a)) + v_k(a)`` for ``c = 0..C``; ``T_K(C)`` is the
optimum and the maximisers, stored per ``(k, c)``, give the joint action back. Exact: the weights
are integers, so feasibility is never decided up to rounding, and every joint action within the
capacity is a path through the table. ``O(K A C)`` time (vectorised over ``c``), ``O(K C)``
memory; ``C`` is at most the largest joint effort (:attr:`~.problem.MultiTargetProblem.knapsack_capacity`).

Ties: of equal values, the smallest action index (the highest priority) of the last target
decided wins first; the result is deterministic. ``-inf`` values mark actions that may not be
taken; if no joint action has a finite value the knapsack raises ``ValueError``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def solve_knapsack(values: Sequence[np.ndarray], weights: Sequence[np.ndarray], capacity: int
                   ) -> tuple[float, tuple[int, ...]]:
    """``(optimum, joint action)`` of the multiple-choice knapsack (module docstring).

    ``values[k]`` and ``weights[k]`` have one entry per action of target ``k`` (weights
    non-negative integers); ``capacity`` a non-negative integer.
    """
    C = int(capacity)
    if C < 0:
        raise ValueError(f"capacity: must be >= 0, got {capacity}")
    table = np.zeros(C + 1)  # T_0(c) = 0 for every c >= 0 ("total weight <= c")
    choices = []
    for k, (v, w) in enumerate(zip(values, weights, strict=True)):
        v = np.asarray(v, dtype=float)
        w = np.asarray(w)
        if v.shape != w.shape or v.ndim != 1 or v.size == 0:
            raise ValueError(f"values[{k}], weights[{k}]: need one value and one weight per action")
        if np.any(np.isnan(v)):
            raise ValueError(f"values[{k}]: NaN")
        if np.any(w < 0) or not np.issubdtype(w.dtype, np.integer):
            raise ValueError(f"weights[{k}]: must be non-negative integers")
        cand = np.full((v.size, C + 1), -np.inf)
        for a in range(v.size):
            wa = int(w[a])
            if wa <= C:
                cand[a, wa:] = table[:C + 1 - wa] + v[a]
        best = np.argmax(cand, axis=0)  # first maximiser: the smallest action index
        table = cand[best, np.arange(C + 1)]
        choices.append(best)
    if not np.isfinite(table[C]):
        raise ValueError("no joint action within the capacity has a finite value")
    c, actions = C, []
    for k in range(len(choices) - 1, -1, -1):
        a = int(choices[k][c])
        actions.append(a)
        c -= int(np.asarray(weights[k])[a])
    return float(table[C]), tuple(reversed(actions))
