"""Structural assumptions of the paper (Sec. III, Assumption 1): checks with certificates.

The myopic policy bounds (Theorem 1, Corollary 1, Theorem 2) are only guaranteed when the
model satisfies Assumption 1 (Krishnamurthy & Pareek 2015). This module checks it, in our
convention ``P[a, i, j] = P(next = j | prev = i, a)``, ``O[a, j, z] = P(z | next = j, a)``,
0-based. The paper's indices are translated here, once (see also docs/THEORY.md):

* (A1) ``T^a`` and ``O^a`` are TP2: every 2x2 minor ``M[i,k] M[j,l] - M[i,l] M[j,k]`` with
  ``i < j``, ``k < l`` is non-negative. A minor of ``M^T`` is a minor of ``M``, so it does not
  matter whether ``T^a`` is read with previous states as rows or columns; what matters is that
  both indices keep their natural (increasing) order. We check ``P[a]`` (rows = previous
  state, columns = next state) and ``O[a]`` (rows = next state, columns = observation).
* (A2) The paper's ``d^{j,a,z}_{m,n} = O^a_{z,j} O^{a+1}_{z,j+1} T^a_{m,j} T^{a+1}_{n,j+1}
  - O^a_{z,j+1} O^{a+1}_{z,j} T^a_{m,j+1} T^{a+1}_{n,j}`` uses ``T^a_{m,j}`` as the probability
  of moving from ``m`` to ``j``, i.e. ``P[a, m, j]``. Derivation, from what it must guarantee
  (Lemma 1 (L2), ``tau(b, a+1, z) >=_r tau(b, a, z)``): with ``tau_a(j) ∝ O[a,j,z] (b P[a])_j``,
  the adjacent likelihood-ratio condition
  ``tau_{a+1}(j+1) tau_a(j) - tau_{a+1}(j) tau_a(j+1) >= 0`` is, up to the positive factor
  ``eta(z|b,a) eta(z|b,a+1)``, the quadratic form ``b^T d b`` with::

      d[m, n] = O[a,j,z] O[a+1,j+1,z] P[a,m,j] P[a+1,n,j+1]
              - O[a,j+1,z] O[a+1,j,z] P[a,m,j+1] P[a+1,n,j]

  and ``b^T d b = b^T D b / 2`` with ``D = d + d^T``. So (A2) asks that every ``D^{j,a,z}``
  (``j = 0..S-2``, ``a = 0..A-2``, ``z = 0..Z-1``) be copositive (``x^T D x >= 0`` for
  ``x >= 0``). Three answers, cheapest first: elementwise non-negativity (A2', sufficient);
  ``D = PSD + N`` with ``N >= 0`` elementwise, an SDP solved with Clarabel (sufficient; exact
  for S <= 4 by Diananda's theorem); a search for ``x >= 0`` with ``x^T D x < 0``
  (a counter-certificate: closed form on all 2-element supports, then projected gradient on
  the simplex from random and eigenvector starts).
* (A3) ``sum_{z <= zbar} sum_j [T^a_{ij} O^a_{zj} - T^{a+1}_{ij} O^{a+1}_{zj}] >= 0`` is, with
  ``T^a_{ij} = P[a, i, j]`` and ``O^a_{zj} = O[a, j, z]``,
  ``cumsum_z (P[a] @ O[a])[i, :] >= cumsum_z (P[a+1] @ O[a+1])[i, :]``. Row ``i`` of
  ``P[a] @ O[a]`` is ``eta(. | e_i, a)``, so (A3) says: from every state, the predicted
  observation under ``a+1`` first-order stochastically dominates that under ``a``; since
  ``eta(. | b, a)`` is linear in ``b``, that is Lemma 1 (L1) for every belief.

Tolerances (``tol``, default 1e-9) are relative where the quantities are products of small
probabilities: a 2x2 minor is compared with ``-tol`` times the sum of its two products, the
entries of ``D`` and ``x^T D x`` (``x`` on the simplex) with ``-tol max|D|``; the (A3) margins
are differences of probabilities and are compared with ``-tol`` itself. (An absolute 1e-9 on
``D``, whose entries are products of four probabilities, accepted real violations.)
Actions are 0-based here; user-facing text names the action pair ``(a, a+1)`` by tracking
priorities ``(a+1, a+2)``.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field, replace
from itertools import combinations

import clarabel
import numpy as np
import scipy.sparse as sp

from .model import POMDP

#: Default largest S for which the (A2) SDP certificate is attempted.
SDP_MAX_STATES = 16
#: Relative tolerance of the PSD part of a certificate: ``lambda_min(D / max|D| - N) >= -SDP_TOL``.
SDP_TOL = 1e-7
#: Largest number of 2x2 minors (per matrix) computed in one numpy block.
_MINOR_BLOCK = 4_000_000
#: Matrices with at most this many 2x2 minors have all of them computed (else see tp2_method).
TP2_FULL_MAX = 1_000_000
#: Largest number of ``D`` entries materialised at once.
_D_BLOCK = 4_000_000

#: Default largest S for the exact small-support test of matrices with <= 2 positive eigenvalues.
EXACT_MAX_STATES = 96
#: Eigenvalues of ``D / max|D|`` above this count as positive (the small-support test).
_POS_EIG = 1e-10
#: Largest number of (matrix, triple) pairs handled in one numpy block.
_TRIPLE_BLOCK = 2_000_000

#: Relative safety margin of the separable lower bound of the (A2') ratio (:func:`check_copositivity`):
#: far above the rounding of the few products involved, so that whatever it clears the exact
#: ratio test clears too.
_SEPARABLE_MARGIN = 1e-12

# Status codes of each D^{j,a,z}; codes <= PROVEN_DOMINATED are proofs.
PROVEN_ELEMENTWISE = 0
PROVEN_SDP = 1
PROVEN_EXACT = 2
PROVEN_DOMINATED = 3
REFUTED = 4
UNKNOWN = 5
UNKNOWN_SDP_SKIPPED = 6
UNKNOWN_UNDERFLOW = 7
STATUS_NAMES = {
    PROVEN_ELEMENTWISE: "proven (A2': elementwise non-negative)",
    PROVEN_SDP: "proven (certificate D = PSD + N, N >= 0: eigenvalues if N = 0, else SDP)",
    PROVEN_EXACT: "proven (exact: <= 2 positive eigenvalues, minimum over supports of size <= 3)",
    PROVEN_DOMINATED: "proven (dominated: c D^(j,a,w) + N with c > 0, N >= 0, and D^(j,a,w) proven, "
                      "w the observation of the largest ratio beta/alpha)",
    REFUTED: "refuted (x >= 0 with x^T D x < 0)",
    UNKNOWN: "unknown (no certificate, no counterexample found)",
    UNKNOWN_SDP_SKIPPED: "unknown (SDP skipped above S = {cap}; no counterexample found)",
    UNKNOWN_UNDERFLOW: "unknown (a positive probability of its frame is below 2^-240: products of four "
                       "leave the range where floating point keeps their sign)",
}

#: Products of two probabilities below this have lost relative precision (or underflowed to 0):
#: the relative 2x2 minor of (A1) is then taken from logarithms (:func:`minor_relative`).
_PRODUCT_SAFE = 2.0**-960
#: (A2) multiplies four probabilities: with every positive one at least this, each product is at
#: least 2^-960, a normal float with full relative precision. A ``D^{j,a,z}`` whose frame holds a
#: smaller positive probability cannot be proven (:data:`UNKNOWN_UNDERFLOW`; :func:`underflow_frames`).
SAFE_PROBABILITY = 2.0**-240
#: A refutation of such a ``D`` stands only when ``x^T D x`` is below minus this, far beyond the
#: absolute error of products that underflowed (a few times 2^-1074 per entry).
_UNDERFLOW_REFUTATION = 2.0**-900


def is_proven(codes: np.ndarray | int) -> np.ndarray | bool:
    """True where a status code is a proof of copositivity."""
    return np.asarray(codes) <= PROVEN_DOMINATED


def _status(holds: bool, refuted: bool = False) -> str:
    return "holds" if holds else ("fails" if refuted else "unknown")


# =============================================================================== (A1)
@dataclass(frozen=True)
class TP2Report:
    """(A1): worst 2x2 minor over all ``P[a]`` and ``O[a]``.

    ``matrix`` (``"transition"`` / ``"observation"``), the 0-based ``action``, ``rows`` ``(i, j)``
    and ``cols`` ``(k, l)`` locate the minor with the smallest ``worst_relative`` (the minor over
    the sum of its two products, see :func:`worst_tp2_minor`); ``worst_minor`` is its value.
    """

    holds: bool
    worst_minor: float
    matrix: str
    action: int
    rows: tuple[int, int]
    cols: tuple[int, int]
    num_negative: int
    tol: float
    methods: tuple[str, ...] = ("full",)
    worst_relative: float = 0.0

    @property
    def status(self) -> str:
        return _status(self.holds, refuted=not self.holds)

    def to_dict(self) -> dict:
        return {
            "status": self.status, "worst_minor": self.worst_minor, "worst_relative": self.worst_relative,
            "matrix": self.matrix,
            "priority": self.action + 1, "rows": list(self.rows), "cols": list(self.cols),
            "num_negative_minors": self.num_negative, "tol": self.tol, "methods": list(self.methods),
        }


def tp2_minors(M: np.ndarray) -> np.ndarray:
    """All 2x2 minors of a matrix (or stack ``(..., n, m)``), shape ``(..., n(n-1)/2, m(m-1)/2)``.

    Entry ``[p, q]`` is the minor with rows ``triu_indices(n, 1)[*][p]`` and columns
    ``triu_indices(m, 1)[*][q]``. Memory grows like ``n^2 m^2 / 4``; :func:`worst_tp2_minor`
    works in blocks.
    """
    M = np.asarray(M, dtype=float)
    i, j = np.triu_indices(M.shape[-2], 1)
    k, l = np.triu_indices(M.shape[-1], 1)
    Mi, Mj = M[..., i, :], M[..., j, :]
    return Mi[..., :, k] * Mj[..., :, l] - Mi[..., :, l] * Mj[..., :, k]


_Minor = tuple[float, tuple[int, int], tuple[int, int], int, float]


def _relative(minor: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """``minor / (|M_ik M_jl| + |M_il M_jk|)`` in [-1, 1] (0 where both products vanish)."""
    den = np.abs(p1) + np.abs(p2)
    return np.where(den > 0, minor / np.where(den > 0, den, 1.0), 0.0)


def minor_relative(x1: np.ndarray, y1: np.ndarray, x2: np.ndarray, y2: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(p1, p2, relative)`` of minors ``p1 - p2`` with ``p1 = x1 y1``, ``p2 = x2 y2`` (non-negative
    entries), ``relative = (p1 - p2) / (p1 + p2)`` (0 where both vanish). Where a product of
    positive entries falls below :data:`_PRODUCT_SAFE` its computed value has lost its relative
    precision (below 2^-1074 it is 0), so ``relative`` is taken there from logarithms,
    ``tanh((log p1 - log p2) / 2)``, whose sign is the exact minor's."""
    p1, p2 = x1 * y1, x2 * y2
    rel = _relative(p1 - p2, p1, p2)
    pos1, pos2 = (x1 > 0) & (y1 > 0), (x2 > 0) & (y2 > 0)
    low = (pos1 & (p1 < _PRODUCT_SAFE)) | (pos2 & (p2 < _PRODUCT_SAFE))
    if np.any(low):
        with np.errstate(divide="ignore", invalid="ignore"):
            s1 = np.where(pos1, np.log(np.where(pos1, x1, 1.0)) + np.log(np.where(pos1, y1, 1.0)), -np.inf)
            s2 = np.where(pos2, np.log(np.where(pos2, x2, 1.0)) + np.log(np.where(pos2, y2, 1.0)), -np.inf)
            exact = np.tanh((s1 - s2) / 2.0)
        rel = np.where(low, np.nan_to_num(exact, nan=0.0), rel)
    return p1, p2, rel


