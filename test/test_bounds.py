"""Tests of core/bounds.py: Theorem 2 constants, the LP for g/h, and what the bounds guarantee.

Every check is against an independent computation: numerical maximisation for the FOSD
constant, the model's own gradient (``rho_gradient``) on many beliefs for the FOSD constraints,
finite differences along MLR-increasing pairs for monotonicity (both constants), scipy's HiGHS
on constraints written here for the LP (both solvers; and one LP per component for the least
element), a hand-derived Farkas certificate for infeasibility, and a 1-D grid value iteration
for Eq. 8.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog, minimize

from pomdp_planner.core import bounds as bd
from pomdp_planner.core.belief import posterior_floor
from pomdp_planner.core.domains.comparison import comparison_model
from pomdp_planner.core.domains.tracking import comparison_reward, tracking_model
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.myopic import MyopicBounds, transform_matrix

ROOT = Path(__file__).resolve().parents[1]
S3 = ROOT / "config" / "models" / "tracking_s3_info.yaml"
S8 = ROOT / "config" / "models" / "tracking_s8_info.yaml"


# ------------------------------------------------------------------ constants
def _renyi_ratio(b: np.ndarray, i: int) -> np.ndarray:
    return (b[..., i] - b[..., i + 1]) / np.sum(b * b, axis=-1)


def _numeric_renyi_sup(S: int, i: int, starts: int = 40, seed: int = 0) -> float:
    """Maximise (b_i - b_{i+1}) / ||b||^2 over the simplex (SLSQP from many random starts)."""
    rng = np.random.default_rng(seed)
    best = -np.inf
    cons = ({"type": "eq", "fun": lambda b: b.sum() - 1.0, "jac": lambda b: np.ones_like(b)},)
    for _ in range(starts):
        x0 = rng.dirichlet(np.full(S, 0.5))
        res = minimize(lambda b: -float(_renyi_ratio(b, i)), x0, method="SLSQP", bounds=[(0, 1)] * S,
                       constraints=cons, options={"ftol": 1e-13, "maxiter": 500})
        b = np.clip(res.x, 0, None)
        best = max(best, float(_renyi_ratio(b / b.sum(), i)))
    return best


@pytest.mark.parametrize("S", [2, 3, 4, 5, 8])
def test_renyi_constant_matches_numerical_maximisation(S: int) -> None:
    C = bd.renyi_constant(S)
    for i in sorted({0, S - 2}):
        num = _numeric_renyi_sup(S, i)
        assert num <= C + 1e-9  # never above the claimed supremum
        assert num == pytest.approx(C, abs=2e-4)  # and (numerically) attained


def test_renyi_constant_dense_grid_s3() -> None:
    n = 600
    k = np.arange(n + 1)
    x, y = np.meshgrid(k, k, indexing="ij")
    keep = x + y <= n
    B = np.stack([x[keep], y[keep], n - x[keep] - y[keep]], axis=-1) / n
    C = bd.renyi_constant(3)
    for i in (0, 1):
        r = _renyi_ratio(B, i)
        assert r.max() <= C + 1e-12
        assert r.max() >= C - 1e-3
        assert r.min() == pytest.approx(-r.max())  # symmetric range (swap b_i and b_{i+1})


def test_renyi_constant_closed_form_and_paper_value() -> None:
    assert bd.renyi_constant(1) == 0.0
    # the FOSD supremum equals the paper's 1 only for S = 2 (for MLR monotonicity 1 is exact for
    # every S: constant="mlr", test_mlr_constant_is_the_papers_and_weaker_than_fosd)
    assert bd.renyi_constant(2) == 1.0
    for S in (3, 4, 8, 64, 256):
        C = bd.renyi_constant(S)
        assert C == pytest.approx((1 + math.sqrt(S - 1)) / 2)
        for i in range(S - 1):
            b = bd.renyi_maximiser(S, i)
            assert b.sum() == pytest.approx(1.0) and b.min() >= 0
            assert _renyi_ratio(b, i) == pytest.approx(C, rel=1e-12)
        assert C > 1.0  # the paper's bound -1 on (b(i+1)-b(i))/sum b^2 fails for S >= 3 (the FOSD route)
    # the paper's Example 3 bound on the gradient ratio, violated by an explicit belief for S = 3
    b = np.array([1 / math.sqrt(2), 0.0, 1 - 1 / math.sqrt(2)])
    assert (b[1] - b[0]) / np.sum(b * b) < -1.2


@pytest.mark.parametrize("S,eps", [(2, 0.01), (3, 1e-3), (5, 0.05), (8, 1e-3)])
def test_shannon_constant_is_the_exact_range_on_b_eps(S: int, eps: float) -> None:
    L = bd.shannon_constant(S, eps)
    assert L < -math.log(eps)  # the paper's bound is valid but looser
    b = np.full(S, eps)
    b[1] = 1 - (S - 1) * eps  # b_0 = eps: the extreme point of B_eps
    assert np.log(b[1]) - np.log(b[0]) == pytest.approx(L)
    rng = np.random.default_rng(1)
    B = eps + (1 - S * eps) * rng.dirichlet(np.full(S, 0.2), size=20000)
    d = np.diff(np.log(B), axis=-1)
    assert np.abs(d).max() <= L + 1e-12
    with pytest.raises(ValueError, match="epsilon"):
        bd.shannon_constant(S, 1.0 / S)


# ------------------------------------------------------------------ models
def _random_model(rng: np.random.Generator, S: int, A: int, unc: str, gamma: float = 0.9,
                  eps: float = 0.01) -> POMDP:
    P = rng.dirichlet(np.ones(S), size=(A, S))
    Z = S
    O = rng.dirichlet(np.ones(Z), size=(A, S))
    r = rng.uniform(-1, 1, (S, A))
    w = rng.uniform(-1.0, 1.5, A) if unc != "none" else None
    return POMDP(P=P, O=O, r=r, gamma=gamma, uncertainty=unc, w=w, epsilon=min(eps, 0.5 / S), name="rand")


def _test_beliefs(model: POMDP, n: int = 3000, seed: int = 0) -> np.ndarray:
    """Random beliefs incl. vertices and edge points; inside B_eps for Shannon entropy."""
    rng = np.random.default_rng(seed)
    S = model.S
    parts = [rng.dirichlet(np.full(S, a), size=n // 3) for a in (0.1, 1.0, 5.0)]
    parts.append(np.eye(S))
    if S >= 2:
        t = rng.uniform(size=(200, 1))
        i = rng.integers(0, S, 200)
        j = (i + rng.integers(1, S, 200)) % S
        E = np.zeros((200, S))
        E[np.arange(200), i] = t[:, 0]
        E[np.arange(200), j] += 1 - t[:, 0]
        parts.append(E)
    if S >= 2:  # the worst case of the Renyi constraint for every pair, and its mirror image
        W = np.array([bd.renyi_maximiser(S, i) for i in range(S - 1)])
        parts += [W, W[:, ::-1]]
    B = np.concatenate(parts)
    if model.uncertainty.name == "shannon":
        eps = model.epsilon
        B = eps + (1 - S * eps) * B  # into B_eps (vertices -> vertices of B_eps)
    return B


def _check_gradient_monotone(model: POMDP, g: np.ndarray, h: np.ndarray, B: np.ndarray) -> None:
    """phi_a(b) = grad rho(b,a) + (I - gamma P[a]) v is increasing (g) / decreasing (h) in the index."""
    grad = model.rho_gradient(B)  # (N, A, S), the model's own gradient
    scale = 1e-9 * (1 + np.abs(grad).max() + np.abs(g).sum() + np.abs(h).sum())
    assert np.diff(grad + transform_matrix(model, g), axis=-1).min() >= -scale
    assert np.diff(grad + transform_matrix(model, h), axis=-1).max() <= scale


def _check_mlr_monotone(model: POMDP, mb: MyopicBounds, B: np.ndarray, seed: int = 0) -> int:
    """rho_lower(b2) >= rho_lower(b1) and rho_upper(b2) <= rho_upper(b1) whenever b2 >=_r b1.

    ``b2`` tilts ``b1`` by a random increasing likelihood ratio. Returns the number of pairs.
    """
    rng = np.random.default_rng(seed)
    S = model.S
    lr = np.cumsum(rng.exponential(size=(B.shape[0], S)) * (rng.uniform(size=(B.shape[0], S)) < 0.7), axis=-1)
    lr = lr + rng.uniform(0.01, 1.0, size=(B.shape[0], 1))
    B2 = B * lr
    B2 /= B2.sum(axis=-1, keepdims=True)
    keep = B2.sum(axis=-1) > 0
    if model.uncertainty.name == "shannon":  # the guarantee covers B_eps only
        keep &= B2.min(axis=-1) >= model.epsilon
    B1, B2 = B[keep], B2[keep]
    lo1, up1 = mb.transformed_rewards(B1)
    lo2, up2 = mb.transformed_rewards(B2)
    tol = 1e-9 * (1 + np.abs(lo1).max() + np.abs(up1).max())
    assert (lo2 - lo1).min() >= -tol
    assert (up2 - up1).max() <= tol
    return int(keep.sum())


@pytest.fixture(scope="module")
def s3() -> POMDP:
    return load_model(S3)


def _check_guarantee(model: POMDP, sol: bd.BoundsSolution, B: np.ndarray, seed: int = 0) -> int:
    """What the chosen constant promises: MLR monotone transformed rewards for both constants;
    for ``fosd`` (and whenever the constants coincide) also a gradient that is monotone in the
    index at every belief (first-order dominance). Returns the number of MLR pairs checked."""
    if sol.constant == "fosd" or model.uncertainty.name != "renyi2":
        _check_gradient_monotone(model, sol.g, sol.h, B)
    return _check_mlr_monotone(model, sol.myopic, B, seed=seed)


@pytest.mark.parametrize("constant", bd.BOUND_CONSTANTS)
def test_paper_s3_model_gives_feasible_g_and_h(s3: POMDP, constant: str) -> None:
    for variant in bd.BOUND_VARIANTS:
        sol = bd.solve_bounds(s3, variant, constant=constant)
        assert sol.feasible and sol.g_feasible and sol.h_feasible, sol.message
        assert sol.myopic is not None and sol.most_violated is None
        assert sol.covers == "simplex" and sol.constant == constant
        c = sol.constants
        assert c["constant"] == constant and constant in c["why"]
        assert c["C_used"] == pytest.approx(1.0 if constant == "mlr" else (1 + math.sqrt(2)) / 2)
        assert c["K_f"] == pytest.approx(2 * c["C_used"])
        assert sol.g[0] == 0.0 and sol.h[0] == 0.0  # the pinned free constant
        assert bd.constraint_margins(s3, sol.g, "g", constant=constant).min() >= 0.0
        assert bd.constraint_margins(s3, sol.h, "h", constant=constant).min() >= 0.0
        assert _check_guarantee(s3, sol, _test_beliefs(s3)) > 1000
        d = sol.to_dict()
        json.dumps(d)
        assert d["constant"] == constant and d["constants"]["why"] == c["why"]


def test_mlr_constant_is_the_papers_and_weaker_than_fosd(s3: POMDP) -> None:
    """Renyi: steps >= 2|w_a| (MLR) against 2 C_S |w_a| (FOSD). Every FOSD-feasible vector is
    MLR-feasible, not conversely: the MLR vectors of the S = 3 problem violate the FOSD rows, and
    their gradient steps are negative at the FOSD worst-case belief (so the MLR solution is not
    first-order monotone there, as it need not be)."""
    m = s3
    assert bd.gradient_spread(m, "mlr") == 2.0
    assert bd.gradient_spread(m, "fosd") == pytest.approx(1 + math.sqrt(2))
    fosd = bd.solve_bounds(m, "feasible", constant="fosd")
    mlr = bd.solve_bounds(m, "feasible", constant="mlr")
    for which in ("g", "h"):
        v_f, v_m = getattr(fosd, which), getattr(mlr, which)
        assert bd.is_feasible(m, v_f, which, constant="mlr")
        assert not bd.is_feasible(m, v_m, which, constant="fosd")
    assert np.abs(mlr.g).sum() < np.abs(fosd.g).sum()  # a smaller constant needs a flatter g
    W = np.array([bd.renyi_maximiser(3, i) for i in range(2)])
    steps = np.diff(m.rho_gradient(np.vstack([W, W[:, ::-1]])) + transform_matrix(m, mlr.g), axis=-1)
    assert steps.min() < -1e-3
    with pytest.raises(ValueError, match="constant"):
        bd.solve_bounds(m, constant="paper")
    with pytest.raises(ValueError, match="constant"):
        bd.gradient_spread(m, "C_S")


@pytest.mark.parametrize("unc", ["none", "shannon"])
def test_constants_coincide_without_renyi_entropy(unc: str) -> None:
    rng = np.random.default_rng(3)
    m = _random_model(rng, 4, 2, unc)
    assert bd.gradient_spread(m, "mlr") == bd.gradient_spread(m, "fosd")
    for constant in bd.BOUND_CONSTANTS:
        why = bd.bound_constants(m, constant)["why"]
        assert ("no closed form" in why) if unc == "shannon" else ("f = none" in why)
    G1, r1 = bd.constraint_system(m, "g", constant="mlr")
    G2, r2 = bd.constraint_system(m, "g", constant="fosd")
    assert np.array_equal(G1, G2) and np.array_equal(r1, r2)


@pytest.mark.parametrize("constant", bd.BOUND_CONSTANTS)
@pytest.mark.parametrize("unc", ["none", "renyi2", "shannon"])
def test_solution_satisfies_every_constraint_on_many_beliefs(unc: str, constant: str) -> None:
    rng = np.random.default_rng(11)
    found = 0
    for _ in range(40):
        m = _random_model(rng, int(rng.integers(2, 6)), int(rng.integers(1, 4)), unc)
        sol = bd.solve_bounds(m, "feasible", constant=constant, samples=60)
        if not sol.feasible:
            continue
        found += 1
        if unc != "shannon":
            assert sol.covers == "simplex"
        elif m.epsilon <= posterior_floor(m):
            assert sol.covers == f"B_epsilon({m.epsilon:g})"
        else:  # posteriors can leave B_eps: rho_lower is still monotone on B_eps, no policy bound is claimed
            assert sol.covers.startswith("none") and "WARNING" in sol.message
        _check_guarantee(m, sol, _test_beliefs(m, n=900, seed=found), seed=found)
        if found == 4:
            break
    assert found >= 2


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), S=st.integers(2, 5), A=st.integers(1, 3),
       unc=st.sampled_from(["none", "renyi2", "shannon"]), variant=st.sampled_from(bd.BOUND_VARIANTS),
       constant=st.sampled_from(bd.BOUND_CONSTANTS))
def test_property_feasible_means_monotone(seed: int, S: int, A: int, unc: str, variant: str, constant: str) -> None:
    m = _random_model(np.random.default_rng(seed), S, A, unc)
    sol = bd.solve_bounds(m, variant, constant=constant, samples=40, seed=seed)
    if sol.g_feasible:
        assert bd.is_feasible(m, sol.g, "g", constant=constant)
    if sol.h_feasible:
        assert bd.is_feasible(m, sol.h, "h", constant=constant)
    if sol.feasible:
        _check_guarantee(m, sol, _test_beliefs(m, n=300, seed=seed), seed=seed)
    else:
        assert sol.myopic is None and sol.most_violated


# ------------------------------------------------------------------ LP cross-check
def _k_f(model: POMDP, constant: str) -> float:
    """The constant written out here (not the module's): steps >= |w_a| K_f."""
    name, S = model.uncertainty.name, model.S
    if name == "renyi2":
        return 2.0 if constant == "mlr" else 1.0 + math.sqrt(S - 1)
    if name == "shannon":
        return math.log((1 - (S - 1) * model.epsilon) / model.epsilon)
    return 0.0


def _written_rows(model: POMDP, which: str, constant: str = "mlr") -> tuple[np.ndarray, np.ndarray]:
    """The constraints as ``A_ub v <= b_ub``, written from their definition (not the module's)."""
    S, A = model.S, model.A
    K = _k_f(model, constant)
    rows, rhs = [], []
    sign = 1.0 if which == "g" else -1.0
    for a in range(A):
        C = np.eye(S) - model.gamma * model.P[a]
        for i in range(S - 1):
            # sign * ((C v)[i+1] - (C v)[i] + r[i+1,a] - r[i,a]) >= |w_a| K
            rows.append(-sign * (C[i + 1] - C[i]))
            rhs.append(sign * (model.r[i + 1, a] - model.r[i, a]) - abs(model.w[a]) * K)
    return np.array(rows), np.array(rhs)


def _highs_l1(model: POMDP, which: str, constant: str = "mlr") -> tuple[int, float]:
    """L1-minimal feasible vector by scipy HiGHS, written from the constraints directly."""
    S = model.S
    G, rhs = _written_rows(model, which, constant)
    A_ub = np.vstack([np.hstack([G, np.zeros_like(G)]), np.hstack([np.eye(S), -np.eye(S)]),
                      np.hstack([-np.eye(S), -np.eye(S)])])
    b_ub = np.concatenate([rhs, np.zeros(2 * S)])
    res = linprog(np.r_[np.zeros(S), np.ones(S)], A_ub=A_ub, b_ub=b_ub,
                  bounds=[(0, 0)] + [(None, None)] * (S - 1) + [(0, None)] * S, method="highs")
    return res.status, (res.fun if res.status == 0 else math.nan)


@pytest.mark.parametrize("solver", bd.BOUND_SOLVERS)
@pytest.mark.parametrize("constant", bd.BOUND_CONSTANTS)
def test_both_solvers_agree_with_an_independent_highs_lp(s3: POMDP, constant: str, solver: str) -> None:
    """The ``feasible`` variant's ||v||_1 (least element or HiGHS dual simplex for ``structured``,
    Clarabel's interior point for ``clarabel``) against HiGHS on constraints written here."""
    rng = np.random.default_rng(5)
    models = [s3, load_model(S8), _infeasible_model(), comparison_model(6, 4), comparison_model(5, 3, natural=True)]
    models += [_random_model(rng, int(rng.integers(2, 7)), int(rng.integers(1, 4)), u)
               for u in ("none", "renyi2", "shannon") for _ in range(4)]
    n_feasible = n_infeasible = 0
    for m in models:
        sol = bd.solve_bounds(m, "feasible", constant=constant, samples=20, solver=solver)
        assert sol.solver == solver
        for which, ok, v in (("g", sol.g_feasible, sol.g), ("h", sol.h_feasible, sol.h)):
            status, obj = _highs_l1(m, which, constant)
            assert (status == 0) == ok, (m.name, which, status, sol.message)
            if ok:
                n_feasible += 1
                assert np.abs(v).sum() == pytest.approx(obj, rel=1e-5, abs=1e-6)
            else:
                n_infeasible += 1
    assert n_feasible >= 6 and n_infeasible >= 1  # both outcomes exercised


# ------------------------------------------------------------------ the least element
def _structured_models() -> list[POMDP]:
    """Models with monotone, action-ordered transitions (the least-element certificate applies)."""
    rng = np.random.default_rng(17)
    out = [load_model(S3), load_model(S8), comparison_model(8, 4), comparison_model(16, 8)]
    for S, A in ((3, 3), (4, 2), (5, 3)):
        x = np.cumsum(rng.uniform(0.3, 1.2, S))
        y = np.cumsum(rng.uniform(0.2, 1.0, S * A)) - 6.0
        out.append(tracking_model(S, A, 0.75, rng.uniform(0, 2, (S, A)), gamma=0.95, x=x, y=y,
                                  uncertainty="renyi2", w=rng.uniform(0.2, 1.5, A), name=f"rand_s{S}"))
    return out


@pytest.mark.parametrize("constant", bd.BOUND_CONSTANTS)
def test_least_element_is_the_componentwise_extreme_feasible_vector(constant: str) -> None:
    """``tight`` on structured models returns the least feasible g and the greatest feasible h:
    each component equals the LP minimum of g_k (maximum of h_k) over the constraints written in
    this file, solved by HiGHS one component at a time."""
    checked = 0
    for m in _structured_models():
        sol = bd.solve_bounds(m, "tight", constant=constant, samples=50)
        assert sol.feasible and sol.tightening["method"].startswith("least elements"), (m.name, sol.tightening)
        for which, v, sign in (("g", sol.g, 1.0), ("h", sol.h, -1.0)):
            G, rhs = _written_rows(m, which, constant)
            for k in sorted({1, m.S // 2, m.S - 1}):
                c = np.zeros(m.S)
                c[k] = sign  # min g_k, or max h_k
                res = linprog(c, A_ub=G, b_ub=rhs, bounds=[(0, 0)] + [(None, None)] * (m.S - 1), method="highs")
                assert res.status == 0
                assert v[k] == pytest.approx(res.x[k], rel=1e-5, abs=1e-5), (m.name, which, k)
                checked += 1
    assert checked >= 30


def test_value_and_policy_iteration_find_the_same_least_element(monkeypatch: pytest.MonkeyPatch) -> None:
    """The fixed point is computed by value iteration when the contraction is strong and by
    policy iteration (dense solves) otherwise: forcing either path gives the same vectors."""
    results = {}
    for kappa in (0.0, 1.0):  # 0: always policy iteration; 1: value iteration wherever kappa_1 < 1
        monkeypatch.setattr(bd, "VALUE_ITERATION_KAPPA", kappa)
        results[kappa] = [bd.solve_bounds(m, "tight", samples=20) for m in _structured_models()]
    for pi, vi in zip(results[0.0], results[1.0], strict=True):
        for which in ("g", "h"):
            a, b = getattr(pi, which), getattr(vi, which)
            assert np.allclose(a, b, rtol=1e-9, atol=1e-9 * (1 + np.abs(a).max()))


def test_least_elements_give_the_tightest_bounds_at_every_belief() -> None:
    """No feasible g gives a higher lower bound, no feasible h a lower upper bound, at any belief:
    compared with the L1-minimal vectors, the hinge-LP vectors of the Clarabel path, and vectors
    moved along a feasible ray and mixed with them (the feasible set is convex), at Dirichlet
    beliefs, vertices and reachable beliefs. On the comparison model the least element is
    strictly tighter than the L1-minimal g somewhere."""
    strictly = 0
    for m in _structured_models():
        best = bd.solve_bounds(m, "tight", samples=50)
        B = np.vstack([_test_beliefs(m, n=600), bd.sample_beliefs(m, 300, seed=7)])
        lo, up = best.myopic.actions(B)
        others = [bd.solve_bounds(m, "feasible", samples=50, solver=s) for s in bd.BOUND_SOLVERS]
        others.append(bd.solve_bounds(m, "tight", samples=50, solver="clarabel"))
        G, _ = _written_rows(m, "g")  # a ray: every row of G r <= -1, i.e. Delta (I - gamma P[a]) r >= 1
        res = linprog(np.zeros(m.S), A_ub=G, b_ub=-np.ones(G.shape[0]),
                      bounds=[(0, 0)] + [(None, None)] * (m.S - 1), method="highs")
        assert res.status == 0
        ray = res.x / np.abs(res.x).max()
        pairs = [(o.g, o.h) for o in others]
        pairs += [(0.5 * (best.g + o.g) + t * ray, 0.5 * (best.h + o.h) - t * ray)
                  for o in others for t in (1e-3, 0.1, 10.0)]
        for g, h in pairs:
            assert bd.is_feasible(m, g, "g") and bd.is_feasible(m, h, "h")
            lo_o, up_o = MyopicBounds(m, g, h).actions(B)
            assert np.all(lo >= lo_o) and np.all(up <= up_o), m.name
            strictly += int(np.any(lo > lo_o) or np.any(up < up_o))
    assert strictly >= 3


def test_unstructured_models_fall_back_to_the_lp_and_hinge_search() -> None:
    rng = np.random.default_rng(2)
    m = _random_model(rng, 4, 3, "renyi2")
    sol = bd.solve_bounds(m, "tight", samples=50)
    assert sol.feasible and sol.tightening["method"].startswith("hinge")
    with pytest.raises(ValueError, match="solver"):
        bd.solve_bounds(m, solver="cplex")


# ------------------------------------------------------------------ infeasibility
def _infeasible_model(gamma: float = 0.9) -> POMDP:
    """S = 3, A = 2, f = none, r decreasing by 1 per state, deterministic transitions:
    P[0] moves state 1 to 2 (amplifies the first increment), P[1] moves state 1 to 0 (the
    second). By hand, with g_0 = 0, the g-constraints are

        (a0,i0) g1 - gamma g2 >= 1     (a0,i1) g2 - g1 >= 1
        (a1,i0) g1 >= 1                (a1,i1) (1 - gamma) g2 - g1 >= 1

    and y = (1, 2 gamma - 1, 2 gamma - 1, 1) >= 0 combines them into 0 >= 4 gamma: infeasible.
    The smallest uniform violation is exactly 1 (at g = 0). h = 0 is feasible.
    """
    P = np.zeros((2, 3, 3))
    P[0, 0, 0] = P[0, 1, 2] = P[0, 2, 2] = 1.0
    P[1, 0, 0] = P[1, 1, 0] = P[1, 2, 2] = 1.0
    O = np.broadcast_to(np.eye(3), (2, 3, 3)).copy()
    r = np.array([[2.0, 2.0], [1.0, 1.0], [0.0, 0.0]])
    return POMDP(P=P, O=O, r=r, gamma=gamma, name="constructed_infeasible")


def test_constructed_infeasible_case_is_reported_with_most_violated_constraint() -> None:
    gamma = 0.9
    m = _infeasible_model(gamma)
    # the hand-written constraints are the module's constraint system (row order (a, i))
    G, rhs = bd.constraint_system(m, "g")
    hand = np.array([[1, -gamma], [-1, 1], [1, 0], [-1, 1 - gamma]])  # columns g1, g2
    assert np.allclose(G[:, 1:], hand) and np.allclose(rhs, 1.0)
    y = np.array([1, 2 * gamma - 1, 2 * gamma - 1, 1])
    assert np.allclose(y @ hand, 0) and y @ rhs > 0  # Farkas certificate, independent of any solver
    for variant, solver in itertools.product(bd.BOUND_VARIANTS, bd.BOUND_SOLVERS):
        sol = bd.solve_bounds(m, variant, solver=solver)
        assert not sol.feasible and not sol.g_feasible and sol.h_feasible
        assert sol.myopic is None and sol.g is None
        assert "infeasible" in sol.message
        mv = sol.most_violated["g"]
        assert mv["violation"] == pytest.approx(1.0, abs=1e-6)
        assert mv["vector"] == "g" and 1 <= mv["priority"] <= 2 and mv["state_pair"][1] == mv["state_pair"][0] + 1
        # the reported multipliers are a Farkas certificate of the hand-written rows (Clarabel's
        # interior point returns the four-row one above, HiGHS a vertex: rows (0,0), (1,0), (1,1)
        # with weights proportional to (1, (2 gamma - 1)/(1 - gamma), gamma/(1 - gamma)) also work)
        y = np.zeros(4)
        for c in mv["conflicting"]:
            y[2 * c["action"] + c["state_pair"][0]] = c["weight"]
        assert y.min() >= 0 and np.count_nonzero(y) >= 3
        assert np.allclose(y @ hand, 0, atol=1e-6 * y.sum()) and y @ rhs > 0.5 * y.sum()
        d = sol.to_dict()
        json.dumps(d)
        assert d["feasible"] is False and d["g"] is None
    assert _highs_l1(m, "g")[0] == 2  # HiGHS: infeasible


def test_no_free_ray_gives_infeasible_even_with_small_margins() -> None:
    # the feasible set of g is empty although every single action alone is feasible
    m = _infeasible_model(0.6)
    for a in range(2):
        single = POMDP(P=m.P[a:a + 1], O=m.O[a:a + 1], r=m.r[:, a:a + 1], gamma=m.gamma)
        assert bd.solve_bounds(single, "feasible").feasible


# ------------------------------------------------------------------ variants
def test_tight_is_no_worse_than_feasible_and_deterministic(s3: POMDP) -> None:
    m8 = load_model(S8)
    for m in (s3, m8):
        f = bd.solve_bounds(m, "feasible", samples=200, seed=3)
        t = bd.solve_bounds(m, "tight", samples=200, seed=3)
        assert t.feasible and f.feasible
        assert t.sample_agreement >= f.sample_agreement
        assert t.sample_crossed == 0.0  # Assumption 1 holds: lower <= upper everywhere
        t2 = bd.solve_bounds(m, "tight", samples=200, seed=3)
        assert np.array_equal(t.g, t2.g) and np.array_equal(t.h, t2.h)
        assert bd.is_feasible(m, t.g, "g") and bd.is_feasible(m, t.h, "h")


def test_tight_variant_improves_agreement_where_it_can() -> None:
    """On an unstructured random model (S = 3, A = 2, Renyi; Assumption 1 need not hold, which
    is irrelevant here: this exercises the tightness LPs) the L1-minimal vectors agree on half
    the fitting samples, the tight ones on far more; both are verified feasible, and the gain
    carries over to held-out beliefs."""
    rng = np.random.default_rng(11)
    m = _random_model(rng, int(rng.integers(3, 6)), int(rng.integers(2, 5)), "renyi2")
    f = bd.solve_bounds(m, "feasible", samples=200, seed=0)
    t = bd.solve_bounds(m, "tight", samples=200, seed=0)
    assert f.feasible and t.feasible
    assert t.sample_agreement >= f.sample_agreement + 0.2
    assert bd.is_feasible(m, t.g, "g") and bd.is_feasible(m, t.h, "h")
    assert not np.array_equal(t.g, f.g) or not np.array_equal(t.h, f.h)
    rounds = t.tightening["rounds"]
    assert rounds[-1]["agreement"] == pytest.approx(t.sample_agreement)
    B = bd.sample_beliefs(m, 500, seed=99)
    assert np.mean(np.equal(*t.myopic.actions(B))) > np.mean(np.equal(*f.myopic.actions(B))) + 0.2
    _check_guarantee(m, t, _test_beliefs(m, n=600))


def test_bad_arguments() -> None:
    m = _infeasible_model()
    with pytest.raises(ValueError, match="variant"):
        bd.solve_bounds(m, "loose")
    with pytest.raises(ValueError, match="samples"):
        bd.solve_bounds(m, samples=0)
    with pytest.raises(ValueError, match="which"):
        bd.constraint_system(m, "x")


def test_sample_beliefs_are_seeded_beliefs(s3: POMDP) -> None:
    B = bd.sample_beliefs(s3, 50, seed=4)
    assert B.shape == (50, 3)
    assert np.allclose(B.sum(axis=1), 1) and B.min() >= 0
    assert np.array_equal(B, bd.sample_beliefs(s3, 50, seed=4))
    assert not np.array_equal(B, bd.sample_beliefs(s3, 50, seed=5))


# ------------------------------------------------------------------ Eq. 8 leaves the policy unchanged
def _grid_vi_s2(model: POMDP, reward: np.ndarray, p: np.ndarray, iters: int) -> tuple[np.ndarray, np.ndarray]:
    """Value iteration on a 1-D grid of beliefs b = (1-p, p) with linear interpolation (S = 2).

    ``reward`` is (N, A) at the grid beliefs. Written from Eqs. 1, 2, 5-7 directly.
    Returns (V, Q) at the grid points.
    """
    B = np.stack([1 - p, p], axis=-1)
    A, Z = model.A, model.Z
    pred = np.einsum("ns,ast->nat", B, model.P)  # b^a
    joint = pred[:, :, :, None] * model.O[None]  # (N, A, S, Z): b^a(s') O(z|s',a)
    eta = joint.sum(axis=2)  # (N, A, Z)
    post_p = np.where(eta > 0, joint[:, :, 1, :] / np.where(eta > 0, eta, 1), 0.0)  # tau(.)(state 1)
    V = np.zeros(p.size)
    for _ in range(iters):
        Vn = np.interp(post_p, p, V)  # (N, A, Z)
        Q = reward + model.gamma * np.sum(eta * Vn, axis=-1)
        V = Q.max(axis=-1)
    assert A >= 1 and Z >= 1
    return V, Q


@pytest.mark.parametrize("unc", ["none", "renyi2"])
def test_transformed_rewards_leave_policy_unchanged_and_shift_value(unc: str) -> None:
    rng = np.random.default_rng(7 if unc == "none" else 8)
    P = np.array([[[0.9, 0.1], [0.3, 0.7]], [[0.6, 0.4], [0.1, 0.9]], [[0.5, 0.5], [0.2, 0.8]]])
    O = np.array([[[0.8, 0.2], [0.3, 0.7]], [[0.6, 0.4], [0.4, 0.6]], [[0.9, 0.1], [0.2, 0.8]]])
    r = rng.uniform(0, 1, (2, 3))
    m = POMDP(P=P, O=O, r=r, gamma=0.9, uncertainty=unc, w=[0.3, 0.5, 0.2] if unc != "none" else None)
    sol = bd.solve_bounds(m, "feasible", samples=50)
    assert sol.feasible  # S = 2 is always feasible (both constraint coefficients are > 0)
    p = np.linspace(0, 1, 801)
    B = np.stack([1 - p, p], axis=-1)
    lo, up = sol.myopic.transformed_rewards(B)
    iters = 400  # gamma^400 ~ 5e-19: converged
    V, Q = _grid_vi_s2(m, m.rho(B), p, iters)
    for v, rew in ((sol.g, lo), (sol.h, up)):
        Vv, Qv = _grid_vi_s2(m, rew, p, iters)
        assert np.abs(Vv - (V + B @ v)).max() < 1e-8 * (1 + np.abs(V).max())
        assert np.abs(Qv - (Q + (B @ v)[:, None])).max() < 1e-8 * (1 + np.abs(Q).max())
        srt = np.sort(Q, axis=-1)
        clear = srt[:, -1] - srt[:, -2] > 1e-6
        assert np.array_equal(Q.argmax(-1)[clear], Qv.argmax(-1)[clear])
    # and the bounds hold for this (grid-optimal) policy where it is not a near-tie
    srt = np.sort(Q, axis=-1)
    clear = srt[:, -1] - srt[:, -2] > 1e-6
    opt = Q.argmax(-1)
    lo_a, up_a = sol.myopic.actions(B)
    assert np.all(lo_a[clear] <= opt[clear]) and np.all(opt[clear] <= up_a[clear])


# ------------------------------------------------------------------ the paper's S = 256, A = 64 case
def test_comparison_s256_a64_lp_is_solved_and_verified() -> None:
    """The paper's largest comparison case (16 320 rows per vector; the L1-minimal g needs the
    LP, h is the least element)."""
    m = tracking_model(256, 64, 0.8, comparison_reward(256, 64), gamma=0.99)
    sol = bd.solve_bounds(m, "feasible", samples=50)
    # feasible, unlike the paper's report: see the certificate in the next test and THEORY.md
    assert sol.feasible, sol.message
    assert bd.is_feasible(m, sol.g, "g") and bd.is_feasible(m, sol.h, "h")
    assert sol.solve_time > 0


def test_comparison_s256_a64_has_a_strictly_feasible_ray() -> None:
    """The paper says no g exists for S = 256, A = 64 (comparison reward, f = 0). A solver-free
    certificate says otherwise for our generator: g0 = (0, 1, ..., S-1) makes every constraint
    row strictly positive, so t * g0 (and -t * g0 for h) is feasible for t large enough."""
    S, A = 256, 64
    m = tracking_model(S, A, 0.8, comparison_reward(S, A), gamma=0.99)
    g0 = np.arange(S, dtype=float)
    # the rows written from the definition: 1 - gamma (E[next | i+1, a] - E[next | i, a])
    expected_next = m.P @ g0  # (A, S)
    rows = 1.0 - m.gamma * np.diff(expected_next, axis=1)
    assert rows.min() > 0.9
    for which, sign in (("g", 1.0), ("h", -1.0)):
        G, rhs = bd.constraint_system(m, which)
        assert np.allclose(G @ (sign * g0), rows.reshape(-1))
        t = max(0.0, rhs.max()) / rows.min() + 1.0
        assert bd.is_feasible(m, sign * t * g0, which)


@pytest.mark.parametrize("solver", bd.BOUND_SOLVERS)
def test_row_generation_gives_the_direct_solution(monkeypatch: pytest.MonkeyPatch, solver: str) -> None:
    """Large systems are solved by row generation (one row per state pair then the worst row
    of each violated pair for ``structured``, whole actions for ``clarabel``); forcing that
    path on small models must give the same L1 optimum (vs HiGHS) and the same infeasibility
    report."""
    monkeypatch.setattr(bd, "DIRECT_ROWS", 0)
    rng = np.random.default_rng(21)
    models = [tracking_model(12, 9, 0.8, comparison_reward(12, 9), gamma=0.99), _infeasible_model(),
              comparison_model(12, 9)]
    models += [_random_model(rng, 4, 6, u) for u in ("none", "renyi2", "shannon")]
    for m in models:
        sol = bd.solve_bounds(m, "feasible", samples=20, solver=solver)
        for which, ok, v in (("g", sol.g_feasible, sol.g), ("h", sol.h_feasible, sol.h)):
            status, obj = _highs_l1(m, which)
            assert (status == 0) == ok
            if ok:
                assert bd.is_feasible(m, v, which)
                assert np.abs(v).sum() == pytest.approx(obj, rel=1e-5, abs=1e-6)
    sol = bd.solve_bounds(_infeasible_model(), "feasible", solver=solver)
    assert sol.most_violated["g"]["violation"] == pytest.approx(1.0, abs=1e-6)


def test_large_comparison_model_is_solved_by_row_generation() -> None:
    S, A = 64, 32  # 2016 rows per vector: above DIRECT_ROWS
    m = tracking_model(S, A, 0.8, comparison_reward(S, A), gamma=0.99)
    assert (S - 1) * A > bd.DIRECT_ROWS
    sol = bd.solve_bounds(m, "feasible", samples=50)
    assert sol.feasible
    for which, v in (("g", sol.g), ("h", sol.h)):
        assert bd.is_feasible(m, v, which)
        assert np.abs(v).sum() == pytest.approx(_highs_l1(m, which)[1], rel=1e-5)
