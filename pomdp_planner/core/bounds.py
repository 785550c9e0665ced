"""Vectors ``g`` and ``h`` of Theorem 2: the LP that makes the transformed rewards MLR monotone.

The transformed rewards (Eq. 8, in our row-stochastic convention, :mod:`.myopic`) are
``rho_lower(b, a) = rho(b, a) + b @ (I - gamma P[a]) @ g`` and the same with ``h``.

Constraints (paper Theorem 2 and Corollary 1, in our convention; docs/THEORY.md):

* Write ``phi_a(b) = grad_b rho(b, a) + (I - gamma P[a]) g`` (the gradient of
  ``rho_lower(., a)``) and ``c_a = (I - gamma P[a]) g``. Corollary 1 needs ``rho_lower(., a)``
  MLR increasing on the domain (``rho_upper`` MLR decreasing). With
  ``grad rho = r_a - w_a grad f`` every constraint is belief-independent and has the form

      g:  Delta_i c_a(g) >= -Delta_i r_a + |w_a| K_f        (A (S-1) constraints)
      h:  Delta_i c_a(h) <= -Delta_i r_a - |w_a| K_f        (A (S-1) constraints)

  (``Delta_i x = x[i+1] - x[i]``), i.e. the steps of ``r_a + c_a`` are at least ``|w_a| K_f``.
* ``K_f`` depends on the monotonicity asked for (:data:`BOUND_CONSTANTS`):

  - ``"mlr"`` (default): exactly what Corollary 1 needs. For Renyi quadratic entropy
    ``b -> phi.b + w log sum b^2`` is MLR increasing on the whole simplex iff every step of
    ``phi`` is ``>= 2 |w|`` (docs/THEORY.md, the proof and its tightness), so ``K_f = 2``:
    the paper's constant 1 (Example 3, whose printed chain has the signs reversed: we use
    the corrected ``Delta_i phi >= 2 |w|``), right for MLR although the paper derives it
    through first-order dominance, where it is not a bound.
  - ``"fosd"``: monotone in first-order stochastic dominance, the stronger property Theorem 2's
    proof establishes (gradient non-decreasing in the index at every belief). Its exact
    constant is ``K_f = 2 C_S``, ``C_S = (1 + sqrt(S-1)) / 2`` (:func:`renyi_constant`); the
    paper's 1 is wrong *for this property* when S >= 3.
  - Shannon entropy (on ``B_eps``): both names use the FOSD value
    ``K_f = log((1 - (S-1) eps) / eps)`` (:func:`shannon_constant`): the exact MLR threshold
    is smaller for S >= 3 but has no known closed form, and the FOSD value is sound for MLR.
    ``f = none``: ``K_f = 0``.

The feasible set is invariant under ``g -> g + t 1`` (``(I - gamma P) 1 = (1 - gamma) 1``;
adding a constant changes every ``rho_lower(b, .)`` by the same amount), so ``g[0] = 0`` is
pinned; it is also a cone-translate (rays ``M g0 >= 0``), so a plain feasibility LP has no
unique answer. Two documented choices (:data:`BOUND_VARIANTS`):

* ``"feasible"``: the L1-minimal feasible vector (``min ||g||_1``, ``g[0] = 0``).
* ``"tight"``: a tightness-seeking choice (Krishnamurthy & Pareek 2015 pick g/h to make the
  bounds coincide on as much of the belief space as possible). Where the model has the
  structure below, the least element (next paragraph) is provably the tightest choice at
  every belief and is returned. Otherwise, on sampled reachable beliefs, hinge-loss LPs push
  the lower-bound policy up and the upper-bound policy down, alternating; every candidate
  (including the L1-minimal one) is scored on the samples (agreement, then mean distance of
  the bounds) and the best is kept.

**Least element (no LP).** In difference coordinates ``d = Delta g`` (``g = cumsum``, ``g[0] = 0``)
the ``g`` constraints read ``d >= beta_a + gamma M_a d`` for every action, with
``M_a[i, k] = sum_{j > k} (P[a, i+1, j] - P[a, i, j])`` (``e = -Delta h`` gives the same form for
``h``). If every ``P[a]`` is stochastically monotone (``M_a >= 0``; TP2 transitions, (A1),
imply it) and ``kappa = gamma max_{a,i} sum_k M_a[i, k] < 1``, the map
``T(d) = max_a (beta_a + gamma M_a d)`` is a monotone sup-norm contraction, and any feasible
``d`` satisfies ``d >= T(d) >= T^2(d) -> d*``: the fixed point ``d*`` (policy iteration, one
dense solve per step) is the componentwise least feasible ``d``, so ``g* = cumsum d*`` is the
least feasible ``g`` (and ``h*`` the greatest ``h``). Consequences: (i) if ``g* >= 0`` it is
L1-minimal (any feasible ``g >= g* >= 0``), so the ``feasible`` variant needs no LP; (ii) if
moreover the actions are ordered in first-order dominance (``P[a+1, i] >=_s P[a, i]`` for
every ``i``), lowering ``d`` raises ``rho_lower(b, a') - rho_lower(b, a)`` for every ``a' > a``
(the action-dependent part is ``-gamma sum_k tail_{k+1}(b P[a]) d_k``), so ``g*`` gives the
highest lower-bound action at *every* belief among all feasible ``g`` (and ``h*`` the lowest
upper bound): the ``tight`` variant returns them.

**Solvers** (:data:`BOUND_SOLVERS`). ``"structured"`` (default): the least element wherever
its conditions hold and it answers the question; otherwise HiGHS dual simplex
(``scipy.optimize.linprog``), with row generation on large systems (start with one row per
state pair, add the most violated action of each pair per round). ``"clarabel"``, for
cross-checks and the LP benchmark (``pomdp_planner.bench.lp``): Clarabel's interior point for
every LP, row generation over whole actions, hinge-LP tightening whatever the structure.

**Sparse models** (``model.sparse``) take the same path with sparse arrays: the constraint
matrices are sparse (``A (S-1) x S``, a few non-zeros per row), the structure test compares the
tails of neighbouring rows where they change, and the least element multiplies by ``M_a``
without forming it (``(M_a d)_i = (P[a] G)_{i+1} - (P[a] G)_i`` with ``G = [0, cumsum(d)]``),
its policy-iteration steps solving a sparse system in ``G``.

Every returned vector is re-checked against the exact constraints of the chosen constant; a
vector is reported feasible only if its worst margin is ``>= -tol``
(:func:`constraint_margins`). Infeasibility is quantified by a phase-1 LP (minimise the
largest violation), whose dual multipliers name the conflicting constraints.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import clarabel
import numpy as np
from scipy import sparse
from scipy.optimize import linprog

from .belief import posterior_floor, update_batch
from .checks import check_choice, check_int
from .model import POMDP, frozen_copy, require_discount_below_one
from .myopic import MyopicBounds
from .sparse import vecmat

#: Choices of ``g``/``h``; the first is the default of :func:`solve_bounds`.
BOUND_VARIANTS = ("tight", "feasible")

#: Monotonicity the constraints guarantee (module docstring); the first is the default.
BOUND_CONSTANTS = ("mlr", "fosd")
DEFAULT_CONSTANT = BOUND_CONSTANTS[0]

#: How the vectors are computed (module docstring); the first is the default.
BOUND_SOLVERS = ("structured", "clarabel")

#: A vector counts as feasible when every constraint margin is >= -FEAS_RTOL * scale.
FEAS_RTOL = 1e-9
#: LPs (and the least element) are solved with constraints tightened by LP_MARGIN_RTOL * scale,
#: so that the solution satisfies the exact constraints (checked afterwards).
LP_MARGIN_RTOL = 1e-7
#: Entries of ``M_a`` and action-order differences above ``-STRUCTURE_TOL`` count as ``>= 0``.
STRUCTURE_TOL = 1e-12


# ---------------------------------------------------------------- constants
def renyi_constant(S: int) -> float:
    """``C_S = sup_{b in simplex} (b_i - b_{i+1}) / ||b||^2 = (1 + sqrt(S - 1)) / 2``.

    The exact constant of the *first-order dominance* route (``constant="fosd"``): the
    gradient of ``w log sum b^2`` changes by at most ``2 C_S |w|`` between neighbouring states.
    Proof sketch (docs/THEORY.md): write ``x = b_i``, ``y = b_{i+1}``, ``u = 1 - x - y``. By
    QM-AM, ``||b||^2 >= x^2 + y^2 + u^2 / (S-2)``. With ``x - y = (x - y)(x + y + u)``,
    ``C ||b||^2 - (x - y) >= (C-1) x^2 - x u + C u^2/(S-2) + [(C+1) y^2 + y u]``, and the
    quadratic form in ``(x, u)`` is PSD iff ``4 C (C-1) >= S-2``, i.e. ``C >= (1 + sqrt(S-1))/2``.
    Equality at ``b_{i+1} = 0``, ``b_i = 1/sqrt(S-1)``, the rest spread evenly. S = 2: ``C = 1``
    (at ``b = e_i``). The paper (Example 3) uses 1 for every S: not a bound on this supremum
    for S >= 3, but the exact constant for the MLR monotonicity Corollary 1 needs
    (``constant="mlr"``). S = 1 has no constraints; returns 0.
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
    # a difference of logarithms: the ratio itself overflows for a subnormal epsilon (1e-320)
    return float(math.log1p(-(S - 1) * epsilon) - math.log(epsilon))


