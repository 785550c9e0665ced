"""Assumption 1 on a sparse model: the checks of :mod:`.structure` where the support is non-trivial.

The same mathematics as :mod:`.structure` (its module docstring has the derivations), with the
work and memory proportional to the non-zeros instead of ``S^2`` per matrix:

* (A1) A 2x2 minor ``M[i,k] M[j,l] - M[i,l] M[j,k]`` (``i < j``, ``k < l``) can be negative only
  when ``M[i,l] > 0`` and ``M[j,k] > 0`` (a *candidate*). A candidate whose other product is zero
  (``M[i,k] M[j,l] = 0``, one of those entries not stored) is negative with relative value -1; the
  others have all four corners stored (*rectangles*: two rows sharing two columns) and are
  computed. So the number of negative minors is the number of candidates (an inversion count over
  the stored entries, :func:`candidate_counts`) minus the rectangles, plus the negative
  rectangles. The reported worst minor: the first lower-left corner ``(j, k)`` in row-major order
  with a candidate whose other product is zero, and its most negative such minor; if there is
  none, the rectangle with the smallest relative value (the worst candidate: every candidate is a
  rectangle then); if there are no candidates at all, the minor on rows and columns ``(0, 1)``, as
  :func:`.structure.worst_tp2_minor` reports with ``method="sparse"``.
* (A2) ``D^{j,a,z} = alpha F1 - beta F2`` with ``F1``, ``F2`` built from the columns ``j`` and
  ``j + 1`` of ``P[a]`` and ``P[a+1]`` (:func:`.structure._rank_factors`): ``D`` is zero outside
  the union ``K_j`` of the supports of those four columns, and a matrix with zero rows and columns
  outside ``K_j`` is copositive iff its principal submatrix on ``K_j`` is. Only the ``(j, z)``
  with ``beta > 0`` can fail the elementwise test (``beta = 0`` gives ``D = alpha F1 >= 0``); each
  is built on ``K_j`` (padded with at least one zero row and column when ``K_j`` is not every
  state, so that its smallest entry is the dense one's) and goes through the same tests and the same
  dominance argument as :func:`.structure.check_copositivity`. Since the matrices are small, the
  exact small-support test applies to each (``|K_j| <= exact_max_states``): a sparse model's
  (A2) is decided exactly where the dense check, above ``exact_max_states`` states, may leave a
  matrix unknown. The report lists only the matrices built (every other one is proven
  elementwise), and counterexamples are stored on their support (:class:`SupportVector`).
* (A3) Each row of ``P[a] @ O[a]`` is a sparse product; the margin
  ``CDF_a(zbar | e_i) - CDF_{a+1}(zbar | e_i)`` is a step function of ``zbar`` that changes only
  where either row has a non-zero, so its minimum and the number of ``zbar`` below ``-tol`` come
  from those points (the cumulative sums are taken row by row in column order, as the dense ones).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .model import POMDP

#: Most stored entries per block of rows in :func:`candidate_counts` (pairs inside a block are
#: compared directly: a block of ``n`` entries costs ``n^2`` comparisons).
CANDIDATE_BLOCK = 2048
#: Most rectangles evaluated in one numpy pass.
RECTANGLE_BLOCK = 2_000_000


class SupportVector:
    """A vector of length ``size`` that is zero outside ``indices`` (a counterexample ``x`` of (A2)
    on a sparse model): ``np.asarray(x)`` gives the dense vector, iteration its entries."""

    def __init__(self, indices: np.ndarray, values: np.ndarray, size: int):
        self.indices = np.asarray(indices, dtype=np.int64)
        self.values = np.asarray(values, dtype=float)
        self.size = int(size)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = np.zeros(self.size, dtype=float if dtype is None else dtype)
        out[self.indices] = self.values
        return out

    def __len__(self) -> int:
        return self.size

    def __iter__(self):
        return iter(np.asarray(self))


# =============================================================================== (A1)
def _row_blocks(indptr: np.ndarray, block: int) -> list[tuple[int, int]]:
    """Ranges of whole rows ``[r0, r1)`` with at most ``block`` entries each (a longer row alone)."""
    out, r0, n = [], 0, indptr.size - 1
    while r0 < n:
        r1 = int(np.searchsorted(indptr, indptr[r0] + block, side="right")) - 1
        r1 = max(r1, r0 + 1)
        out.append((r0, min(r1, n)))
        r0 = min(r1, n)
    return out


def candidate_counts(M: sp.csr_array) -> np.ndarray:
    """For every stored entry ``(j, k)`` of ``M`` (in CSR order), the number of stored entries
    ``(i, l)`` with ``i < j`` and ``l > k``: its candidate minors (module docstring)."""
    n, m = M.shape
    cols = M.indices.astype(np.int64)
    rows = np.repeat(np.arange(n), np.diff(M.indptr))
    out = np.zeros(cols.size, dtype=np.int64)
    hist = np.zeros(m + 1, dtype=np.int64)  # stored entries of the rows done, per column
    for r0, r1 in _row_blocks(M.indptr, CANDIDATE_BLOCK):
        e0, e1 = int(M.indptr[r0]), int(M.indptr[r1])
        if e0 == e1:
            continue
        greater = np.cumsum(hist[::-1])[::-1]  # greater[c] = entries with column >= c
        bc, br = cols[e0:e1], rows[e0:e1]
        out[e0:e1] = greater[bc + 1]
        if r1 - r0 > 1:  # pairs inside the block: an earlier row, a larger column
            out[e0:e1] += np.count_nonzero((br[:, None] < br[None, :]) & (bc[:, None] > bc[None, :]), axis=0)
        hist += np.bincount(bc, minlength=m + 1)
    return out


def _copairs(M: sp.csr_array) -> tuple[np.ndarray, ...]:
    """Every pair of stored entries of one row, ``k < l``: ``(key = k m + l, row, M[row, k],
    M[row, l], entry index of (row, k))``, sorted by key then row."""
    n, m = M.shape
    counts = np.diff(M.indptr)
    row_end = np.repeat(M.indptr[1:], counts)  # per entry: the end of its row
    left_n = row_end - np.arange(M.nnz) - 1  # partners after it in its row
    total = int(left_n.sum())
    left = np.repeat(np.arange(M.nnz), left_n)
    first = np.repeat(np.cumsum(left_n) - left_n, left_n)
    right = left + 1 + (np.arange(total) - first)
    rows = np.repeat(np.arange(n), counts)[left]
    cols = M.indices.astype(np.int64)
    key = cols[left] * m + cols[right]
    order = np.lexsort((rows, key))
    return key[order], rows[order], M.data[left][order], M.data[right][order], left[order]


def worst_minor_support(M: sp.csr_array, tol: float = 1e-9) -> tuple:
    """The worst 2x2 minor of the sparse matrix ``M``: ``(minor, (i, j), (k, l), count, relative)``
    as :func:`.structure.worst_tp2_minor` returns it (module docstring, (A1))."""
    from .structure import minor_relative

    n, m = M.shape
    if n < 2 or m < 2:
        return 0.0, (0, 0), (0, 0), 0, 0.0
    c = candidate_counts(M)
    key, rows, vk, vl, ek = _copairs(M)
    rect_at = np.zeros(M.nnz, dtype=np.int64)  # rectangles whose lower-left corner is each entry
    best = (np.inf, 0.0, (0, 0, 0, 0))
    negative_rect = 0
    if key.size:
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        sizes = np.diff(np.r_[starts, key.size])
        group_end = np.repeat(starts + sizes, sizes)
        partners = group_end - np.arange(key.size) - 1
        pos = 0
        while pos < key.size:  # rectangles in blocks of positions
            acc = np.cumsum(partners[pos:])
            stop = pos + max(1, int(np.searchsorted(acc, RECTANGLE_BLOCK, side="right")))
            nb = partners[pos:stop]
            x = np.repeat(np.arange(pos, stop), nb)
            y = x + 1 + (np.arange(x.size) - np.repeat(np.cumsum(nb) - nb, nb))
            p1, p2, rel = minor_relative(vk[x], vl[y], vl[x], vk[y])  # M[i,k] M[j,l], M[i,l] M[j,k]
            negative_rect += int(np.count_nonzero(rel < -tol))
            np.add.at(rect_at, ek[y], 1)
            if x.size:
                q = int(np.argmin(rel))
                if rel[q] < best[0]:
                    k_, l_ = divmod(int(key[x[q]]), m)
                    best = (float(rel[q]), float(p1[q] - p2[q]), (int(rows[x[q]]), int(rows[y[q]]), k_, l_))
            pos = stop
    zero = c - rect_at
    count = int(zero.sum()) + negative_rect
    if zero.any():
        e = int(np.argmax(zero > 0))
        j = int(np.searchsorted(M.indptr, e, side="right") - 1)
        k = int(M.indices[e])
        upto = int(M.indptr[j])
        cand = np.flatnonzero(M.indices[:upto] > k)
        i_c = np.searchsorted(M.indptr, cand, side="right") - 1
        l_c = M.indices[cand].astype(np.int64)
        corner_ik = np.asarray(M[i_c, np.full(cand.size, k)]).ravel()
        corner_jl = np.asarray(M[np.full(cand.size, j), l_c]).ravel()
        open_ = (corner_ik == 0) | (corner_jl == 0)
        vals = np.where(open_, M.data[cand], -np.inf)
        q = int(np.argmax(vals))
        p2 = float(M.data[cand[q]] * M.data[e])
        return -p2, (int(i_c[q]), j), (k, int(l_c[q])), count, -1.0
    if np.isfinite(best[0]):
        i, j, k, l = best[2]
        return best[1], (i, j), (k, l), count, best[0]
    p1, p2, rel = minor_relative(np.float64(M[0, 0]), np.float64(M[1, 1]), np.float64(M[0, 1]), np.float64(M[1, 0]))
    return float(p1 - p2), (0, 1), (0, 1), count, float(rel)


# =============================================================================== (A2)
def _frame(PT: list, a: int, j: int) -> tuple[np.ndarray, ...]:
    """``K_j`` and the columns ``u = P[a,:,j]``, ``v = P[a+1,:,j+1]``, ``u' = P[a,:,j+1]``,
    ``v' = P[a+1,:,j]`` on it (``PT``: the transposed stacks, rows = columns of ``P``)."""
    parts = [PT.row(a, j), PT.row(a + 1, j + 1), PT.row(a, j + 1), PT.row(a + 1, j)]
    K = np.unique(np.concatenate([p[0] for p in parts]))
    vals = []
    for idx, data in parts:
        vec = np.zeros(K.size)
        vec[np.searchsorted(K, idx)] = data
        vals.append(vec)
    return (K, *vals)