def _worst_minor_full(M: np.ndarray, tol: float) -> _Minor:
    n, m = M.shape
    ri, rj = np.triu_indices(n, 1)
    k, l = np.triu_indices(m, 1)
    Mk, Ml = M[:, k], M[:, l]  # (n, C)
    step = max(1, _MINOR_BLOCK // max(1, k.size))
    best, where, count = (np.inf, 0.0), (0, 0, 0), 0
    for start in range(0, ri.size, step):
        i, j = ri[start:start + step], rj[start:start + step]
        p1, p2, rel = minor_relative(Mk[i], Ml[j], Ml[i], Mk[j])  # (block, C)
        count += int(np.count_nonzero(rel < -tol))
        p, q = divmod(int(np.argmin(rel)), k.size)
        if rel[p, q] < best[0]:
            best, where = (float(rel[p, q]), float(p1[p, q] - p2[p, q])), (int(i[p]), int(j[p]), q)
    q = where[2]
    return best[1], (where[0], where[1]), (int(k[q]), int(l[q])), count, best[0]


def _worst_minor_adjacent(M: np.ndarray, tol: float) -> _Minor:
    """Contiguous minors only: for a matrix with positive entries, TP2 holds iff all
    ``M[i,k] M[i+1,k+1] - M[i,k+1] M[i+1,k] >= 0`` (the ratios ``M[i+1,k] / M[i,k]`` increase in
    ``k``, and ratios chain). The reported worst is the worst contiguous minor."""
    p1, p2, rel = minor_relative(M[:-1, :-1], M[1:, 1:], M[:-1, 1:], M[1:, :-1])
    i, k = np.unravel_index(int(np.argmin(rel)), rel.shape)
    return (float(p1[i, k] - p2[i, k]), (int(i), int(i) + 1), (int(k), int(k) + 1),
            int(np.count_nonzero(rel < -tol)), float(rel[i, k]))


def _worst_minor_sparse(M: np.ndarray, tol: float) -> _Minor:
    """Only minors that can be negative: ``M[i,l] > 0`` and ``M[j,k] > 0`` (``i < j``, ``k < l``);
    every other minor is ``M[i,k] M[j,l] >= 0``. Exact for negativity; when TP2 holds the
    reported worst is over these candidates (the minor on rows/cols (0, 1) if there are none)."""
    r, c = np.nonzero(M > 0)
    p1, p2, rel0 = minor_relative(M[0, 0], M[1, 1], M[0, 1], M[1, 0])
    best = (float(rel0), float(p1 - p2))
    where, count = (0, 1, 0, 1), 0
    step = max(1, _MINOR_BLOCK // max(1, r.size))
    first = True
    for start in range(0, r.size, step):
        i, l = r[start:start + step, None], c[start:start + step, None]  # (block, 1): entry (i, l)
        ok = (r[None, :] > i) & (c[None, :] < l)  # entry (j, k) with j > i, k < l
        bi, bj = np.nonzero(ok)
        if bi.size == 0:
            continue
        ii, ll, jj, kk = i[bi, 0], l[bi, 0], r[bj], c[bj]
        p1, p2, rel = minor_relative(M[ii, kk], M[jj, ll], M[ii, ll], M[jj, kk])
        count += int(np.count_nonzero(rel < -tol))
        p = int(np.argmin(rel))
        if first or rel[p] < best[0]:
            best, first = (float(rel[p]), float(p1[p] - p2[p])), False
            where = (int(ii[p]), int(jj[p]), int(kk[p]), int(ll[p]))
    return best[1], (where[0], where[1]), (where[2], where[3]), count, best[0]


def tp2_method(M: np.ndarray, full_max: int | None = None) -> str:
    """``"full"`` (every minor) when there are at most ``full_max`` minors, else ``"adjacent"``
    for a matrix with positive entries and ``"sparse"`` otherwise (both exact decisions)."""
    n, m = np.shape(M)
    full_max = TP2_FULL_MAX if full_max is None else full_max
    if n * (n - 1) // 2 * (m * (m - 1) // 2) <= full_max:
        return "full"
    return "adjacent" if np.all(np.asarray(M) > 0) else "sparse"


def worst_tp2_minor(M: np.ndarray, tol: float = 1e-9, method: str = "auto") -> _Minor:
    """The worst 2x2 minor of ``M``: ``(minor, (i, j), (k, l), count, relative)``.

    Minors are compared relative to their two products,
    ``relative = (M_ik M_jl - M_il M_jk) / (|M_ik M_jl| + |M_il M_jk|)`` in [-1, 1], so that
    the sign test is not swamped by the size of tiny probabilities; ``count`` is the number of
    minors with ``relative < -tol``; TP2 holds iff ``relative >= -tol``. Vectorised in
    memory-bounded blocks.

    ``method``: ``"full"`` (all minors, the exact worst), ``"adjacent"`` (positive matrices),
    ``"sparse"`` (minors that can be negative), or ``"auto"`` (:func:`tp2_method`). All three
    decide TP2 exactly; only the reported worst of a TP2 matrix differs.
    """
    M = np.asarray(M, dtype=float)
    n, m = M.shape
    if n < 2 or m < 2:
        return 0.0, (0, 0), (0, 0), 0, 0.0
    method = tp2_method(M) if method == "auto" else method
    if method == "adjacent" and not np.all(M > 0):
        raise ValueError("worst_tp2_minor: the adjacent-minor test needs a matrix with positive entries")
    return {"full": _worst_minor_full, "adjacent": _worst_minor_adjacent, "sparse": _worst_minor_sparse}[method](M, tol)


def check_tp2(model: POMDP, tol: float = 1e-9) -> TP2Report:
    """(A1): TP2 of every ``P[a]`` (rows previous state) and ``O[a]`` (rows next state).

    Identical matrices (e.g. an observation model shared by all actions) are checked once (found
    by a digest of their bytes, then compared). Large matrices use an exact reduced test
    (:func:`tp2_method`).
    """
    if model.sparse:
        return _check_tp2_support(model, tol)
    found: list[tuple[str, int, _Minor]] = []
    methods: set[str] = set()
    for label, stack in (("transition", model.P), ("observation", model.O)):
        seen: dict[bytes, list[tuple[np.ndarray, tuple]]] = {}
        for a in range(stack.shape[0]):
            M = stack[a]
            key = hashlib.blake2b(np.ascontiguousarray(M).tobytes(), digest_size=16).digest()
            cached = next((res for prev, res in seen.get(key, ()) if np.array_equal(prev, M)), None)
            if cached is None:
                method = tp2_method(M) if min(M.shape) >= 2 else "full"
                methods.add(method)
                cached = worst_tp2_minor(M, tol, method)
                seen.setdefault(key, []).append((M, cached))
            found.append((label, a, cached))
    return _tp2_report(found, tol, tuple(sorted(methods)))


def _tp2_report(found: list[tuple[str, int, _Minor]], tol: float, methods: tuple[str, ...]) -> TP2Report:
    """The report of the worst minors ``(matrix label, action, minor)`` of every matrix."""
    worst = (np.inf, "transition", 0, (0, 0), (0, 0), 0.0)
    total = 0
    for label, a, (value, rows, cols, count, rel) in found:
        total += count
        if rel < worst[0]:
            worst = (rel, label, a, rows, cols, value)
    rel, label, a, rows, cols, value = worst
    rel = 0.0 if not np.isfinite(rel) else rel
    return TP2Report(holds=rel >= -tol, worst_minor=value, matrix=label, action=a, rows=rows, cols=cols,
                     num_negative=total, tol=tol, methods=methods, worst_relative=rel)


def _check_tp2_support(model: POMDP, tol: float) -> TP2Report:
    """:func:`check_tp2` of a sparse model: the candidate minors only (:mod:`.structure_sparse`);
    identical matrices are checked once."""
    from .structure_sparse import worst_minor_support

    found: list[tuple[str, int, _Minor]] = []
    for label, stack in (("transition", model.P_csr), ("observation", model.O_csr)):
        done: list[tuple[int, _Minor]] = []
        for a in range(len(stack)):
            cached = next((res for b, res in done if stack.same(a, b)), None)
            if cached is None:
                cached = worst_minor_support(stack[a], tol)
                done.append((a, cached))
            found.append((label, a, cached))
    return _tp2_report(found, tol, ("support",))


# =============================================================================== (A2)
def copositivity_matrices(model: POMDP, a: int, j: np.ndarray | slice | None = None) -> np.ndarray:
    """The matrices ``D^{j,a,z} = d + d^T`` of (A2) for one action pair ``(a, a+1)`` (0-based).

    Returns shape ``(len(j), Z, S, S)`` for the requested ``j`` in ``0..S-2`` (all by default),
    with ``d[m, n] = O[a,j,z] O[a+1,j+1,z] P[a,m,j] P[a+1,n,j+1]
    - O[a,j+1,z] O[a+1,j,z] P[a,m,j+1] P[a+1,n,j]`` (module docstring for the derivation).
    """
    if not 0 <= a < model.A - 1:
        raise ValueError(f"action pair: a must be in 0..{model.A - 2}, got {a}")
    js = np.arange(model.S - 1)[slice(None) if j is None else j]
    js = np.atleast_1d(js)
    Pa, Pb, Oa, Ob = model.P[a], model.P[a + 1], model.O[a], model.O[a + 1]
    alpha = Oa[js] * Ob[js + 1]  # (J, Z): O[a,j,z] O[a+1,j+1,z]
    beta = Oa[js + 1] * Ob[js]  # (J, Z): O[a,j+1,z] O[a+1,j,z]
    d = (np.einsum("jz,mj,nj->jzmn", alpha, Pa[:, js], Pb[:, js + 1])
         - np.einsum("jz,mj,nj->jzmn", beta, Pa[:, js + 1], Pb[:, js]))
    return d + np.swapaxes(d, -1, -2)


def _project_simplex(X: np.ndarray) -> np.ndarray:
    """Euclidean projection of each row (last axis) onto the probability simplex."""
    n = X.shape[-1]
    U = -np.sort(-X, axis=-1)
    css = np.cumsum(U, axis=-1) - 1.0
    ind = np.arange(1, n + 1)
    cond = U - css / ind > 0
    rho = n - 1 - np.argmax(cond[..., ::-1], axis=-1)
    theta = np.take_along_axis(css, rho[..., None], axis=-1) / (rho[..., None] + 1.0)
    return np.maximum(X - theta, 0.0)


#: Longest belief a report prints in full; a longer one is printed by its largest entries.
SHORT_BELIEF_STATES = 8
SHORT_BELIEF_ENTRIES = 6


def short_belief(x: np.ndarray) -> str:
    """A belief as a report prints it, on one line: every entry (3 decimals) up to
    :data:`SHORT_BELIEF_STATES` states; beyond, its nonzero entries by state (``{4: 0.406, 20:
    0.594} (S=30, the other 28 entries 0)``), at most :data:`SHORT_BELIEF_ENTRIES` of them, the
    largest, with the number and the sum of the others."""
    x = np.asarray(x, dtype=float)
    if x.size <= SHORT_BELIEF_STATES:
        return np.array2string(x, precision=3, suppress_small=True, max_line_width=10**6)
    nonzero = np.flatnonzero(np.abs(x) > 5e-4)
    shown = nonzero[np.argsort(-x[nonzero], kind="stable")][:SHORT_BELIEF_ENTRIES]
    shown = np.sort(shown)
    text = "{" + ", ".join(f"{i}: {x[i]:.3g}" for i in shown) + "}"
    rest = x.size - shown.size
    rest_sum = float(x.sum() - x[shown].sum())
    if rest_sum > 5e-4:
        return f"{text} (S={x.size}; the other {rest} entries sum to {rest_sum:.3g})"
    return f"{text} (S={x.size}, the other {rest} entries 0)"


def _pair_counterexamples(D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact minimum of ``x^T D x`` over the simplex points supported on 1 or 2 indices.

    On the edge ``x = (1-s) e_m + s e_n``, ``f(s) = (1-s)^2 D_mm + 2 s (1-s) D_mn + s^2 D_nn`` is
    minimised at ``s* = (D_mm - D_mn) / (D_mm + D_nn - 2 D_mn)`` clipped to [0, 1] when the
    denominator is positive, else at a vertex. (So the 2x2 block is copositive iff
    ``D_mm, D_nn >= 0`` and ``D_mn >= -sqrt(D_mm D_nn)``.) Returns, per matrix of the batch
    ``(B, S, S)``, the minimising ``x`` and its value.
    """
    B, S, _ = D.shape
    diag = np.diagonal(D, axis1=1, axis2=2)
    X = np.zeros((B, S))
    best = diag.min(axis=1)
    X[np.arange(B), diag.argmin(axis=1)] = 1.0
    m, n = np.triu_indices(S, 1)
    if m.size == 0:
        return X, best
    a, b, c = diag[:, m], diag[:, n], D[:, m, n]
    den = a + b - 2.0 * c
    pos = den > 0
    sn = np.where(pos, np.clip((a - c) / np.where(pos, den, 1.0), 0.0, 1.0), 0.0)
    sm = 1.0 - sn
    vals = sm**2 * a + 2.0 * sm * sn * c + sn**2 * b
    p = vals.argmin(axis=1)
    pv = vals[np.arange(B), p]
    rows = np.nonzero(pv < best)[0]
    X[rows] = 0.0
    X[rows, m[p[rows]]] = sm[rows, p[rows]]
    X[rows, n[p[rows]]] = sn[rows, p[rows]]
    best = np.minimum(pv, best)
    return X, best


def _triple_counterexamples(D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum of ``x^T D x`` over simplex points supported on exactly 3 indices, at interior
    critical points: on the face ``J``, ``D_JJ x = lambda 1`` gives ``x ∝ adj(D_JJ) 1`` (also when
    ``D_JJ`` is singular but ``D`` is positive definite on ``{y : sum y = 0}``, the only case a
    minimiser needs). Vectorised over all triples in blocks. Returns ``(x, value)`` per matrix
    (``+inf`` where no triple has an interior critical point)."""
    B, S, _ = D.shape
    best_x = np.zeros((B, S))
    best_v = np.full(B, np.inf)
    if S < 3:
        return best_x, best_v
    tri = np.array(list(combinations(range(S), 3)))
    i, j, l = tri[:, 0], tri[:, 1], tri[:, 2]
    step = max(1, _TRIPLE_BLOCK // B)
    rows = np.arange(B)[:, None]
    for t0 in range(0, len(tri), step):
        ii, jj, ll = i[t0:t0 + step], j[t0:t0 + step], l[t0:t0 + step]
        a, d, f = D[:, ii, ii], D[:, jj, jj], D[:, ll, ll]
        b, c, e = D[:, ii, jj], D[:, ii, ll], D[:, jj, ll]
        y = np.stack([d * f - e * e + c * e - b * f + b * e - c * d,
                      c * e - b * f + a * f - c * c + b * c - a * e,
                      b * e - c * d + b * c - a * e + a * d - b * b], axis=-1)  # adj(D_JJ) 1
        tot = y.sum(axis=-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = y / tot
        ok = np.all(x > 0, axis=-1) & np.isfinite(x).all(axis=-1)
        vals = (a * x[..., 0] ** 2 + d * x[..., 1] ** 2 + f * x[..., 2] ** 2
                + 2 * (b * x[..., 0] * x[..., 1] + c * x[..., 0] * x[..., 2] + e * x[..., 1] * x[..., 2]))
        vals = np.where(ok, vals, np.inf)
        k = vals.argmin(axis=1)
        v = vals[rows[:, 0], k]
        better = np.nonzero(v < best_v)[0]
        if better.size:
            best_v[better] = v[better]
            best_x[better] = 0.0
            kb = k[better]
            for col, idx in enumerate((ii, jj, ll)):
                best_x[better, idx[kb]] = x[better, kb, col]
    return best_x, best_v


def _search_counterexamples(D: np.ndarray, rng: np.random.Generator, starts: int = 16, iters: int = 300,
                            target: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Heuristic minimisation of ``x^T D x`` on the simplex for a batch ``(B, S, S)``.

    Projected gradient descent from random Dirichlet starts and from the clipped positive and
    negative parts of the eigenvector of the most negative eigenvalue of ``D`` and of ``D``
    restricted to that part's support. Matrices whose best value is already below ``target``
    (per matrix) stop early. Returns the best ``x`` per matrix and its value.
    """
    B, S, _ = D.shape
    w, V = np.linalg.eigh(D)
    v = V[:, :, 0]  # most negative eigenvalue's eigenvector
    cand = [np.maximum(v, 0.0), np.maximum(-v, 0.0)]
    for part in list(cand):
        mask = part > 0
        Dm = np.where(mask[:, :, None] & mask[:, None, :], D, 0.0)
        Dm = Dm + np.where(mask, 0.0, np.abs(D).max() + 1.0)[:, :, None] * np.eye(S)  # push others up
        _, Vm = np.linalg.eigh(Dm)
        vm = Vm[:, :, 0]
        cand += [np.maximum(vm, 0.0) * mask, np.maximum(-vm, 0.0) * mask]
    C = np.stack(cand, axis=1)  # (B, c, S)
    sums = C.sum(axis=-1, keepdims=True)
    C = np.where(sums > 0, C / np.where(sums > 0, sums, 1.0), 1.0 / S)
    X = np.concatenate([C, rng.dirichlet(np.ones(S), size=(B, starts))], axis=1)
    lip = 2.0 * np.maximum(np.abs(w).max(axis=1), 1e-300)[:, None, None]
    target = np.full(B, -np.inf) if target is None else np.asarray(target, dtype=float)
    best_x = np.zeros((B, S))
    best_v = np.full(B, np.inf)
    active = np.arange(B)
    done = 0
    while active.size and done < iters:
        Da, Xa, La = D[active], X[active], lip[active]
        for _ in range(min(50, iters - done)):
            Xa = _project_simplex(Xa - 2.0 * (Xa @ Da) / La)  # D symmetric: gradient 2 D x
        done += 50
        X[active] = Xa
        vals = np.einsum("bkm,bkm->bk", Xa @ Da, Xa)
        k = vals.argmin(axis=1)
        v = vals[np.arange(active.size), k]
        better = v < best_v[active]
        best_v[active[better]] = v[better]
        best_x[active[better]] = Xa[np.nonzero(better)[0], k[better]]
        active = active[best_v[active] >= target[active]]
    return best_x, best_v


def psd_plus_nonnegative(D: np.ndarray, tol: float = SDP_TOL) -> tuple[bool, float]:
    """SDP certificate of copositivity: is ``D = PSD + N`` with ``N >= 0`` elementwise?

    Solves ``max t  s.t.  D/s - N - t I  PSD,  N >= 0`` with Clarabel (``s = max|D|``), then
    verifies the returned ``N`` (clipped to ``N >= 0``): the certificate holds if
    ``lambda_min(D/s - N) >= -tol``. Returns ``(certified, t)``. Exact for S <= 4 (Diananda),
    sufficient beyond (e.g. the 5x5 Horn matrix is copositive but not PSD + N).
    """
    D = np.asarray(D, dtype=float)
    n = D.shape[0]
    scale = float(np.abs(D).max())
    if scale == 0.0:
        return True, 0.0
    Dn = D / scale
    # Clarabel's PSD triangle: upper triangle stacked column by column, off-diagonals * sqrt(2).
    r, c = np.triu_indices(n)
    order = np.lexsort((r, c))
    r, c = r[order], c[order]
    p = r.size
    wts = np.where(r == c, 1.0, np.sqrt(2.0))
    A_nn = sp.hstack([sp.csc_matrix((p, 1)), -sp.identity(p, format="csc")])
    A_psd = sp.hstack([sp.csc_matrix((r == c).astype(float)[:, None]), sp.diags(wts, format="csc")])
    A = sp.vstack([A_nn, A_psd]).tocsc()
    b = np.concatenate([np.zeros(p), wts * Dn[r, c]])
    q = np.zeros(p + 1)
    q[0] = -1.0
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(sp.csc_matrix((p + 1, p + 1)), q, A, b,
                                    [clarabel.NonnegativeConeT(p), clarabel.PSDTriangleConeT(n)], settings)
    sol = solver.solve()
    x = np.asarray(sol.x, dtype=float)
    if x.size != p + 1 or not np.all(np.isfinite(x)):
        return False, -np.inf
    N = np.zeros((n, n))
    N[r, c] = np.maximum(x[1:], 0.0)
    N = N + np.triu(N, 1).T
    lam = float(np.linalg.eigvalsh(Dn - N).min())
    return lam >= -tol, float(x[0])


@dataclass(frozen=True)
class CopositivityReport:
    """(A2): the verdict for every ``D^{j,a,z}``.

    ``codes[a, j, z]`` is one of the status codes of :data:`STATUS_NAMES`; ``min_entry`` the
    smallest entry of each ``D`` (A2' margin; NaN where a ratio test proved ``D >= 0``);
    ``refutations`` maps ``(a, j, z)`` to ``(x, x^T D x)`` with ``x`` on the simplex (a belief
    at which Lemma 1 (L2) fails).

    A *compact* report (a sparse model's, :mod:`.structure_sparse`) lists only the matrices it
    built: ``index`` (``k x 3``, rows ``(a, j, z)``), their ``codes`` and ``min_entry`` (``k``
    each), and ``shape``; every matrix not listed is proven elementwise without being built.
    """

    codes: np.ndarray
    min_entry: np.ndarray
    refutations: dict = field(repr=False)
    sdp_max_states: int
    tol: float
    index: np.ndarray | None = field(default=None, repr=False)
    shape: tuple[int, int, int] | None = None

    @property
    def total(self) -> int:
        """How many matrices ``D^{j,a,z}`` (A2) asks about."""
        return int(np.prod(self.shape)) if self.index is not None else int(self.codes.size)

    def _where(self, k: int) -> tuple[int, int, int]:
        """``(a, j, z)`` of position ``k`` (flat) of :attr:`codes`."""
        if self.index is not None:
            a, j, z = self.index[k]
        else:
            a, j, z = np.unravel_index(k, self.codes.shape)
        return int(a), int(j), int(z)

    @property
    def holds(self) -> bool:
        return bool(np.all(is_proven(self.codes)))

    @property
    def refuted(self) -> bool:
        return bool(np.any(self.codes == REFUTED))

    @property
    def status(self) -> str:
        return _status(self.holds, self.refuted)

    def counts(self) -> dict[str, int]:
        keys = {PROVEN_ELEMENTWISE: "proven_elementwise", PROVEN_SDP: "proven_sdp", PROVEN_EXACT: "proven_exact",
                PROVEN_DOMINATED: "proven_dominated", REFUTED: "refuted", UNKNOWN: "unknown",
                UNKNOWN_SDP_SKIPPED: "unknown_sdp_skipped", UNKNOWN_UNDERFLOW: "unknown_underflow"}
        out = {name: int(np.count_nonzero(self.codes == code)) for code, name in keys.items()}
        out["proven_elementwise"] += self.total - int(self.codes.size)
        return out

    def worst_refutation(self) -> tuple[tuple[int, int, int], np.ndarray, float] | None:
        if not self.refutations:
            return None
        key = min(self.refutations, key=lambda k: self.refutations[k][1])
        x, val = self.refutations[key]
        return key, x, val

    def worst_entry(self) -> tuple[float, int, int, int] | None:
        """``(value, a, j, z)`` of the most negative entry of any ``D`` that was built, or None
        when the ratio test proved every ``D`` elementwise non-negative without building it."""
        if self.min_entry.size == 0 or np.all(np.isnan(self.min_entry)):
            return None
        k = int(np.nanargmin(self.min_entry))
        a, j, z = self._where(k)
        return float(self.min_entry.flat[k]), a, j, z

    def status_of(self, a: int, j: int, z: int) -> str:
        if self.index is None:
            code = int(self.codes[a, j, z])
        else:
            hit = np.flatnonzero((self.index[:, 0] == a) & (self.index[:, 1] == j) & (self.index[:, 2] == z))
            code = int(self.codes[hit[0]]) if hit.size else PROVEN_ELEMENTWISE
        return STATUS_NAMES[code].format(cap=self.sdp_max_states)

    def to_dict(self, max_listed: int = 50) -> dict:
        """JSON-ready: counts by verdict, the worst A2' entry and up to ``max_listed``
        undecided or refuted ``(j, a, z)`` (states/observations 0-based, actions as priorities)."""
        out: dict = {"status": self.status, "counts": self.counts(), "sdp_max_states": self.sdp_max_states,
                     "tol": self.tol}
        worst = self.worst_entry()
        if worst is not None:
            value, a, j, z = worst
            out["worst_entry"] = {"value": value, "priorities": [a + 1, a + 2], "j": j, "z": z}
        listed = []
        for k in np.flatnonzero(self.codes.ravel() >= REFUTED)[:max_listed]:
            a, j, z = self._where(int(k))
            item = {"priorities": [a + 1, a + 2], "j": j, "z": z, "verdict": self.status_of(a, j, z)}
            if (a, j, z) in self.refutations:
                x, val = self.refutations[(a, j, z)]
                if hasattr(x, "indices"):  # a counterexample stored on its support (a sparse model)
                    item["x_support"] = [int(i) for i in x.indices]
                    item["x_values"] = [float(v) for v in x.values]
                else:
                    item["x"] = [float(v) for v in x]
                item["xDx"] = float(val)
            listed.append(item)
        out["not_proven"] = listed
        out["not_proven_total"] = int(np.count_nonzero(self.codes >= REFUTED))
        return out


def classify_copositive(D: np.ndarray, tol: float = 1e-9, sdp_max_states: int = SDP_MAX_STATES,
                        rng: np.random.Generator | None = None, search: bool = True,
                        exact_max_states: int = EXACT_MAX_STATES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Copositivity verdicts for a batch of symmetric matrices ``D`` of shape ``(B, S, S)``.

    Tolerances are relative to ``max|D|`` (for ``x`` on the simplex, ``|x^T D x| <= max|D|``).
    Cheapest test first:

    1. A2': ``min(D) >= -tol max|D|`` proves.
    2. 1- and 2-element supports, exact minimum in closed form, refute.
    3. ``D`` PSD (eigenvalues, any S) proves (``D = PSD + N`` with ``N = 0``).
    4. Exact small-support test (``S <= exact_max_states``): if ``D`` has at most 2 positive
       eigenvalues, some minimiser of ``x^T D x`` on the simplex has support <= 3 (on its face
       the form must be positive definite on ``{sum y = 0}``, a space of dimension
       ``|support| - 1`` <= the number of positive eigenvalues), so the minimum over supports
       of size <= 3 decides: proves or refutes. Every ``D^{j,a,z}`` of (A2) qualifies: it is
       ``alpha (u v^T + v u^T) - beta (u' v'^T + v' u'^T)``, at most 2 positive eigenvalues.
    5. For ``S <= sdp_max_states``, the Clarabel SDP ``D = PSD + N`` proves (exact for S <= 4).
    6. Projected-gradient search on the simplex refutes (``search=False`` skips it).

    Returns ``(codes (B,), X (B, S), values (B,))``: the status code of :data:`STATUS_NAMES` and,
    for refuted matrices, ``x`` on the simplex with ``x^T D x = value < -tol max|D|`` (NaN
    elsewhere).
    """
    return _classify(D, tol, sdp_max_states, rng, search, exact_max_states)[:3]


def _classify(D: np.ndarray, tol: float, sdp_max_states: int, rng: np.random.Generator | None, search: bool,
              exact_max_states: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`classify_copositive`, plus ``lower (B,)``: a lower bound of ``min x^T D x`` over the
    simplex where a test gives one (elementwise: ``min(D)``; PSD: ``min(lambda_min, 0)``; exact:
    the minimum itself), NaN elsewhere. :func:`check_copositivity` passes it on to dominated
    matrices."""
    D = np.asarray(D, dtype=float)
    B, S, _ = D.shape
    rng = np.random.default_rng(0) if rng is None else rng
    codes = np.full(B, PROVEN_ELEMENTWISE, dtype=np.int8)
    X = np.full((B, S), np.nan)
    values = np.full(B, np.nan)
    scale = np.abs(D).max(axis=(-2, -1))  # tolerances are relative to max|D|
    lower = D.min(axis=(-2, -1))  # x^T D x = sum x_m x_n D_mn >= min(D) on the simplex
    todo = np.nonzero(lower < -tol * scale)[0]
    lower[todo] = np.nan
    if todo.size == 0:
        return codes, X, values, lower
    Xp, vp = _pair_counterexamples(D[todo])
    thr = -tol * scale[todo]
    refuted = vp < thr
    codes[todo[refuted]], X[todo[refuted]], values[todo[refuted]] = REFUTED, Xp[refuted], vp[refuted]
    rest = todo[~refuted]
    if rest.size == 0:
        return codes, X, values, lower
    eig = np.linalg.eigvalsh(D[rest] / scale[rest, None, None])
    psd = eig[:, 0] >= -SDP_TOL
    codes[rest[psd]] = PROVEN_SDP
    lower[rest[psd]] = np.minimum(eig[psd, 0], 0.0) * scale[rest[psd]]  # x^T D x >= lambda_min |x|^2, |x| <= 1
    rest, eig = rest[~psd], eig[~psd]
    if rest.size and S <= exact_max_states:
        low = np.count_nonzero(eig > _POS_EIG, axis=1) <= 2
        exact = rest[low]
        if exact.size:
            Xt, vt = _triple_counterexamples(D[exact])
            pos = np.searchsorted(todo, exact)  # the pair minima of step 2, reused
            Xq, vq = Xp[pos], vp[pos]
            use_t = vt < vq
            xbest = np.where(use_t[:, None], Xt, Xq)
            vbest = np.minimum(vt, vq)
            bad = vbest < -tol * scale[exact]
            codes[exact[~bad]] = PROVEN_EXACT
            lower[exact[~bad]] = vbest[~bad]
            codes[exact[bad]], X[exact[bad]], values[exact[bad]] = REFUTED, xbest[bad], vbest[bad]
        rest = rest[~low]
    undecided = []
    for b in rest:
        if S <= sdp_max_states and psd_plus_nonnegative(D[b])[0]:
            codes[b] = PROVEN_SDP
        else:
            codes[b] = UNKNOWN if S <= sdp_max_states else UNKNOWN_SDP_SKIPPED
            undecided.append(b)
    if search and undecided:
        idx = np.asarray(undecided)
        Xs, vs = _search_counterexamples(D[idx], rng, target=-tol * scale[idx])
        bad = vs < -tol * scale[idx]
        codes[idx[bad]], X[idx[bad]], values[idx[bad]] = REFUTED, Xs[bad], vs[bad]
    return codes, X, values, lower


def _rank_factors(model: POMDP, a: int, js: np.ndarray) -> tuple[np.ndarray, ...]:
    """``D^{j,a,z} = alpha[j,z] F1[j] - beta[j,z] F2[j]`` with ``F1 = u v^T + v u^T``,
    ``F2 = u' v'^T + v' u'^T`` (``u = P[a,:,j]``, ``v = P[a+1,:,j+1]``, ``u' = P[a,:,j+1]``,
    ``v' = P[a+1,:,j]``), ``alpha = O[a,j,z] O[a+1,j+1,z]``, ``beta = O[a,j+1,z] O[a+1,j,z]``."""
    Pa, Pb, Oa, Ob = model.P[a], model.P[a + 1], model.O[a], model.O[a + 1]
    F1 = np.einsum("mj,nj->jmn", Pa[:, js], Pb[:, js + 1])
    F2 = np.einsum("mj,nj->jmn", Pa[:, js + 1], Pb[:, js])
    F1 = F1 + np.swapaxes(F1, 1, 2)
    F2 = F2 + np.swapaxes(F2, 1, 2)
    return Oa[js] * Ob[js + 1], Oa[js + 1] * Ob[js], F1, F2


#: The largest finite float: a ratio beyond it (a subnormal denominator) is counted as this, which
#: is below its true value, so every ratio test that uses it stays a sound (if weaker) proof.
_RATIO_CAP = float(np.finfo(float).max)
#: Below the smallest normal float a ratio or product has lost its relative precision; it is
#: counted as 0, a lower bound of every ratio.
_RATIO_FLOOR = float(np.finfo(float).tiny)


def _min_ratio(num: np.ndarray, den: np.ndarray, axis: int) -> np.ndarray:
    """``min(num / den)`` over ``den > 0`` along ``axis``, each ratio capped at :data:`_RATIO_CAP`
    and below :data:`_RATIO_FLOOR` counted as 0 (a lower bound of the true minimum); ``inf`` only
    where no entry of ``den`` is positive."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = np.minimum(num / np.where(den > 0, den, 1.0), _RATIO_CAP)
    ratio = np.where(ratio < _RATIO_FLOOR, 0.0, ratio)
    return np.where(den > 0, ratio, np.inf).min(axis=axis)


def separable_ratio_bound(model: POMDP, a: int) -> np.ndarray:
    """A lower bound, in ``O(S)`` per ``j``, of the (A2') ratio ``t(j) = min F1[j] / F2[j]`` over
    ``F2 > 0`` (:func:`_rank_factors`), for the action pair ``(a, a+1)``; shape ``(S-1,)``.

    With ``u, v, u', v'`` as in :func:`_rank_factors`, every ratio is a mediant,
    ``(u_m v_n + v_m u_n) / (u'_m v'_n + v'_m u'_n) >= min(u_m v_n / (u'_m v'_n), v_m u_n / (v'_m u'_n))``
    (terms with a zero denominator left out), and each term is at least
    ``min_m (u_m / u'_m) min_n (v_n / v'_n)``, so ``t(j) >= min(u / u') min(v / v')``. ``inf``
    where ``u' = 0`` or ``v' = 0`` (then ``F2 = 0`` and ``t = inf`` too). On TP2 kernels whose
    likelihood ratios are extreme at the ends (the tracking models) the bound is tight enough to
    clear every ``D`` of the comparison models without building ``F1``, ``F2``.
    """
    P = model.P
    u, up = P[a, :, :-1], P[a, :, 1:]  # u = P[a, :, j], u' = P[a, :, j+1]
    v, vp = P[a + 1, :, 1:], P[a + 1, :, :-1]  # v = P[a+1, :, j+1], v' = P[a+1, :, j]
    ru, rv = _min_ratio(u, up, 0), _min_ratio(v, vp, 0)
    empty = np.isinf(ru) | np.isinf(rv)  # no positive denominator (the ratios themselves are capped)
    with np.errstate(over="ignore"):
        product = np.minimum(np.where(empty, 0.0, ru) * np.where(empty, 0.0, rv), _RATIO_CAP)
    product = np.where(product < _RATIO_FLOOR, 0.0, product)
    return np.where(empty, np.inf, product)


def _elementwise_clean(model: POMDP, a: int, js: np.ndarray, alpha: np.ndarray, beta: np.ndarray,
                       t_sep: np.ndarray | None) -> np.ndarray:
    """``clean[j, z]``: ``D^{j,a,z}`` is proven elementwise non-negative by the ratio test
    (``beta <= alpha t(j)``, :func:`check_copositivity`), for ``j`` in ``js``. Given ``t_sep``, the
    separable bound of every ``j`` (:func:`separable_ratio_bound`), it clears first, with a safety margin, and the
    exact ratio (``O(S^2)`` per ``j``) is computed only for the ``j`` it leaves undecided; it
    clears a subset of what the exact ratio clears (:data:`_SEPARABLE_MARGIN`), so the
    result is the same as without it."""
    clean = np.zeros(alpha.shape, dtype=bool)
    rest = np.arange(js.size)
    if t_sep is not None:
        t = t_sep[js]
        with np.errstate(invalid="ignore", over="ignore"):
            clean = (beta == 0) | np.isinf(t)[:, None] | (beta <= (t * (1.0 - _SEPARABLE_MARGIN))[:, None] * alpha)
        rest = np.nonzero(~clean.all(axis=1))[0]
    if rest.size:
        _, _, F1, F2 = _rank_factors(model, a, js[rest])
        t_elem = _min_ratio(F1, F2, (1, 2))  # (J,)
        with np.errstate(invalid="ignore", over="ignore"):
            clean[rest] = (beta[rest] == 0) | np.isinf(t_elem)[:, None] | (beta[rest] <= t_elem[:, None] * alpha[rest])
    return clean


def check_copositivity(model: POMDP, tol: float = 1e-9, sdp_max_states: int = SDP_MAX_STATES,
                       seed: int = 0, search: bool = True,
                       exact_max_states: int = EXACT_MAX_STATES, reduce: bool = True) -> CopositivityReport:
    """(A2): copositivity of every ``D^{j,a,z}`` (:func:`classify_copositive` on each).

    Every ``D^{j,a,z}`` is ``alpha F1 - beta F2`` with non-negative rank-2 matrices ``F1``,
    ``F2`` that do not depend on ``z`` (:func:`_rank_factors`), so the elementwise test (A2')
    for all ``z`` at once is a ratio test: ``D >= 0`` iff ``beta <= alpha min(F1 / F2)`` (over
    ``F2 > 0``), i.e. a ratio over states compared with the largest ``beta / alpha`` over the
    observations. With ``reduce`` (the default) the ratio is first bounded below in ``O(S)``
    per ``(j, a)`` (:func:`separable_ratio_bound`), and ``F1 / F2`` (``O(S^2)``) is formed only
    where that bound does not clear every ``z``. Only the ``D`` that fail the test are built
    (einsum, memory-bounded blocks) and passed on; ``min_entry`` is NaN where the ratio test
    proved ``D >= 0`` without building it.

    Dominance (``reduce``): for one ``(j, a)`` and ``alpha_z > 0``, with ``t_z = beta_z / alpha_z``
    and ``w`` the observation of the largest ``t`` among the ``D`` not proven elementwise,
    ``D^z = (alpha_z / alpha_w) D^w + alpha_z (t_w - t_z) F2``, and the second term is
    elementwise non-negative; so ``min x^T D^z x >= (alpha_z / alpha_w) min x^T D^w x`` on the
    simplex. Only ``D^w`` goes through the expensive tests (eigenvalues, the exact support test,
    the SDP); another ``D^z`` is proven (:data:`PROVEN_DOMINATED`) when that lower bound is at
    least ``-tol max|D^z|``, its own tolerance, and classified on its own otherwise. On models
    with one observation model for all actions every ``t_z`` is 1 and one matrix per ``(j, a)``
    decides all ``Z``. A dominated ``D`` is copositive within its tolerance, so no test could
    refute it: ``reduce`` changes which test proves a matrix, never whether it is proven or
    refuted (except where the old path could only say "unknown": above ``exact_max_states``).
    ``reduce=False`` is the previous path (every ratio exact, every ``D`` classified alone),
    kept for the benchmark and the tests that compare both.

    Floating point: where the frame of a ``D`` holds a positive probability below
    :data:`SAFE_PROBABILITY` (2^-240), products of four probabilities may underflow and an entry
    that is negative in exact arithmetic may be computed as 0; no proof of such a ``D`` is given
    (:data:`UNKNOWN_UNDERFLOW`), and a refutation stands only where ``x^T D x`` is far below the
    error of the underflowed products (:func:`_withdraw_underflow`).
    """
    if model.sparse:
        from .structure_sparse import check_copositivity_support

        rep = check_copositivity_support(model, tol, sdp_max_states, seed, search, exact_max_states, reduce)
    else:
        rep = _check_copositivity_dense(model, tol, sdp_max_states, seed, search, exact_max_states, reduce)
    return _withdraw_underflow(rep, underflow_frames(model))


def _smallest_positive(M: np.ndarray | sp.csr_array, axis: int) -> np.ndarray:
    """The smallest positive entry of each row (``axis=1``) or column (``axis=0``); ``inf`` if none."""
    if sp.issparse(M):
        C = sp.csr_array(M.T if axis == 0 else M)
        out = np.full(C.shape[0], np.inf)
        nz = np.flatnonzero(np.diff(C.indptr))
        if nz.size:
            out[nz] = np.minimum.reduceat(np.where(C.data > 0, C.data, np.inf), C.indptr[nz])
        return out
    return np.where(M > 0, M, np.inf).min(axis=axis)


def underflow_frames(model: POMDP) -> np.ndarray:
    """``(A-1, S-1)`` booleans: the frame of ``D^{j,a,z}`` (columns ``j, j+1`` of ``P[a]`` and
    ``P[a+1]``, rows ``j, j+1`` of ``O[a]`` and ``O[a+1]``) holds a positive probability below
    :data:`SAFE_PROBABILITY`, so a product of four may have left the range where floating point
    keeps its sign (an entry that is negative in exact arithmetic can be computed as 0)."""
    A, S = model.A, model.S
    if A < 2 or S < 2:
        return np.zeros((max(A - 1, 0), max(S - 1, 0)), dtype=bool)
    stacks = (model.P_csr, model.O_csr) if model.sparse else (model.P, model.O)
    low = np.stack([(_smallest_positive(stacks[0][a], 0) < SAFE_PROBABILITY)
                    | (_smallest_positive(stacks[1][a], 1) < SAFE_PROBABILITY) for a in range(A)])  # (A, S)
    pair = low[:-1] | low[1:]  # actions a, a+1
    return pair[:, :-1] | pair[:, 1:]  # states j, j+1


def _withdraw_underflow(rep: CopositivityReport, frames: np.ndarray) -> CopositivityReport:
    """``rep`` with every proof of a ``D`` whose frame underflows (:func:`underflow_frames`) withdrawn
    (:data:`UNKNOWN_UNDERFLOW`), and its refutations kept only where ``x^T D x`` is below
    ``-``:data:`_UNDERFLOW_REFUTATION`; a compact report lists such matrices it had not built."""
    if not frames.any():
        return rep
    codes, mins, refutations = rep.codes.copy(), rep.min_entry.copy(), dict(rep.refutations)
    index = rep.index
    if index is None:
        at = np.broadcast_to(frames[:, :, None], codes.shape)
        keys = [tuple(int(v) for v in k) for k in np.argwhere(at & (codes == REFUTED))]
    else:
        at = frames[index[:, 0], index[:, 1]]
        keys = [tuple(int(v) for v in index[k]) for k in np.flatnonzero(at & (codes == REFUTED))]
    weak = [k for k in keys if refutations[k][1] >= -_UNDERFLOW_REFUTATION]
    for k in weak:
        del refutations[k]
    withdraw = at & (is_proven(codes) | np.isin(codes, [UNKNOWN, UNKNOWN_SDP_SKIPPED]))
    if index is None:
        codes[withdraw] = UNKNOWN_UNDERFLOW
        for k in weak:
            codes[k] = UNKNOWN_UNDERFLOW
        return replace(rep, codes=codes, refutations=refutations)
    where = {tuple(int(v) for v in index[k]): k for k in np.flatnonzero(at)}
    codes[withdraw] = UNKNOWN_UNDERFLOW
    for k in weak:
        codes[where[k]] = UNKNOWN_UNDERFLOW
    a, j = np.nonzero(frames)  # the matrices of these frames the report does not list: all z
    Z = rep.shape[2]
    extra = np.stack([np.repeat(a, Z), np.repeat(j, Z), np.tile(np.arange(Z), a.size)], axis=1).astype(np.int64)
    listed = np.isin(extra[:, 0] * (rep.shape[1] * Z) + extra[:, 1] * Z + extra[:, 2],
                     index[:, 0] * (rep.shape[1] * Z) + index[:, 1] * Z + index[:, 2])
    extra = extra[~listed]
    index = np.concatenate([index, extra])
    codes = np.concatenate([codes, np.full(len(extra), UNKNOWN_UNDERFLOW, dtype=codes.dtype)])
    mins = np.concatenate([mins, np.full(len(extra), np.nan)])
    order = np.lexsort((index[:, 2], index[:, 1], index[:, 0]))
    return replace(rep, codes=codes[order], min_entry=mins[order], refutations=refutations, index=index[order])


def _check_copositivity_dense(model: POMDP, tol: float, sdp_max_states: int, seed: int, search: bool,
                              exact_max_states: int, reduce: bool) -> CopositivityReport:
    """:func:`check_copositivity` of a model stored dense (before :func:`_withdraw_underflow`)."""
    S, A, Z = model.S, model.A, model.Z
    shape = (max(A - 1, 0), max(S - 1, 0), Z)
    codes = np.full(shape, PROVEN_ELEMENTWISE, dtype=np.int8)
    min_entry = np.full(shape, np.nan)
    refutations: dict = {}
    rng = np.random.default_rng(seed)
    jstep = max(1, _D_BLOCK // max(1, 3 * S * S))
    kstep = max(1, _D_BLOCK // max(1, S * S))

    def classify(a: int, jz: np.ndarray, alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """Build ``D^{j,a,z}`` for the rows ``(j, z)`` of ``jz`` in blocks, record ``min_entry``,
        codes and refutations; returns the lower bounds of :func:`_classify`."""
        lower = np.full(len(jz), np.nan)
        for k0 in range(0, len(jz), kstep):
            jj, zz = jz[k0:k0 + kstep, 0], jz[k0:k0 + kstep, 1]
            _, _, F1, F2 = _rank_factors(model, a, jj)
            D = alpha[jj, zz, None, None] * F1 - beta[jj, zz, None, None] * F2
            min_entry[a, jj, zz] = D.min(axis=(1, 2))
            c, X, v, lower[k0:k0 + kstep] = _classify(D, tol, sdp_max_states, rng, search, exact_max_states)
            codes[a, jj, zz] = c
            for k in np.nonzero(c == REFUTED)[0]:
                refutations[(a, int(jj[k]), int(zz[k]))] = (X[k], float(v[k]))
        return lower

    for a in range(shape[0]):
        Oa, Ob = model.O[a], model.O[a + 1]
        alpha, beta = Oa[:-1] * Ob[1:], Oa[1:] * Ob[:-1]  # (S-1, Z)
        dirty = np.zeros(shape[1:], dtype=bool)
        t_sep = separable_ratio_bound(model, a) if reduce else None
        for j0 in range(0, shape[1], jstep):
            js = np.arange(j0, min(j0 + jstep, shape[1]))
            dirty[js] = ~_elementwise_clean(model, a, js, alpha[js], beta[js], t_sep)
        todo = np.argwhere(dirty)  # (k, 2): (j, z)
        if not reduce:
            classify(a, todo, alpha, beta)
            continue
        # dominance: the worst observation of each j first, then the others from its lower bound
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(alpha > 0, beta / np.where(alpha > 0, alpha, 1.0), -np.inf)
        t_dirty = np.where(dirty & (alpha > 0), t, -np.inf)
        has = np.isfinite(t_dirty.max(axis=1))
        worst = np.stack([np.nonzero(has)[0], t_dirty.argmax(axis=1)[has]], axis=1)
        lower_w = np.full(shape[1], np.nan)
        lower_w[worst[:, 0]] = classify(a, worst, alpha, beta)
        others = todo[~np.isin(todo[:, 0] * Z + todo[:, 1], worst[:, 0] * Z + worst[:, 1])]
        jo, zo = others[:, 0], others[:, 1]
        wz = t_dirty.argmax(axis=1)[jo]
        proven_w = is_proven(codes[a, jo, wz]) & np.isfinite(lower_w[jo]) & (alpha[jo, zo] > 0)
        bound = np.where(proven_w, alpha[jo, zo] / np.where(proven_w, alpha[jo, wz], 1.0), 0.0) * \
            np.where(proven_w, lower_w[jo], 0.0)
        scale = np.zeros(len(others))
        for k0 in range(0, len(others), kstep):
            jj, zz = jo[k0:k0 + kstep], zo[k0:k0 + kstep]
            _, _, F1, F2 = _rank_factors(model, a, jj)
            D = alpha[jj, zz, None, None] * F1 - beta[jj, zz, None, None] * F2
            min_entry[a, jj, zz] = D.min(axis=(1, 2))
            scale[k0:k0 + kstep] = np.abs(D).max(axis=(1, 2))
        elementwise = min_entry[a, jo, zo] >= -tol * scale  # step 1 of _classify, as on its own
        dominated = ~elementwise & proven_w & (bound >= -tol * scale)
        codes[a, jo[dominated], zo[dominated]] = PROVEN_DOMINATED
        alone = ~elementwise & ~dominated
        classify(a, others[alone], alpha, beta)
    return CopositivityReport(codes=codes, min_entry=min_entry, refutations=refutations,
                              sdp_max_states=sdp_max_states, tol=tol)


# =============================================================================== (A3)
@dataclass(frozen=True)
class DominanceReport:
    """(A3): ``margins[a, i, zbar] = CDF_a(zbar | e_i) - CDF_{a+1}(zbar | e_i)`` of the predicted
    observation, for ``zbar = 0..Z-2`` (at ``zbar = Z-1`` both CDFs are 1)."""

    margins: np.ndarray | None
    tol: float
    #: A sparse model's report keeps the smallest margin and the count, not the margins.
    worst_margin: tuple[float, int, int, int] | None = None
    violations: int | None = None

    @property
    def worst(self) -> tuple[float, int, int, int]:
        """``(margin, a, i, zbar)`` of the smallest margin (0-based)."""
        if self.margins is None:
            return self.worst_margin
        if self.margins.size == 0:
            return 0.0, 0, 0, 0
        a, i, z = np.unravel_index(int(np.argmin(self.margins)), self.margins.shape)
        return float(self.margins[a, i, z]), int(a), int(i), int(z)

    @property
    def holds(self) -> bool:
        return self.worst[0] >= -self.tol

    @property
    def status(self) -> str:
        return _status(self.holds, refuted=not self.holds)

    def to_dict(self) -> dict:
        m, a, i, z = self.worst
        return {"status": self.status, "worst_margin": m, "priorities": [a + 1, a + 2], "state": i, "zbar": z,
                "num_violations": self.num_violations, "tol": self.tol}

    @property
    def num_violations(self) -> int:
        """How many ``(a, i, zbar)`` have a margin below ``-tol``."""
        if self.margins is None:
            return int(self.violations)
        return int(np.count_nonzero(self.margins < -self.tol))


def observation_cdf_margins(model: POMDP) -> np.ndarray:
    """``cumsum_z (P[a] @ O[a]) - cumsum_z (P[a+1] @ O[a+1])``, shape ``(A-1, S, Z-1)`` (A3).

    With one observation model for every action (the tracking models) the products are one
    matrix product of the stacked ``P`` (several times faster than ``A`` of them at S = 256)."""
    P, O = model.P, model.O
    A, S, Z = O.shape
    if all(np.array_equal(O[a], O[0]) for a in range(1, A)):
        PO = (P.reshape(A * S, S) @ O[0]).reshape(A, S, Z)
    else:
        PO = P @ O
    C = np.cumsum(PO, axis=-1)[..., :-1]
    return C[:-1] - C[1:]


def check_dominance(model: POMDP, tol: float = 1e-9) -> DominanceReport:
    """(A3): from every state, ``eta(. | e_i, a+1)`` first-order dominates ``eta(. | e_i, a)``."""
    if model.sparse:
        from .structure_sparse import dominance_support

        worst, violations = dominance_support(model, tol)
        return DominanceReport(margins=None, tol=tol, worst_margin=worst, violations=violations)
    return DominanceReport(margins=observation_cdf_margins(model), tol=tol)


# =========================================================================== report
@dataclass(frozen=True)
class AssumptionReport:
    """Assumption 1 for one model: (A1) TP2, (A2) copositivity, (A3) dominance."""

    model_name: str
    S: int
    A: int
    Z: int
    tp2: TP2Report
    copositivity: CopositivityReport
    dominance: DominanceReport
    seconds: dict

    @property
    def holds(self) -> bool:
        """True iff A1 holds, every ``D^{j,a,z}`` is proven copositive, and A3 holds."""
        return self.tp2.holds and self.copositivity.holds and self.dominance.holds

    @property
    def status(self) -> dict[str, str]:
        return {"A1": self.tp2.status, "A2": self.copositivity.status, "A3": self.dominance.status}

    def to_dict(self) -> dict:
        return {
            "model": self.model_name, "S": self.S, "A": self.A, "Z": self.Z, "holds": self.holds,
            "status": self.status, "index_convention": "states and observations 0-based; actions as "
            "tracking priorities 1..A (pair (a, a+1) of the paper = priorities (a, a+1))",
            "A1_tp2": self.tp2.to_dict(), "A2_copositivity": self.copositivity.to_dict(),
            "A3_dominance": self.dominance.to_dict(), "seconds": dict(self.seconds),
        }

    def summary(self) -> str:
        """A readable report: which assumption holds, which fails, worst margins, consequences."""
        lines = [f"Assumption 1 (paper Sec. III) for {self.model_name} (S={self.S}, A={self.A}, Z={self.Z}); "
                 "actions are priorities 1..A, states/observations 0-based:"]
        t = self.tp2
        where = f"{t.matrix} priority {t.action + 1}, rows {t.rows}, cols {t.cols}"
        lines.append(f"  (A1) TP2 of transitions and observations: {t.status.upper()} "
                     f"(worst 2x2 minor {t.worst_minor:.3g}, relative {t.worst_relative:.3g}, at {where}"
                     + (f"; {t.num_negative} negative minors)" if not t.holds else ")"))
        c = self.copositivity
        n = c.counts()
        total = c.total
        parts = [f"{n['proven_elementwise']} elementwise (A2')"]
        if n["proven_sdp"]:
            parts.append(f"{n['proven_sdp']} as PSD + N")
        if n["proven_exact"]:
            parts.append(f"{n['proven_exact']} by the exact small-support test")
        if n["proven_dominated"]:
            parts.append(f"{n['proven_dominated']} as dominated by a proven D of the same (j,a)")
        detail = f"{total} matrices D^(j,a,z): proven {' + '.join(parts)}"
        if n["refuted"]:
            detail += f", refuted {n['refuted']}"
        if n["unknown"]:
            detail += f", unknown {n['unknown']}"
        if n["unknown_sdp_skipped"]:
            detail += f", unknown {n['unknown_sdp_skipped']} (SDP skipped above S={c.sdp_max_states})"
        lines.append(f"  (A2) copositivity: {c.status.upper()} ({detail})")
        we = c.worst_entry()
        if we is not None:
            value, a, j, z = we
            lines.append(f"       smallest entry of the D's built: {value:.3g} at priorities ({a + 1},{a + 2}), "
                         f"j={j}, z={z}")
        worst = c.worst_refutation()
        if worst is not None:
            (a, j, z), x, val = worst
            xs = short_belief(x)
            lines.append(f"       counterexample: priorities ({a + 1},{a + 2}), j={j}, z={z}: belief x={xs} "
                         f"gives x^T D x = {val:.3g} < 0, so tau(x, {a + 2}, {z}) is not MLR-above "
                         f"tau(x, {a + 1}, {z}) (Lemma 1 (L2) fails)")
        m, a, i, z = self.dominance.worst
        lines.append(f"  (A3) observation dominance: {self.dominance.status.upper()} (worst margin {m:.3g} at "
                     f"priorities ({a + 1},{a + 2}), state {i}, zbar {z})")
        if self.holds:
            lines.append("  => Assumption 1 holds: Theorem 2's myopic policy bounds are valid wherever the LP "
                         "for g/h is feasible, and branch-and-bound pruning with them is exact.")
        else:
            bad = [k for k, v in self.status.items() if v != "holds"]
            verdict = "violated" if any(self.status[k] == "fails" for k in bad) else "not proven"
            lines.append(f"  => Assumption 1 is {verdict}"
                         f" ({', '.join(f'{k} {self.status[k]}' for k in bad)}): the myopic policy bounds are NOT "
                         "guaranteed; the planner falls back to exhaustive search unless told otherwise.")
        return "\n".join(lines)


def check_assumptions(model: POMDP, *, tol: float = 1e-9, sdp_max_states: int = SDP_MAX_STATES,
                      seed: int = 0, search: bool = True,
                      exact_max_states: int = EXACT_MAX_STATES, reduce: bool = True) -> AssumptionReport:
    """Check Assumption 1 (A1)-(A3) of the paper for ``model`` (see the module docstring).

    ``reduce=False`` runs the previous (A2) path (:func:`check_copositivity`): same verdicts,
    for comparisons."""
    t0 = time.perf_counter()
    tp2 = check_tp2(model, tol)
    t1 = time.perf_counter()
    cop = check_copositivity(model, tol=tol, sdp_max_states=sdp_max_states, seed=seed, search=search,
                             exact_max_states=exact_max_states, reduce=reduce)
    t2 = time.perf_counter()
    dom = check_dominance(model, tol)
    t3 = time.perf_counter()
    return AssumptionReport(model_name=model.name, S=model.S, A=model.A, Z=model.Z, tp2=tp2, copositivity=cop,
                            dominance=dom, seconds={"A1": t1 - t0, "A2": t2 - t1, "A3": t3 - t2, "total": t3 - t0})


# ====================================================================== quick (A1)
def _quick_minor(M: np.ndarray | sp.csr_array, tol: float) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """A negative 2x2 minor of ``M`` found in one pass, or ``None``: an adjacent minor (consecutive
    rows and columns) below ``-tol`` relative, or rows ``i, i+1`` with the last stored column ``l``
    of row ``i`` right of the first stored column ``k`` of row ``i+1`` and ``M[i,k] M[i+1,l] = 0``
    (then the minor on rows ``(i, i+1)`` and columns ``(k, l)`` is ``-M[i,l] M[i+1,k] < 0``)."""
    n, m = M.shape
    if n < 2 or m < 2:
        return None
    if sp.issparse(M):
        counts = np.diff(M.indptr)
        i = np.flatnonzero((counts[:-1] > 0) & (counts[1:] > 0))
        last = M.indices[M.indptr[i + 1] - 1].astype(np.int64)
        first = M.indices[M.indptr[i + 1]].astype(np.int64)
        cand = np.flatnonzero(first < last)
        if cand.size:
            ii, k, l = i[cand], first[cand], last[cand]
            ik = np.asarray(M[ii, k]).ravel()
            jl = np.asarray(M[ii + 1, l]).ravel()
            hit = np.flatnonzero((ik == 0) | (jl == 0))
            if hit.size:
                q = hit[0]
                return (int(ii[q]), int(ii[q]) + 1), (int(k[q]), int(l[q]))
        return None
    M = np.asarray(M)
    p1, p2 = M[:-1, :-1] * M[1:, 1:], M[:-1, 1:] * M[1:, :-1]
    den = p1 + p2
    bad = (p1 - p2) < -tol * den
    if bad.any():
        i, k = np.unravel_index(int(np.argmax(bad)), bad.shape)
        return (int(i), int(i) + 1), (int(k), int(k) + 1)
    nz = M > 0
    has = nz.any(axis=1)
    last = m - 1 - np.argmax(nz[:, ::-1], axis=1)
    first = np.argmax(nz, axis=1)
    i = np.flatnonzero(has[:-1] & has[1:] & (first[1:] < last[:-1]))
    if i.size:
        k, l = first[i + 1], last[i]
        hit = np.flatnonzero((M[i, k] == 0) | (M[i + 1, l] == 0))
        if hit.size:
            q = i[hit[0]]
            return (int(q), int(q) + 1), (int(first[q + 1]), int(last[q]))
    return None


def quick_tp2_refutation(model: POMDP, tol: float = 1e-9) -> str:
    """``""``, or one line naming a negative 2x2 minor of some ``P[a]`` or ``O[a]`` found in one pass
    over the matrices (:func:`_quick_minor`): proof that (A1) fails, so the bound LP will not be
    solved (the set-up estimate leaves it out). Finding none proves nothing."""
    for label, name in (("transition", "P"), ("observation", "O")):
        stack = getattr(model, f"{name}_csr") if model.sparse else getattr(model, name)
        for a in range(model.A):
            same = stack.same(a, a - 1) if model.sparse else np.array_equal(stack[a], stack[a - 1])
            if a and same:
                continue
            hit = _quick_minor(stack[a], tol)
            if hit is not None:
                (i, j), (k, l) = hit
                return (f"(A1) fails: the {label} matrix of priority {a + 1} has a negative 2x2 minor "
                        f"(rows {i}, {j}, columns {k}, {l})")
    return ""


# ==================================================================== cost estimate
#: Unit costs (seconds) behind :func:`estimate_check`, CPU time measured on the development machine
#: (two cores shared with other work; ``python -m pomdp_planner.bench.scale --suite setup`` compares
#: estimate and set-up): one array entry through one numpy pass; one entry of the exact ratio
#: ``F1 / F2``; one multiply-add of a matrix product (BLAS); ``eigvalsh`` per ``S^3``; one
#: (matrix, 3-support) of the exact test; the counterexample search per matrix (fixed part, part
#: per ``S^2``); one Clarabel SDP.
COST_ELEMENT = 3e-9
COST_RATIO = 2e-8
COST_FLOP = 1.5e-10
COST_EIG = 3e-9
COST_TRIPLE = 5e-7
COST_SEARCH = (0.05, 5e-6)
COST_SDP = 0.1
#: How many (j, a) pairs :func:`estimate_check` samples to predict how many ``D`` must be built.
ESTIMATE_SAMPLE_PAIRS = 32
#: How many of the sampled pairs' ``D`` it builds to measure the share the pair test refutes.
ESTIMATE_SAMPLE_MATRICES = 64
#: The fixed part of the check's time (reports, small arrays).
COST_CHECK_FIXED = 1e-3
#: Fixed part of the check's memory in :func:`estimate_check` (the reports, small temporaries).
CHECK_OVERHEAD_BYTES = 256 * 2**10


@dataclass(frozen=True)
class CheckEstimate:
    """What :func:`check_assumptions` is expected to cost on one model, before running it.

    ``seconds``: the expected time when every undecided ``(j, a)`` is settled by its worst
    observation (dominance, :func:`check_copositivity`); ``seconds_max``: when each ``D`` that
    fails (A2') needs the expensive tests on its own (the most a check takes when (A2) fails or
    dominance does not apply). ``bytes``: peak memory of the check's temporaries (blocks of
    :data:`_D_BLOCK`, :data:`_TRIPLE_BLOCK`, :data:`_MINOR_BLOCK` entries and the ``(A, S, Z)``
    arrays of (A3)). ``pairs``: the ``(j, a)`` pairs whose ``D`` are not all cleared by the
    separable ratio bound; ``dirty``: the expected number of ``D`` built (from
    :data:`ESTIMATE_SAMPLE_PAIRS` sampled pairs). Good to a factor of a few
    (:data:`COST_ELEMENT` and the other unit costs; ``python -m pomdp_planner.bench.structure``
    prints estimate and measurement side by side).
    """

    seconds: float
    seconds_max: float
    bytes: int
    pairs: int
    dirty: int

    def describe(self) -> str:
        """``"about 2 s"`` or ``"about 2 s, up to 40 s if (A2) needs every matrix tested alone"``."""
        text = f"about {seconds_text(self.seconds)}"
        if self.seconds_max > 2.0 * self.seconds + 1.0:
            text += f", up to {seconds_text(self.seconds_max)} if (A2) needs every matrix tested alone"
        return text


def seconds_text(t: float) -> str:
    """A duration for people: ``"0.3 s"``, ``"12 s"``, ``"34 min"``, ``"2 h"``."""
    if t < 90:
        return f"{max(t, 0.1):.2g} s" if t < 10 else f"{t:.0f} s"
    return f"{t / 60:.0f} min" if t < 5400 else f"{t / 3600:.0f} h"


def _tp2_cost(M: np.ndarray) -> tuple[float, int]:
    """``(seconds, bytes)`` of :func:`worst_tp2_minor` on ``M`` with the method it will choose."""
    n, m = M.shape
    if n < 2 or m < 2:
        return 0.0, 0
    method = tp2_method(M)
    if method == "full":
        entries = n * (n - 1) // 2 * (m * (m - 1) // 2)
        return 8 * entries * COST_ELEMENT, 8 * 6 * min(entries, _MINOR_BLOCK + m * m)
    if method == "adjacent":
        return 16 * n * m * COST_ELEMENT, 8 * 6 * n * m
    nnz = int(np.count_nonzero(M > 0))
    return 6 * nnz * nnz * COST_ELEMENT, 8 * 8 * min(nnz * nnz, _MINOR_BLOCK + nnz)


def estimate_check(model: POMDP, *, sdp_max_states: int = SDP_MAX_STATES, search: bool = True,
                   exact_max_states: int = EXACT_MAX_STATES, reduce: bool = True) -> CheckEstimate:
    """Predict the time and memory of :func:`check_assumptions` with the same options.

    Costs ``O(A S^2)`` (the separable bound of :func:`separable_ratio_bound` for every action
    pair, as the check starts with it) plus the exact ratio on :data:`ESTIMATE_SAMPLE_PAIRS`
    sampled ``(j, a)``: at S = 256, A = 64 about a tenth of a second. The time is the sum of the
    stages' operation counts times the unit costs (:data:`COST_ELEMENT` ...); see
    :class:`CheckEstimate` for what ``seconds`` and ``seconds_max`` assume.
    """
    if model.sparse:
        from .structure_sparse import estimate_check_support

        return estimate_check_support(model, sdp_max_states, search, exact_max_states, reduce)
    S, A, Z = model.S, model.A, model.Z
    tol_estimate = 1e-9
    seconds, peak = COST_CHECK_FIXED, 8 * 4 * A * S * Z + CHECK_OVERHEAD_BYTES  # (A3): P @ O and its cumsums
    for stack in (model.P, model.O):  # (A1), one matrix per distinct action (identical ones are cached)
        for a in range(stack.shape[0]):
            if a and np.array_equal(stack[a], stack[a - 1]):
                continue
            t, b = _tp2_cost(stack[a])
            seconds, peak = seconds + t, max(peak, b + CHECK_OVERHEAD_BYTES)
    seconds += A * S * S * Z * COST_FLOP + 4 * A * S * Z * COST_ELEMENT
    pairs, sample = 0, []
    for a in range(max(A - 1, 0)):
        seconds += 12 * S * S * COST_ELEMENT
        Oa, Ob = model.O[a], model.O[a + 1]
        alpha, beta = Oa[:-1] * Ob[1:], Oa[1:] * Ob[:-1]
        if reduce:
            t_sep = separable_ratio_bound(model, a)
            with np.errstate(invalid="ignore", over="ignore"):
                clean = (beta == 0) | np.isinf(t_sep)[:, None] | \
                    (beta <= (t_sep * (1.0 - _SEPARABLE_MARGIN))[:, None] * alpha)
            left = np.nonzero(~clean.all(axis=1))[0]
        else:
            left = np.arange(S - 1)
        pairs += left.size
        sample += [(a, int(j)) for j in left]
    if not pairs:
        return CheckEstimate(seconds, seconds, peak, 0, 0)
    seconds += pairs * S * S * COST_RATIO
    peak = max(peak, 8 * 5 * min(_D_BLOCK, pairs * 3 * S * S) + CHECK_OVERHEAD_BYTES)
    rng = np.random.default_rng(0)
    picked = [sample[k] for k in rng.choice(len(sample), min(ESTIMATE_SAMPLE_PAIRS, len(sample)), replace=False)]
    dirty_z, dirty_j, tried, easy = 0, 0, 0, 0
    for a, j in picked:
        Oa, Ob = model.O[a], model.O[a + 1]
        js = np.array([j])
        alpha, beta = (Oa[:-1] * Ob[1:])[js], (Oa[1:] * Ob[:-1])[js]
        clean = _elementwise_clean(model, a, js, alpha, beta, None)
        zs = np.flatnonzero(~clean[0])
        dirty_z += zs.size
        dirty_j += bool(zs.size)
        zs = zs[:max(0, ESTIMATE_SAMPLE_MATRICES - tried)]
        if zs.size:  # the share of built D that the cheap pair test refutes (no expensive test then)
            _, _, F1, F2 = _rank_factors(model, a, js)
            D = alpha[0, zs, None, None] * F1 - beta[0, zs, None, None] * F2
            scale = np.abs(D).max(axis=(1, 2))
            easy += int(np.count_nonzero(_pair_counterexamples(D)[1] < -tol_estimate * scale))
            tried += zs.size
    dirty = round(pairs * dirty_z / len(picked))
    worst = round(pairs * dirty_j / len(picked))
    if not dirty:
        return CheckEstimate(seconds, seconds, peak, pairs, 0)
    hard_share = 1.0 - easy / tried if tried else 1.0
    build = 10 * S * S * COST_ELEMENT  # D, min, max|D|, the pair test
    kstep = max(1, _D_BLOCK // max(1, S * S))  # matrices per block
    hard = COST_EIG * S**3
    if S <= exact_max_states:
        hard += COST_TRIPLE * (S * (S - 1) * (S - 2) // 6)
    else:
        hard += COST_SDP if S <= sdp_max_states else 0.0
        hard += (COST_SEARCH[0] + COST_SEARCH[1] * S * S) if search else 0.0
    peak = max(peak, 8 * 6 * min(_D_BLOCK, dirty * S * S) + CHECK_OVERHEAD_BYTES)
    # dominance needs a proven worst D: only the exact test (S <= exact_max_states) proves these;
    # a D the pair test refutes needs no expensive test
    alone = hard_share * (dirty if not reduce or S > exact_max_states else worst)
    if S <= exact_max_states:  # one block of (matrix, triple) pairs: about 20 arrays of that size
        peak = max(peak, 8 * 20 * min(_TRIPLE_BLOCK, min(max(round(alone), 1), kstep) * (S * (S - 1) * (S - 2) // 6))
                   + CHECK_OVERHEAD_BYTES)
    expected = seconds + dirty * build + alone * hard
    return CheckEstimate(expected, seconds + dirty * build + hard_share * dirty * hard, peak, pairs, dirty)