def check_variant(variant: object, field: str = "variant") -> str:
    """``variant`` if it is one of :data:`BOUND_VARIANTS`, else an :class:`~.errors.OptionError`
    naming ``field`` and the choices: the one check of a bound variant, wherever it is given."""
    return check_choice(variant, BOUND_VARIANTS, field)


def check_constant(constant: object, field: str = "constant") -> str:
    """``constant`` if it is one of :data:`BOUND_CONSTANTS`, else an :class:`~.errors.OptionError`
    naming ``field`` and the choices: the one check of a bound constant, wherever it is given."""
    return check_choice(constant, BOUND_CONSTANTS, field)


def gradient_spread(model: POMDP, constant: str = DEFAULT_CONSTANT) -> float:
    """``K_f``: every step of ``r_a + (I - gamma P[a]) g`` must be ``>= |w_a| K_f`` (module docstring).

    Renyi: ``2`` for ``"mlr"`` (exact for MLR monotonicity), ``2 C_S`` for ``"fosd"``;
    Shannon: the FOSD value for both; ``f = none``: 0.
    """
    check_constant(constant)
    name = model.uncertainty.name
    if name == "none":
        return 0.0
    if name == "renyi2":  # grad f = -2 b / ||b||^2
        if model.S < 2:
            return 0.0
        return 2.0 if constant == "mlr" else 2.0 * renyi_constant(model.S)
    if name == "shannon":  # grad f = -(1 + log b)
        return shannon_constant(model.S, model.epsilon)
    raise ValueError(f"uncertainty.function: no belief-independent constant for {name!r}")


def _constant_reason(name: str, constant: str) -> str:
    if name == "renyi2" and constant == "mlr":
        return ("mlr: steps >= 2|w_a| is exact for the MLR monotonicity Corollary 1 needs "
                "(docs/THEORY.md); the paper's constant 1")
    if name == "renyi2":
        return ("fosd: steps >= 2 C_S |w_a|, C_S = (1 + sqrt(S-1))/2, is exact for first-order dominance "
                "monotonicity (Theorem 2's route), stronger than Corollary 1 needs")
    if name == "shannon":
        return (f"{constant}: Shannon uses the FOSD value log((1-(S-1)eps)/eps) for both constants; the exact "
                "MLR threshold on B_eps is smaller but has no closed form, and the FOSD value is sound")
    return f"{constant}: no uncertainty term (f = none), K_f = 0 for both constants"


def bound_constants(model: POMDP, constant: str = DEFAULT_CONSTANT) -> dict[str, Any]:
    """The belief-independent constant used for ``model``: which, its value, and why (JSON-ready)."""
    check_constant(constant)
    name = model.uncertainty.name
    out: dict[str, Any] = {"constant": constant, "uncertainty": name,
                           "K_f": gradient_spread(model, constant), "why": _constant_reason(name, constant)}
    if name == "renyi2":
        out["C_used"] = out["K_f"] / 2.0
        out["C_mlr"] = 1.0
        out["C_fosd"] = renyi_constant(model.S)
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
def _check_which(which: str) -> None:
    if which not in ("g", "h"):
        raise ValueError(f"which must be 'g' or 'h', got {which!r}")


def constraint_rhs(model: POMDP, which: str, *, constant: str = DEFAULT_CONSTANT) -> np.ndarray:
    """Right-hand sides ``(A, S-1)`` of :func:`constraint_system` (row ``(a, i)``)."""
    _check_which(which)
    dr = np.diff(model.r, axis=0).T  # (A, S-1): r[i+1, a] - r[i, a]
    kw = (np.abs(model.w) * gradient_spread(model, constant))[:, None]  # (A, 1)
    return (-dr + kw) if which == "g" else (dr + kw)


def _transition_matvec(model: POMDP, v: np.ndarray) -> np.ndarray:
    """``P[a] @ v`` for every action, shape ``(A, S)`` (sparse products for a sparse model)."""
    if model.sparse:
        return np.stack([model.P_csr[a] @ v for a in range(model.A)])
    return _matvec(model.P, v)


def _mv(G: np.ndarray | sparse.csr_array, x: np.ndarray) -> np.ndarray:
    """``G @ x`` for a dense (``einsum``, :func:`_matvec`) or sparse constraint matrix."""
    return G @ x if sparse.issparse(G) else _matvec(G, x)


