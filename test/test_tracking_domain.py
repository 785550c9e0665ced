"""The Sec. VI tracking generator against the paper's formulas evaluated independently here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pomdp_planner.core.domains.tracking import (
    comparison_reward,
    default_x,
    default_y,
    tracking_model,
    tracking_observations,
    tracking_transitions,
)
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import ModelError

PAPER_X = [1, 2, 3]
PAPER_Y = [-9, -8, -7, -6, -5, -4, -3, -2, -1]


def paper_transitions(S, A, x, y):
    """Sec. VI, literally: A_ij = exp(x_i y_j) (i = 1..S, j = 1..SA), each column normalised to
    sum to one, T^a = columns (a-1)S+1 .. aS. A column of T^a is the next-state distribution
    given the previous state (paper Sec. II: previous states column-wise), so in our convention
    P[a][prev][next] = T^a[next][prev]."""
    K = [[math.exp(x[i] * y[j]) for j in range(S * A)] for i in range(S)]
    for j in range(S * A):
        col = sum(K[i][j] for i in range(S))
        for i in range(S):
            K[i][j] /= col
    P = np.zeros((A, S, S))
    for a in range(1, A + 1):
        T = [[K[i][j] for j in range((a - 1) * S, a * S)] for i in range(S)]   # T^a (S x S)
        for prev in range(S):
            for nxt in range(S):
                P[a - 1, prev, nxt] = T[nxt][prev]
    return P


def paper_observations(S, q):
    """Eq. 9 with the paper's typo "i != S" read as "j != S": O^a_{z,j}; returned as O[j][z]."""
    O = np.zeros((S, S))
    for j in range(1, S + 1):
        for z in range(1, S + 1):
            if z == j:
                v = q
            elif abs(z - j) == 1:
                v = (1 - q) if j in (1, S) else (1 - q) / 2
            else:
                v = 0.0
            O[j - 1, z - 1] = v
    return O


def test_paper_s3_transitions_given_sequences():
    expected = paper_transitions(3, 3, PAPER_X, PAPER_Y)
    np.testing.assert_allclose(tracking_transitions(3, 3, PAPER_X, PAPER_Y), expected, rtol=1e-12, atol=1e-15)


def test_default_sequences_are_the_papers_for_s3():
    np.testing.assert_allclose(default_x(3), PAPER_X, rtol=0, atol=1e-15)
    np.testing.assert_allclose(default_y(3, 3), PAPER_Y, rtol=0, atol=1e-15)
    expected = paper_transitions(3, 3, PAPER_X, PAPER_Y)
    np.testing.assert_allclose(tracking_transitions(3, 3), expected, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize(("S", "A"), [(2, 2), (4, 3), (8, 3), (5, 1)])
def test_default_sequences_any_size(S, A):
    x, y = default_x(S), default_y(S, A)
    assert x.shape == (S,) and y.shape == (S * A,)
    assert np.all(np.diff(x) > 0) and np.all(np.diff(y) > 0)
    assert x[-1] == pytest.approx(3.0) and y[0] == pytest.approx(-9.0) and y[-1] == pytest.approx(-1.0)
    np.testing.assert_allclose(tracking_transitions(S, A), paper_transitions(S, A, list(x), list(y)),
                               rtol=1e-11, atol=1e-15)


def test_transitions_are_tp2_and_move_up_with_lower_priority():
    P = tracking_transitions(3, 3, PAPER_X, PAPER_Y)
    for a in range(3):
        for i in range(3):
            for j in range(i + 1, 3):
                for k in range(3):
                    for l in range(k + 1, 3):
                        assert P[a, i, k] * P[a, j, l] - P[a, i, l] * P[a, j, k] >= -1e-15
    # lower priority (larger a): probability of the dangerous state grows
    assert np.all(np.diff(P[:, :, -1], axis=0) > 0)


def test_large_sizes_do_not_underflow():
    P = tracking_transitions(256, 4)
    assert np.isfinite(P).all() and np.allclose(P.sum(axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize(("S", "q"), [(3, 0.7), (2, 0.8), (6, 0.55), (1, 0.9)])
def test_observations_eq9(S, q):
    O = tracking_observations(S, 2, q)
    assert O.shape == (2, S, S)
    expected = np.ones((1, 1)) if S == 1 else paper_observations(S, q)
    for a in range(2):
        np.testing.assert_allclose(O[a], expected, rtol=0, atol=1e-15)


def test_paper_s3_observation_matrix_written_out():
    O = tracking_observations(3, 3, 0.7)
    np.testing.assert_allclose(O[0], [[0.7, 0.3, 0.0], [0.15, 0.7, 0.15], [0.0, 0.3, 0.7]], rtol=0, atol=1e-15)


def test_comparison_reward_by_hand_s10_a2():
    # S = 10, A = 2: c_a = 1/4, c_p = 1, c_d = 0.1, k_r = 2/10; S_p = {s <= 2}, S_d = {s >= 9}.
    r = comparison_reward(10, 2)
    t = {1: -1.0, 2: -0.5, 9: -0.1 / 2, 10: -0.1 / 1}
    for s in range(1, 11):
        ts = t.get(s, 0.2 * s)
        for a in (1, 2):
            expected = -0.25 * (2 - a + 1) + ts
            assert r[s - 1, a - 1] == pytest.approx(expected, abs=1e-15), (s, a)


def test_comparison_reward_constants_override():
    r = comparison_reward(5, 3, c_a=1.0, c_p=2.0, c_d=3.0, k_r=0.5)
    # S = 5: S_p = {1}, S_d = {s >= 4.5} = {5}
    t = [-2.0, 1.0, 1.5, 2.0, -3.0]
    for s in range(5):
        for a in range(3):
            assert r[s, a] == pytest.approx(-1.0 * (3 - (a + 1) + 1) + t[s], abs=1e-15)


def test_shipped_s3_model_is_the_paper_problem():
    m = load_model("config/models/tracking_s3_info.yaml")
    np.testing.assert_allclose(m.P, paper_transitions(3, 3, PAPER_X, PAPER_Y), rtol=1e-12, atol=1e-15)
    for a in range(3):
        np.testing.assert_allclose(m.O[a], paper_observations(3, 0.7), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(m.r, [[2, 2.5, 1], [1.1, 1.2, 0.5], [0.3, 2, 0.2]])
    np.testing.assert_array_equal(m.w, [1.1, 1.6, 1.0])
    assert m.uncertainty.name == "renyi2" and m.gamma == 0.99


def test_tracking_model_and_errors():
    m = tracking_model(4, 2, 0.8, r=comparison_reward(4, 2))
    assert (m.S, m.A, m.Z) == (4, 2, 4) and m.metadata["generator"]["q"] == 0.8
    with pytest.raises(ModelError, match=r"generator.x: expected 3 values"):
        tracking_transitions(3, 2, x=[1, 2])
    with pytest.raises(ModelError, match=r"generator.y: expected S\*A = 6 values"):
        tracking_transitions(3, 2, y=[1, 2, 3])
    with pytest.raises(ModelError, match="strictly increasing"):
        tracking_transitions(3, 1, x=[1, 1, 2])
    for q in (0.0, 1.5, -0.1):
        with pytest.raises(ModelError, match=r"generator.q: observation accuracy must be in \(0, 1\]"):
            tracking_observations(3, 1, q)
