"""Independent optimal-policy references for small POMDPs (validation of Sec. IV's bounds).

Two solvers, both independent of the myopic bounds they are used to check:

1. :func:`solve_grid` -- value iteration on a regular grid of the belief simplex (any
   uncertainty function, practical for S = 2, 3 and small S = 4). The Bellman backup of the
   paper's Sec. II-B (Eqs. 4-6),

       Q(b, a) = rho(b, a) + gamma * sum_z eta(z | b, a) V(tau(b, a, z)),

   is applied at the grid beliefs ``b = k / n`` (integer ``k``, ``sum k = n``), and ``V`` at
   the off-grid posterior ``tau`` is interpolated barycentrically on the Freudenthal (Kuhn)
   triangulation of the grid (Lovejoy 1991, "Computationally feasible bounds for partially
   observed Markov decision processes"). The interpolation weights of every
   (grid belief, action, observation) are computed once and folded, with ``eta``, into one
   sparse matrix ``T`` of shape ``(N*A, N)``: a backup is then ``R + gamma * T @ V``. This is
   an ordinary finite MDP on the grid, solved exactly by policy iteration with sparse LU
   solves (:func:`scipy.sparse.linalg.splu`), or by exactly ``H`` backups for the
   finite-horizon ``Q_H`` (``horizon=H``).

2. :func:`alpha_vector_value_iteration` -- exact finite-horizon value iteration for rewards
   linear in the belief (``f = 0`` or ``w = 0``), with alpha vectors and LP pruning
   (incremental pruning, Lark's filter, scipy's HiGHS). With an a-priori error bound it
   certifies the infinite-horizon optimal action at given beliefs (:func:`certified_actions`).

Accuracy of the grid reference (read this before trusting an action)
--------------------------------------------------------------------
The grid solution is the exact optimum of a *discretised* problem, not of the POMDP. Where
``rho`` is convex in ``b`` (``w >= 0`` and a concave ``f``: Shannon, or Renyi only for S = 2;
Renyi quadratic entropy is not concave for S >= 3), ``V*`` is convex and its
piecewise-linear interpolation lies above it, so the grid ``V`` is an upper bound on ``V*``
(Lovejoy 1991) and converges to it as ``n`` grows; the error of ``V`` is of order
``h^2 |curvature| / (1 - gamma)`` with ``h = 1/n`` (``h log h`` near the boundary for Shannon
entropy). Most of that error is common to all actions at a belief -- it is an error of the
continuation value that every action shares -- so the *differences* ``Q(b,a) - Q(b,a')`` that
decide the action are far more accurate than ``V``. An action is trustworthy where the gap
between the best and second-best ``Q`` exceeds the error of those differences. We do not
guess that error: :func:`reference_policy` solves the grid at resolutions ``n`` and ``2n``
(the coarse grid is a subset of the fine one) and takes

    tie_margin = safety * max over coarse beliefs b and actions a, a' of
                 |(Q_2n(b,a) - Q_2n(b,a')) - (Q_n(b,a) - Q_n(b,a'))|,

the largest change of any action difference when the resolution doubles. With first-order
convergence the error left in the ``2n`` differences is at most that change, with second
order a third of it; ``safety`` (default 2) covers the rest. Beliefs where the fine gap is
at most ``tie_margin`` are *near-ties* and are excluded from validation; elsewhere the
fine-grid action is the reference optimal action. ``test/test_reference.py`` checks that the
true error of the Q differences (against a brute-force expectimax tree and against exact
alpha vectors) stays below this margin. On the paper's S = 3 problem the margin is 1.5e-3 at
n = 40 (9.5e-4 at n = 60) and fewer than 0.4 % of the grid beliefs are near-ties.

Cost of the exact solver: the number of alpha vectors (and LPs) per backup is problem
dependent; with gamma <= 0.75 and S <= 5 a certified horizon of 20-30 takes well under a
second to a few seconds. For gamma = 0.99 the a-priori certificate needs H ~ 1000 backups.

Conventions: ``P[a, i, j] = P(j | i, a)``, ``O[a, j, z] = P(z | j, a)``, 0-based actions
(see :mod:`pomdp_planner.core.model`).

Independence: from the package this module uses only the model's arrays (``P``, ``O``, ``r``,
``w``, ``gamma``, the name of the uncertainty function). The Bayes update (Eqs. 1-2) and the
belief reward (Eq. 3, with the entropies written out) are re-derived here
(:func:`_posteriors`, :func:`_belief_reward`) rather than imported from ``core/belief.py``
and ``POMDP.rho``, so the validation of the bounds does not rest on the code it checks.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog
from scipy.sparse.linalg import splu

from .checks import check_int
from .model import POMDP, require_discount_below_one

__all__ = [
    "AlphaVectorSolution",
    "FreudenthalGrid",
    "GridSolution",
    "ReferencePolicy",
    "alpha_vector_value_iteration",
    "certified_actions",
    "prune_alpha_vectors",
    "reference_policy",
    "solve_grid",
]


# ---------------------------------------------------------------- Eqs. 1-3, written here
def _posteriors(model: POMDP, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``tau(b, a, z)`` and ``eta(z | b, a)`` for every belief, action and observation.

    Eq. 1: ``b^a(s') = sum_s b(s) P[a, s, s']``; Eq. 2: ``eta = sum_s' b^a(s') O[a, s', z]`` and
    ``tau(s') = b^a(s') O[a, s', z] / eta``. Where ``eta = 0`` the posterior carries no weight;
    it is set to ``b^a``. Shapes ``(M, A, Z, S)`` and ``(M, A, Z)``.
    """
    B = np.asarray(B, dtype=float)
    pred = np.einsum("ms,ast->mat", B, model.P)  # (M, A, S)
    joint = pred[:, :, None, :] * np.transpose(model.O, (0, 2, 1))[None, :, :, :]  # (M, A, Z, S)
    eta = joint.sum(axis=-1)
    pos = eta > 0.0
    tau = np.where(pos[..., None], joint / np.where(pos, eta, 1.0)[..., None], pred[:, :, None, :])
    return tau, eta