def _min_ratio_1d(num: np.ndarray, den: np.ndarray) -> float:
    from .structure import _min_ratio

    return float(_min_ratio(num[None, :], den[None, :], 1)[0]) if den.size else np.inf


def _separable(fr: tuple) -> float:
    """:func:`.structure.separable_ratio_bound` for one ``j`` on its frame."""
    from .structure import _RATIO_CAP, _RATIO_FLOOR

    _, u, v, up, vp = fr
    ru, rv = _min_ratio_1d(u, up), _min_ratio_1d(v, vp)
    if np.isinf(ru) or np.isinf(rv):
        return np.inf
    with np.errstate(over="ignore"):
        product = min(ru * rv, _RATIO_CAP)
    return 0.0 if product < _RATIO_FLOOR else product


def _factors(frames: list[tuple], k: int) -> tuple[np.ndarray, np.ndarray]:
    """``F1``, ``F2`` of :func:`.structure._rank_factors` on the frames, padded to ``k`` (zeros)."""
    B = len(frames)
    U, V, Up, Vp = (np.zeros((B, k)) for _ in range(4))
    for b, (K, u, v, up, vp) in enumerate(frames):
        n = K.size
        U[b, :n], V[b, :n], Up[b, :n], Vp[b, :n] = u, v, up, vp
    F1 = U[:, :, None] * V[:, None, :]
    F2 = Up[:, :, None] * Vp[:, None, :]
    return F1 + np.swapaxes(F1, 1, 2), F2 + np.swapaxes(F2, 1, 2)


