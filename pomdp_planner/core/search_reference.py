"""The numpy search of :class:`~pomdp_planner.core.search.Planner`: the reference of the compiled kernel.

Algorithm 1 of the paper (Sec. V) written with numpy on arrays of beliefs; the compiled kernel
(``core/search_kernel.c``, through :mod:`.search_kernel`) computes the same thing and the tests
hold it to this module (equal values, equal node counts, the same deadline readings). The planner
uses this module when the kernel is not installed, when asked to (``Planner(kernel="numpy")``),
and for what the kernel does not take (an uncertainty function other than Shannon, Renyi-2 or
none; bounds other than :class:`~.myopic.MyopicBounds`).

Traversal (shared with the kernel, step for step): the nodes of a level are taken in chunks
(``leaf_chunk`` parents when the level below is the leaf level, ``expand_chunk`` otherwise); in
each chunk the actions in order (the root level's ``order``, else ``0..A-1``); for each action
that at least one parent of the chunk allows, one *step*: the deadline is read, then the allowed
parents' children under that action are formed (parent-major, then observation; branches with
``eta <= ETA_SKIP`` are impossible and not generated), valued depth-first by the same rule, and
backed up, ``Q(b, a) = rho(b, a) + gamma sum_z eta V(tau)`` (Eqs. 1, 2, 5). So a step costs only
the pairs (parent, action) it keeps: children and leaf values of pruned actions are never formed.

Leaves (the level that dominates) need no posterior belief: for the predicted beliefs ``b^a`` of
the step's parents, with ``u = b^a ∘ O[a][:, z]`` and ``eta = sum u``,
``eta V(leaf) = max_a' (u · r_a' - c_a' eta - w_a' eta f(u / eta))`` (``c``: the action-only price
of :meth:`~.search.Planner.priced`, zero otherwise), where ``u · r_a'``, ``eta`` and

* Renyi: ``eta f = -eta log(sum_s u_s^2 / eta^2)``, ``sum_s u_s^2 = (b^a)^2 @ O[a]^2``;
* Shannon: ``eta f = eta log eta - sum_s u_s log u_s`` with
  ``sum_s u_s log u_s = (b^a log b^a) @ O[a] + b^a @ (O[a] log O[a])``

are matrix products. Branches with tiny ``eta < ETA_FUSED_MIN`` (where ``u_s^2`` could underflow)
are valued from the normalised posterior, so no division blows up. Products over the small ``S``
dimension are ``einsum`` loops, not BLAS calls: on a shared 2-core machine multi-threaded BLAS
waiting for a busy core made the leaf level several times slower.

Leaf tables: ``eta`` and ``u · r_a'`` for every ``a'`` are one product per action. Up to
``FUSED_TABLE_MAX_BYTES`` (:mod:`.search`) the engine keeps the *fused* table ``WT[a]`` (rows
``O[a][:, z]`` and ``O[a][:, z] r[:, a']``: ``A (A + 1) Z S`` floats) and multiplies it with
``b^a``; beyond it it multiplies ``O[a]^T`` with ``b^a`` stacked with ``r_a' ∘ b^a``: the same
sums with the products taken in another order (equal up to rounding). The tables never hold the
price: it is subtracted as ``c_a' eta``, so a priced planner shares them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .belief import ETA_MIN
from .model import POMDP
from .myopic import MyopicBounds, TrivialBounds, argmax_smallest, transform_matrix

#: Observation branches with ``eta <= ETA_SKIP`` are impossible and not generated.
ETA_SKIP = ETA_MIN
#: Below this ``eta`` the fused leaf formulas are replaced by the normalised computation.
ETA_FUSED_MIN = 1e-100

Bounds = MyopicBounds | TrivialBounds


class DeadlineExceeded(Exception):
    """Raised inside a depth when the wall-clock deadline passes: :meth:`~.search.Planner.plan`
    catches it (never lets it escape); :meth:`~.search.Planner.search` and
    :meth:`~.search.Planner.q_values_batch` with a ``deadline`` raise it to their caller."""


@dataclass
class Traversal:
    """One search's settings and counters (both engines take the same ones).

    ``order``: the root level's action order. ``deadline``: a reading of ``clock`` (``None``: no
    deadline); read before every step (module docstring), except the root level's first when
    ``first_free``. ``sizes``: nodes per level, filled as the search goes.
    """

    bounds: Any
    cost: np.ndarray
    order: Sequence[int]
    sizes: list[int]
    deadline: float | None = None
    clock: Callable[[], float] | None = None
    first_free: bool = False
    count_only: bool = False
    _root_steps: int = field(default=0, repr=False)

    def check(self, level: int) -> None:
        """Read the deadline before a step of ``level`` (:class:`DeadlineExceeded` once it has passed)."""
        if self.deadline is None:
            return
        if level == 0 and self.first_free:
            self._root_steps += 1
            if self._root_steps == 1:
                return
        if self.clock() > self.deadline:
            raise DeadlineExceeded


def _mm(M: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``M @ X`` for a small ``M`` (``k x S``) and a wide ``X`` (``S x n``), single-threaded.

    ``einsum`` runs its own vectorised loops instead of a multi-threaded BLAS; on a shared
    machine (other processes, a ROS node) BLAS threads waiting for a busy core made the
    leaf level several times slower, and these products are memory-bound anyway.
    """
    return np.einsum("ks,sn->kn", M, X)


