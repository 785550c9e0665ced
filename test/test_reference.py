"""Tests of the optimal-policy reference (core/reference.py) against independent computations.

* Freudenthal interpolation: exact reconstruction of beliefs and of linear functions,
  weights on the simplex, grid size, convex functions interpolated from above.
* Grid value iteration vs. a brute-force expectimax tree (finite horizon, nonlinear rewards),
  vs. the exact alpha-vector solution (linear rewards), and convergence in ``n``.
* Alpha-vector value iteration vs. the expectimax tree; pruning keeps the upper envelope.
* The documented tie margin (n vs 2n) bounds the true error of the Q differences.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.belief import update
from pomdp_planner.core.domains.tracking import tracking_model, tracking_observations, tracking_transitions
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.reference import (
    FreudenthalGrid,
    _witness_lp,
    alpha_vector_value_iteration,
    certified_actions,
    prune_alpha_vectors,
    reference_policy,
    solve_grid,
)

MODELS_DIR = Path(__file__).resolve().parents[1] / "config" / "models"


# ------------------------------------------------------------------ independent brute force
def tree_q(model: POMDP, b: np.ndarray, horizon: int) -> np.ndarray:
    """Depth-``horizon`` expectimax (paper Eqs. 4-6) by plain recursion: ``Q_H(b, .)``."""
    q = model.rho(b).astype(float)
    if horizon == 1:
        return q
    for a in range(model.A):
        ba = b @ model.P[a]
        for z in range(model.Z):
            eta = float(ba @ model.O[a, :, z])
            if eta > 1e-15:
                q[a] += model.gamma * eta * tree_q(model, update(model, b, a, z), horizon - 1).max()
    return q


def small_tracking(S: int, uncertainty: str, gamma: float, seed: int = 0) -> POMDP:
    rng = np.random.default_rng(seed)
    A = 2
    r = rng.uniform(0.0, 2.0, (S, A))
    w = rng.uniform(0.3, 1.2, A) if uncertainty != "none" else None
    return tracking_model(S, A, q=0.75, r=r, gamma=gamma, uncertainty=uncertainty, w=w,
                          x=np.arange(1, S + 1, dtype=float), y=np.linspace(-3.0, -0.5, S * A))


# ------------------------------------------------------------------ the grid
@pytest.mark.parametrize(("S", "n"), [(2, 7), (3, 5), (3, 12), (4, 6), (5, 3)])
def test_grid_size_and_beliefs(S, n):
    g = FreudenthalGrid(S, n)
    assert g.size == math.comb(n + S - 1, S - 1)
    k = np.rint(g.beliefs * n)
    assert np.allclose(g.beliefs * n, k) and np.allclose(g.beliefs.sum(1), 1.0) and g.beliefs.min() >= 0
    assert len(np.unique(k, axis=0)) == g.size
    assert np.array_equal(g.index_of(g.beliefs), np.arange(g.size))


@settings(max_examples=40, deadline=None)
@given(S=st.integers(2, 5), n=st.integers(1, 9), seed=st.integers(0, 2**31 - 1))
def test_barycentric_weights_reconstruct_the_belief(S, n, seed):
    rng = np.random.default_rng(seed)
    B = rng.dirichlet(np.full(S, 0.5), size=50)
    B[:5] = np.eye(S)[rng.integers(0, S, 5)]  # vertices
    B[5] = np.full(S, 1.0 / S)
    B[6, :] = 0.0
    B[6, :2] = 0.5  # on an edge
    g = FreudenthalGrid(S, n)
    idx, lam = g.vertices_and_weights(B)
    assert np.all(lam >= 0) and np.allclose(lam.sum(1), 1.0)
    assert np.allclose(np.einsum("ms,msk->mk", lam, g.beliefs[idx]), B, atol=1e-12)
    c = rng.normal(size=S)  # linear functions are interpolated exactly
    assert np.allclose(g.interpolate(g.beliefs @ c, B), B @ c, atol=1e-12)
    W = g.interpolation_matrix(B)
    assert np.allclose(W @ (g.beliefs @ c), B @ c, atol=1e-12)


def test_vertices_of_the_simplex_are_adjacent_grid_points():
    # The containing simplex's vertices differ by at most one step 1/n in each coordinate.
    g = FreudenthalGrid(3, 10)
    B = np.random.default_rng(2).dirichlet(np.ones(3), size=200)
    idx, _ = g.vertices_and_weights(B)
    V = g.beliefs[idx]
    assert np.max(np.abs(V - B[:, None, :])) <= 2.0 / g.n + 1e-12


def test_convex_function_is_interpolated_from_above():
    g = FreudenthalGrid(3, 8)
    f = lambda X: np.sum(X * X, axis=-1)  # noqa: E731
    B = np.random.default_rng(3).dirichlet(np.ones(3), size=500)
    assert np.all(g.interpolate(f(g.beliefs), B) >= f(B) - 1e-12)


def test_bad_grid_arguments_are_rejected():
    with pytest.raises(ValueError, match="n:"):
        FreudenthalGrid(3, 0)
    with pytest.raises(ValueError, match="S:"):
        FreudenthalGrid(1, 4)


# ------------------------------------------------------------------ grid value iteration
@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon"])
def test_finite_horizon_grid_matches_expectimax_tree_s2(uncertainty):
    model = small_tracking(2, uncertainty, gamma=0.5)
    H = 5
    sol = solve_grid(model, 400, horizon=H)
    for b0 in (0.0, 0.1, 0.35, 0.5, 0.8, 1.0):
        b = np.array([1.0 - b0, b0])
        k = sol.grid.index_of(b[None])[0]
        assert k >= 0
        assert np.allclose(sol.Q[k], tree_q(model, b, H), atol=2e-5)


def test_finite_horizon_grid_matches_tree_s3_within_documented_margin():
    """The true error of every Q difference is below the n-vs-2n tie margin."""
    model = small_tracking(3, "renyi2", gamma=0.5, seed=4)
    H = 4
    ref = reference_policy(model, 20, horizon=H)
    rng = np.random.default_rng(5)
    for k in rng.choice(len(ref.beliefs), size=12, replace=False):
        exact = tree_q(model, ref.beliefs[k], H)
        err = ref.Q[k] - exact
        assert np.max(np.abs(err)) < 1e-2  # values themselves are close
        assert err.max() - err.min() <= ref.tie_margin  # differences within the margin
        if ref.decided[k]:
            assert ref.actions[k] == int(np.argmax(exact))


def test_finite_horizon_one_is_the_reward():
    model = small_tracking(3, "renyi2", gamma=0.9)
    sol = solve_grid(model, 6, horizon=1)
    assert np.allclose(sol.Q, model.rho(sol.beliefs))


def test_policy_iteration_is_the_fixed_point_of_value_iteration():
    model = small_tracking(3, "shannon", gamma=0.8, seed=1)
    pi = solve_grid(model, 15)
    assert pi.residual < 1e-9
    vi = solve_grid(model, 15, horizon=200)  # 0.8^200: converged
    assert np.allclose(pi.V, vi.V, atol=1e-8)
    assert np.allclose(pi.Q, vi.Q, atol=1e-8)


def test_grid_solution_is_a_bellman_fixed_point_off_the_grid_too():
    # Q at grid beliefs re-derived by hand from the interpolated V at the exact posteriors.
    model = load_model(MODELS_DIR / "tracking_s3_info.yaml")
    sol = solve_grid(model, 12)
    rng = np.random.default_rng(0)
    for k in rng.choice(sol.grid.size, 8, replace=False):
        b = sol.beliefs[k]
        q = model.rho(b).copy()
        for a in range(model.A):
            ba = b @ model.P[a]
            for z in range(model.Z):
                eta = float(ba @ model.O[a, :, z])
                if eta > 0:
                    q[a] += model.gamma * eta * sol.value(update(model, b, a, z)[None])[0]
        assert np.allclose(q, sol.Q[k], atol=1e-9)


def test_q_values_off_the_grid():
    model = load_model(MODELS_DIR / "tracking_s3_info.yaml")
    sol = solve_grid(model, 20)
    assert np.allclose(sol.q_values(sol.beliefs), sol.Q, atol=1e-9)
    fine = solve_grid(model, 60)  # most n = 60 grid beliefs are off the n = 20 grid
    B = fine.beliefs[::7]
    assert np.mean(sol.grid.index_of(B) < 0) > 0.8
    err = sol.q_values(B) - fine.Q[::7]
    assert np.max(np.abs(err.max(1) - err.min(1))) < 0.01


def linear_model(S: int, gamma: float, seed: int, A: int = 3) -> POMDP:
    rng = np.random.default_rng(seed)
    P = tracking_transitions(S, A, np.arange(1, S + 1) * 0.8, np.linspace(-4.0, -0.5, S * A))
    O = tracking_observations(S, A, 0.8)
    return POMDP(P=P, O=O, r=rng.uniform(0, 2, (S, A)), gamma=gamma, name=f"linear_s{S}")


def test_grid_converges_to_the_exact_solution_for_linear_rewards():
    """V_n -> V* (alpha vectors) as n grows, and V_n >= V* (convex V*, interpolation from above)."""
    model = linear_model(3, gamma=0.8, seed=1)
    exact = alpha_vector_value_iteration(model, horizon=90)  # 0.8^90 ~ 2e-9
    assert exact.error_bound < 1e-7
    errs = []
    for n in (5, 10, 20, 40):
        sol = solve_grid(model, n)
        v_star = exact.value(sol.beliefs)
        assert np.all(sol.V >= v_star - 2 * exact.error_bound - 1e-9)
        errs.append(float(np.max(np.abs(sol.V - v_star))))
    assert all(e2 < e1 for e1, e2 in itertools.pairwise(errs))
    assert errs[-1] < 0.25 * errs[0]


def test_grid_actions_agree_with_exact_actions_away_from_ties_s2():
    model = linear_model(2, gamma=0.9, seed=1)
    exact = alpha_vector_value_iteration(model, horizon=200)
    assert len(exact.alphas) >= 3  # a value function with kinks, not a single plane
    ref = reference_policy(model, 200)
    gap = ref.fine.V - exact.value(ref.fine.beliefs)  # interpolation error: small, from above
    assert np.all(gap >= -2 * exact.error_bound) and np.max(gap) < 1e-3
    actions, certified, q_exact = certified_actions(exact, ref.beliefs)
    both = ref.decided & certified
    assert both.mean() > 0.9
    assert np.array_equal(ref.actions[both], actions[both])
    # and the margin is honest: Q differences are within it everywhere
    err = ref.Q - q_exact
    assert np.max(err.max(1) - err.min(1)) <= ref.tie_margin + 2 * exact.error_bound


def test_grid_s4_agrees_with_exact_for_linear_rewards():
    model = linear_model(4, gamma=0.75, seed=3, A=2)
    exact = alpha_vector_value_iteration(model, horizon=60)
    ref = reference_policy(model, 8)
    actions, certified, _ = certified_actions(exact, ref.beliefs)
    both = ref.decided & certified
    assert both.mean() > 0.8
    assert np.array_equal(ref.actions[both], actions[both])


# ------------------------------------------------------------------ alpha vectors
@pytest.mark.parametrize(("S", "A", "H"), [(2, 3, 5), (3, 2, 4), (4, 2, 4)])
def test_alpha_vectors_match_expectimax_tree(S, A, H):
    model = linear_model(S, gamma=0.9, seed=S, A=A)
    sol = alpha_vector_value_iteration(model, H)
    # The tree starts from V_0 = 0, the alpha vectors from the constant v0; a constant passes
    # through H discounted backups unchanged except for the factor gamma^H.
    rmin, rmax = model.r.min(), model.r.max()
    v0 = 0.5 * (rmin + rmax) / (1 - model.gamma)
    rng = np.random.default_rng(H)
    for b in rng.dirichlet(np.ones(S), size=6):
        expected = tree_q(model, b, H) + model.gamma**H * v0
        assert np.allclose(sol.q_values(b[None])[0], expected, atol=1e-9)


def test_pruning_keeps_the_upper_envelope():
    rng = np.random.default_rng(11)
    for S in (2, 3, 4):
        V = rng.normal(size=(60, S))
        P, _ = prune_alpha_vectors(V)
        assert 0 < len(P) < len(V)
        B = np.vstack([np.eye(S), rng.dirichlet(np.ones(S), size=3000)])
        assert np.allclose((B @ P.T).max(1), (B @ V.T).max(1), atol=1e-12)
        # every kept vector is needed: removing it lowers the envelope somewhere (LP witness)
        for i in range(len(P)):
            rest = np.delete(P, i, axis=0)
            delta, _ = _witness_lp(P[i], rest)
            assert delta > 0


def test_alpha_vector_solver_rejects_nonlinear_rewards():
    model = small_tracking(2, "renyi2", gamma=0.5)
    with pytest.raises(ValueError, match="belief-linear"):
        alpha_vector_value_iteration(model, 3)


def test_certified_actions_are_stable_in_the_horizon():
    """The action certified at horizon H is the action at horizon 2H (finite-horizon policy converged)."""
    model = linear_model(4, gamma=0.75, seed=2)
    B = np.random.default_rng(0).dirichlet(np.ones(4), size=200)
    s1 = alpha_vector_value_iteration(model, 30)
    s2 = alpha_vector_value_iteration(model, 60)
    a1, c1, _ = certified_actions(s1, B)
    a2, _, _ = certified_actions(s2, B)
    assert c1.mean() > 0.9
    assert np.array_equal(a1[c1], a2[c1])


@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
def test_reference_bayes_update_and_reward_agree_with_the_package(uncertainty):
    """The reference re-derives Eqs. 1-3 so as not to rest on the code it validates; the two
    derivations agree (beliefs with zeros, vertices, and zero-probability observations)."""
    from pomdp_planner.core.belief import posteriors_all
    from pomdp_planner.core.reference import _belief_reward, _posteriors

    model = small_tracking(3, uncertainty, 0.9, seed=4)
    O = model.O.copy()
    O[0, :, 0] = 0.0  # after action 0, observation 0 is impossible from every state
    O[0] /= O[0].sum(axis=1, keepdims=True)
    model = POMDP(P=model.P, O=O, r=model.r, gamma=model.gamma, uncertainty=uncertainty, w=model.w)
    rng = np.random.default_rng(0)
    B = np.vstack([np.eye(3), rng.dirichlet(np.full(3, 0.3), size=200), [[0.5, 0.5, 0.0]]])
    tau, eta = _posteriors(model, B)
    tau_p, eta_p = posteriors_all(model, B)
    assert np.allclose(eta, eta_p, atol=1e-15)
    ok = eta > 1e-12
    assert not ok[:, 0, 0].any() and ok[:, 1].all()
    assert np.allclose(tau[ok], tau_p[ok], atol=1e-12)
    assert np.allclose(_belief_reward(model, B), model.rho(B), atol=1e-12)
