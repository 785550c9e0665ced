"""The exact multiple-choice knapsack that chooses the joint action.

Given, for every target ``k`` and action ``a``, a value ``v_k(a)`` and an integer weight
``w_k(a) >= 0`` (the effort in the units of :attr:`~.problem.MultiTargetProblem.scale`), and an
integer capacity ``C``, find

    max_{a_1..a_K} sum_k v_k(a_k)   subject to   sum_k w_k(a_k) <= C,

one action per target. Two exact algorithms over the capacity ``c = 0..C`` give the same optimum
and the same joint action (up to the order in which floating-point values are added):

* :func:`solve_knapsack_reference`, dynamic programming target after target: ``T_0(c) = 0`` and
  ``T_k(c) = max_{a: w_k(a) <= c} T_{k-1}(c - w_k(a)) + v_k(a)``; ``T_K(C)`` is the optimum and
  the maximisers, stored per ``(k, c)``, give the joint action back. ``O(K A C)`` time, a Python
  step per target.
* the tree (:func:`solve_padded`'s default): the targets are leaves of a balanced binary tree and
  every node holds its subtree's best value for every capacity (``P(c)``: the best total of its
  targets within ``c``); a parent is the max-plus convolution of its children,
  ``P(c) = max_{c_L + c_R = c} P_L(c_L) + P_R(c_R)``, computed for all nodes of a level at once,
  so a decision costs ``log2 K`` vectorised steps instead of ``K`` Python steps. A level of ``m``
  nodes whose children hold ``n`` capacities costs ``m n min(C + 1, 2n - 1)``: about ``3 K C
  max_a w`` in all when the weights are small beside ``C`` (the planner's case). Where that
  would exceed the target-by-target cost several times (large weights, e.g. fine fractional
  efforts) the reference runs instead.

Exact: the weights are integers, so feasibility is never decided up to rounding, and every
joint action within the capacity is a path through either table.

**Ties** (both algorithms): of the joint actions with the optimal value, the one whose *last*
target's action index is the smallest (the highest priority), then the next-to-last's, and so
on: the reverse-lexicographic minimum. The reference gets it by taking the first maximiser when
it goes back from the last target; the tree by ranking, in every node, the joint actions it keeps
for its capacities in that order, and preferring, among a parent's best splits, the one whose
later half ranks first, then its earlier half. The result is deterministic. ``-inf`` values mark
actions that may not be taken; if no joint action has a finite value the knapsack raises
``ValueError``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: The tree runs when its element count is at most this multiple of the reference's
#: (``K A (C + 1)``, plus :data:`STEP_ELEMENTS` per target for the reference's Python step) ...
TREE_COST_FACTOR = 4.0
#: ... and no level needs more than this many elements (the memory of one level's candidates).
TREE_MAX_LEVEL_ELEMENTS = 1 << 22
#: The reference's fixed cost per target, in array elements (a Python step of a few numpy calls).
STEP_ELEMENTS = 4000
METHODS = ("auto", "tree", "reference")
_NO_RANK = np.iinfo(np.int64).max


def padded(values: Sequence[np.ndarray], weights: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(V, W)``: the targets' values and integer weights as ``K x max_k A_k`` arrays, the missing
    actions of targets with fewer actions given the value ``-inf`` (never chosen) and weight 0."""
    if len(values) != len(weights):
        raise ValueError(f"values, weights: {len(values)} and {len(weights)} targets")
    amax = max((np.asarray(v).size for v in values), default=1)
    V = np.full((len(values), amax), -np.inf)
    W = np.zeros((len(values), amax), dtype=np.int64)
    for k, (v, w) in enumerate(zip(values, weights, strict=True)):
        v = np.asarray(v, dtype=float)
        w = np.asarray(w)
        if v.shape != w.shape or v.ndim != 1 or v.size == 0:
            raise ValueError(f"values[{k}], weights[{k}]: need one value and one weight per action")
        if not np.issubdtype(w.dtype, np.integer):
            raise ValueError(f"weights[{k}]: must be non-negative integers")
        V[k, :v.size] = v
        W[k, :w.size] = w
    return V, W


def solve_knapsack(values: Sequence[np.ndarray], weights: Sequence[np.ndarray], capacity: int,
                   method: str = "auto") -> tuple[float, tuple[int, ...]]:
    """``(optimum, joint action)`` of the multiple-choice knapsack (module docstring).

    ``values[k]`` and ``weights[k]`` have one entry per action of target ``k`` (weights
    non-negative integers); ``capacity`` a non-negative integer. ``method``: :data:`METHODS`
    (``"auto"`` picks the tree unless it would cost more, see the module docstring).
    """
    if method == "reference":
        return solve_knapsack_reference(values, weights, capacity)
    V, W = padded(values, weights)
    return solve_padded(V, W, capacity, method)