def _batches(sizes: np.ndarray, S: int, limit: int) -> list[tuple[int, int, int]]:
    """Consecutive batches ``(start, stop, k)`` of items whose frames have ``sizes`` states, each
    padded to ``k`` = the batch's largest frame + 1 (at most ``S``), ``(stop - start) k^2 <= limit``."""
    out, start, kmax = [], 0, 0
    for t, s in enumerate(sizes.tolist()):
        k_try = min(max(kmax, s) + 1, S)
        if t > start and (t - start + 1) * k_try * k_try > limit:
            out.append((start, t, min(kmax + 1, S)))
            start, kmax = t, 0
        kmax = max(kmax, s)
    if start < sizes.size:
        out.append((start, sizes.size, min(kmax + 1, S)))
    return out


def check_copositivity_support(model: POMDP, tol: float, sdp_max_states: int, seed: int, search: bool,
                               exact_max_states: int, reduce: bool):
    """(A2) of a sparse model (module docstring); the same verdicts as
    :func:`.structure.check_copositivity` on the dense model, decided exactly on every matrix
    whose support has at most ``exact_max_states`` states."""
    from .structure import (
        _D_BLOCK,
        _SEPARABLE_MARGIN,
        PROVEN_DOMINATED,
        REFUTED,
        CopositivityReport,
        _classify,
        _min_ratio,
        is_proven,
    )

    S, A, Z = model.S, model.A, model.Z
    shape = (max(A - 1, 0), max(S - 1, 0), Z)
    PT, O = model.P_csr.T, model.O_csr
    rng = np.random.default_rng(seed)
    idx_out: list[np.ndarray] = []
    code_out: list[np.ndarray] = []
    min_out: list[np.ndarray] = []
    refutations: dict = {}

    def build(frames: list[tuple], al: np.ndarray, be: np.ndarray) -> tuple[np.ndarray, list]:
        """``D`` of the items, in batches: yields (start, stop, D, batch frames)."""
        sizes = np.array([fr[0].size for fr in frames])
        for start, stop, k in _batches(sizes, S, _D_BLOCK):
            F1, F2 = _factors(frames[start:stop], k)
            yield start, stop, al[start:stop, None, None] * F1 - be[start:stop, None, None] * F2

    def classify(a: int, js: np.ndarray, zs: np.ndarray, frames: list[tuple], al: np.ndarray, be: np.ndarray
                 ) -> np.ndarray:
        lower = np.full(js.size, np.nan)
        codes = np.zeros(js.size, dtype=np.int8)
        mins = np.full(js.size, np.nan)
        for start, stop, D in build(frames, al, be):
            mins[start:stop] = D.min(axis=(1, 2))
            c, X, v, lower[start:stop] = _classify(D, tol, sdp_max_states, rng, search, exact_max_states)
            codes[start:stop] = c
            for t in np.nonzero(c == REFUTED)[0]:
                K = frames[start + t][0]
                x = X[t]
                idx, vals = list(K), list(x[:K.size])
                rest = float(x[K.size:].sum())
                if rest > 0.0:  # mass on a padding state: any state outside K_j (its rows of D are zero)
                    outside = int(np.setdiff1d(np.arange(min(S, K.size + 1)), K)[0])
                    idx.append(outside)
                    vals.append(rest)
                refutations[(a, int(js[start + t]), int(zs[start + t]))] = (SupportVector(idx, vals, S), float(v[t]))
        idx_out.append(np.stack([np.full(js.size, a), js, zs], axis=1))
        code_out.append(codes)
        min_out.append(mins)
        return lower

    for a in range(shape[0]):
        Oa, Ob = O[a], O[a + 1]
        beta = sp.csr_array(Oa[1:].multiply(Ob[:-1]))
        beta.eliminate_zeros()
        jb = np.repeat(np.arange(S - 1), np.diff(beta.indptr))
        zb = beta.indices.astype(np.int64)
        bv = beta.data
        av = np.asarray(sp.csr_array(Oa[:-1].multiply(Ob[1:]))[jb, zb]).ravel() if jb.size else np.zeros(0)
        if jb.size == 0:
            continue
        ujs = np.unique(jb)
        frames = {int(j): _frame(PT, a, int(j)) for j in ujs}
        clean = np.zeros(jb.size, dtype=bool)
        if reduce:
            t_sep = np.array([_separable(frames[int(j)]) for j in jb])
            with np.errstate(invalid="ignore", over="ignore"):
                clean = (bv == 0) | np.isinf(t_sep) | (bv <= (t_sep * (1.0 - _SEPARABLE_MARGIN)) * av)
        open_j = np.unique(jb[~clean])
        t_elem = {}
        for j in open_j:
            fr = frames[int(j)]
            F1, F2 = _factors([fr], fr[0].size)
            t_elem[int(j)] = float(_min_ratio(F1, F2, (1, 2))[0])
        todo = ~clean & np.isin(jb, open_j)
        te = np.array([t_elem.get(int(j), np.inf) for j in jb])
        with np.errstate(invalid="ignore", over="ignore"):
            exact_clean = (bv == 0) | np.isinf(te) | (bv <= te * av)
        dirty = todo & ~exact_clean
        d = np.flatnonzero(dirty)
        if d.size == 0:
            continue
        if not reduce:
            classify(a, jb[d], zb[d], [frames[int(j)] for j in jb[d]], av[d], bv[d])
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(av[d] > 0, bv[d] / np.where(av[d] > 0, av[d], 1.0), -np.inf)
        jd = jb[d]
        # the worst observation of each j: largest t among its dirty (j, z) with alpha > 0, first z on ties
        order = np.lexsort((np.arange(d.size), -t, jd))
        first = order[np.r_[True, jd[order][1:] != jd[order][:-1]]]
        worst = first[np.isfinite(t[first])]
        lower_w = dict(zip(jd[worst].tolist(), classify(a, jd[worst], zb[d][worst],
                                                         [frames[int(j)] for j in jd[worst]], av[d][worst],
                                                         bv[d][worst]).tolist(), strict=True))
        code_w = dict(zip(jd[worst].tolist(), code_out[-1].tolist(), strict=True)) if worst.size else {}
        alpha_w = dict(zip(jd[worst].tolist(), av[d][worst].tolist(), strict=True))
        others = np.setdiff1d(np.arange(d.size), worst)
        if others.size == 0:
            continue
        jo, zo, ao, bo = jd[others], zb[d][others], av[d][others], bv[d][others]
        lw = np.array([lower_w.get(int(j), np.nan) for j in jo])
        cw = np.array([code_w.get(int(j), REFUTED) for j in jo])
        aw = np.array([alpha_w.get(int(j), 1.0) for j in jo])
        proven_w = is_proven(cw) & np.isfinite(lw) & (ao > 0)
        bound = np.where(proven_w, ao / np.where(proven_w, aw, 1.0), 0.0) * np.where(proven_w, lw, 0.0)
        fr_o = [frames[int(j)] for j in jo]
        mins = np.empty(others.size)
        scale = np.empty(others.size)
        for start, stop, D in build(fr_o, ao, bo):
            mins[start:stop] = D.min(axis=(1, 2))
            scale[start:stop] = np.abs(D).max(axis=(1, 2))
        elementwise = mins >= -tol * scale
        dominated = ~elementwise & proven_w & (bound >= -tol * scale)
        settled = elementwise | dominated
        idx_out.append(np.stack([np.full(int(settled.sum()), a), jo[settled], zo[settled]], axis=1))
        code_out.append(np.where(dominated[settled], PROVEN_DOMINATED, 0).astype(np.int8))
        min_out.append(mins[settled])
        alone = np.flatnonzero(~settled)
        if alone.size:
            classify(a, jo[alone], zo[alone], [fr_o[t] for t in alone], ao[alone], bo[alone])
    if idx_out:
        index = np.concatenate(idx_out).astype(np.int64)
        codes = np.concatenate(code_out)
        mins = np.concatenate(min_out)
        order = np.lexsort((index[:, 2], index[:, 1], index[:, 0]))
        index, codes, mins = index[order], codes[order], mins[order]
    else:
        index, codes, mins = np.zeros((0, 3), np.int64), np.zeros(0, np.int8), np.zeros(0)
    return CopositivityReport(codes=codes, min_entry=mins, refutations=refutations, sdp_max_states=sdp_max_states,
                              tol=tol, index=index, shape=shape)


