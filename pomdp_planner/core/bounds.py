"""Vectors ``g`` and ``h`` of Theorem 2: the LP that makes the transformed rewards MLR monotone.

The transformed rewards (Eq. 8, in our row-stochastic convention, :mod:`.myopic`) are
``rho_lower(b, a) = rho(b, a) + b @ (I - gamma P[a]) @ g`` and the same with ``h``.

Constraint derivation (paper Theorem 2 and its proof, in our convention; docs/THEORY.md):

* Write ``phi_a(b) = grad_b rho(b, a) + (I - gamma P[a]) g`` (the gradient of
  ``rho_lower(., a)``). With ``delta = K^{-1} b`` (tail sums, ``delta_1 = 1`` fixed) the
  derivative is ``phi_a(b)^T K``, whose component ``j >= 2`` is ``phi_a[j] - phi_a[j-1]``; the
  first component multiplies the fixed ``delta_1`` and plays no role. So Theorem 2's
  ``[.]^T K >= 0`` is: ``phi_a(b)[i+1] - phi_a(b)[i] >= 0`` for ``i = 0..S-2``.
* Sufficiency: for ``b1 <=_s b2`` in a convex domain, along ``b(t) = b1 + t (b2 - b1)``,
  ``d/dt rho_lower = sum_i (phi[i+1] - phi[i]) (tail_{i+1}(b2) - tail_{i+1}(b1)) >= 0``
  (Abel summation, ``sum(b2 - b1) = 0``). So ``rho_lower`` is first-order increasing, hence MLR
  increasing. For ``h`` the differences must be ``<= 0`` (MLR decreasing).
* The constraint must hold for ALL beliefs of the domain. With ``grad rho = r_a - w_a grad f``:
  ``Delta_i phi_a(b) = Delta_i r_a + Delta_i c_a - w_a Delta_i grad f(b)``, ``c_a = (I - gamma P[a]) g``.
  For every uncertainty function here, ``{Delta_i grad f(b)}`` over the domain is a symmetric
  interval ``[-K_f, K_f]`` (the same for every ``i``), so the exact belief-independent form is

      g:  Delta_i c_a(g) >= -Delta_i r_a + |w_a| K_f        (A (S-1) constraints)
      h:  Delta_i c_a(h) <= -Delta_i r_a - |w_a| K_f        (A (S-1) constraints)

  ``K_f = 0`` (f = none), ``K_f = 2 C_S`` (Renyi, :func:`renyi_constant`; the paper's value
  ``C_S = 1`` is wrong for S >= 3) and ``K_f = log((1 - (S-1) eps) / eps)`` (Shannon, on
  ``B_eps`` only, :func:`shannon_constant`).

The feasible set is invariant under ``g -> g + t 1`` (``(I - gamma P) 1 = (1 - gamma) 1``;
adding a constant changes every ``rho_lower(b, .)`` by the same amount), so ``g[0] = 0`` is
pinned; it is also a cone-translate (rays ``M g0 >= 0``), so a plain feasibility LP has no
unique answer. Two documented choices (:data:`BOUND_VARIANTS`):

* ``"feasible"``: the L1-minimal feasible vector (``min ||g||_1``, ``g[0] = 0``).
* ``"tight"``: a tightness-seeking choice (Krishnamurthy & Pareek 2015 pick g/h to make the
  bounds coincide on as much of the belief space as possible). On sampled reachable beliefs,
  hinge-loss LPs push the lower-bound policy up (towards the current upper action) and the
  upper-bound policy down (towards the current lower action), alternating; every candidate
  (including the L1-minimal one) is scored by the mean lower action (for ``g``, larger is
  better) and the mean upper action (for ``h``, smaller is better) on the samples -- these are
  separable because ``E[upper - lower] = E[upper] - E[lower]`` -- and the best is kept.

Every returned vector is re-checked against the exact constraints; a vector is reported
feasible only if its worst margin is ``>= -tol`` (:func:`constraint_margins`). Infeasibility
is quantified by a phase-1 LP (minimise the largest violation), whose dual multipliers name
the conflicting constraints.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import clarabel
import numpy as np
from scipy import sparse

from .belief import posterior_floor, update_batch
from .model import POMDP
from .myopic import MyopicBounds

#: Choices of ``g``/``h``; the first is the default of :func:`solve_bounds`.
BOUND_VARIANTS = ("tight", "feasible")

#: A vector counts as feasible when every constraint margin is >= -FEAS_RTOL * scale.
FEAS_RTOL = 1e-9
#: LPs are solved with constraints tightened by LP_MARGIN_RTOL * scale, so that the
#: interior-point solution satisfies the exact constraints (checked afterwards).
LP_MARGIN_RTOL = 1e-7


# ---------------------------------------------------------------- constants
def renyi_constant(S: int) -> float:
    """``C_S = sup_{b in simplex} (b_i - b_{i+1}) / ||b||^2 = (1 + sqrt(S - 1)) / 2``.

    Proof sketch (docs/THEORY.md): write ``x = b_i``, ``y = b_{i+1}``, ``u = 1 - x - y``. By
    QM-AM, ``||b||^2 >= x^2 + y^2 + u^2 / (S-2)``. With ``x - y = (x - y)(x + y + u)``,
    ``C ||b||^2 - (x - y) >= (C-1) x^2 - x u + C u^2/(S-2) + [(C+1) y^2 + y u]``, and the
    quadratic form in ``(x, u)`` is PSD iff ``4 C (C-1) >= S-2``, i.e. ``C >= (1 + sqrt(S-1))/2``.
    Equality at ``b_{i+1} = 0``, ``b_i = 1/sqrt(S-1)``, the rest spread evenly. S = 2: ``C = 1``
    (at ``b = e_i``). The paper (Example 3) uses 1 for every S, which is false for S >= 3.
    S = 1 has no constraints; returns 0.
    """
    if S < 1:
        raise ValueError(f"S must be >= 1, got {S}")
    if S == 1:
        return 0.0
    return 0.5 * (1.0 + math.sqrt(S - 1.0))


def renyi_maximiser(S: int, i: int = 0) -> np.ndarray:
    """A belief attaining :func:`renyi_constant` for the pair ``(i, i+1)`` (S >= 2)."""
    if not 0 <= i < S - 1:
        raise ValueError(f"i must be in 0..{S - 2}, got {i}")
    b = np.zeros(S)
    if S == 2:
        b[i] = 1.0
        return b
    x = 1.0 / math.sqrt(S - 1.0)
    b[:] = (1.0 - x) / (S - 2)
    b[i], b[i + 1] = x, 0.0
    return b


def shannon_constant(S: int, epsilon: float) -> float:
    """``sup_{b in B_eps} |log b_{i+1} - log b_i| = log((1 - (S-1) eps) / eps)`` (Example 2).

    On ``B_eps = {b : b_j >= eps}`` the ratio ``b_{i+1} / b_i`` is largest with ``b_i = eps``
    and all remaining mass ``1 - (S-1) eps`` on ``b_{i+1}``. The paper's ``-log eps`` is a
    valid but looser bound. Requires ``0 < eps < 1/S`` (checked by the model).
    """
    if S <= 1:
        return 0.0
    if not 0.0 < epsilon < 1.0 / S:
        raise ValueError(f"epsilon must satisfy 0 < epsilon < 1/S = {1.0 / S:.6g}, got {epsilon}")
    return float(math.log((1.0 - (S - 1) * epsilon) / epsilon))


def gradient_spread(model: POMDP) -> float:
    """``K_f = sup_b |d f / d b_{i+1} - d f / d b_i|`` over the domain of the guarantee."""
    name = model.uncertainty.name
    if name == "none":
        return 0.0
    if name == "renyi2":  # grad f = -2 b / ||b||^2
        return 2.0 * renyi_constant(model.S)
    if name == "shannon":  # grad f = -(1 + log b)
        return shannon_constant(model.S, model.epsilon)
    raise ValueError(f"uncertainty.function: no belief-independent constant for {name!r}")


def bound_constants(model: POMDP) -> dict[str, Any]:
    """The belief-independent constants used for ``model`` (JSON-ready)."""
    name = model.uncertainty.name
    out: dict[str, Any] = {"uncertainty": name, "K_f": gradient_spread(model)}
    if name == "renyi2":
        out["C_S"] = renyi_constant(model.S)
        out["C_S_paper"] = 1.0
    if name == "shannon":
        out["epsilon"] = model.epsilon
        out["log_ratio_bound"] = out["K_f"]
        out["log_ratio_bound_paper"] = -math.log(model.epsilon)
    return out


def covered_domain(model: POMDP) -> str:
    """Where the guarantee holds: the whole simplex, or ``B_epsilon`` for Shannon entropy.

    For Shannon entropy the LP makes the transformed rewards monotone on ``B_epsilon`` only,
    and Corollary 1's induction evaluates ``V`` at posteriors ``tau(b, a, z)``: the guarantee
    holds on ``B_epsilon`` only when every posterior stays in it, i.e. when ``epsilon`` is at
    most :func:`~.belief.posterior_floor`. The paper claims ``B_epsilon`` without this
    condition; a counterexample is in ``test/test_bounds_validation.py`` (docs/THEORY.md).
    """
    if model.uncertainty.name == "shannon":
        floor = posterior_floor(model)
        if model.epsilon <= floor:
            return f"B_epsilon({model.epsilon:g})"
        return (f"none: epsilon = {model.epsilon:g} exceeds the posterior floor {floor:.3g}, so posteriors "
                f"can leave B_epsilon({model.epsilon:g}) and the Shannon bounds are not guaranteed")
    return "simplex"


# ---------------------------------------------------------------- constraints
def constraint_system(model: POMDP, which: str) -> tuple[np.ndarray, np.ndarray]:
    """``(G, rhs)`` with the constraints written ``G v >= rhs``, rows ordered ``(a, i)``.

    ``which="g"``: ``Delta_i (I - gamma P[a]) g >= -Delta_i r_a + |w_a| K_f``;
    ``which="h"``: ``-Delta_i (I - gamma P[a]) h >= Delta_i r_a + |w_a| K_f``.
    Row ``a * (S-1) + i`` belongs to action ``a`` and the state pair ``(i, i+1)``.
    """
    if which not in ("g", "h"):
        raise ValueError(f"which must be 'g' or 'h', got {which!r}")
    S, A = model.S, model.A
    M = np.diff(np.eye(S)[None, :, :] - model.gamma * model.P, axis=1)  # (A, S-1, S)
    dr = np.diff(model.r, axis=0).T  # (A, S-1): r[i+1, a] - r[i, a]
    kw = (np.abs(model.w) * gradient_spread(model))[:, None]  # (A, 1)
    if which == "g":
        G, rhs = M, -dr + kw
    else:
        G, rhs = -M, dr + kw
    return G.reshape(A * (S - 1), S), np.broadcast_to(rhs, (A, S - 1)).reshape(-1).copy()


def constraint_margins(model: POMDP, v: np.ndarray, which: str) -> np.ndarray:
    """``G v - rhs`` reshaped ``(A, S-1)``: all ``>= 0`` iff ``v`` satisfies the constraints."""
    G, rhs = constraint_system(model, which)
    return (G @ np.asarray(v, dtype=float) - rhs).reshape(model.A, model.S - 1)


def _scale(model: POMDP, which: str) -> float:
    _, rhs = constraint_system(model, which)
    return 1.0 + (float(np.max(np.abs(rhs))) if rhs.size else 0.0)


def feasibility_tolerance(model: POMDP, v: np.ndarray, which: str) -> float:
    """Absolute tolerance on constraint margins for ``v`` (rounding in ``G v``)."""
    return FEAS_RTOL * (_scale(model, which) + float(np.sum(np.abs(v))))


def is_feasible(model: POMDP, v: np.ndarray, which: str) -> bool:
    """Exact post-check: every constraint margin ``>= -tol``."""
    if model.S < 2:
        return True
    return bool(constraint_margins(model, v, which).min() >= -feasibility_tolerance(model, v, which))


# ---------------------------------------------------------------- LPs (Clarabel)
@dataclass
class _LPResult:
    status: str
    x: np.ndarray | None
    z: np.ndarray | None
    obj: float


def _clarabel_lp(c: np.ndarray, A_eq: sparse.spmatrix | None, b_eq: np.ndarray | None,
                 A_ub: sparse.spmatrix, b_ub: np.ndarray) -> _LPResult:
    """``min c.x`` s.t. ``A_eq x = b_eq``, ``A_ub x <= b_ub`` with Clarabel."""
    n = c.size
    blocks, rhs, cones = [], [], []
    if A_eq is not None and A_eq.shape[0]:
        blocks.append(sparse.csc_matrix(A_eq))
        rhs.append(b_eq)
        cones.append(clarabel.ZeroConeT(A_eq.shape[0]))
    blocks.append(sparse.csc_matrix(A_ub))
    rhs.append(b_ub)
    cones.append(clarabel.NonnegativeConeT(A_ub.shape[0]))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(sparse.csc_matrix((n, n)), np.asarray(c, float),
                                    sparse.vstack(blocks, format="csc"), np.concatenate(rhs), cones, settings)
    sol = solver.solve()
    status = str(sol.status).split(".")[-1]
    if status in ("Solved", "AlmostSolved"):
        return _LPResult(status, np.array(sol.x), np.array(sol.z), float(sol.obj_val))
    return _LPResult(status, None, None, math.nan)


def _l1_lp(G: np.ndarray, rhs: np.ndarray, margin: float, extra_obj: np.ndarray | None = None,
           hinge: tuple[np.ndarray, np.ndarray] | None = None, l1_weight: float = 1.0) -> _LPResult:
    """``min l1_weight ||v||_1 + extra_obj.v + sum(s)`` s.t. ``G v >= rhs + margin``, ``v[0] = 0``,
    and optional hinge rows ``H v + s >= d``, ``s >= 0`` (``hinge = (H, d)``).

    Variables ``(v, t, s)``; ``|v| <= t``.
    """
    m, S = G.shape
    k = 0 if hinge is None else hinge[0].shape[0]
    n = 2 * S + k
    c = np.concatenate([np.zeros(S) if extra_obj is None else extra_obj, np.full(S, l1_weight), np.ones(k)])
    I = sparse.identity(S, format="csc")
    Zsk = sparse.csc_matrix((S, k))
    rows = [sparse.hstack([-sparse.csc_matrix(G), sparse.csc_matrix((m, S + k))]),
            sparse.hstack([I, -I, Zsk]), sparse.hstack([-I, -I, Zsk])]
    b = [-(rhs + margin), np.zeros(S), np.zeros(S)]
    if k:
        H, d = hinge
        Ik = sparse.identity(k, format="csc")
        rows += [sparse.hstack([-sparse.csc_matrix(H), sparse.csc_matrix((k, S)), -Ik]),
                 sparse.hstack([sparse.csc_matrix((k, 2 * S)), -Ik])]
        b += [-d, np.zeros(k)]
    A_eq = sparse.csc_matrix(([1.0], ([0], [0])), shape=(1, n))
    return _clarabel_lp(c, A_eq, np.zeros(1), sparse.vstack(rows, format="csc"), np.concatenate(b))


def _phase1(G: np.ndarray, rhs: np.ndarray, box: float) -> _LPResult:
    """``min t`` s.t. ``G v + t >= rhs``, ``v[0] = 0``, ``|v| <= box``, ``t >= -1``: the smallest
    achievable largest violation ``t*`` (``> 0`` means infeasible). Variables ``(v, t)``."""
    m, S = G.shape
    c = np.zeros(S + 1)
    c[-1] = 1.0
    Gs = sparse.csc_matrix(G)
    I = sparse.identity(S, format="csc")
    rows = [sparse.hstack([-Gs, -sparse.csc_matrix(np.ones((m, 1)))]),
            sparse.hstack([I, sparse.csc_matrix((S, 1))]), sparse.hstack([-I, sparse.csc_matrix((S, 1))]),
            sparse.csc_matrix(([-1.0], ([0], [S])), shape=(1, S + 1))]
    b = np.concatenate([-rhs, np.full(2 * S, box), [1.0]])
    A_eq = sparse.csc_matrix(([1.0], ([0], [0])), shape=(1, S + 1))
    return _clarabel_lp(c, A_eq, np.zeros(1), sparse.vstack(rows, format="csc"), b)


#: Constraint systems with more rows than this are solved by row generation over actions:
#: the LP is solved with the rows of a few actions (first, middle, last) and the actions
#: with the most violated rows are added until none is violated. (Clarabel on the full dense
#: S = 256, A = 64 system takes minutes; for the tracking models three actions suffice.)
DIRECT_ROWS = 1500


def _cutting_planes(G: np.ndarray, rhs: np.ndarray, solve: Any, violation: Any,
                    per_round: int = 2) -> tuple[_LPResult, np.ndarray]:
    """Solve an LP whose rows ``G v >= rhs`` (ordered by action, ``S - 1`` rows each) may be
    many, by generating the rows of whole actions.

    ``solve(rows)`` solves the LP restricted to ``rows``; ``violation(x)`` gives each row's
    violation at the solution ``x`` (``> 0``: violated beyond the accepted tolerance). The
    restricted LP is a relaxation, so a restricted optimum feasible for all rows is optimal
    and an infeasible restriction proves the full LP infeasible. Terminates after at most
    ``A`` rounds (then all rows are in).
    """
    m, S = G.shape
    if m <= DIRECT_ROWS:
        rows = np.arange(m)
        return solve(rows), rows
    n = S - 1
    A = m // n

    def action_rows(acts: np.ndarray) -> np.ndarray:
        return (acts[:, None] * n + np.arange(n)[None, :]).reshape(-1)

    acts = np.unique(np.linspace(0, A - 1, min(A, 3)).round().astype(int))
    while True:
        rows = action_rows(acts)
        res = solve(rows)
        if res.x is None:
            return res, rows
        worst = violation(res.x).reshape(A, n).max(axis=1)
        worst[acts] = -np.inf
        bad = np.flatnonzero(worst > 0)
        if bad.size == 0:
            return res, rows
        acts = np.union1d(acts, bad[np.argsort(-worst[bad], kind="stable")[:per_round]])


def _solve_l1(G: np.ndarray, rhs: np.ndarray, margin: float, accept: float,
              hinge: tuple[np.ndarray, np.ndarray] | None = None, l1_weight: float = 1.0) -> _LPResult:
    """:func:`_l1_lp` with row generation; the result satisfies ``G v >= rhs + margin - accept``."""
    S = G.shape[1]
    return _cutting_planes(
        G, rhs, lambda rows: _l1_lp(G[rows], rhs[rows], margin, hinge=hinge, l1_weight=l1_weight),
        lambda x: rhs + margin - accept - G @ x[:S])[0]


@dataclass
class _VectorResult:
    feasible: bool
    v: np.ndarray | None
    message: str
    most_violated: dict[str, Any] | None = None
    min_margin: float | None = None


def _pair(model: POMDP, row: int) -> tuple[int, int]:
    return divmod(int(row), model.S - 1)


def _solve_vector(model: POMDP, which: str) -> _VectorResult:
    """L1-minimal feasible ``g`` (``which="g"``) or ``h``, or a phase-1 infeasibility report."""
    S = model.S
    if S < 2:
        return _VectorResult(True, np.zeros(S), "S = 1: no constraints", None, None)
    G, rhs = constraint_system(model, which)
    scale = _scale(model, which)
    for margin in (LP_MARGIN_RTOL * scale, 0.0):
        accept = 0.5 * margin if margin > 0 else 0.5 * FEAS_RTOL * scale
        res = _solve_l1(G, rhs, margin, accept)
        if res.x is not None:
            v = res.x[:S].copy()
            v[0] = 0.0
            if is_feasible(model, v, which):
                mm = float(constraint_margins(model, v, which).min())
                return _VectorResult(True, v, f"{which}: L1-minimal feasible vector (||{which}||_1 = "
                                     f"{np.abs(v).sum():.6g})", None, mm)
    return _infeasible_report(model, which, G, rhs, scale)


def _infeasible_report(model: POMDP, which: str, G: np.ndarray, rhs: np.ndarray, scale: float) -> _VectorResult:
    S = model.S
    box = 1e6 * scale
    tol = FEAS_RTOL * scale
    p1, rows = _cutting_planes(G, rhs, lambda rows: _phase1(G[rows], rhs[rows], box),
                               lambda x: rhs - G @ x[:S] - x[S] - tol)
    if p1.x is None:
        return _VectorResult(False, None, f"{which}: LP solver failed ({p1.status}); treated as infeasible",
                             {"vector": which, "solver_status": p1.status}, None)
    v = p1.x[:S].copy()
    v[0] = 0.0
    viol = rhs - G @ v  # > 0 where violated
    t_star = float(viol.max())
    if t_star <= feasibility_tolerance(model, v, which):
        mm = float(-t_star)
        return _VectorResult(True, v, f"{which}: feasible only at the boundary (phase-1 vector)", None, mm)
    m = G.shape[0]
    duals = np.zeros(m)
    if p1.z is not None:  # zero cone first, then the active G rows
        duals[rows] = p1.z[1:1 + rows.size]
    worst = int(np.argmax(viol))
    a, i = _pair(model, worst)
    order = np.argsort(-duals)
    conflicting = [{"action": _pair(model, r)[0], "priority": _pair(model, r)[0] + 1,
                    "state_pair": [_pair(model, r)[1], _pair(model, r)[1] + 1], "weight": float(duals[r])}
                   for r in order[:8] if duals[r] > 1e-6 * max(duals.max(), 1e-300)]
    kind = "increasing" if which == "g" else "decreasing"
    box_active = bool(np.max(np.abs(v)) >= 0.999 * box)
    report = {
        "vector": which, "action": a, "priority": a + 1, "state_pair": [i, i + 1],
        "violation": t_star, "box_active": box_active, "conflicting": conflicting,
    }
    msg = (f"{which}: infeasible -- no {which} makes rho_{'lower' if which == 'g' else 'upper'} MLR {kind}; "
           f"best achievable largest violation {t_star:.6g} (action priority {a + 1}, states {i}-{i + 1}"
           f"{'; |' + which + '| hit the box ' + format(box, '.3g') if box_active else ''})")
    return _VectorResult(False, None, msg, report, -t_star)


# ---------------------------------------------------------------- tightness
def sample_beliefs(model: POMDP, n: int, seed: int = 0, horizon: int = 8) -> np.ndarray:
    """``n`` beliefs reachable by simulating the model (seeded).

    Trajectories start from random beliefs (flat Dirichlet), pick uniformly random actions,
    draw states and observations from the model, and apply the Bayes filter (Eqs. 1, 2). The
    starting beliefs are included. Returns an ``(n, S)`` array.
    """
    if n < 1:
        raise ValueError(f"samples must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    S, A = model.S, model.A
    n_traj = max(1, math.ceil(n / (horizon + 1)))
    B = rng.dirichlet(np.ones(S), size=n_traj)
    s = np.array([rng.choice(S, p=b) for b in B])
    out = [B]
    for _ in range(horizon):
        a = rng.integers(0, A, size=n_traj)
        s = np.array([rng.choice(S, p=model.P[ai, si]) for ai, si in zip(a, s, strict=True)])
        z = np.array([rng.choice(model.Z, p=model.O[ai, si]) for ai, si in zip(a, s, strict=True)])
        B, _ = update_batch(model, B, a, z)
        out.append(B)
    allB = np.concatenate(out, axis=0)
    idx = rng.permutation(allB.shape[0])[:n]
    return allB[np.sort(idx)]


#: At most this many hinge rows in the tightness LP.
MAX_HINGE_ROWS = 1500


def _hinge_rows(model: POMDP, B: np.ndarray, target: np.ndarray, which: str,
                margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``H v >= d`` asking the transformed reward of ``target[k]`` to beat every action
    below it (``which="g"``: lower bound pushed up) or above it (``"h"``: upper pushed down)
    at belief ``B[k]`` by ``margin``. Linear in ``v`` because only ``-gamma b P[a] v`` depends on a.
    """
    rho = model.rho(B)  # (N, A)
    BP = np.einsum("ks,ast->kat", B, model.P)  # (N, A, S): b P[a]
    A = model.A
    ks, others = [], []
    for k, t in enumerate(target):
        rng_a = range(0, t) if which == "g" else range(t + 1, A)
        for a in rng_a:
            ks.append((k, t))
            others.append(a)
    if not ks:
        return np.zeros((0, model.S)), np.zeros(0)
    if len(ks) > MAX_HINGE_ROWS:  # keep the LP small: an evenly spaced, deterministic subset
        keep = np.linspace(0, len(ks) - 1, MAX_HINGE_ROWS).round().astype(int)
        ks = [ks[i] for i in keep]
        others = [others[i] for i in keep]
    k_idx = np.array([k for k, _ in ks])
    t_idx = np.array([t for _, t in ks])
    a_idx = np.array(others)
    # rho_v(b, t) - rho_v(b, a) = rho(b,t) - rho(b,a) - gamma (bP[t] - bP[a]) v >= margin
    H = -model.gamma * (BP[k_idx, t_idx] - BP[k_idx, a_idx])
    d = margin - (rho[k_idx, t_idx] - rho[k_idx, a_idx])
    return H, d