def _checked(V: np.ndarray, W: np.ndarray, capacity: int, method: str) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """``(V, W, C, tree)``: the arrays checked, ``V`` set to ``-inf`` where an action is heavier than
    the capacity, and whether the tree runs (module docstring)."""
    C = int(capacity)
    if C < 0:
        raise ValueError(f"capacity: must be >= 0, got {capacity}")
    if method not in METHODS:
        raise ValueError(f"method: one of {', '.join(METHODS)}, got {method!r}")
    V = np.asarray(V, dtype=float)
    W = np.asarray(W)
    if V.ndim != 2 or V.shape != W.shape or V.shape[1] == 0:
        raise ValueError(f"values, weights: need two K x A arrays of one shape, got {V.shape} and {W.shape}")
    if not np.issubdtype(W.dtype, np.integer) or np.any(W < 0):
        raise ValueError("weights: must be non-negative integers")
    if np.any(np.isnan(V)):
        raise ValueError(f"values[{int(np.argwhere(np.isnan(V))[0, 0])}]: NaN")
    if np.any(V == np.inf):
        raise ValueError(f"values[{int(np.argwhere(V == np.inf)[0, 0])}]: +inf")
    V = np.where(W <= C, V, -np.inf)  # an action heavier than the capacity is never within it
    W = np.minimum(W, C + 1).astype(np.int64)
    tree = V.shape[0] > 0 and (method == "tree" or (method == "auto" and _tree_pays(V.shape[0], V.shape[1],
                                                                                      int(W.max()), C)))
    return V, W, C, tree


def solve_padded(V: np.ndarray, W: np.ndarray, capacity: int, method: str = "auto",
                 ties: bool = True) -> tuple[float, tuple[int, ...]]:
    """:func:`solve_knapsack` for values ``V`` and integer weights ``W`` given as ``K x A`` arrays
    (:func:`padded`; ``-inf`` values are actions that may not be taken). The tree first goes back
    down the root's path only, taking the first best split of every node on it; where that finds
    the only optimal joint action (no ties on the path) it is the answer, else the tie rule's
    ranks are computed for every node. ``ties=False``: any optimal joint action will do (the
    path's, also where it is not the only one: deterministic, but not the tie rule)."""
    V, W, C, tree = _checked(V, W, capacity, method)
    if V.shape[0] == 0:
        return 0.0, ()
    if not tree:
        return solve_knapsack_reference(list(V), list(W), C)
    optimum, actions, unique = _solve_path(V, W, C)
    return (optimum, actions) if unique or not ties else _solve_tree(V, W, C)


def knapsack_optimum(V: np.ndarray, W: np.ndarray, capacity: int, method: str = "auto") -> float:
    """The optimum of :func:`solve_padded` without the joint action: the tree's values only (no
    ties to break, no way back), a few vectorised steps per level. Equal to ``solve_padded(V, W,
    capacity)[0]`` (the same sums in the same order); ``ValueError`` where that raises."""
    V, W, C, tree = _checked(V, W, capacity, method)
    if V.shape[0] == 0:
        return 0.0
    if not tree:
        return solve_knapsack_reference(list(V), list(W), C)[0]
    val = _leaves(V, W, C)[0]
    while val.shape[0] > 1:
        val = _merge_values(val, C)[0]
    return _finite(float(val[0, -1]))


def _finite(optimum: float) -> float:
    if not np.isfinite(optimum):
        raise ValueError("no joint action within the capacity has a finite value")
    return optimum


def _tree_levels(K: int, wmax: int, C: int) -> list[tuple[int, int, int]]:
    """``(nodes, n, columns)`` per level of the tree: ``n`` capacities per child, ``columns`` computed."""
    m = 1 << max(K - 1, 0).bit_length()
    n = min(C, wmax) + 1
    out = []
    while m > 1:
        m //= 2
        n2 = min(C, 2 * (n - 1)) + 1
        out.append((m, n, 1 if m == 1 else n2))
        n = n2
    return out


def _tree_pays(K: int, A: int, wmax: int, C: int) -> bool:
    """The tree's cost (elements over all levels, and the largest level) against the reference's."""
    levels = _tree_levels(K, wmax, C)
    tree = K * A * (min(C, wmax) + 1) + sum(m * n * c for m, n, c in levels)  # the leaves, the levels
    largest = max((m * n * c for m, n, c in levels), default=0)
    return largest <= TREE_MAX_LEVEL_ELEMENTS and tree <= TREE_COST_FACTOR * K * (A * (C + 1) + STEP_ELEMENTS)


