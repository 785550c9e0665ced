"""Uncertainty functions f(b) of Eq. 3: values, zero entries, gradients, vectorisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.uncertainty import NONE, RENYI2, SHANNON, UNCERTAINTY_FUNCTIONS, get_uncertainty


def shannon_plain(b):
    return -sum(p * math.log(p) for p in b if p > 0)


def renyi2_plain(b):
    return -math.log(sum(p * p for p in b))


def beliefs(min_size=2, max_size=6, interior=False):
    lo = 0.05 if interior else 0.0
    return st.lists(st.floats(lo, 1.0), min_size=min_size, max_size=max_size).filter(
        lambda v: sum(v) > 0.1).map(lambda v: np.asarray(v) / sum(v))


@settings(max_examples=100, deadline=None)
@given(beliefs())
def test_values_match_plain_formulas_including_zeros(b):
    assert SHANNON(b) == pytest.approx(shannon_plain(b), abs=1e-12)
    assert RENYI2(b) == pytest.approx(renyi2_plain(b), abs=1e-12)
    assert NONE(b) == 0.0
    assert np.isfinite(SHANNON.gradient(b)).all() and np.isfinite(RENYI2.gradient(b)).all()


@settings(max_examples=60, deadline=None)
@given(beliefs(interior=True))
def test_gradients_against_finite_differences(b):
    h = 1e-6
    for f in (SHANNON, RENYI2, NONE):
        g = f.gradient(b)
        fd = np.empty_like(b)
        for i in range(b.size):
            e = np.zeros_like(b)
            e[i] = h
            fd[i] = (float(f(b + e)) - float(f(b - e))) / (2 * h)
        np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-6, err_msg=f.name)


@settings(max_examples=40, deadline=None)
@given(beliefs(min_size=3, max_size=3), beliefs(min_size=3, max_size=3), st.floats(0, 1))
def test_concave_on_the_simplex(b1, b2, lam):
    """Shannon entropy is concave (paper Definition 1). Renyi quadratic entropy is only
    quasi-concave for S >= 3 (``sum b^2`` is convex, so ``-log sum b^2`` of a mixture is at
    least the smaller of the two values); see the next test for a concavity counterexample."""
    mix = lam * b1 + (1 - lam) * b2
    assert float(SHANNON(mix)) >= lam * float(SHANNON(b1)) + (1 - lam) * float(SHANNON(b2)) - 1e-12
    assert float(RENYI2(mix)) >= min(float(RENYI2(b1)), float(RENYI2(b2))) - 1e-12


@settings(max_examples=40, deadline=None)
@given(st.floats(0, 1), st.floats(0, 1), st.floats(0, 1))
def test_renyi2_is_concave_for_two_states(p1, p2, lam):
    b1, b2 = np.array([p1, 1 - p1]), np.array([p2, 1 - p2])
    mix = lam * b1 + (1 - lam) * b2
    assert float(RENYI2(mix)) >= lam * float(RENYI2(b1)) + (1 - lam) * float(RENYI2(b2)) - 1e-12


def test_renyi2_is_not_concave_for_three_states():
    """The paper calls every uncertainty function concave (Definition 1) and uses Renyi quadratic
    entropy (Example 3); for S = 3 it is not concave: midpoint of e_2 and (1/6, 2/3, 1/6)."""
    b1, b2 = np.array([0.0, 1.0, 0.0]), np.array([1 / 6, 2 / 3, 1 / 6])
    mix = 0.5 * (b1 + b2)
    assert float(RENYI2(mix)) < 0.5 * (float(RENYI2(b1)) + float(RENYI2(b2))) - 1e-3


def test_vertices_uniform_and_zero_entries():
    S = 4
    for s in range(S):
        e = np.eye(S)[s]
        assert SHANNON(e) == 0.0 and RENYI2(e) == 0.0
        assert not np.isnan(SHANNON.gradient(e)).any()
    u = np.full(S, 1 / S)
    assert SHANNON(u) == pytest.approx(math.log(S), abs=1e-14)
    assert RENYI2(u) == pytest.approx(math.log(S), abs=1e-14)
    b = np.array([0.5, 0.0, 0.5, 0.0])
    assert SHANNON(b) == pytest.approx(math.log(2), abs=1e-15)
    g = SHANNON.gradient(b)
    assert np.isfinite(g).all() and g[1] > 100  # unbounded derivative at 0 evaluated at a tiny value


def test_vectorised_over_batches():
    rng = np.random.default_rng(1)
    B = rng.dirichlet(np.ones(5), size=(4, 3))
    B[0, 0] = [0, 0, 1, 0, 0]
    for f in (SHANNON, RENYI2, NONE):
        vals = f(B)
        grads = f.gradient(B)
        assert vals.shape == (4, 3) and grads.shape == (4, 3, 5)
        for i in range(4):
            for j in range(3):
                assert vals[i, j] == pytest.approx(float(f(B[i, j])), abs=1e-14)
                np.testing.assert_allclose(grads[i, j], f.gradient(B[i, j]), rtol=0, atol=1e-12)


def test_registry_and_unknown_name():
    assert set(UNCERTAINTY_FUNCTIONS) == {"shannon", "renyi2", "none"}
    assert get_uncertainty("renyi2") is RENYI2
    with pytest.raises(ValueError, match=r"uncertainty.function: unknown function 'entropy'"):
        get_uncertainty("entropy")