def _tight_vector(model: POMDP, which: str, B: np.ndarray, target: np.ndarray,
                  base: np.ndarray) -> np.ndarray | None:
    """Hinge-loss LP: feasible ``v`` making ``target`` the bound action on as many samples as it can."""
    S = model.S
    G, rhs = constraint_system(model, which)
    scale = _scale(model, which)
    rho = model.rho(B)
    spread = float(np.ptp(rho)) if rho.size else 1.0
    H, d = _hinge_rows(model, B, target, which, 1e-6 * (1.0 + spread))
    if H.shape[0] == 0:
        return None
    # a small L1 weight keeps the LP bounded along the rays of the feasible set
    margin = LP_MARGIN_RTOL * scale
    res = _solve_l1(G, rhs, margin, 0.5 * margin, hinge=(H, d),
                    l1_weight=1e-4 * H.shape[0] / (np.abs(base).sum() + 1.0))
    if res.x is None:
        return None
    v = res.x[:S].copy()
    v[0] = 0.0
    return v if is_feasible(model, v, which) else None


def _score(lo: np.ndarray, up: np.ndarray) -> tuple[float, float]:
    """Agreement rate, then minus the mean distance ``|upper - lower|`` (larger is better).

    Under Assumption 1 ``lower <= upper`` and the distance is ``E[upper] - E[lower]``; the
    absolute value also penalises crossed bounds (``lower > upper``), which can only occur when
    Assumption 1 fails (then pushing the bounds towards each other would cross them further).
    """
    return float(np.mean(lo == up)), -float(np.mean(np.abs(up - lo)))