def _dense_rank(node: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Ranks of the pairs ``(first, second)`` in lexicographic order within each ``node`` (equal
    pairs equal ranks; increasing across nodes, which only the order within a node needs)."""
    order = np.lexsort((second, first, node))
    a, b, c = node[order], first[order], second[order]
    new = np.ones(order.size, dtype=bool)
    new[1:] = (a[1:] != a[:-1]) | (b[1:] != b[:-1]) | (c[1:] != c[:-1])
    out = np.empty(order.size, dtype=np.int64)
    out[order] = np.cumsum(new) - 1
    return out


def _leaves(V: np.ndarray, W: np.ndarray, C: int) -> tuple[np.ndarray, int, np.ndarray]:
    """The tree's leaves, padded to a power of two (the extra targets: one action of value 0 and
    weight 0): ``(values, n, actions)``, ``(Kp, n)`` each, for the capacities ``0..n-1``: the best
    value within each capacity and its action; of equal values the smallest index, which is also
    the leaf's rank in the tie order."""
    K = V.shape[0]
    Kp = 1 << max(K - 1, 0).bit_length()
    n = min(C, int(W.max())) + 1
    M = np.where(W[:, :, None] <= np.arange(n), V[:, :, None], -np.inf)  # (K, A, n)
    val = np.zeros((Kp, n))
    val[:K] = M.max(axis=1)
    leaf = np.zeros((Kp, n), dtype=np.int64)
    leaf[:K] = np.argmax(M == val[:K, None, :], axis=1)
    return val, n, leaf


def _skewed(first: np.ndarray, second: np.ndarray, fill: float | int, columns: int, add: bool) -> np.ndarray:
    """``D[j, c_L, c] = first[j, c_L] + second[j, c - c_L]`` (or ``second[j, c - c_L]`` alone if not
    ``add``; ``fill`` where ``c - c_L`` is outside ``0..n-1``) for ``c = 0..columns-1``: the table of
    pairs ``(c_L, c_R)`` with row ``c_L`` shifted right by ``c_L`` (a view of one padded array), so the
    pairs ``c_L + c_R = c`` of a max-plus convolution stand in column ``c``."""
    m, n = first.shape
    Y = np.empty((m, n, 2 * n), dtype=second.dtype)
    Y[:, :, n:] = fill
    if add:
        np.add(first[:, :, None], second[:, None, :], out=Y[:, :, :n])
    else:
        Y[:, :, :n] = second[:, None, :]
    return Y.reshape(m, 2 * n * n)[:, :n * (2 * n - 1)].reshape(m, n, 2 * n - 1)[:, :, :columns]


def _merge_values(val: np.ndarray, C: int) -> tuple[np.ndarray, np.ndarray]:
    """One level up: ``(parents, X)``, ``X[j, c_L, c] = P_L(c_L) + P_R(c - c_L)`` for the pairs of rows
    ``(2j, 2j + 1)`` of ``val`` and the capacities ``c = 0..min(C, 2n - 2)``, ``parents = max_{c_L} X``."""
    n = val.shape[1]
    X = _skewed(val[0::2], val[1::2], -np.inf, min(C, 2 * (n - 1)) + 1, add=True)
    return X.max(axis=1), X


def _solve_tree(V: np.ndarray, W: np.ndarray, C: int) -> tuple[float, tuple[int, ...]]:
    """The tree of the module docstring (``V`` already ``-inf`` above the capacity)."""
    val, n, leaf = _leaves(V, W, C)
    K, Kp = V.shape[0], val.shape[0]
    rank = leaf
    splits: list[np.ndarray] = []
    while val.shape[0] > 1:
        m = val.shape[0] // 2
        parent, X = _merge_values(val, C)
        n2 = parent.shape[1]
        rL, rR = rank[0::2], rank[1::2]
        # Of the best splits, the one whose later half ranks first, then its earlier half.
        tied = X == parent[:, None, :]
        kR = np.where(tied, _skewed(rL, rR, _NO_RANK, n2, add=False), _NO_RANK)
        tied &= kR == kR.min(axis=1)[:, None, :]
        split = np.argmin(np.where(tied, rL[:, :, None], _NO_RANK), axis=1)  # (m, n2): c_L
        splits.append(split)
        if m > 1:  # the parents' ranks: their joint actions (later half, earlier half) in that order
            first = np.take_along_axis(rR, np.arange(n2)[None, :] - split, axis=1)
            second = np.take_along_axis(rL, split, axis=1)
            rank = _dense_rank(np.repeat(np.arange(m), n2), first.ravel(), second.ravel()).reshape(m, n2)
        val, n = parent, n2
    optimum = _finite(float(val[0, n - 1]))  # the root at its capacity (its last column)
    # Back down the tree: every node's capacity, split into its halves'.
    caps = np.array([n - 1], dtype=np.int64)
    for split in reversed(splits):
        left = split[np.arange(split.shape[0]), caps]
        caps = np.stack([left, caps - left], axis=1).ravel()
    actions = leaf[np.arange(Kp), caps][:K]
    return optimum, tuple(int(a) for a in actions)