# =============================================================================== (A3)
def _row_cumsums(M: sp.csr_array) -> np.ndarray:
    """The cumulative sum of each row's stored values, in column order, row by row (the order of a
    dense row's ``cumsum``: the zeros between add nothing)."""
    counts = np.diff(M.indptr)
    if M.nnz == 0:
        return np.zeros(0)
    width = int(counts.max())
    pad = np.zeros((M.shape[0], width))
    col = np.arange(M.nnz) - np.repeat(M.indptr[:-1], counts)
    rows = np.repeat(np.arange(M.shape[0]), counts)
    pad[rows, col] = M.data
    return np.cumsum(pad, axis=1)[rows, col]


def dominance_support(model: POMDP, tol: float) -> tuple[tuple[float, int, int, int], int]:
    """(A3) of a sparse model: ``((margin, a, i, zbar), violations)``, the smallest margin (first in
    ``(a, i, zbar)`` order on ties) and the number of ``(a, i, zbar)`` below ``-tol`` (module
    docstring)."""
    A, S, Z = model.A, model.S, model.Z
    if A < 2 or Z < 2:
        return (0.0, 0, 0, 0), 0
    PO = [sp.csr_array(model.P_csr[a] @ model.O_csr[a]) for a in range(A)]
    for M in PO:
        M.sum_duplicates()
        M.sort_indices()
    cands: list[np.ndarray] = []  # rows (value, a, i, zbar)
    violations = 0
    for a in range(A - 1):
        parts = []
        for src, M in enumerate((PO[a], PO[a + 1])):
            rows = np.repeat(np.arange(S), np.diff(M.indptr))
            parts.append((rows, M.indices.astype(np.int64), np.full(M.nnz, src), _row_cumsums(M)))
        R, C, src, cum = (np.concatenate(x) for x in zip(*parts, strict=True))
        order = np.lexsort((src, C, R))
        R, C, src, cum = R[order], C[order], src[order], cum[order]
        pos = np.arange(R.size)
        fill = []
        for s in (0, 1):
            last = np.maximum.accumulate(np.where(src == s, pos, -1))
            ok = (last >= 0) & (R[np.maximum(last, 0)] == R)
            fill.append(np.where(ok, cum[np.maximum(last, 0)], 0.0))
        end = np.r_[(R[1:] != R[:-1]) | (C[1:] != C[:-1]), True]  # the last of each (row, column)
        R, C, margin = R[end], C[end], (fill[0] - fill[1])[end]
        nxt = np.r_[C[1:], Z]
        nxt = np.where(np.r_[R[1:] == R[:-1], False], nxt, Z)
        length = np.clip(np.minimum(nxt, Z - 1) - C, 0, None)
        seg = length > 0
        violations += int(length[seg & (margin < -tol)].sum())
        cands.append(np.stack([margin[seg], np.full(int(seg.sum()), a), R[seg], C[seg]], axis=1))
        first_col = np.full(S, Z, dtype=np.int64)
        np.minimum.at(first_col, R, C)
        lead = np.flatnonzero(first_col > 0)  # margin 0 before a row's first change
        cands.append(np.stack([np.zeros(lead.size), np.full(lead.size, a), lead, np.zeros(lead.size)], axis=1))
    allc = np.concatenate(cands)
    q = np.lexsort((allc[:, 3], allc[:, 2], allc[:, 1], allc[:, 0]))[0]
    m, a, i, z = allc[q]
    return (float(m), int(a), int(i), int(z)), violations


