"""Random POMDPs satisfying Assumption 1, for validating the myopic bounds against optimal policies.

Models are tracking-style (paper Sec. VI): transitions ``exp(x_i y_j)`` with random increasing
``x`` (S values) and ``y`` (S*A values, so action ``a+1`` uses larger ``y`` and moves the state
up: (A3)), and one TP2 observation kernel ``O[j, z] ~ exp(u_j v_z)`` with random increasing
``u``, ``v`` shared by all actions (A1), or one such kernel per action
(``per_action_observations``; most of those fail (A2)/(A3) and are filtered out). Rewards and
weights are random. A candidate is kept
only if the structural checks pass and the bound LP is feasible.

Assumption 1 is checked by ``core/structure.py`` and the bounds come from ``core/bounds.py``;
:func:`minimal_bounds` is an independent plain feasibility LP for ``g``/``h`` (Theorem 2 with
belief-independent constants, MLR or first-order dominance; scipy's HiGHS) that the validation
tests use where the LP alone, not its tightening, is the subject. The transition kernel is
written here (:func:`tracking_kernel`), not taken from the package's generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog, minimize_scalar

from pomdp_planner.core.bounds import solve_bounds
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.myopic import MyopicBounds
from pomdp_planner.core.structure import check_assumptions


def assumptions_hold(model: POMDP) -> bool:
    """Assumption 1 (``core/structure.py``)."""
    return bool(check_assumptions(model).holds)


# ------------------------------------------------------------------ minimal bound LP
def renyi_constant(S: int) -> float:
    """``sup_b (b_i - b_{i+1}) / ||b||^2`` over the simplex, by 1-D maximisation.

    For S = 2 the belief is ``(x, 1-x)``; for S >= 3 the sup puts ``b_{i+1} = 0`` and spreads
    ``1 - x`` evenly on the other ``S - 2`` states.
    """
    if S == 2:
        f = lambda x: -(2 * x - 1) / (x * x + (1 - x) ** 2)  # noqa: E731
    else:
        f = lambda x: -x / (x * x + (1 - x) ** 2 / (S - 2))  # noqa: E731
    res = minimize_scalar(f, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-12})
    return float(max(-res.fun, -f(1.0)))


def gradient_spread(model: POMDP, constant: str = "mlr") -> float:
    """The step every ``r_a + (I - gamma P_a) g`` needs, per unit ``|w_a|``: Renyi ``2`` for MLR
    monotonicity (``constant="mlr"``, the package default) or ``sup_b (df/db_{i+1} - df/db_i)``
    (first-order dominance, ``"fosd"``); Shannon (on B_eps) the latter for both."""
    name, S = model.uncertainty.name, model.S
    if name == "none":
        return 0.0
    if name == "renyi2":  # df/db = -2 b / ||b||^2
        return 2.0 if constant == "mlr" else 2.0 * renyi_constant(S)
    if name == "shannon":  # df/db = -(1 + log b): spread log(b_i / b_{i+1}) <= log((1-(S-1)eps)/eps)
        eps = model.epsilon
        return float(np.log((1.0 - (S - 1) * eps) / eps))
    raise ValueError(name)


def minimal_bounds(model: POMDP, constant: str = "mlr") -> MyopicBounds | None:
    """Feasible ``g`` (lower) and ``h`` (upper) of Theorem 2, or None if either LP is infeasible.

    Lower: ``phi_a = r_a + (I - gamma P_a) g`` with ``phi_a[i+1] - phi_a[i] >= w_a * c`` and
    upper: ``psi_a[i+1] - psi_a[i] <= -w_a * c``, ``c = gradient_spread`` (``w_a >= 0``).
    ``g[0] = 0`` pins the free constant; among feasible vectors the L1-minimal one is taken.
    """
    S, A, gamma = model.S, model.A, model.gamma
    c = gradient_spread(model, constant)
    if np.any(model.w < 0):
        raise ValueError("minimal_bounds assumes non-negative weights")
    D = np.diff(np.eye(S), axis=0)  # (S-1, S): row i = e_{i+1} - e_i
    vecs = []
    for sign in (+1.0, -1.0):  # +1: increasing (g), -1: decreasing (h)
        rows, rhs = [], []
        for a in range(A):
            C = np.eye(S) - gamma * model.P[a]
            # sign * D (r_a + C v) >= w_a c  ->  -sign * D C v <= sign * D r_a - w_a c
            rows.append(-sign * D @ C)
            rhs.append(sign * D @ model.r[:, a] - model.w[a] * c)
        # variables (v, t): minimise sum t with -t <= v <= t (L1-minimal v), v[0] = 0
        G = np.vstack(rows)
        A_ub = np.vstack([np.hstack([G, np.zeros_like(G)]),
                          np.hstack([np.eye(S), -np.eye(S)]), np.hstack([-np.eye(S), -np.eye(S)])])
        b_ub = np.concatenate([np.concatenate(rhs), np.zeros(2 * S)])
        res = linprog(np.concatenate([np.zeros(S), np.ones(S)]), A_ub=A_ub, b_ub=b_ub,
                      bounds=[(0.0, 0.0)] + [(None, None)] * (S - 1) + [(0.0, None)] * S, method="highs")
        if res.status != 0:
            return None
        vecs.append(res.x[:S])
    return MyopicBounds(model, vecs[0], vecs[1])


def bounds_for(model: POMDP, variant: str = "tight", constant: str = "mlr") -> MyopicBounds | None:
    """The bounds of ``core/bounds.py`` (``variant``, ``constant``), or None if the LP is infeasible."""
    sol = solve_bounds(model, variant, constant=constant)
    return sol.myopic if sol.feasible else None


# ------------------------------------------------------------------ the generator
@dataclass(frozen=True)
class ModelSpec:
    S: int
    A: int
    Z: int
    uncertainty: str
    gamma: float
    per_action_observations: bool = False  # one TP2 kernel per action (then (A2) is not trivial)


def tracking_kernel(S: int, A: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``P[a, j, i] = exp(x_i y_{aS+j}) / sum_k exp(x_k y_{aS+j})`` (paper Sec. VI, written here so
    the validation models do not come from the package's generator)."""
    E = np.outer(y, x)  # (S*A, S): row aS+j, column i
    E = np.exp(E - E.max(axis=1, keepdims=True))
    return (E / E.sum(axis=1, keepdims=True)).reshape(A, S, S)