def _better(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] > b[0] + 1e-12 or (abs(a[0] - b[0]) <= 1e-12 and a[1] > b[1] + 1e-12)


def _tighten(model: POMDP, g: np.ndarray, h: np.ndarray, B: np.ndarray, rounds: int = 3
             ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Alternate hinge LPs for ``g`` (target: one action above the current lower action where
    the bounds disagree) and ``h`` (one below the current upper action); a candidate replaces
    the current vector only if it improves :func:`_score` on the samples, so the result is
    never worse there than the L1-minimal start."""
    rho = model.rho(B)
    best_g, best_h = g, h
    lo, up = MyopicBounds(model, g, h).actions(B, rho)
    best = _score(lo, up)
    history = [{"round": 0, "agreement": best[0], "mean_distance": -best[1]}]
    for r in range(1, rounds + 1):
        if np.all(lo == up):
            break
        changed = False
        # targets one action beyond the current bound where the bounds disagree: a target the
        # optimal policy cannot reach (lower can never exceed it) would only waste hinge loss
        cand_g = _tight_vector(model, "g", B, np.where(lo < up, lo + 1, lo), best_g)
        if cand_g is not None:
            lo_c = MyopicBounds(model, cand_g, best_h).lower(B, rho)
            score = _score(lo_c, up)
            if _better(score, best):
                best_g, lo, best, changed = cand_g, lo_c, score, True
        cand_h = _tight_vector(model, "h", B, np.where(up > lo, up - 1, up), best_h)
        if cand_h is not None:
            up_c = MyopicBounds(model, best_g, cand_h).upper(B, rho)
            score = _score(lo, up_c)
            if _better(score, best):
                best_h, up, best, changed = cand_h, up_c, score, True
        history.append({"round": r, "agreement": best[0], "mean_distance": -best[1]})
        if not changed:
            break
    return best_g, best_h, {"rounds": history}


# ---------------------------------------------------------------- public API
@dataclass(frozen=True, eq=False)
class BoundsSolution:
    """Result of :func:`solve_bounds` (Theorem 2 LP for ``g`` and ``h``)."""

    model: POMDP = field(repr=False)
    variant: str
    feasible: bool
    g_feasible: bool
    h_feasible: bool
    g: np.ndarray | None
    h: np.ndarray | None
    solve_time: float
    message: str
    constants: dict[str, Any]
    covers: str
    most_violated: dict[str, Any] | None = None
    min_margin: dict[str, float | None] = field(default_factory=dict)
    samples: int = 0
    sample_agreement: float | None = None
    sample_mean_gap: float | None = None
    sample_crossed: float | None = None
    tightening: dict[str, Any] | None = None

    @property
    def myopic(self) -> MyopicBounds | None:
        """The myopic bound policies (Eq. 8) when both ``g`` and ``h`` are feasible, else None."""
        if not self.feasible or self.g is None or self.h is None:
            return None
        return MyopicBounds(self.model, self.g, self.h)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (vectors as lists)."""
        return {
            "model": self.model.name, "variant": self.variant, "feasible": self.feasible,
            "g_feasible": self.g_feasible, "h_feasible": self.h_feasible,
            "g": None if self.g is None else self.g.tolist(),
            "h": None if self.h is None else self.h.tolist(),
            "solve_time": self.solve_time, "message": self.message, "constants": dict(self.constants),
            "covers": self.covers, "most_violated": self.most_violated, "min_margin": dict(self.min_margin),
            "samples": self.samples, "sample_agreement": self.sample_agreement,
            "sample_mean_gap": self.sample_mean_gap, "sample_crossed": self.sample_crossed,
        }


def solve_bounds(model: POMDP, variant: str = "tight", *, samples: int = 400, seed: int = 0) -> BoundsSolution:
    """Solve the Theorem 2 LPs for ``g`` (lower bound) and ``h`` (upper bound).

    ``variant``: ``"feasible"`` (L1-minimal vectors) or ``"tight"`` (starts from those and
    improves the agreement of the bounds on ``samples`` reachable beliefs drawn with
    ``seed``; see the module docstring). The solution is feasible only if both vectors are;
    each returned vector satisfies every constraint (post-checked).
    """
    if variant not in BOUND_VARIANTS:
        raise ValueError(f"variant: expected one of {', '.join(BOUND_VARIANTS)}, got {variant!r}")
    if not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples: expected a positive integer, got {samples!r}")
    t0 = time.perf_counter()
    constants = bound_constants(model)
    rg = _solve_vector(model, "g")
    rh = _solve_vector(model, "h")
    feasible = rg.feasible and rh.feasible
    g, h = rg.v, rh.v
    tightening = None
    agreement = gap = crossed = None
    n_samples = 0
    if feasible:
        B = sample_beliefs(model, samples, seed)
        n_samples = B.shape[0]
        if variant == "tight" and model.A > 1 and model.S > 1:
            g, h, tightening = _tighten(model, g, h, B)
        lo, up = MyopicBounds(model, g, h).actions(B)
        agreement = float(np.mean(lo == up))
        gap = float(np.mean(up - lo))
        crossed = float(np.mean(lo > up))
    # final guarantee: never report an infeasible vector as feasible
    g_ok = g is not None and is_feasible(model, g, "g")
    h_ok = h is not None and is_feasible(model, h, "h")
    if (rg.feasible and not g_ok) or (rh.feasible and not h_ok):  # pragma: no cover - defensive
        raise RuntimeError("internal error: a vector reported feasible fails the exact post-check")
    parts = [rg.message, rh.message]
    covers = covered_domain(model)
    if covers.startswith("none"):
        parts.append(f"WARNING: guarantee covers {covers}")
    if feasible:
        parts.append(f"agreement of lower and upper bound on {n_samples} sampled beliefs: {agreement:.3f}")
        if crossed:
            parts.append(f"WARNING: lower > upper on {crossed:.1%} of them, impossible under Assumption 1 "
                         "(check the model with 'pomdp-planner check')")
    most = None
    if not feasible:
        most = {k: r.most_violated for k, r in (("g", rg), ("h", rh)) if r.most_violated is not None}
    margins = {"g": None if g is None or model.S < 2 else float(constraint_margins(model, g, "g").min()),
               "h": None if h is None or model.S < 2 else float(constraint_margins(model, h, "h").min())}
    return BoundsSolution(
        model=model, variant=variant, feasible=feasible, g_feasible=rg.feasible, h_feasible=rh.feasible,
        g=None if g is None else _ro(g), h=None if h is None else _ro(h),
        solve_time=time.perf_counter() - t0, message="; ".join(parts), constants=constants,
        covers=covers, most_violated=most, min_margin=margins, samples=n_samples,
        sample_agreement=agreement, sample_mean_gap=gap, sample_crossed=crossed, tightening=tightening,
    )


def _ro(v: np.ndarray) -> np.ndarray:
    v = np.array(v, dtype=float, copy=True)
    v.setflags(write=False)
    return v
