"""The target-tracking domain of the paper's Sec. VI, for any S and A.

* Transitions: ``A_{ij} = exp(x_i y_j)`` for ``i = 1..S``, ``j = 1..S*A``, each column
  normalised to sum to one; ``T^a`` is the block of columns ``(a-1)S+1 .. aS``. A column of
  ``T^a`` is the distribution of the next state ``i`` given the previous state ``j``, so in
  our row-stochastic convention ``P[a] = (T^a)^T``:
  ``P[a, j, i] = exp(x_i y_{aS+j}) / sum_k exp(x_k y_{aS+j})`` (0-based ``a``, ``j``).
  Columns are normalised with a log-sum-exp so large S does not underflow.
* Observations: ``Z = S``, correct with probability ``q``; otherwise an adjacent state,
  ``(1-q)/2`` each side, and a boundary state puts all of ``1-q`` on its single neighbour
  (Eq. 9 with the paper's ``i`` typo read as ``j``). Identical for every action.
* Default sequences, generalising the paper's S = 3 choice (``x = {1,2,3}``,
  ``y = {-9,...,-1}``) to any S and A while keeping the range of ``x_i y_j`` fixed, so the
  dynamics keep the same character at every size:
  ``x_i = 3 i / S`` (i = 1..S) and ``y`` = ``S*A`` points evenly spaced on ``[-9, -1]``.
  Both give exactly the paper's sequences for S = A = 3.
* Sec. VI-B comparison reward ``r(s,a) = -c_a (A - a + 1) + t(s, a)`` (1-based ``s``, ``a``)
  with ``c_a = 1/(2A)``, ``c_p = 1``, ``c_d = 0.1``, ``k_r = 2/S``, poor-tracking region
  ``s <= S/5`` and dangerous region ``s >= 9S/10``.
* Sizes: ``S`` and ``A`` must be integers >= 1 and the model's matrices must fit in
  ``MAX_MODEL_BYTES`` (``core.model.check_model_size``); both are checked before anything
  is allocated, so a generator asked for S = 5000 refuses at once instead of allocating gigabytes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.special import logsumexp

from ..model import POMDP, ModelError, as_count, check_model_size


def _check_sizes(S: int, A: int) -> tuple[int, int]:
    """``S``, ``A`` as counts, and the model's ``P`` and ``O`` (Z = S) within ``MAX_MODEL_BYTES``."""
    S, A = as_count(S, "generator.S"), as_count(A, "generator.A")
    check_model_size(S, A, S, "generator")
    return S, A


def default_x(S: int) -> np.ndarray:
    """``x_i = 3 i / S``: the paper's ``{1, 2, 3}`` for S = 3, same range for any S."""
    return 3.0 * np.arange(1, S + 1) / S


def default_y(S: int, A: int) -> np.ndarray:
    """``S*A`` evenly spaced values on ``[-9, -1]``: the paper's ``{-9,...,-1}`` for S=A=3."""
    n = S * A
    return np.linspace(-9.0, -1.0, n) if n > 1 else np.array([-1.0])


def tracking_transitions(S: int, A: int, x: Sequence[float] | None = None,
                         y: Sequence[float] | None = None) -> np.ndarray:
    """Transition matrices ``P`` (A x S x S, row-stochastic) of Sec. VI."""
    S, A = _check_sizes(S, A)
    x = default_x(S) if x is None else np.asarray(x, dtype=float)
    y = default_y(S, A) if y is None else np.asarray(y, dtype=float)
    if x.shape != (S,):
        raise ModelError(f"generator.x: expected {S} values (one per state), got {x.size}")
    if y.shape != (S * A,):
        raise ModelError(f"generator.y: expected S*A = {S * A} values, got {y.size}")
    if np.any(np.diff(x) <= 0) or np.any(np.diff(y) <= 0):
        raise ModelError("generator.x/y: both sequences must be strictly increasing (TP2 kernel)")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ModelError("generator.x/y: values must be finite")
    with np.errstate(over="ignore", invalid="ignore"):
        logk = np.outer(x, y)  # (S, S*A): log A_{ij}
        logk -= logsumexp(logk, axis=0, keepdims=True)  # column-normalised
        cols = np.exp(logk, out=logk)  # column j = distribution of the next state i
        # T^a = columns a*S .. (a+1)*S-1; P[a] = (T^a)^T so rows are previous states.
        P = cols.reshape(S, A, S).transpose(1, 2, 0)  # P[a, j, i] = cols[i, a*S + j]
        P = P / P.sum(axis=-1, keepdims=True)
    if not np.all(np.isfinite(P)):
        raise ModelError("generator.x/y: values too large: products x_i y_j overflow, transitions are not finite")
    return P


def tracking_observations(S: int, A: int, q: float) -> np.ndarray:
    """Observation matrices ``O`` (A x S x S) of Eq. 9, identical for every action."""
    S, A = _check_sizes(S, A)
    if not 0.0 < q <= 1.0:
        raise ModelError(f"generator.q: observation accuracy must be in (0, 1], got {q}")
    O = np.zeros((S, S))
    if S == 1:
        O[0, 0] = 1.0
    else:
        for j in range(S):
            O[j, j] = q
            neighbours = [k for k in (j - 1, j + 1) if 0 <= k < S]
            for k in neighbours:
                O[j, k] = (1.0 - q) / len(neighbours)
    return np.broadcast_to(O, (A, S, S)).copy()


def comparison_reward(S: int, A: int, c_a: float | None = None, c_p: float = 1.0,
                      c_d: float = 0.1, k_r: float | None = None) -> np.ndarray:
    """The Sec. VI-B state reward ``r(s, a) = -c_a (A - a + 1) + t(s, a)`` (S x A)."""
    c_a = 1.0 / (2 * A) if c_a is None else float(c_a)
    k_r = 2.0 / S if k_r is None else float(k_r)
    s = np.arange(1, S + 1, dtype=float)
    t = k_r * s
    poor = s <= S / 5.0
    danger = s >= 9.0 * S / 10.0
    t = np.where(danger, -c_d / (S - s + 1.0), t)
    t = np.where(poor, -c_p / s, t)  # the poor region wins where both apply (tiny S)
    a = np.arange(1, A + 1, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):  # a huge parameter: the model refuses the result
        return t[:, None] - c_a * (A - a + 1.0)[None, :]


def tracking_model(S: int, A: int, q: float, r: np.ndarray, gamma: float = 0.99,
                   x: Sequence[float] | None = None, y: Sequence[float] | None = None,
                   uncertainty: str = "none", w: Sequence[float] | None = None,
                   epsilon: float = 1e-3, name: str | None = None) -> POMDP:
    """A complete Sec. VI tracking POMDP."""
    return POMDP(
        P=tracking_transitions(S, A, x, y), O=tracking_observations(S, A, q), r=r, gamma=gamma,
        uncertainty=uncertainty, w=w, epsilon=epsilon, name=name or f"tracking_s{S}_a{A}",
        metadata={"generator": {"domain": "tracking", "S": S, "A": A, "q": q,
                                "x": None if x is None else list(map(float, x)),
                                "y": None if y is None else list(map(float, y))}},
    )