def constraint_system(model: POMDP, which: str, *, constant: str = DEFAULT_CONSTANT
                      ) -> tuple[np.ndarray | sparse.csr_array, np.ndarray]:
    """``(G, rhs)`` with the constraints written ``G v >= rhs``, rows ordered ``(a, i)``.

    ``which="g"``: ``Delta_i (I - gamma P[a]) g >= -Delta_i r_a + |w_a| K_f``;
    ``which="h"``: ``-Delta_i (I - gamma P[a]) h >= Delta_i r_a + |w_a| K_f``;
    ``K_f = gradient_spread(model, constant)``.
    Row ``a * (S-1) + i`` belongs to action ``a`` and the state pair ``(i, i+1)``. ``G`` is a sparse
    CSR matrix for a sparse model.
    """
    _check_which(which)
    S, A = model.S, model.A
    rhs = constraint_rhs(model, which, constant=constant)
    if model.sparse:
        step = sparse.diags_array([-np.ones(S - 1), np.ones(S - 1)], offsets=[0, 1], shape=(S - 1, S))
        eye = sparse.eye_array(S, format="csr")
        G = sparse.vstack([step @ (eye - model.gamma * model.P_csr[a]) for a in range(A)], format="csr")
        return (G if which == "g" else -G), rhs.reshape(-1).copy()
    M = np.diff(np.eye(S)[None, :, :] - model.gamma * model.P, axis=1)  # (A, S-1, S)
    G = M if which == "g" else -M
    return G.reshape(A * (S - 1), S), rhs.reshape(-1).copy()


def _margins(model: POMDP, v: np.ndarray, which: str, rhs: np.ndarray) -> np.ndarray:
    """``(A, S-1)`` margins from the definition ``Delta_i (v - gamma P[a] v)``, without forming ``G``."""
    v = np.asarray(v, dtype=float)
    steps = np.diff(v[None, :] - model.gamma * _transition_matvec(model, v), axis=1)  # (A, S-1)
    return (steps if which == "g" else -steps) - rhs


def constraint_margins(model: POMDP, v: np.ndarray, which: str, *, constant: str = DEFAULT_CONSTANT
                       ) -> np.ndarray:
    """``G v - rhs`` reshaped ``(A, S-1)``: all ``>= 0`` iff ``v`` satisfies the constraints."""
    return _margins(model, v, which, constraint_rhs(model, which, constant=constant))


def _scale_of(rhs: np.ndarray) -> float:
    return 1.0 + (float(np.max(np.abs(rhs))) if rhs.size else 0.0)


def _tolerance(scale: float, v: np.ndarray) -> float:
    """Absolute tolerance on the constraint margins of ``v`` (rounding in ``G v``): a vector counts as
    feasible when every margin is ``>= -FEAS_RTOL (scale + ||v||_1)``, ``scale`` from :func:`_scale_of`."""
    return FEAS_RTOL * (scale + float(np.sum(np.abs(v))))


def is_feasible(model: POMDP, v: np.ndarray, which: str, *, constant: str = DEFAULT_CONSTANT) -> bool:
    """Exact post-check: every constraint margin (for ``constant``) is ``>= -tol`` (:func:`_tolerance`)."""
    return _System.build(model, which, constant).feasible(v)


@dataclass
class _System:
    """One vector's constraints, built once per solve (``G`` only when an LP needs it)."""

    model: POMDP
    which: str
    constant: str
    rhs: np.ndarray  # (A * (S-1),)
    scale: float
    _G: np.ndarray | None = None

    @classmethod
    def build(cls, model: POMDP, which: str, constant: str) -> _System:
        rhs = constraint_rhs(model, which, constant=constant).reshape(-1)
        return cls(model, which, constant, rhs, _scale_of(rhs))

    @property
    def G(self) -> np.ndarray:  # noqa: N802 - the constraint matrix of the docs
        if self._G is None:
            self._G = constraint_system(self.model, self.which, constant=self.constant)[0]
        return self._G

    def margins(self, v: np.ndarray) -> np.ndarray:
        return _margins(self.model, v, self.which, self.rhs.reshape(self.model.A, -1))

    def feasible(self, v: np.ndarray) -> bool:
        if self.model.S < 2:
            return True
        return bool(self.margins(v).min() >= -_tolerance(self.scale, v))


# ---------------------------------------------------------------- structure: the least element
class _DenseM:
    """``M_a`` (tail differences, ``(A, S-1, S-1)``) as an array: its products and the dense solves
    of policy iteration."""

    def __init__(self, M: np.ndarray):
        self.M = M
        self.A, self.n = M.shape[:2]

    def mv(self, d: np.ndarray) -> np.ndarray:
        """``M_a d`` for every action, ``(A, S-1)``."""
        return _matvec(self.M, d)

    def solve(self, pol: np.ndarray, rhs: np.ndarray, gamma: float) -> np.ndarray:
        """``d`` with ``d - gamma M_{pol(i)}[i] . d = rhs`` for every ``i``."""
        idx = np.arange(self.n)
        return np.linalg.solve(np.eye(self.n) - gamma * self.M[pol, idx], rhs)


class _SparseM:
    """``M_a`` of a sparse model without forming it (module docstring): ``(M_a d)_i = (P[a] G)_{i+1}
    - (P[a] G)_i`` with ``G = [0, cumsum(d)]``; policy iteration solves the sparse system in ``G``."""

    def __init__(self, model: POMDP):
        self.model = model
        self.A, self.n = model.A, model.S - 1

    def mv(self, d: np.ndarray) -> np.ndarray:
        G = np.concatenate([[0.0], np.cumsum(d)])
        return np.stack([np.diff(self.model.P_csr[a] @ G) for a in range(self.model.A)])

    def solve(self, pol: np.ndarray, rhs: np.ndarray, gamma: float) -> np.ndarray:
        from scipy.sparse.linalg import spsolve

        S, n = self.model.S, self.n
        stacked = self.model.P_csr.stacked()
        i = np.arange(n)
        diff = stacked[pol * S + i + 1] - stacked[pol * S + i]  # (S-1, S): P[pol(i)][i+1] - P[pol(i)][i]
        step = sparse.diags_array([-np.ones(n), np.ones(n)], offsets=[0, 1], shape=(n, S))
        K = sparse.csc_array((step - gamma * diff)[:, 1:])
        G = spsolve(K, rhs)
        return np.diff(np.concatenate([[0.0], np.atleast_1d(G)]))


@dataclass(frozen=True)
class _Structure:
    """``M_a`` (tail differences) and the conditions of the least-element argument."""

    M: _DenseM | _SparseM  # M[a, i, k] = sum_{j>k} (P[a, i+1, j] - P[a, i, j])
    monotone: bool  # every M_a >= 0: each P[a] is stochastically monotone
    kappa: float  # contraction factor of T in a weighted sup norm (inf if none was found)
    ordered: bool  # P[a+1, i] >=_s P[a, i] for every a, i (actions ordered in first-order dominance)
    kappa1: float  # gamma max_{a,i} sum_k M[a, i, k]: the factor in the plain sup norm

    @property
    def contraction(self) -> bool:
        return self.monotone and self.kappa < 1.0

    @property
    def certifies_tightest(self) -> bool:
        return self.contraction and self.ordered


