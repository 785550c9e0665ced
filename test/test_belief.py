"""Bayes filter (Eqs. 1, 2) against a brute-force joint-table computation; simplex; errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.belief import (
    BeliefError,
    ImpossibleObservation,
    check_belief,
    check_belief_rows,
    observation_probabilities,
    posteriors_all,
    predict,
    predict_all,
    start_belief,
    uniform_belief,
    update,
    update_batch,
)
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP, ModelError


def random_model(rng, S, A, Z, zero_frac=0.3):
    def stoch(shape):
        M = rng.random(shape)
        M[rng.random(shape) < zero_frac] = 0.0
        M[M.sum(axis=-1) == 0, 0] = 1.0
        return M / M.sum(axis=-1, keepdims=True)

    return POMDP(P=stoch((A, S, S)), O=stoch((A, S, Z)), r=rng.normal(size=(S, A)), gamma=0.9)


def bayes_brute_force(model, b, a, z):
    """Joint table J[s, s', z'] = b(s) P(s'|s,a) O(z'|s',a), then condition on z' = z."""
    S, Z = model.S, model.Z
    J = np.zeros((S, S, Z))
    for s in range(S):
        for s2 in range(S):
            for zz in range(Z):
                J[s, s2, zz] = b[s] * model.P[a, s, s2] * model.O[a, s2, zz]
    eta = J.sum(axis=(0, 1))                 # P(z' | b, a)
    joint_z = J[:, :, z].sum(axis=0)         # P(s', z' = z | b, a)
    return (joint_z / eta[z] if eta[z] > 0 else None), eta


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 5), st.integers(1, 3), st.integers(1, 4), st.integers(0, 2**32 - 1))
def test_update_matches_brute_force_bayes(S, A, Z, seed):
    rng = np.random.default_rng(seed)
    m = random_model(rng, S, A, Z)
    b = rng.dirichlet(np.ones(S))
    if S > 1:
        b[rng.integers(S)] = 0.0
        b = b / b.sum() if b.sum() > 0 else uniform_belief(m)
    tau, eta_all = posteriors_all(m, b)
    for a in range(A):
        np.testing.assert_allclose(predict(m, b, a), b @ m.P[a], rtol=0, atol=1e-15)
        for z in range(Z):
            post, eta = bayes_brute_force(m, b, a, z)
            np.testing.assert_allclose(observation_probabilities(m, b, a)[z], eta[z], rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(eta_all[a, z], eta[z], rtol=1e-12, atol=1e-15)
            if eta[z] > 0:
                np.testing.assert_allclose(update(m, b, a, z), post, rtol=1e-10, atol=1e-13)
                np.testing.assert_allclose(tau[a, z], post, rtol=1e-10, atol=1e-13)
            else:
                with pytest.raises(ImpossibleObservation):
                    update(m, b, a, z)


def test_batch_functions_agree_with_single_ones():
    rng = np.random.default_rng(3)
    m = random_model(rng, 4, 3, 5, zero_frac=0.0)
    B = rng.dirichlet(np.ones(4), size=(2, 6))
    pa = predict_all(m, B)
    assert pa.shape == (2, 6, 3, 4)
    tau, eta = posteriors_all(m, B)
    assert tau.shape == (2, 6, 3, 5, 4) and eta.shape == (2, 6, 3, 5)
    for i in range(2):
        for j in range(6):
            for a in range(3):
                np.testing.assert_allclose(pa[i, j, a], predict(m, B[i, j], a), rtol=0, atol=1e-15)
                for z in range(5):
                    np.testing.assert_allclose(tau[i, j, a, z], update(m, B[i, j], a, z), rtol=1e-12, atol=1e-15)
    flat = B.reshape(-1, 4)
    a = rng.integers(3, size=12)
    z = rng.integers(5, size=12)
    post, eta_b = update_batch(m, flat, a, z)
    for n in range(12):
        np.testing.assert_allclose(post[n], update(m, flat[n], a[n], z[n]), rtol=1e-12, atol=1e-15)
        assert eta_b[n] == pytest.approx(observation_probabilities(m, flat[n], a[n])[z[n]], rel=1e-12)


@pytest.mark.parametrize("source", ["tracking_s8", "random_with_zeros"])
def test_beliefs_stay_on_simplex_after_10000_random_updates(source):
    rng = np.random.default_rng(11)
    if source == "tracking_s8":
        m = load_model("config/models/tracking_s8_info.yaml")
    else:
        m = random_model(rng, 6, 3, 4, zero_frac=0.4)
    N = 32
    B = rng.dirichlet(np.ones(m.S), size=N)
    cumO = np.cumsum(m.O, axis=-1)
    cumP = np.cumsum(m.P, axis=-1)
    states = rng.integers(m.S, size=N)
    T = 10_000
    actions = rng.integers(m.A, size=(T, N))
    u = rng.random((T, 2, N, 1))
    worst_sum = worst_neg = 0.0
    for t in range(T):
        a = actions[t]
        # simulate true states and observations so every observation is possible
        states = np.minimum((cumP[a, states] < u[t, 0]).sum(axis=1), m.S - 1)
        z = np.minimum((cumO[a, states] < u[t, 1]).sum(axis=1), m.Z - 1)
        B, eta = update_batch(m, B, a, z)
        worst_sum = max(worst_sum, float(np.abs(B.sum(axis=1) - 1).max()))
        worst_neg = min(worst_neg, float(B.min()))
        assert np.all(eta > 0)
    assert np.isfinite(B).all()
    assert worst_neg >= 0.0
    assert worst_sum < 1e-12


def test_zero_entries_without_nan():
    P = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]])
    O = np.array([[[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]]])
    m = POMDP(P=P, O=O, r=np.zeros((3, 1)), gamma=0.5)
    b = np.array([0.0, 0.5, 0.5])
    np.testing.assert_allclose(update(m, b, 0, 1), [0.0, 1 / 3, 2 / 3], rtol=0, atol=1e-15)
    tau, eta = posteriors_all(m, np.array([[1.0, 0.0, 0.0], b]))
    assert np.isfinite(tau).all() and np.isfinite(eta).all()
    assert eta[0, 0, 1] == 0.0
    np.testing.assert_array_equal(tau[0, 0, 1], [1.0, 0.0, 0.0])  # predicted belief where undefined
    post, eta_b = update_batch(m, np.array([[1.0, 0.0, 0.0]]), np.array([0]), np.array([1]))
    assert eta_b[0] == 0.0 and np.isfinite(post).all()


def test_impossible_observation_carries_eta_and_predicted_belief():
    P = np.array([[[0.0, 1.0], [0.0, 1.0]]])   # always moves to state 1
    O = np.array([[[1.0, 0.0], [0.0, 1.0]]])   # perfect sensor
    m = POMDP(P=P, O=O, r=np.zeros((2, 1)), gamma=0.5)
    with pytest.raises(ImpossibleObservation) as info:
        update(m, np.array([0.7, 0.3]), 0, 0)
    err = info.value
    assert err.eta == 0.0 and err.action == 0 and err.observation == 0
    np.testing.assert_array_equal(err.predicted, [0.0, 1.0])
    assert "priority 1" in str(err)


@pytest.mark.parametrize("bad_a", [-1, 2, 1.0, True, "0", None])
def test_action_out_of_range_raises_belief_error(bad_a):
    m = random_model(np.random.default_rng(0), 3, 2, 2)
    b = uniform_belief(m)
    for fn in (lambda: predict(m, b, bad_a), lambda: update(m, b, bad_a, 0),
               lambda: observation_probabilities(m, b, bad_a)):
        with pytest.raises(BeliefError, match="action: must be an integer in"):
            fn()


@pytest.mark.parametrize("bad_z", [-1, 2, 0.5, False])
def test_observation_out_of_range_raises_belief_error(bad_z):
    m = random_model(np.random.default_rng(0), 3, 2, 2)
    with pytest.raises(BeliefError, match="observation: must be an integer in"):
        update(m, uniform_belief(m), 0, bad_z)


def test_update_batch_index_errors():
    m = random_model(np.random.default_rng(0), 3, 2, 2)
    B = np.full((2, 3), 1 / 3)
    with pytest.raises(BeliefError, match=r"action: indices out of range 0\.\.1"):
        update_batch(m, B, np.array([0, 2]), np.array([0, 0]))
    with pytest.raises(BeliefError, match=r"observation: indices out of range 0\.\.1"):
        update_batch(m, B, np.array([0, 1]), np.array([0, -1]))


@pytest.mark.parametrize(("b", "pattern"), [
    ([0.5, 0.5], "expected 3 probabilities"),
    ([0.5, np.nan, 0.5], "non-finite"),
    ([0.5, -0.1, 0.6], "entry 1 is negative"),
    ([0.5, 0.5, 0.5], "sums to 1.5"),
])
def test_check_belief_errors(b, pattern):
    m = random_model(np.random.default_rng(0), 3, 2, 2)
    with pytest.raises(BeliefError, match=pattern):
        check_belief(m, np.array(b))


@pytest.mark.parametrize("S", [2, 3, 8, 9, 33])
def test_checking_rows_at_once_equals_checking_each(S):
    """``check_belief_rows``: the same arrays as ``check_belief`` on each row, bit for bit."""
    rng = np.random.default_rng(S)
    for _ in range(50):
        rows = rng.dirichlet(np.ones(S) * rng.choice([0.1, 1.0, 10.0]), size=int(rng.integers(1, 12)))
        rows += rng.normal(scale=1e-8, size=rows.shape) * (rng.random() < 0.5)  # within the tolerance
        rows[:, 0] = np.maximum(rows[:, 0], 0.0)
        want = np.array([check_belief(S, b) for b in rows])
        np.testing.assert_array_equal(check_belief_rows(S, list(rows), [f"b[{i}]" for i in range(len(rows))]), want)


@pytest.mark.parametrize("bad, pattern", [
    ([0.5, 0.5], r"^b\[1\]: expected 3 probabilities"),
    ([0.5, np.nan, 0.5], r"^b\[1\]: contains non-finite"),
    ([0.5, -0.1, 0.6], r"^b\[1\]: entry 1 is negative"),
    ([0.5, 0.5, 0.5], r"^b\[1\]: sums to 1.5"),
])
def test_checking_rows_at_once_names_the_first_bad_row(bad, pattern):
    rows = [[0.2, 0.3, 0.5], bad, [0.5, 0.5, 0.5]]
    with pytest.raises(BeliefError, match=pattern):
        check_belief_rows(3, rows, ["b[0]", "b[1]", "b[2]"])


def test_check_belief_renormalises_tiny_errors():
    m = random_model(np.random.default_rng(0), 3, 2, 2)
    b = check_belief(m, np.array([0.5, -1e-9, 0.5 + 2e-9]))
    assert b.min() >= 0 and b.sum() == pytest.approx(1.0, abs=1e-15)


def test_start_belief_forms():
    kw = dict(P=np.ones((1, 3, 3)) / 3, O=np.ones((1, 3, 1)), r=np.zeros((3, 1)), gamma=0.5,
              state_names=["a", "b", "c"])
    assert start_belief(POMDP(**kw)) is None
    np.testing.assert_allclose(start_belief(POMDP(**kw, metadata={"start": "uniform"})), 1 / 3)
    np.testing.assert_array_equal(start_belief(POMDP(**kw, metadata={"start": "b"})), [0, 1, 0])
    np.testing.assert_allclose(start_belief(POMDP(**kw, metadata={"start": [0.2, 0.3, 0.5]})), [0.2, 0.3, 0.5])
    for bad, pattern in ((["x", 1, 2], "start: expected a list of 3 numbers"), ([0.5, 0.5], "start: expected 3"),
                         ("d", "start: expected a list of 3 probabilities, 'uniform' or a state name")):
        with pytest.raises(ModelError, match=pattern):
            start_belief(POMDP(**kw, metadata={"start": bad}))