# ==================================================================== cost estimate
#: Unit costs (seconds) of :func:`estimate_check_support`, measured on the development machine:
#: one comparison of two stored entries (candidate counts); one column of a block's suffix sums;
#: one pair of stored entries of a row or one rectangle; the Python work per ``(a, j)`` frame and
#: per candidate ``(j, z)``; one entry of a built ``D``; one stored product of ``P[a] @ O[a]``.
COST_PAIR = 2.5e-9
COST_COLUMN = 3e-9
COST_COPAIR = 1.5e-7
COST_FRAME = 1.2e-4
COST_CANDIDATE = 1e-5
COST_D_ENTRY = 5e-8
COST_PRODUCT = 1.8e-7
#: How many ``(a, j)`` frames :func:`estimate_check_support` samples to predict how many ``D`` are built.
ESTIMATE_SAMPLE_FRAMES = 64


def _tp2_cost(M: sp.csr_array) -> tuple[float, int]:
    """``(seconds, bytes)`` of :func:`worst_minor_support` on ``M``."""
    n, m = M.shape
    if n < 2 or m < 2 or M.nnz == 0:
        return 0.0, 0
    blocks = _row_blocks(M.indptr, CANDIDATE_BLOCK)
    sizes = np.array([int(M.indptr[r1] - M.indptr[r0]) for r0, r1 in blocks])
    pairs = float(np.sum(sizes.astype(float) ** 2))
    copairs = float(np.sum(np.diff(M.indptr).astype(float) * (np.diff(M.indptr) - 1) / 2))
    seconds = COST_PAIR * pairs + COST_COLUMN * len(blocks) * m + COST_COPAIR * copairs
    memory = 8 * (int(sizes.max()) ** 2 + 8 * int(copairs) + 4 * M.nnz) if sizes.size else 0
    return seconds, memory