def _tail_gap_min(X: sparse.csr_array, Y: sparse.csr_array) -> float:
    """``min`` over rows ``r`` and ``k = 0..m-2`` of ``T_Y[r](k) - T_X[r](k)``, ``T[r](k) = sum_{j > k}
    row_r[j]`` (each tail summed from the right, as a dense reversed ``cumsum``): the tails change
    only where either row has a non-zero, so those points (and ``k = 0``) decide. ``inf`` when
    ``m < 2``."""
    n, m = X.shape
    if m < 2 or n == 0:
        return math.inf

    def tails(M: sparse.csr_array) -> tuple[np.ndarray, np.ndarray]:
        counts = np.diff(M.indptr)
        rows = np.repeat(np.arange(n), counts)
        keys = rows * m + M.indices.astype(np.int64)
        if M.nnz == 0:
            return keys, np.zeros(0)
        width = int(counts.max())
        back = np.repeat(M.indptr[1:], counts) - 1 - np.arange(M.nnz)  # position from the row's end
        pad = np.zeros((n, width))
        pad[rows, back] = M.data
        return keys, np.cumsum(pad, axis=1)[rows, back]

    def at(keys: np.ndarray, rc: np.ndarray, r: np.ndarray, k: np.ndarray) -> np.ndarray:
        pos = np.searchsorted(keys, r * m + k, side="right")  # first stored entry with column > k
        ok = (pos < keys.size) & ((keys[np.minimum(pos, keys.size - 1)] // m) == r) if keys.size else \
            np.zeros(r.size, bool)
        return np.where(ok, rc[np.minimum(pos, max(rc.size - 1, 0))] if rc.size else 0.0, 0.0)

    kx, rx = tails(X)
    ky, ry = tails(Y)
    cols = np.concatenate([kx % m, ky % m])
    rows = np.concatenate([kx // m, ky // m])
    keep = cols <= m - 2
    r = np.concatenate([rows[keep], np.arange(n)])
    k = np.concatenate([cols[keep], np.zeros(n, dtype=np.int64)])
    return float(np.min(at(ky, ry, r, k) - at(kx, rx, r, k)))


def _structure(model: POMDP) -> _Structure:
    S = model.S
    kappa1 = float(model.gamma * np.diff(_transition_matvec(model, np.arange(S, dtype=float)), axis=1).max()) if S > 1 \
        else 0.0
    if model.sparse:
        P = model.P_csr
        monotone = bool(min((_tail_gap_min(P[a][:-1], P[a][1:]) for a in range(model.A)), default=math.inf)
                        >= -STRUCTURE_TOL) if S > 1 else True
        ordered = bool(min((_tail_gap_min(P[a], P[a + 1]) for a in range(model.A - 1)), default=math.inf)
                       >= -STRUCTURE_TOL)
        op: _DenseM | _SparseM = _SparseM(model)
        empty = S < 2
    else:
        # tails[a, i, k] = sum_{j > k} P[a, i, j], k = 0..S-2
        tails = np.ascontiguousarray(model.P[:, :, :0:-1]).cumsum(axis=2)[:, :, ::-1]
        M = np.diff(tails, axis=1)
        monotone = bool(M.min() >= -STRUCTURE_TOL) if M.size else True
        ordered = bool(np.all(np.diff(tails, axis=0) >= -STRUCTURE_TOL)) if tails.size else True
        op = _DenseM(M)
        empty = not M.size
        kappa1 = kappa1 if M.size else 0.0
    if empty:
        kappa = 0.0
    else:
        kappa = _contraction_factor(op, model.gamma, kappa1) if monotone else math.inf
    return _Structure(op, monotone, kappa, ordered, kappa1)


def _contraction_factor(M: _DenseM | _SparseM, gamma: float, kappa1: float) -> float:
    """``kappa = max_{a,i} gamma (M_a u)_i / u_i`` for weights ``u > 0`` (``M >= 0``): ``T`` is a
    ``kappa``-contraction in the ``u``-weighted sup norm. ``u = 1`` first (``kappa = kappa1``,
    gamma times the largest row sum of ``M_a``); if that is ``>= 1``, ``u`` = the least solution
    of ``u >= 1 + gamma M_a u`` (policy iteration), accepted only if it verifies ``kappa < 1``."""
    if kappa1 < 1.0:
        return kappa1
    out = _least_element(M, np.ones((M.A, M.n)), gamma, kappa1)
    if out is None:
        return math.inf
    u = out[0]
    if not (np.all(np.isfinite(u)) and u.min() > 0.0):
        return math.inf
    return float(np.max(gamma * M.mv(u) / u))


def _matvec(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``M @ x`` over the last axis with numpy's own loops (``einsum``), not a BLAS call: on a
    shared machine multi-threaded BLAS waiting for busy cores made these products, and LAPACK
    solves, 5-200x slower (measured: a 255 x 255 solve 0.7 ms single-threaded, 140 ms with the
    default threads; core/search.py avoids BLAS for the same reason)."""
    return np.einsum("...ij,j->...i", M, x)


#: Value iteration (no dense solve) is used for the least element when ``gamma`` times the
#: largest row sum of ``M_a`` is below this; policy iteration otherwise.
VALUE_ITERATION_KAPPA = 0.5


def _least_element(M: _DenseM | _SparseM, beta: np.ndarray, gamma: float, kappa1: float, max_iter: int = 200
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """Least ``d`` with ``d >= beta_a + gamma M_a d`` for all ``a`` (``beta``: ``(A, S-1)``), the
    fixed point of ``T(d) = max_a (beta_a + gamma M_a d)``; ``(d, policy)`` or None.

    With ``kappa_1 = gamma max_{a,i} sum_k M_a[i, k] < VALUE_ITERATION_KAPPA``, value iteration
    (``T`` is a ``kappa_1``-contraction in the sup norm; stop when the a-posteriori error bound
    ``kappa_1 / (1 - kappa_1) |d_{k+1} - d_k|`` is below ``1e-13 (1 + |d|)``); otherwise policy
    iteration (dense solves, or sparse ones for a sparse model). (The caller certifies the result:
    a contraction factor, or an exact feasibility check.)"""
    n = beta.shape[1]
    idx = np.arange(n)
    d = beta.max(axis=0)  # T(0)
    Q = beta + gamma * M.mv(d)
    if kappa1 < VALUE_ITERATION_KAPPA:
        for _ in range(10 * max_iter):
            d_new = Q.max(axis=0)
            step = float(np.max(np.abs(d_new - d)))
            d = d_new
            Q = beta + gamma * M.mv(d)
            if kappa1 / (1.0 - kappa1) * step <= 1e-13 * (1.0 + float(np.max(np.abs(d)))):
                return Q.max(axis=0), np.argmax(Q, axis=0)
    pol = np.argmax(Q, axis=0)
    for _ in range(max_iter):
        try:
            d = M.solve(pol, beta[pol, idx], gamma)
        except (np.linalg.LinAlgError, RuntimeError):
            return None
        if not np.all(np.isfinite(d)):
            return None
        Q = beta + gamma * M.mv(d)
        best = Q.max(axis=0)
        improve = best > Q[pol, idx] + 1e-12 * (1.0 + np.abs(best))
        if not improve.any():
            return d, pol
        pol = np.where(improve, np.argmax(Q, axis=0), pol)
    return None


def _least_vector(system: _System, st: _Structure) -> tuple[np.ndarray, np.ndarray] | None:
    """The least feasible ``g`` (greatest ``h``) of the tightened system, post-checked; with the
    row of each state pair that is active there (the LP's warm rows)."""
    model = system.model
    A, n = model.A, model.S - 1
    beta = system.rhs.reshape(A, n) + LP_MARGIN_RTOL * system.scale
    out = _least_element(st.M, beta, model.gamma, st.kappa1)
    if out is None:
        return None
    d, pol = out
    steps = np.cumsum(d)
    v = np.concatenate([[0.0], steps if system.which == "g" else -steps])
    if not system.feasible(v):
        return None
    return v, pol * n + np.arange(n)


# ---------------------------------------------------------------- LPs
@dataclass
class _LPResult:
    status: str
    x: np.ndarray | None
    z: np.ndarray | None  # multipliers (>= 0) of the A_ub rows
    obj: float


def _highs_lp(c: np.ndarray, A_ub: np.ndarray, b_ub: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> _LPResult:
    """``min c.x`` s.t. ``A_ub x <= b_ub``, ``lb <= x <= ub`` by HiGHS dual simplex."""
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=np.column_stack([lb, ub]), method="highs-ds")
    if res.status == 0:
        return _LPResult("Solved", np.asarray(res.x), -np.asarray(res.ineqlin.marginals), float(res.fun))
    return _LPResult({2: "PrimalInfeasible", 3: "Unbounded"}.get(res.status, f"HiGHS status {res.status}"),
                     None, None, math.nan)


def _clarabel_lp(c: np.ndarray, A_ub: np.ndarray, b_ub: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> _LPResult:
    """The same LP with Clarabel (interior point); bounds become rows (``lb == ub``: equalities)."""
    n = c.size
    eq = np.flatnonzero(lb == ub)
    lo = np.flatnonzero(np.isfinite(lb) & (lb != ub))
    hi = np.flatnonzero(np.isfinite(ub) & (lb != ub))
    E = sparse.csc_matrix((np.ones(eq.size), (np.arange(eq.size), eq)), shape=(eq.size, n))
    Lo = sparse.csc_matrix((-np.ones(lo.size), (np.arange(lo.size), lo)), shape=(lo.size, n))
    Hi = sparse.csc_matrix((np.ones(hi.size), (np.arange(hi.size), hi)), shape=(hi.size, n))
    Amat = sparse.vstack([E, sparse.csc_matrix(A_ub), Lo, Hi], format="csc")
    bvec = np.concatenate([lb[eq], b_ub, -lb[lo], ub[hi]])
    cones = [clarabel.NonnegativeConeT(A_ub.shape[0] + lo.size + hi.size)]
    if eq.size:
        cones.insert(0, clarabel.ZeroConeT(eq.size))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    sol = clarabel.DefaultSolver(sparse.csc_matrix((n, n)), np.asarray(c, float), Amat, bvec, cones,
                                 settings).solve()
    status = str(sol.status).split(".")[-1]
    if status in ("Solved", "AlmostSolved"):
        z = np.array(sol.z)[eq.size:eq.size + A_ub.shape[0]]
        return _LPResult(status, np.array(sol.x), z, float(sol.obj_val))
    return _LPResult(status, None, None, math.nan)


_BACKENDS = {"structured": _highs_lp, "clarabel": _clarabel_lp}


def _l1_lp(G: np.ndarray, rhs: np.ndarray, margin: float, backend: Callable[..., _LPResult],
           hinge: tuple[np.ndarray, np.ndarray] | None = None, l1_weight: float = 1.0) -> _LPResult:
    """``min l1_weight ||v||_1 + sum(s)`` s.t. ``G v >= rhs + margin``, ``v[0] = 0``, and optional
    hinge rows ``H v + s >= d``, ``s >= 0`` (``hinge = (H, d)``).

    Variables ``(p, n, s)`` with ``v = p - n``, ``p, n >= 0``; the solution's ``x[:S]`` is ``v``.
    """
    m, S = G.shape
    k = 0 if hinge is None else hinge[0].shape[0]
    c = np.concatenate([np.full(2 * S, l1_weight), np.ones(k)])
    b = [-(rhs + margin)]
    if sparse.issparse(G):
        rows = [sparse.hstack([-G, G, sparse.csr_array((m, k))], format="csr")]
        if k:
            H, d = hinge
            rows.append(sparse.hstack([sparse.csr_array(-H), sparse.csr_array(H), -sparse.eye_array(k)], format="csr"))
            b.append(-d)
        A_ub = sparse.vstack(rows, format="csr")
    else:
        rows = [np.hstack([-G, G, np.zeros((m, k))])]
        if k:
            H, d = hinge
            rows.append(np.hstack([-H, H, -np.eye(k)]))
            b.append(-d)
        A_ub = np.vstack(rows)
    lb = np.zeros(2 * S + k)
    ub = np.full(2 * S + k, np.inf)
    ub[[0, S]] = 0.0  # v[0] = 0
    res = backend(c, A_ub, np.concatenate(b), lb, ub)
    if res.x is not None:
        res.x = np.concatenate([res.x[:S] - res.x[S:2 * S], res.x[2 * S:]])
    return res


def _phase1(G: np.ndarray, rhs: np.ndarray, box: float, backend: Callable[..., _LPResult]) -> _LPResult:
    """``min t`` s.t. ``G v + t >= rhs``, ``v[0] = 0``, ``|v| <= box``, ``t >= -1``: the smallest
    achievable largest violation ``t*`` (``> 0`` means infeasible). Variables ``(v, t)``."""
    m, S = G.shape
    c = np.zeros(S + 1)
    c[-1] = 1.0
    lb = np.concatenate([[0.0], np.full(S - 1, -box), [-1.0]])
    ub = np.concatenate([[0.0], np.full(S - 1, box), [np.inf]])
    if sparse.issparse(G):
        return backend(c, sparse.hstack([-G, -sparse.csr_array(np.ones((m, 1)))], format="csr"), -rhs, lb, ub)
    return backend(c, np.hstack([-G, -np.ones((m, 1))]), -rhs, lb, ub)


#: Constraint systems with more rows than this are solved by row generation: the LP is
#: solved with a subset of the rows and violated rows are added until none is (the dense
#: S = 256, A = 64 system in one piece takes Clarabel minutes and HiGHS seconds).
DIRECT_ROWS = 1500


def _cutting_planes(G: np.ndarray, rhs: np.ndarray, solve: Callable[[np.ndarray], _LPResult],
                    violation: Callable[[np.ndarray], np.ndarray], by_pairs: bool,
                    start: np.ndarray | None = None, per_round: int = 2) -> tuple[_LPResult, np.ndarray]:
    """Solve an LP whose rows ``G v >= rhs`` (ordered by action, ``S - 1`` rows each) may be
    many, by row generation.

    ``solve(rows)`` solves the LP restricted to ``rows``; ``violation(x)`` gives each row's
    violation at the solution ``x`` (``> 0``: violated beyond the accepted tolerance). The
    restricted LP is a relaxation, so a restricted optimum feasible for all rows is optimal
    and an infeasible restriction proves the full LP infeasible. ``by_pairs`` (HiGHS path):
    start from one row per state pair (``start``, else the largest right-hand side) and add,
    per round, the most violated row of every violated pair. Otherwise (Clarabel path): start
    from the rows of the first, middle and last action and add the ``per_round`` actions with
    the worst violations. Every round adds a row, so both terminate.
    """
    m, S = G.shape
    if m <= DIRECT_ROWS:
        rows = np.arange(m)
        return solve(rows), rows
    n = S - 1
    A = m // n
    if by_pairs:
        rows = np.unique(start if start is not None else np.argmax(rhs.reshape(A, n), axis=0) * n + np.arange(n))
    else:
        acts = np.unique(np.linspace(0, A - 1, min(A, 3)).round().astype(int))
        rows = (acts[:, None] * n + np.arange(n)[None, :]).reshape(-1)
    while True:
        res = solve(rows)
        if res.x is None:
            return res, rows
        viol = violation(res.x)
        viol[rows] = -np.inf
        V = viol.reshape(A, n)
        if by_pairs:
            worst = np.argmax(V, axis=0)
            pairs = np.flatnonzero(V[worst, np.arange(n)] > 0)
            new = worst[pairs] * n + pairs
        else:
            wa = V.max(axis=1)
            bad = np.flatnonzero(wa > 0)
            top = bad[np.argsort(-wa[bad], kind="stable")[:per_round]]
            new = (top[:, None] * n + np.arange(n)[None, :]).reshape(-1)
        if new.size == 0:
            return res, rows
        rows = np.union1d(rows, new)


def _solve_l1(system: _System, margin: float, accept: float, solver: str,
              hinge: tuple[np.ndarray, np.ndarray] | None = None, l1_weight: float = 1.0,
              start: np.ndarray | None = None) -> _LPResult:
    """:func:`_l1_lp` with row generation; the result satisfies ``G v >= rhs + margin - accept``."""
    G, rhs, S = system.G, system.rhs, system.model.S
    backend = _BACKENDS[solver]
    return _cutting_planes(
        G, rhs, lambda rows: _l1_lp(G[rows], rhs[rows], margin, backend, hinge=hinge, l1_weight=l1_weight),
        lambda x: rhs + margin - accept - _mv(G, x[:S]), by_pairs=solver != "clarabel", start=start)[0]


@dataclass
class _VectorResult:
    feasible: bool
    v: np.ndarray | None
    message: str
    most_violated: dict[str, Any] | None = None
    min_margin: float | None = None
    least: bool = False  # the least feasible g (greatest h)


def _pair(model: POMDP, row: int) -> tuple[int, int]:
    return divmod(int(row), model.S - 1)


def _solve_vector(system: _System, solver: str, st: _Structure | None, goal: str = "l1") -> _VectorResult:
    """``goal="l1"``: the L1-minimal feasible vector; ``goal="least"``: the least feasible ``g``
    (greatest ``h``) when ``st`` proves it exists. Else a phase-1 infeasibility report."""
    model, which = system.model, system.which
    S = model.S
    if S < 2:
        return _VectorResult(True, np.zeros(S), "S = 1: no constraints", None, None)
    start = None
    if st is not None and st.contraction:
        least = _least_vector(system, st)
        if least is not None:
            v, start = least
            mm = float(system.margins(v).min())
            norm = f"||{which}||_1 = {np.abs(v).sum():.6g}"
            extreme = "least feasible g" if which == "g" else "greatest feasible h"
            if goal == "least":
                bound = "higher lower" if which == "g" else "lower upper"
                return _VectorResult(True, v, f"{which}: the {extreme} (no feasible {which} gives a {bound} bound "
                                     f"at any belief; {norm})", None, mm, least=True)
            delta = 1e-9 * (1.0 + float(np.abs(v).max()))
            if np.all((v if which == "g" else -v) >= -delta):  # extreme and of one sign: L1-minimal
                return _VectorResult(True, v, f"{which}: L1-minimal feasible vector (the {extreme}; {norm})",
                                     None, mm, least=True)
    for margin in (LP_MARGIN_RTOL * system.scale, 0.0):
        accept = 0.5 * margin if margin > 0 else 0.5 * FEAS_RTOL * system.scale
        res = _solve_l1(system, margin, accept, solver, start=start)
        if res.x is not None:
            v = res.x[:S].copy()
            v[0] = 0.0
            if system.feasible(v):
                mm = float(system.margins(v).min())
                return _VectorResult(True, v, f"{which}: L1-minimal feasible vector (||{which}||_1 = "
                                     f"{np.abs(v).sum():.6g})", None, mm)
    return _infeasible_report(system, solver)


def _infeasible_report(system: _System, solver: str) -> _VectorResult:
    model, which, G, rhs = system.model, system.which, system.G, system.rhs
    S = model.S
    box = 1e6 * system.scale
    tol = FEAS_RTOL * system.scale
    backend = _BACKENDS[solver]
    p1, rows = _cutting_planes(G, rhs, lambda rows: _phase1(G[rows], rhs[rows], box, backend),
                               lambda x: rhs - _mv(G, x[:S]) - x[S] - tol, by_pairs=solver != "clarabel")
    if p1.x is None:
        return _VectorResult(False, None, f"{which}: LP solver failed ({p1.status}); treated as infeasible",
                             {"vector": which, "solver_status": p1.status}, None)
    v = p1.x[:S].copy()
    v[0] = 0.0
    viol = rhs - _mv(G, v)  # > 0 where violated
    t_star = float(viol.max())
    if t_star <= _tolerance(system.scale, v):
        return _VectorResult(True, v, f"{which}: feasible only at the boundary (phase-1 vector)", None, -t_star)
    m = G.shape[0]
    duals = np.zeros(m)
    if p1.z is not None:
        duals[rows] = np.maximum(p1.z, 0.0)
    worst = int(np.argmax(viol))
    a, i = _pair(model, worst)
    order = np.argsort(-duals, kind="stable")
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
def _draw(rng: np.random.Generator, probs: np.ndarray) -> np.ndarray:
    """One index per row of ``probs`` (rows are distributions), by inverse CDF."""
    cdf = np.cumsum(probs, axis=-1)
    u = rng.random(probs.shape[0]) * cdf[:, -1]
    return np.minimum(np.sum(cdf <= u[:, None], axis=-1), probs.shape[-1] - 1)


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
    s = _draw(rng, B)
    out = [B]
    for _ in range(horizon):
        a = rng.integers(0, A, size=n_traj)
        s = _draw(rng, model.P_csr.dense_rows(a, s) if model.sparse else model.P[a, s])
        z = _draw(rng, model.O_csr.dense_rows(a, s) if model.sparse else model.O[a, s])
        B, _ = update_batch(model, B, a, z)
        out.append(B)
    allB = np.concatenate(out, axis=0)
    idx = rng.permutation(allB.shape[0])[:n]
    return allB[np.sort(idx)]


#: At most this many hinge rows in the tightness LP.
MAX_HINGE_ROWS = 1500


def _predicted_rows(model: POMDP, B: np.ndarray, k: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``B[k[j]] @ P[a[j]]`` for every ``j`` (one matrix product per action)."""
    out = np.empty((k.size, model.S))
    for act in np.unique(a):
        sel = a == act
        out[sel] = vecmat(model.P_csr, int(act), B[k[sel]]) if model.sparse else B[k[sel]] @ model.P[act]
    return out


def _hinge_rows(model: POMDP, B: np.ndarray, rho: np.ndarray, target: np.ndarray, which: str,
                margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``H v >= d`` asking the transformed reward of ``target[k]`` to beat every action
    below it (``which="g"``: lower bound pushed up) or above it (``"h"``: upper pushed down)
    at belief ``B[k]`` by ``margin``. Linear in ``v`` because only ``-gamma b P[a] v`` depends on a.
    """
    acts = np.arange(model.A)[None, :]
    mask = acts < target[:, None] if which == "g" else acts > target[:, None]
    k_idx, a_idx = np.nonzero(mask)  # belief-major, actions increasing
    if k_idx.size == 0:
        return np.zeros((0, model.S)), np.zeros(0)
    if k_idx.size > MAX_HINGE_ROWS:  # keep the LP small: an evenly spaced, deterministic subset
        keep = np.linspace(0, k_idx.size - 1, MAX_HINGE_ROWS).round().astype(int)
        k_idx, a_idx = k_idx[keep], a_idx[keep]
    t_idx = target[k_idx]
    # rho_v(b, t) - rho_v(b, a) = rho(b,t) - rho(b,a) - gamma (bP[t] - bP[a]) v >= margin
    H = -model.gamma * (_predicted_rows(model, B, k_idx, t_idx) - _predicted_rows(model, B, k_idx, a_idx))
    d = margin - (rho[k_idx, t_idx] - rho[k_idx, a_idx])
    return H, d


def _tight_vector(system: _System, solver: str, B: np.ndarray, rho: np.ndarray, target: np.ndarray,
                  base: np.ndarray) -> np.ndarray | None:
    """Hinge-loss LP: feasible ``v`` making ``target`` the bound action on as many samples as it can."""
    model = system.model
    spread = float(np.ptp(rho)) if rho.size else 1.0
    H, d = _hinge_rows(model, B, rho, target, system.which, 1e-6 * (1.0 + spread))
    if H.shape[0] == 0:
        return None
    # a small L1 weight keeps the LP bounded along the rays of the feasible set
    margin = LP_MARGIN_RTOL * system.scale
    res = _solve_l1(system, margin, 0.5 * margin, solver, hinge=(H, d),
                    l1_weight=1e-4 * H.shape[0] / (np.abs(base).sum() + 1.0))
    if res.x is None:
        return None
    v = res.x[:model.S].copy()
    v[0] = 0.0
    return v if system.feasible(v) else None


def _score(lo: np.ndarray, up: np.ndarray) -> tuple[float, float]:
    """Agreement rate, then minus the mean distance ``|upper - lower|`` (larger is better).

    Under Assumption 1 ``lower <= upper`` and the distance is ``E[upper] - E[lower]``; the
    absolute value also penalises crossed bounds (``lower > upper``), which can only occur when
    Assumption 1 fails (then pushing the bounds towards each other would cross them further).
    """
    return float(np.mean(lo == up)), -float(np.mean(np.abs(up - lo)))


def _better(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] > b[0] + 1e-12 or (abs(a[0] - b[0]) <= 1e-12 and a[1] > b[1] + 1e-12)


def _tighten(sg: _System, sh: _System, solver: str, g: np.ndarray, h: np.ndarray, B: np.ndarray,
             rounds: int = 3) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Alternate hinge LPs for ``g`` (target: one action above the current lower action where
    the bounds disagree) and ``h`` (one below the current upper action); a candidate replaces
    the current vector only if it improves :func:`_score` on the samples, so the result is
    never worse there than the L1-minimal start."""
    model = sg.model
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
        cand_g = _tight_vector(sg, solver, B, rho, np.where(lo < up, lo + 1, lo), best_g)
        if cand_g is not None:
            lo_c = MyopicBounds(model, cand_g, best_h).lower(B, rho)
            score = _score(lo_c, up)
            if _better(score, best):
                best_g, lo, best, changed = cand_g, lo_c, score, True
        cand_h = _tight_vector(sh, solver, B, rho, np.where(up > lo, up - 1, up), best_h)
        if cand_h is not None:
            up_c = MyopicBounds(model, best_g, cand_h).upper(B, rho)
            score = _score(lo, up_c)
            if _better(score, best):
                best_h, up, best, changed = cand_h, up_c, score, True
        history.append({"round": r, "agreement": best[0], "mean_distance": -best[1]})
        if not changed:
            break
    return best_g, best_h, {"method": "hinge LPs on the samples", "rounds": history}


#: Unit costs (seconds) of :func:`estimate_solve_bounds`, CPU time measured on the development
#: machine (``python -m pomdp_planner.bench.scale --suite setup`` compares estimate and set-up): the
#: fixed part; per ``A S^2`` entry of the structure test; per ``S^2`` of the sampled beliefs (45
#: trajectories of 8 steps); per ``A S^2`` entry and value-iteration step; per ``S^3`` of a
#: policy-iteration solve; the HiGHS path per ``S^3`` and ``A S^2``; a sparse model's HiGHS path per
#: ``S^1.7``, and its least element per stored non-zero and step.
COST_LP_FIXED = 3e-3
COST_STRUCTURE = 2e-8
COST_SAMPLES = 8e-7
COST_ITERATION = 5e-9
COST_SOLVE = 1e-9
COST_HIGHS = (3e-6, 3e-6)
COST_SPARSE_HIGHS = 6e-6
COST_SPARSE_ITERATION = 3e-8
#: Policy-iteration steps counted for the least element.
POLICY_STEPS = 5
#: The tight variant without the least element adds hinge-LP rounds: about this many times the LP.
TIGHTEN_FACTOR = 5.0


def _iterations(kappa1: float) -> int:
    """Value-iteration steps to the least element's stopping rule (error ``1e-13``) at factor ``kappa1``."""
    return min(2000, math.ceil(math.log(1e-13) / math.log(min(max(kappa1, 1e-6), 0.999))) + 1)


def estimate_solve_bounds(model: POMDP, variant: str = "tight") -> tuple[float, int]:
    """Rough ``(seconds, peak bytes)`` of :func:`solve_bounds` with the default solver, before it runs.

    Runs the structure test the solver starts with (``O(A S^2)``, ``O(non-zeros)`` sparse): where
    the least element applies (monotone transitions, a contraction) the cost is the structure test,
    the sampled beliefs and the value-iteration steps (``kappa_1`` sets their number) or a few
    policy-iteration solves; otherwise the HiGHS path (the constraint matrices of ``g`` and ``h``,
    ``A (S-1) x S`` each, and the solver's copies), and for ``tight`` the hinge-LP rounds. Good to a
    factor of a few (the unit costs :data:`COST_LP_FIXED` ...)."""
    S, A = model.S, model.A
    if S < 2:
        return 0.0, 0
    st = _structure(model)
    certified = variant == "tight" and st.certifies_tightest
    if model.sparse:
        nnz = model.P_csr.nnz
        memory = 8 * 8 * (nnz + A * S) + 8 * 400 * S * 2
        if st.contraction:
            steps = _iterations(st.kappa1) if st.kappa1 < VALUE_ITERATION_KAPPA else POLICY_STEPS * 10
            seconds = COST_LP_FIXED + COST_SPARSE_ITERATION * (nnz + A * S) * steps
            if variant == "tight" and not certified:
                seconds += COST_SPARSE_HIGHS * S**1.7 * A / 3 * TIGHTEN_FACTOR
            return seconds, memory
        return COST_LP_FIXED + COST_SPARSE_HIGHS * S**1.7 * A / 3 * (1.5 if variant == "tight" else 1.0), memory
    rows = A * S * S
    memory = 8 * 5 * rows + 8 * 400 * S * (A + 2)  # constraint matrices and copies; the sampled beliefs
    base = COST_LP_FIXED + COST_STRUCTURE * rows + COST_SAMPLES * S * S
    highs = COST_HIGHS[0] * S**3 + COST_HIGHS[1] * rows
    if st.contraction:
        if st.kappa1 < VALUE_ITERATION_KAPPA:
            seconds = base + _iterations(st.kappa1) * COST_ITERATION * rows
        else:
            seconds = base + POLICY_STEPS * (COST_SOLVE * S**3 + COST_ITERATION * rows)
        if variant == "tight" and not certified:
            seconds += highs * TIGHTEN_FACTOR
        return seconds, memory
    return base + highs * (TIGHTEN_FACTOR if variant == "tight" else 1.0), memory


# ---------------------------------------------------------------- public API
@dataclass(frozen=True, eq=False)
class BoundsSolution:
    """Result of :func:`solve_bounds` (Theorem 2 LP for ``g`` and ``h``)."""

    model: POMDP = field(repr=False)
    variant: str
    constant: str
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
    solver: str = BOUND_SOLVERS[0]

    @property
    def myopic(self) -> MyopicBounds | None:
        """The myopic bound policies (Eq. 8) when both ``g`` and ``h`` are feasible, else None."""
        if not self.feasible or self.g is None or self.h is None:
            return None
        return MyopicBounds(self.model, self.g, self.h)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (vectors as lists)."""
        return {
            "model": self.model.name, "variant": self.variant, "constant": self.constant,
            "feasible": self.feasible, "g_feasible": self.g_feasible, "h_feasible": self.h_feasible,
            "g": None if self.g is None else self.g.tolist(),
            "h": None if self.h is None else self.h.tolist(),
            "solve_time": self.solve_time, "message": self.message, "constants": dict(self.constants),
            "covers": self.covers, "most_violated": self.most_violated, "min_margin": dict(self.min_margin),
            "samples": self.samples, "sample_agreement": self.sample_agreement,
            "sample_mean_gap": self.sample_mean_gap, "sample_crossed": self.sample_crossed,
            "solver": self.solver,
        }


def solve_bounds(model: POMDP, variant: str = "tight", *, constant: str = DEFAULT_CONSTANT, samples: int = 400,
                 seed: int = 0, solver: str = BOUND_SOLVERS[0]) -> BoundsSolution:
    """Solve the Theorem 2 LPs for ``g`` (lower bound) and ``h`` (upper bound).

    ``variant``: ``"feasible"`` (L1-minimal vectors) or ``"tight"`` (the least elements where
    they are provably tightest, else the L1-minimal vectors improved for agreement of the
    bounds on ``samples`` reachable beliefs drawn with ``seed``; see the module docstring).
    ``constant``: ``"mlr"`` (exact for what Corollary 1 needs) or ``"fosd"`` (the stronger
    first-order dominance constant). ``solver``: ``"structured"`` or ``"clarabel"`` (the
    previous path, for cross-checks). The solution is feasible only if both vectors are; each
    returned vector satisfies every constraint of ``constant`` (post-checked).
    """
    check_variant(variant)
    check_constant(constant)
    check_choice(solver, BOUND_SOLVERS, "solver")
    check_int(samples, "samples", 1)
    require_discount_below_one(model, "the bound LP (Theorem 2)")
    t0 = time.perf_counter()
    constants = bound_constants(model, constant)
    sg, sh = _System.build(model, "g", constant), _System.build(model, "h", constant)
    st = _structure(model) if solver == "structured" and model.S > 1 else None
    certified = (variant == "tight" and st is not None and st.certifies_tightest and model.A > 1)
    goal = "least" if certified else "l1"
    rg = _solve_vector(sg, solver, st, goal)
    rh = _solve_vector(sh, solver, st, goal)
    feasible = rg.feasible and rh.feasible
    g, h = rg.v, rh.v
    tightening = None
    agreement = gap = crossed = None
    n_samples = 0
    if feasible:
        B = sample_beliefs(model, samples, seed)
        n_samples = B.shape[0]
        if variant == "tight" and model.A > 1 and model.S > 1:
            if certified and rg.least and rh.least:
                lo, up = MyopicBounds(model, g, h).actions(B)
                tightening = {"method": "least elements (tightest at every belief: monotone transitions, "
                                        f"kappa = {st.kappa:.3g} < 1, actions ordered)",
                              "rounds": [{"round": 0, "agreement": float(np.mean(lo == up)),
                                          "mean_distance": float(np.mean(np.abs(up - lo)))}]}
            else:
                g, h, tightening = _tighten(sg, sh, solver, g, h, B)
        lo, up = MyopicBounds(model, g, h).actions(B)
        agreement = float(np.mean(lo == up))
        gap = float(np.mean(up - lo))
        crossed = float(np.mean(lo > up))
    # final guarantee: never report an infeasible vector as feasible
    g_ok = g is not None and sg.feasible(g)
    h_ok = h is not None and sh.feasible(h)
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
    margins = {"g": None if g is None or model.S < 2 else float(sg.margins(g).min()),
               "h": None if h is None or model.S < 2 else float(sh.margins(h).min())}
    return BoundsSolution(
        model=model, variant=variant, constant=constant, feasible=feasible, g_feasible=rg.feasible,
        h_feasible=rh.feasible, g=None if g is None else frozen_copy(g), h=None if h is None else frozen_copy(h),
        solve_time=time.perf_counter() - t0, message="; ".join(parts), constants=constants,
        covers=covers, most_violated=most, min_margin=margins, samples=n_samples,
        sample_agreement=agreement, sample_mean_gap=gap, sample_crossed=crossed, tightening=tightening,
        solver=solver,
    )