def posterior_floor(model: POMDP) -> float:
    """Smallest coordinate of any posterior ``tau(b, a, z)`` with ``eta > 0``, over the whole simplex.

    Each coordinate of ``tau(b, a, z)`` is a linear-fractional function of ``b`` with a
    positive denominator, so its minimum over the simplex is attained at a vertex ``e_i``.
    If ``epsilon <= posterior_floor``, every posterior lies in ``B_epsilon``.
    """
    floor = np.inf
    for i in range(model.S):
        for a in range(model.A):
            ba = model.P[a, i]
            for z in range(model.Z):
                u = ba * model.O[a, :, z]
                if u.sum() > 0:
                    floor = min(floor, float((u / u.sum()).min()))
    return floor


def random_candidate(rng: np.random.Generator, spec: ModelSpec, epsilon: float | None = None,
                     sharpness: float | None = None) -> POMDP:
    """One random tracking-style model (may or may not pass the filters).

    For Shannon entropy, ``epsilon`` is set to :func:`posterior_floor` (capped below ``1/S``)
    so that ``B_epsilon`` contains every posterior: only then does the paper's induction
    (Corollary 1) run inside ``B_epsilon`` (see ``test_bounds_validation.py``). Passing
    ``epsilon`` overrides that choice (to build counterexamples), ``sharpness`` the scale of
    the kernels' exponents (default 1, and 0.3 for Shannon).
    """
    S, A, Z = spec.S, spec.A, spec.Z
    # Shannon: flatter kernels, so that posteriors stay away from the boundary and a useful
    # epsilon = posterior_floor exists (the gradient constant grows like log(1/epsilon)).
    sharp = sharpness if sharpness is not None else (0.3 if spec.uncertainty == "shannon" else 1.0)
    x = np.cumsum(rng.uniform(0.3, 1.5, S)) * sharp
    y = (np.cumsum(rng.uniform(0.2, 1.5, S * A)) - rng.uniform(5.0, 12.0)) * sharp
    P = tracking_kernel(S, A, x, y)
    kernels = []
    for _ in range(A if spec.per_action_observations else 1):
        u = np.cumsum(rng.uniform(0.5, 2.0, S)) * sharp
        v = np.cumsum(rng.uniform(0.5, 2.0, Z)) * sharp
        K = np.exp(np.outer(u, v) - np.outer(u, v).max(axis=1, keepdims=True))
        kernels.append(K / K.sum(axis=1, keepdims=True))
    O = np.broadcast_to(np.array(kernels), (A, S, Z)).copy()
    r = rng.uniform(0.0, 2.0, (S, A))
    w = rng.uniform(0.1, 1.5, A) if spec.uncertainty != "none" else np.zeros(A)
    m = POMDP(P=P, O=O, r=r, gamma=spec.gamma, uncertainty=spec.uncertainty, w=w,
              name=f"random_s{S}_a{A}_{spec.uncertainty}")
    if spec.uncertainty == "shannon":
        eps = min(posterior_floor(m), 0.9 / S) if epsilon is None else epsilon
        if eps < 1e-6:  # effectively on the boundary: B_eps would be the whole simplex
            eps = 1e-6
        m = POMDP(P=P, O=O, r=r, gamma=spec.gamma, uncertainty="shannon", w=w, epsilon=eps, name=m.name)
    return m


def random_valid_models(seed: int, spec: ModelSpec, count: int, max_tries: int = 2000
                        ) -> list[tuple[POMDP, MyopicBounds]]:
    """``count`` random models that satisfy Assumption 1 and have a feasible bound LP."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(max_tries):
        m = random_candidate(rng, spec)
        if m.uncertainty.name == "shannon" and m.epsilon > posterior_floor(m):
            continue  # posteriors can leave B_eps: the guarantee does not cover B_eps (see module doc)
        if not assumptions_hold(m):
            continue
        bounds = bounds_for(m)
        if bounds is None:
            continue
        out.append((m, bounds))
        if len(out) == count:
            return out
    raise RuntimeError(f"only {len(out)} of {count} valid models in {max_tries} tries for {spec}")