def estimate_check_support(model: POMDP, sdp_max_states: int, search: bool, exact_max_states: int,
                           reduce: bool):
    """:func:`.structure.estimate_check` for a sparse model: the check's operation counts from the
    non-zeros (:func:`check_copositivity_support`), with the share of built matrices measured on
    :data:`ESTIMATE_SAMPLE_FRAMES` sampled frames (their size sets the cost of the matrices built);
    the Python work per frame and per candidate includes the matrices' tests (on small supports the
    cheap ones decide)."""
    from .structure import CHECK_OVERHEAD_BYTES, COST_CHECK_FIXED, CheckEstimate

    S, A = model.S, model.A
    seconds, peak = COST_CHECK_FIXED, CHECK_OVERHEAD_BYTES
    for stack in (model.P_csr, model.O_csr):
        done: list[int] = []
        for a in range(len(stack)):
            if any(stack.same(a, b) for b in done):
                continue
            done.append(a)
            t, b = _tp2_cost(stack[a])
            seconds, peak = seconds + t, max(peak, b + CHECK_OVERHEAD_BYTES)
    products = sum(float(np.sum(np.diff(model.O_csr[a].indptr)[model.P_csr[a].indices])) for a in range(A))
    seconds += COST_PRODUCT * products
    peak = max(peak, int(8 * 6 * products) + CHECK_OVERHEAD_BYTES)
    PT, O = model.P_csr.T, model.O_csr
    rng = np.random.default_rng(0)
    frames = cands = 0
    entries = 0.0
    for a in range(max(A - 1, 0)):
        beta = sp.csr_array(O[a][1:].multiply(O[a + 1][:-1]))
        beta.eliminate_zeros()
        jb = np.repeat(np.arange(S - 1), np.diff(beta.indptr))
        if jb.size == 0:
            continue
        ujs = np.unique(jb)
        frames += ujs.size
        cands += jb.size
        picked = rng.choice(ujs, min(ESTIMATE_SAMPLE_FRAMES, ujs.size), replace=False)
        sizes = np.array([_frame(PT, a, int(j))[0].size for j in picked])
        entries += float(np.mean((sizes + 1.0) ** 2)) * jb.size / max(A - 1, 1)
    seconds += COST_FRAME * frames + COST_CANDIDATE * cands
    if cands:
        k = max(1.0, np.sqrt(entries / cands * max(A - 1, 1)))
        seconds += cands * COST_D_ENTRY * k * k
        peak = max(peak, int(8 * 8 * min(cands, 4_000_000 / max(k * k, 1.0)) * k * k) + CHECK_OVERHEAD_BYTES)
    return CheckEstimate(seconds, seconds, int(peak), frames, cands)