def _belief_reward(model: POMDP, B: np.ndarray) -> np.ndarray:
    """Eq. 3, ``rho(b, a) = b . r[:, a] - w_a f(b)``, shape ``(M, A)``, with ``f`` written out:
    Shannon ``-sum b log b`` (``0 log 0 = 0``), Renyi quadratic ``-log sum b^2``, none ``0``."""
    B = np.asarray(B, dtype=float)
    name = model.uncertainty.name
    if name == "shannon":
        f = -np.sum(np.where(B > 0.0, B * np.log(np.where(B > 0.0, B, 1.0)), 0.0), axis=-1)
    elif name == "renyi2":
        f = -np.log(np.sum(B * B, axis=-1))
    elif name == "none":
        f = np.zeros(B.shape[0])
    else:  # pragma: no cover - the model refuses other names
        raise ValueError(f"uncertainty.function: no reference formula for {name!r}")
    return B @ model.r - f[:, None] * np.asarray(model.w, dtype=float)[None, :]


# ---------------------------------------------------------------------------- the grid
class FreudenthalGrid:
    """The regular grid ``{k / n : k in N^S, sum k = n}`` of the simplex and its triangulation.

    A belief ``b`` is mapped to ``y = n * (b_2 + ... + b_S, b_3 + ... + b_S, ..., b_S)``, so
    that ``n >= y_1 >= ... >= y_{S-1} >= 0``; grid beliefs are exactly the integer ``y``. The
    Freudenthal triangulation of ``R^{S-1}`` (unit cubes cut into simplices by the order of
    the fractional parts) restricted to this region triangulates the simplex (Lovejoy 1991),
    and barycentric weights of a point are ``1 - d_(1), d_(1) - d_(2), ..., d_(S-1)`` for the
    fractional parts ``d`` sorted in decreasing order.
    """

    def __init__(self, S: int, n: int):
        check_int(S, "S", 2, note="(a grid needs at least 2 states)")
        check_int(n, "n", 1, note="(the grid resolution)")
        self.S = int(S)
        self.n = int(n)
        m = self.S - 1
        lattice = np.array(
            [sorted(c, reverse=True) for c in itertools.combinations_with_replacement(range(self.n + 1), m)],
            dtype=np.int64,
        ).reshape(-1, m)
        self.lattice = lattice  # (N, S-1) integer y
        full = np.concatenate([np.full((len(lattice), 1), self.n), lattice, np.zeros((len(lattice), 1), int)], axis=1)
        self.beliefs = (full[:, :-1] - full[:, 1:]) / self.n  # (N, S)
        self._index = np.full((self.n + 1,) * m, -1, dtype=np.int64)
        self._index[tuple(lattice.T)] = np.arange(len(lattice))

    @property
    def size(self) -> int:
        """Number of grid beliefs, ``C(n + S - 1, S - 1)``."""
        return len(self.lattice)

    def index_of(self, B: np.ndarray) -> np.ndarray:
        """Grid index of beliefs that lie on the grid (``-1`` for those that do not)."""
        B = np.asarray(B, dtype=float).reshape(-1, self.S)
        y = self.n * np.cumsum(B[:, ::-1], axis=1)[:, ::-1][:, 1:]
        k = np.rint(y).astype(np.int64)
        on = np.all(np.abs(y - k) < 1e-9, axis=1) & np.all((k >= 0) & (k <= self.n), axis=1)
        out = np.full(len(B), -1, dtype=np.int64)
        out[on] = self._index[tuple(k[on].T)]
        return out

    def vertices_and_weights(self, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Freudenthal simplex containing each belief: grid indices and barycentric weights.

        ``B`` has shape ``(M, S)``; returns ``(idx, lam)`` of shape ``(M, S)`` each, with
        ``lam >= 0``, ``lam.sum(1) == 1`` and ``lam @ beliefs[idx] == B`` (to rounding).
        """
        B = np.asarray(B, dtype=float).reshape(-1, self.S)
        M, m = len(B), self.S - 1
        tails = np.cumsum(B[:, ::-1], axis=1)[:, ::-1][:, 1:]  # (M, S-1): b_2+..+b_S, ...
        y = np.clip(self.n * tails, 0.0, float(self.n))
        y = np.minimum.accumulate(y, axis=1)  # repair rounding so that y is non-increasing
        v = np.minimum(np.floor(y), self.n - 1).astype(np.int64)
        d = y - v
        order = np.argsort(-d, axis=1, kind="stable")  # ties: lower coordinate first keeps y monotone
        ds = np.take_along_axis(d, order, axis=1)
        lam = np.empty((M, m + 1))
        lam[:, 0] = 1.0 - ds[:, 0]
        lam[:, 1:m] = ds[:, :-1] - ds[:, 1:]
        lam[:, m] = ds[:, -1]
        steps = np.zeros((M, m + 1, m), dtype=np.int64)
        rows = np.arange(M)
        for k in range(1, m + 1):
            steps[:, k] = steps[:, k - 1]
            steps[rows, k, order[:, k - 1]] += 1
        verts = v[:, None, :] + steps  # (M, S, S-1)
        idx = self._index[tuple(np.moveaxis(verts, -1, 0))]
        lam = np.clip(lam, 0.0, None)
        if np.any(idx[lam > 0] < 0):  # pragma: no cover - a bug guard, not an input error
            raise RuntimeError("Freudenthal interpolation left the grid")
        idx = np.where(idx < 0, 0, idx)  # only possible with zero weight
        return idx, lam / lam.sum(axis=1, keepdims=True)

    def interpolation_matrix(self, B: np.ndarray) -> sp.csr_matrix:
        """Sparse ``(M, N)`` matrix ``W`` with ``W @ V`` the interpolated values at ``B``."""
        idx, lam = self.vertices_and_weights(B)
        M = idx.shape[0]
        rows = np.repeat(np.arange(M), self.S)
        return sp.csr_matrix((lam.ravel(), (rows, idx.ravel())), shape=(M, self.size))

    def interpolate(self, values: np.ndarray, B: np.ndarray) -> np.ndarray:
        """Barycentric interpolation of grid ``values`` (``(N,)`` or ``(N, k)``) at beliefs ``B``."""
        idx, lam = self.vertices_and_weights(B)
        vals = np.asarray(values)[idx]  # (M, S, ...)
        return np.einsum("ms,ms...->m...", lam, vals)


# ------------------------------------------------------------------ grid value iteration
@dataclass(frozen=True, eq=False)
class GridSolution:
    """Result of :func:`solve_grid` (all arrays over the grid beliefs, 0-based actions).

    ``Q[k, a]`` is the Bellman backup of ``V`` at ``beliefs[k]``; ``actions`` the smallest
    maximiser; ``gap`` the best minus the second-best Q (``inf`` when ``A == 1``).
    ``horizon`` is ``None`` for the infinite-horizon fixed point, else the number of
    decisions ``H`` of ``Q_H`` (paper Eqs. 4-7: ``Q_1 = rho``).
    """

    model: POMDP
    grid: FreudenthalGrid
    V: np.ndarray
    Q: np.ndarray
    actions: np.ndarray
    gap: np.ndarray
    horizon: int | None
    iterations: int
    residual: float
    method: str

    @property
    def beliefs(self) -> np.ndarray:
        return self.grid.beliefs

    @property
    def n(self) -> int:
        return self.grid.n

    def value(self, B: np.ndarray) -> np.ndarray:
        """Interpolated ``V`` at arbitrary beliefs ``(M, S)``."""
        return self.grid.interpolate(self.V, B)

    def q_values(self, B: np.ndarray) -> np.ndarray:
        """One exact Bellman backup of the grid ``V`` at arbitrary beliefs: ``(M, A)``.

        ``Q(b, a) = rho(b, a) + gamma sum_z eta(z | b, a) V(tau(b, a, z))`` with ``V``
        interpolated; at grid beliefs this is ``Q`` (for ``horizon=None``). Use it for the
        reference action off the grid (e.g. at sampled reachable beliefs).
        """
        B = np.atleast_2d(np.asarray(B, dtype=float))
        tau, eta = _posteriors(self.model, B)  # (M, A, Z, S), (M, A, Z)
        v = self.grid.interpolate(self.V, tau.reshape(-1, self.model.S)).reshape(eta.shape)
        return _belief_reward(self.model, B) + self.model.gamma * np.sum(eta * v, axis=-1)


def _q_gap(Q: np.ndarray) -> np.ndarray:
    if Q.shape[1] < 2:
        return np.full(Q.shape[0], np.inf)
    top2 = np.sort(Q, axis=1)[:, -2:]
    return top2[:, 1] - top2[:, 0]


def _backup_operator(model: POMDP, grid: FreudenthalGrid) -> tuple[np.ndarray, sp.csr_matrix]:
    """``R`` (N*A,) and the sparse ``T`` (N*A, N) with ``Q.ravel() = R + gamma T @ V``."""
    B = grid.beliefs
    N, A, Z, S = grid.size, model.A, model.Z, model.S
    tau, eta = _posteriors(model, B)  # (N, A, Z, S), (N, A, Z)
    idx, lam = grid.vertices_and_weights(tau.reshape(-1, S))  # (N*A*Z, S)
    data = (lam * eta.reshape(-1, 1)).ravel()
    rows = np.repeat(np.arange(N * A), Z * S)  # row (k, a) collects all z and vertices
    T = sp.csr_matrix((data, (rows, idx.ravel())), shape=(N * A, N))
    T.sum_duplicates()
    R = _belief_reward(model, B).ravel()
    return R, T


def solve_grid(model: POMDP, n: int, horizon: int | None = None, tol: float = 1e-10,
               max_iter: int = 200) -> GridSolution:
    """Optimal values and actions of ``model`` at the grid beliefs of resolution ``n``.

    ``horizon=None``: the infinite-horizon fixed point of the discretised Bellman operator
    by policy iteration (each evaluation an exact sparse LU solve of
    ``(I - gamma T_pi) V = R_pi``; improvement keeps the current action unless another is
    better by more than ``tol``, so it cannot cycle). ``horizon=H``: exactly ``H`` backups
    from ``V_0 = 0``, i.e. the ``Q_H`` of the paper's Eqs. 4-6.
    """
    if model.S < 2:
        raise ValueError("model: grid value iteration needs S >= 2")
    if horizon is None:
        require_discount_below_one(model, "the reference policy iteration (infinite horizon)")
    grid = FreudenthalGrid(model.S, n)
    R, T = _backup_operator(model, grid)
    N, A, gamma = grid.size, model.A, model.gamma
    if horizon is not None:
        if horizon < 1:
            raise ValueError(f"horizon: must be >= 1, got {horizon}")
        V = np.zeros(N)
        for _ in range(horizon):
            Q = (R + gamma * (T @ V)).reshape(N, A)
            V_new = Q.max(axis=1)
            residual = float(np.max(np.abs(V_new - V)))
            V = V_new
        return GridSolution(model, grid, V, Q, np.argmax(Q, axis=1), _q_gap(Q), horizon, horizon, residual,
                            "finite-horizon value iteration")
    rows_of = np.arange(N) * A
    pi = np.argmax(R.reshape(N, A), axis=1)
    eye = sp.identity(N, format="csc")
    iterations = 0
    while iterations < max_iter:
        iterations += 1
        Tpi = T[rows_of + pi]
        V = splu((eye - gamma * Tpi).tocsc()).solve(R[rows_of + pi])
        Q = (R + gamma * (T @ V)).reshape(N, A)
        best = np.argmax(Q, axis=1)
        improve = Q[np.arange(N), best] > Q[np.arange(N), pi] + tol * max(1.0, float(np.max(np.abs(V))))
        if not np.any(improve):
            break
        pi = np.where(improve, best, pi)
    else:  # pragma: no cover - policy iteration on a finite MDP terminates long before
        raise RuntimeError(f"policy iteration did not converge in {max_iter} iterations")
    residual = float(np.max(np.abs(Q.max(axis=1) - V)))
    return GridSolution(model, grid, Q.max(axis=1), Q, np.argmax(Q, axis=1), _q_gap(Q), None, iterations, residual,
                        "policy iteration (sparse LU)")


@dataclass(frozen=True, eq=False)
class ReferencePolicy:
    """Optimal actions at the grid beliefs of resolution ``n`` with a measured tie margin.

    Built by :func:`reference_policy` from grid solutions at ``n`` (``coarse``) and ``2n``
    (``fine``). For each coarse grid belief: ``Q`` and ``actions`` are the fine solution's,
    ``gap`` its best-minus-second-best, ``decided = gap > tie_margin``. ``allowed[k, a]`` is
    True for every action whose fine Q is within ``tie_margin`` of the best (the set of
    actions the reference cannot rule out as optimal).
    """

    beliefs: np.ndarray
    Q: np.ndarray
    actions: np.ndarray
    gap: np.ndarray
    tie_margin: float
    discretisation_change: float
    coarse: GridSolution
    fine: GridSolution
    decided: np.ndarray = field(init=False)
    allowed: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "decided", self.gap > self.tie_margin)
        top = self.Q.max(axis=1, keepdims=True)
        object.__setattr__(self, "allowed", self.Q >= top - self.tie_margin)

    def to_dict(self) -> dict:
        """Summary figures (JSON-ready)."""
        return {
            "n": self.coarse.n, "fine_n": self.fine.n, "beliefs": len(self.beliefs),
            "tie_margin": float(self.tie_margin), "discretisation_change": float(self.discretisation_change),
            "decided_fraction": float(np.mean(self.decided)),
        }


def _max_difference_change(Qc: np.ndarray, Qf: np.ndarray) -> float:
    """``max_{b,a,a'} |(Qf(b,a) - Qf(b,a')) - (Qc(b,a) - Qc(b,a'))|``."""
    E = Qf - Qc
    return float(np.max(E.max(axis=1) - E.min(axis=1)))


def reference_policy(model: POMDP, n: int, safety: float = 2.0, horizon: int | None = None,
                     tol: float = 1e-10) -> ReferencePolicy:
    """Reference optimal policy on the resolution-``n`` grid, checked against resolution ``2n``.

    ``tie_margin = safety * max |change of Q(b,a) - Q(b,a') from n to 2n|`` (see the module
    docstring) plus a floor of ``1e-9 * max|Q|`` for rounding.
    """
    coarse = solve_grid(model, n, horizon=horizon, tol=tol)
    fine = solve_grid(model, 2 * n, horizon=horizon, tol=tol)
    idx = fine.grid.index_of(coarse.beliefs)
    if np.any(idx < 0):  # pragma: no cover - the coarse grid is a subset of the fine one
        raise RuntimeError("coarse grid is not contained in the fine grid")
    Qf = fine.Q[idx]
    change = _max_difference_change(coarse.Q, Qf)
    margin = safety * change + 1e-9 * max(1.0, float(np.max(np.abs(Qf))))
    return ReferencePolicy(coarse.beliefs, Qf, np.argmax(Qf, axis=1), _q_gap(Qf), margin, change, coarse, fine)


# ------------------------------------------------------------ exact alpha-vector solver
def _witness_lp(w: np.ndarray, U: np.ndarray) -> tuple[float, np.ndarray | None]:
    """``max_b min_u (w - u) . b`` over the simplex (Lark's LP). Returns (delta, b)."""
    S = w.size
    c = np.zeros(S + 1)
    c[-1] = -1.0  # maximise delta
    A_ub = np.hstack([-(w[None, :] - U), np.ones((len(U), 1))])
    b_ub = np.zeros(len(U))
    A_eq = np.hstack([np.ones((1, S)), np.zeros((1, 1))])
    bounds = [(0.0, 1.0)] * S + [(None, None)]
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=[1.0], bounds=bounds, method="highs")
    if res.status != 0:  # pragma: no cover - the LP is always feasible and bounded
        raise RuntimeError(f"witness LP failed: {res.message}")
    return float(-res.fun), res.x[:S]


def prune_alpha_vectors(V: np.ndarray, labels: np.ndarray | None = None, tol: float = 1e-9,
                        rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Remove alpha vectors that are nowhere strictly best on the simplex (Lark's filter).

    Duplicates and pointwise-dominated vectors go first; vectors that win at sampled
    beliefs are kept without an LP; each remaining vector is kept iff the witness LP finds a
    belief where it beats every kept vector by more than ``tol`` (then the best candidate at
    that witness is added, as in Lark's algorithm). Returns ``(vectors, labels)``.
    """
    V = np.asarray(V, dtype=float)
    labels = np.zeros(len(V), dtype=int) if labels is None else np.asarray(labels)
    if len(V) <= 1:
        return V, labels
    S = V.shape[1]
    _, first = np.unique(np.round(V, 12), axis=0, return_index=True)
    first = np.sort(first)
    V, labels = V[first], labels[first]
    # pointwise dominance (a vector <= another everywhere, by at most tol)
    dom = np.all(V[:, None, :] <= V[None, :, :] + tol, axis=2)  # dom[i, j]: i <= j (+tol) everywhere
    np.fill_diagonal(dom, False)
    mutual = dom & dom.T  # equal within tol: keep the first of the two
    dom &= ~(mutual & (np.arange(len(V))[None, :] > np.arange(len(V))[:, None]))
    keep = ~np.any(dom, axis=1)
    V, labels = V[keep], labels[keep]
    if len(V) <= 1:
        return V, labels
    rng = np.random.default_rng(0) if rng is None else rng
    samples = np.vstack([np.eye(S), np.full((1, S), 1.0 / S), rng.dirichlet(np.ones(S), size=20 * S)])
    winners = np.unique(np.argmax(samples @ V.T, axis=1))
    kept = list(winners)
    candidates = [i for i in range(len(V)) if i not in set(kept)]
    while candidates:
        i = candidates.pop()
        delta, b = _witness_lp(V[i], V[kept])
        if delta > tol:
            pool = [*candidates, i]
            j = pool[int(np.argmax(V[pool] @ b))]
            kept.append(j)
            if j != i:
                candidates.remove(j)
                candidates.append(i)
    kept = np.array(sorted(kept))
    return V[kept], labels[kept]


@dataclass(frozen=True, eq=False)
class AlphaVectorSolution:
    """Exact finite-horizon solution for a belief-linear reward.

    ``alphas`` (K, S) represent ``V_{H-1}`` (``max_k alphas[k] . b``), from which
    :meth:`q_values` gives ``Q_H(b, a)`` exactly; ``V_0`` is the constant ``v0``.
    ``error_bound`` bounds ``|Q_H(b,a) - Q*(b,a)|`` for the infinite-horizon ``Q*``:
    ``gamma^H * (max r - min r) / (2 (1 - gamma))`` (contraction from ``V_0`` at the centre
    of the range of ``V*``).
    """

    model: POMDP
    horizon: int
    alphas: np.ndarray
    sizes: tuple[int, ...]
    error_bound: float

    def q_values(self, B: np.ndarray) -> np.ndarray:
        """``Q_H(b, a) = b . r_a + gamma sum_z max_k (b P_a diag(O_az)) . alpha_k``, shape (M, A)."""
        m = self.model
        B = np.atleast_2d(np.asarray(B, dtype=float))
        ba = np.einsum("mi,aij->maj", B, m.P)  # (M, A, S)
        unnorm = ba[:, :, None, :] * np.swapaxes(m.O, 1, 2)[None]  # (M, A, Z, S)
        best = (unnorm @ self.alphas.T).max(axis=-1)  # (M, A, Z)
        return B @ m.r + m.gamma * best.sum(axis=-1)

    def value(self, B: np.ndarray) -> np.ndarray:
        return self.q_values(B).max(axis=1)


def _linear_reward_check(model: POMDP) -> None:
    if model.uncertainty.name != "none" and np.any(model.w != 0.0):
        raise ValueError(
            f"model: the exact alpha-vector solver needs a belief-linear reward, but uncertainty "
            f"'{model.uncertainty.name}' has nonzero weights; use solve_grid")


def alpha_vector_value_iteration(model: POMDP, horizon: int, tol: float = 1e-9) -> AlphaVectorSolution:
    """Exact ``Q_H`` for a belief-linear reward by incremental pruning (Cassandra et al. 1997).

    ``Gamma_0 = {v0 * 1}`` with ``v0`` the centre of ``[min r, max r] / (1 - gamma)``; then
    ``Gamma_k = prune(U_a [r_a + prune(... prune(G_a1 (+) G_a2) (+) ...)])`` with
    ``G_az = {gamma P_a diag(O_az) alpha : alpha in Gamma_{k-1}}`` and ``(+)`` the cross sum.
    The returned solution holds ``Gamma_{H-1}``.
    """
    _linear_reward_check(model)
    require_discount_below_one(model, "the exact alpha-vector value iteration (its start and error bound are "
                               "infinite-horizon)")
    if horizon < 1:
        raise ValueError(f"horizon: must be >= 1, got {horizon}")
    m, gamma = model, model.gamma
    rmin, rmax = float(m.r.min()), float(m.r.max())
    v0 = 0.5 * (rmin + rmax) / (1.0 - gamma)
    alphas = np.full((1, m.S), v0)
    sizes = [1]
    # M[a, z] = gamma * P_a diag(O[a, :, z]) so that G_az = alphas @ M[a, z].T
    M = gamma * m.P[:, None, :, :] * np.swapaxes(m.O, 1, 2)[:, :, None, :]  # (A, Z, S, S)
    for _ in range(horizon - 1):
        new = []
        for a in range(m.A):
            acc = None
            for z in range(m.Z):
                G, _ = prune_alpha_vectors(alphas @ M[a, z].T, tol=tol)
                acc = G if acc is None else prune_alpha_vectors((acc[:, None, :] + G[None, :, :]).reshape(-1, m.S),
                                                                tol=tol)[0]
            new.append(acc + m.r[:, a][None, :])
        alphas, _ = prune_alpha_vectors(np.vstack(new), tol=tol)
        sizes.append(len(alphas))
    err = gamma ** horizon * (rmax - rmin) / (2.0 * (1.0 - gamma))
    return AlphaVectorSolution(model, horizon, alphas, tuple(sizes), err)


def certified_actions(solution: AlphaVectorSolution, B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Infinite-horizon optimal actions certified by the finite-horizon solution.

    Returns ``(actions, certified, Q)``: the argmax of ``Q_H`` at each belief, whether it is
    provably the infinite-horizon optimal action (best-minus-second gap of ``Q_H`` larger than
    ``2 * error_bound``), and ``Q_H``.
    """
    Q = solution.q_values(B)
    return np.argmax(Q, axis=1), _q_gap(Q) > 2.0 * solution.error_bound, Q