def _xlogx(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0.0, x * np.log(np.where(x > 0.0, x, 1.0)), 0.0)


def uncertainty_kind(model: POMDP) -> str:
    """How the leaves are valued: ``"renyi2"``, ``"shannon"``, ``"none"`` (also when every weight
    is zero) or ``"generic"`` (another uncertainty function: from explicit posteriors)."""
    name = model.uncertainty.name
    kind = name if name in ("none", "renyi2", "shannon") else "generic"
    return "none" if kind != "none" and not np.any(model.w) else kind


class ReferenceEngine:
    """The numpy search over one model (the tables are built once, with the engine).

    ``fused``: build the fused leaf table (module docstring). ``leaf_chunk``, ``expand_chunk``:
    parents per chunk (:func:`~.search.chunk_sizes`).
    """

    def __init__(self, model: POMDP, fused: bool, leaf_chunk: int, expand_chunk: int):
        self.model = model
        self.leaf_chunk, self.expand_chunk = int(leaf_chunk), int(expand_chunk)
        S, A, Z = model.S, model.A, model.Z
        P, O, r = model.P, model.O, model.r
        ar = np.arange(A)
        lo, up = ar[None, :, None], ar[None, None, :]
        # _range_mask[a, lo, up]: a in [lo, up]; crossed bounds (lo > up) keep every action
        self._range_mask = ((ar[:, None, None] >= lo) & (ar[:, None, None] <= up)) | (lo > up)
        self._OT = np.ascontiguousarray(np.swapaxes(O, 1, 2))  # (A, Z, S)
        self._r = np.ascontiguousarray(r)
        self._WT: np.ndarray | None = None
        if fused:
            # Transposed leaf matrices: WT[a] rows = O[a][:, z] (z = 0..Z-1), then O[a][:, z] * r[:, a']
            # for a' = 0..A-1 (Z rows each). Filled in place: A^2 S Z floats (planner_table_bytes).
            self._WT = np.empty((A, Z * (A + 1), S))
            self._WT[:, :Z] = self._OT
            for k in range(A):
                np.multiply(self._OT, r[:, k], out=self._WT[:, Z * (k + 1):Z * (k + 2)])
        self._PT = np.ascontiguousarray(np.swapaxes(P, 1, 2))
        self._w = np.asarray(model.w, dtype=float)
        self._rT = np.ascontiguousarray(r.T)
        self._gamma = float(model.gamma)
        self._kind = uncertainty_kind(model)
        # only the leaf formula of the model's uncertainty needs its table
        self._O2T = np.ascontiguousarray(np.swapaxes(O * O, 1, 2)) if self._kind == "renyi2" else None
        self._OlogOT = np.ascontiguousarray(np.swapaxes(_xlogx(O), 1, 2)) if self._kind == "shannon" else None
        self._bound_cache: tuple[Any, np.ndarray] | None = None
        self._count_tables: tuple[np.ndarray, np.ndarray] | None = None  # count mode only: built on first use

    # ------------------------------------------------------------------ entry points
    def search(self, BT: np.ndarray, depth: int, tr: Traversal, all_root: bool,
               out: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Root Q values of a depth-``depth`` search from the belief columns ``BT (S, n)`` into
        ``out (A, n)`` (``-inf`` where not searched; filled step by step, so a
        :class:`DeadlineExceeded` leaves the finished root actions in it). Returns the roots'
        ``(rho, lower, upper)`` (bounds ``None`` for :class:`TrivialBounds`). ``depth = 0``: ``rho``."""
        rhoT, lo, up = self.rho_bounds(tr.bounds, BT, tr.cost)
        out[...] = -np.inf
        if depth == 0:
            out[...] = rhoT
            return rhoT, lo, up
        allowed = np.ones_like(out, dtype=bool) if all_root else self._allowed(lo, up, BT.shape[1])
        self._values(BT, rhoT, allowed, depth, 0, tr, out)
        return rhoT, lo, up

    def rho_bounds(self, bounds: Any, BT: np.ndarray, cost: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """``(rho, lower, upper)`` for the columns ``BT``; ``lower = upper = None`` for
        :class:`TrivialBounds`. For ``MyopicBounds`` one product gives both ``r^T b`` and the
        bound terms ``C_g b``, ``C_h b`` of Eq. 8 (raw: crossed bounds stay crossed)."""
        if isinstance(bounds, TrivialBounds):
            return self._rho(BT, cost), None, None
        if type(bounds) is not MyopicBounds:
            rhoT = self._rho(BT, cost)
            lo, up = bounds.actions(np.ascontiguousarray(BT.T), np.ascontiguousarray(rhoT.T))
            return rhoT, np.asarray(lo), np.asarray(up)
        A = self.model.A
        X = _mm(self._bound_matrix(bounds), BT)  # rows: r^T b (A), C_g b (A), C_h b reversed (A)
        rhoT = self._rho(BT, cost, X[:A])
        T = X[A:].reshape(2, A, -1)
        T[0] += rhoT
        T[1] += rhoT[::-1]
        first = argmax_smallest(T, axis=1)  # lower: smallest maximiser; upper: largest (reversed rows)
        return rhoT, first[0], A - 1 - first[1]

    # --------------------------------------------------------------------- internals
    def _rho(self, BT: np.ndarray, cost: np.ndarray, linear: np.ndarray | None = None) -> np.ndarray:
        """``rho(b, a) - c_a`` (Eq. 3 with the price) for beliefs given as columns ``BT (S, n)``;
        returns ``(A, n)``. ``linear`` may carry ``r^T BT`` if already computed."""
        out = (_mm(self._rT, BT) if linear is None else linear) - cost[:, None]
        kind = self._kind
        if kind == "none":
            return out
        if kind == "renyi2":
            f = -np.log(np.einsum("sn,sn->n", BT, BT))
        elif kind == "shannon":
            f = -_xlogx(BT).sum(axis=0)
        else:
            f = self.model.uncertainty.value(BT.T)
        out -= self._w[:, None] * f[None, :]
        return out

    def _allowed(self, lo: np.ndarray | None, up: np.ndarray | None, n: int) -> np.ndarray:
        """Boolean ``(A, n)``: ``a`` in ``[lo, up]`` (every action if the bounds cross or are absent)."""
        if lo is None:
            return np.ones((self.model.A, n), dtype=bool)
        return self._range_mask[:, lo, up]

    def _bound_matrix(self, bounds: MyopicBounds) -> np.ndarray:
        """``[r^T; C_g; C_h reversed]`` (``3A x S``), cached for the last bounds object."""
        cache = self._bound_cache
        if cache is None or cache[0] is not bounds:
            Ch = transform_matrix(self.model, bounds.h)[::-1]  # upper: actions in reversed order
            M = np.concatenate([self._rT, transform_matrix(self.model, bounds.g), Ch])
            cache = (bounds, np.ascontiguousarray(M))
            self._bound_cache = cache
        return cache[1]

    def _values(self, BT: np.ndarray, rhoT: np.ndarray, allowed: np.ndarray, remaining: int, level: int,
                tr: Traversal, out: np.ndarray | None = None) -> np.ndarray:
        """``Q(b, a)`` as ``(A, n)`` (``-inf`` where not allowed) for the belief columns ``BT (S, n)``
        with ``remaining`` action-observation levels below them (the traversal of the module
        docstring). Count mode: only ``tr.sizes``."""
        A, n = self.model.A, BT.shape[1]
        QT = np.full((A, n), -np.inf) if out is None else out
        step = self.leaf_chunk if remaining == 1 else self.expand_chunk
        order = tr.order if level == 0 else range(A)
        for s in range(0, n, step):
            al = allowed[:, s:s + step]
            for a in order:
                idx = np.flatnonzero(al[a])
                if not idx.size:
                    continue
                tr.check(level)
                cols = idx + s
                BP = BT[:, cols]
                if remaining == 1:
                    if tr.count_only:
                        tr.sizes[level + 1] += self._count_leaves(a, BP)
                        continue
                    val, cnt = self._leaf_sum(a, BP, tr.cost)
                    QT[a, cols] = rhoT[a, cols] + self._gamma * val
                    tr.sizes[level + 1] += cnt
                    continue
                CT, parent, eta = self._children(a, BP)
                tr.sizes[level + 1] += CT.shape[1]
                rho_c, lo_c, up_c = self.rho_bounds(tr.bounds, CT, tr.cost)
                Qc = self._values(CT, rho_c, self._allowed(lo_c, up_c, CT.shape[1]), remaining - 1, level + 1, tr)
                if tr.count_only:
                    continue
                acc = np.bincount(parent, weights=eta * Qc.max(axis=0), minlength=idx.size)
                QT[a, cols] = rhoT[a, cols] + self._gamma * acc
                del CT, parent, eta, rho_c, Qc, acc  # not held while the next step recurses
        return QT

    def _children(self, a: int, BT: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Children of the columns ``BT (S, m)`` under action ``a`` and the possible observations.

        Eqs. 1-2: ``b^a = b @ P[a]``, ``u = b^a * O[a][:, z]``, ``eta = sum u``, ``tau = u / eta``.
        Returns posteriors as columns ``(S, k)`` ordered by (parent, observation), each child's
        parent (column of ``BT``) and ``eta``.
        """
        S, Z = self.model.S, self.model.Z
        m = BT.shape[1]
        Ba = _mm(self._PT[a], BT)  # (S, m)
        unnorm = (Ba[:, :, None] * self.model.O[a][:, None, :]).reshape(S, m * Z)  # column parent * Z + z
        eta = unnorm.sum(axis=0)
        sel = np.flatnonzero(eta > ETA_SKIP)
        e = eta[sel]
        return unnorm[:, sel] / e, sel // Z, e

    def _leaf_sum(self, a: int, BT: np.ndarray, cost: np.ndarray) -> tuple[np.ndarray, int]:
        """``sum_z eta max_a' rho(tau(b, a, z), a')`` for the leaf parents ``BT (S, m)`` under ``a``.

        Fused formulas (module docstring): no posterior belief is formed; every per-leaf quantity
        is a contiguous ``Z x m`` block. Returns the sums (``m``) and the number of leaves
        (branches with ``eta > ETA_SKIP``).
        """
        A = self.model.A
        w, kind = self._w, self._kind
        Ba = _mm(self._PT[a], BT)  # predicted beliefs as columns, (S, m)
        XT = self._leaf_products(a, Ba)  # eta (Z x m), then u . r_a' for each a' (Z x m each)
        eta = XT[0]
        ok = eta > ETA_SKIP
        if kind == "none":
            val = XT[1] - cost[0] * eta
            for k in range(1, A):
                np.maximum(val, XT[1 + k] - cost[k] * eta, out=val)
        elif kind == "generic":
            val = self._leaf_generic(Ba, a, eta, ok, cost)
        else:
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                if kind == "renyi2":
                    t = _mm(self._O2T[a], Ba * Ba)  # sum_s u_s^2, (Z, m)
                    np.divide(t, eta * eta, out=t)
                    np.log(t, out=t)
                    t *= eta  # -eta f(tau)
                else:  # shannon
                    t = _mm(self._OT[a], _xlogx(Ba))
                    t += _mm(self._OlogOT[a], Ba)  # sum_s u_s log u_s
                    t -= eta * np.log(eta)  # -eta f(tau)
                val = XT[1] - cost[0] * eta + w[0] * t
                for k in range(1, A):
                    np.maximum(val, XT[1 + k] - cost[k] * eta + w[k] * t, out=val)
            tiny = ok & (eta < ETA_FUSED_MIN)
            if tiny.any():
                val[tiny] = self._leaf_generic(Ba, a, eta, tiny, cost)[tiny]
        if not ok.all():
            val = np.where(ok, val, 0.0)
        return val.sum(axis=0), int(np.count_nonzero(ok))

    def _leaf_products(self, a: int, Ba: np.ndarray) -> np.ndarray:
        """``(A + 1, Z, m)``: ``eta = O[a]^T b^a`` and ``u . r_a'`` for every ``a'``, for the predicted
        beliefs ``Ba (S, m)`` (module docstring, "Leaf tables"): one product with the fused table
        ``WT[a]``, or, without it, ``O[a]^T`` times ``b^a`` stacked with ``r_a' * b^a``."""
        A, Z = self.model.A, self.model.Z
        m = Ba.shape[1]
        if self._WT is not None:
            return _mm(self._WT[a], Ba).reshape(A + 1, Z, m)
        R = np.empty((Ba.shape[0], A + 1, m))
        R[:, 0] = Ba
        np.multiply(self._r[:, :, None], Ba[:, None, :], out=R[:, 1:])
        return _mm(self._OT[a], R.reshape(Ba.shape[0], (A + 1) * m)).reshape(Z, A + 1, m).transpose(1, 0, 2)

    def _leaf_generic(self, BaT: np.ndarray, a: int, eta: np.ndarray, mask: np.ndarray,
                      cost: np.ndarray) -> np.ndarray:
        """``eta max_a' rho(tau, a')`` from explicit posteriors, for the ``(z, parent)`` in ``mask``."""
        out = np.zeros(eta.shape)
        zi, pi = np.nonzero(mask)
        if pi.size:
            unnorm = BaT[:, pi].T * self._OT[a][zi]
            tau = unnorm / unnorm.sum(axis=1, keepdims=True)
            out[zi, pi] = eta[zi, pi] * self._rho(np.ascontiguousarray(tau.T), cost).max(axis=0)
        return out

    def _count_leaves(self, a: int, BT: np.ndarray) -> int:
        """Leaves (branches with ``eta > ETA_SKIP``) of the parents ``BT (S, m)`` under ``a``."""
        if self._count_tables is None:
            PO = self.model.P @ self.model.O  # (A, S, Z): eta(z | b, a) = b @ PO[a][:, z]
            self._count_tables = (np.ascontiguousarray(np.swapaxes(PO, 1, 2)), PO.min(axis=1) > 2.0 * ETA_SKIP)
        POT, sure_obs = self._count_tables
        sure = sure_obs[a]  # eta >= min_s (P O)[a][s, z] > ETA_SKIP for any belief
        count = BT.shape[1] * int(np.count_nonzero(sure))
        if not sure.all():
            count += int(np.count_nonzero(_mm(POT[a][~sure], BT) > ETA_SKIP))
        return count