def _solve_path(V: np.ndarray, W: np.ndarray, C: int) -> tuple[float, tuple[int, ...], bool]:
    """An optimal joint action by the tree without the tie rule: the values level by level, then
    back down the root's path only, the first best split of each node on it (``m n`` values per
    level instead of ``m n^2``). Also whether that joint action is the only optimal one: every
    node on the path has one best split and every target one best action within its capacity
    (another optimal joint action would split some node on the path otherwise, or give some
    target another action), so the tie rule has nothing to choose."""
    val, n, leaf = _leaves(V, W, C)
    levels = [val]
    while levels[-1].shape[0] > 1:
        levels.append(_merge_values(levels[-1], C)[0])
    optimum = _finite(float(levels[-1][0, -1]))
    caps = np.array([levels[-1].shape[1] - 1], dtype=np.int64)
    unique = True
    for below in reversed(levels[:-1]):
        m, n = below.shape[0] // 2, below.shape[1]
        left = np.arange(n)[None, :]
        right = caps[:, None] - left
        ok = (right >= 0) & (right < n)
        rows = np.arange(m)[:, None]
        X = np.where(ok, below[2 * rows, left] + below[2 * rows + 1, np.clip(right, 0, n - 1)], -np.inf)
        split = np.argmax(X, axis=1)
        unique = unique and bool(np.all(np.count_nonzero(X == X[rows[:, 0], split][:, None], axis=1) == 1))
        caps = np.stack([split, caps - split], axis=1).ravel()
    K = V.shape[0]
    caps = caps[:K]
    best = val[np.arange(K), caps]
    unique = unique and bool(np.all(np.count_nonzero((W <= caps[:, None]) & (V == best[:, None]), axis=1) == 1))
    return optimum, tuple(int(a) for a in leaf[np.arange(K), caps]), unique


def near_optimal(V: np.ndarray, W: np.ndarray, capacity: int, tolerance: float, limit: int
                 ) -> list[tuple[int, ...]]:
    """The joint actions within ``capacity`` whose value is at least the optimum minus ``tolerance``,
    at most ``limit`` of them: the first is the optimum the tie rule picks (exact arithmetic), the
    others follow in the order of a depth-first search from the last target that tries each
    target's actions from the least loss to the greatest (ties: index order). ``V``, ``W`` as in
    :func:`solve_padded`.

    The reference's tables ``T_k(c)`` (the best value of the first ``k`` targets within ``c``) make
    the search exact: a partial choice of the last targets is continued only while its value plus
    the best completion, ``T_k(c)``, stays within the tolerance, so every joint action the search
    reaches qualifies and every qualifying one is reached (until ``limit``). ``O(K A C)`` for the
    tables, ``O(limit K A)`` steps for the search."""
    V, W, C, _ = _checked(V, W, capacity, "reference")
    K, A = V.shape
    if K == 0:
        return [()]
    c = np.arange(C + 1)
    T = np.zeros((K + 1, C + 1))
    for k in range(K):
        shifted = c[None, :] - W[k][:, None]
        T[k + 1] = np.where(shifted >= 0, T[k][np.maximum(shifted, 0)] + V[k][:, None], -np.inf).max(axis=0)
    _finite(float(T[K, C]))
    rows_V, rows_W, table = V.tolist(), W.tolist(), T.tolist()
    out: list[tuple[int, ...]] = []
    stack: list[tuple[int, int, float, tuple[int, ...]]] = [(K, C, 0.0, ())]  # (targets left, capacity, loss, tail)
    while stack and len(out) < limit:
        k, cap, loss, tail = stack.pop()
        if k == 0:
            out.append(tail)
            continue
        best = table[k][cap]
        follow = []
        for a in range(A):
            w, v = rows_W[k - 1][a], rows_V[k - 1][a]
            if w > cap or v == -np.inf:
                continue
            extra = best - (table[k - 1][cap - w] + v)
            if loss + extra <= tolerance:
                follow.append((extra, a, (k - 1, cap - w, loss + max(extra, 0.0), (a, *tail))))
        stack.extend(item for _, _, item in sorted(follow, reverse=True))  # popped: the least loss first
    return out


def solve_knapsack_reference(values: Sequence[np.ndarray], weights: Sequence[np.ndarray], capacity: int
                             ) -> tuple[float, tuple[int, ...]]:
    """The target-by-target dynamic programme (module docstring): the tree's reference."""
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
