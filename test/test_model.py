"""The POMDP model object: validation errors, immutability, rho (Eq. 3) and its gradient."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pomdp_planner.core.errors import BeliefError
from pomdp_planner.core.model import POMDP, STOCHASTIC_ATOL, ModelError, action_of_priority, priority_of


def base(**overrides):
    """A valid 2-action, 2-state, 3-observation model's keyword arguments."""
    kw = dict(
        P=np.array([[[0.9, 0.1], [0.2, 0.8]], [[0.5, 0.5], [0.0, 1.0]]]),
        O=np.array([[[0.7, 0.2, 0.1], [0.1, 0.2, 0.7]], [[1 / 3, 1 / 3, 1 / 3], [0.0, 0.5, 0.5]]]),
        r=np.array([[1.0, 2.0], [3.0, -4.0]]),
        gamma=0.9,
        uncertainty="renyi2",
        w=[0.5, 1.5],
    )
    kw.update(overrides)
    return kw


def test_valid_model_sizes_and_immutability():
    m = POMDP(**base(state_names=["lo", "hi"]))
    assert (m.S, m.A, m.Z) == (2, 2, 3)
    assert (m.num_states, m.num_actions, m.num_observations) == (2, 2, 3)
    assert m.state_names == ("lo", "hi") and m.action_names is None
    for arr in (m.P, m.O, m.r, m.w):
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[0] = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.gamma = 0.5
    # the model copies its inputs: changing the caller's array does not change the model
    P = base()["P"].copy()
    m2 = POMDP(**base(P=P))
    P[0, 0, 0] = 0.0
    assert m2.P[0, 0, 0] == 0.9
    assert "S=2 A=2 Z=3" in m.describe()


P0 = base()["P"]
O0 = base()["O"]


@pytest.mark.parametrize(("overrides", "pattern"), [
    (dict(P=np.ones((2, 2))), r"transition: expected shape A x S x S"),
    (dict(P=np.ones((2, 2, 3)) / 3), r"transition: expected shape A x S x S"),
    (dict(P=np.zeros((0, 2, 2))), r"transition: needs at least one action"),
    (dict(O=np.ones((2, 3, 3)) / 3), r"observation: expected shape 2 x 2 x Z"),
    (dict(O=np.ones((2, 2, 0))), r"observation: needs at least one observation"),
    (dict(r=np.ones((2, 3))), r"reward: expected shape 2 x 2 \(S x A\)"),
    (dict(P=np.where(np.arange(2)[:, None, None] == 1, np.nan, P0)), r"transition\[1\]\[0\]\[0\]: value is not finite"),
    (dict(P=P0 * np.array([1, -1])[None, None, :]), r"transition\[0\]\[0\]\[1\]: probability is negative"),
    (dict(P=P0 + np.array([[[0, 0], [0, 0]], [[0, 0], [0, 0.01]]])),
     r"transition\[1\]\[1\]: row \(previous state 1, action 1\) sums to 1.01"),
    (dict(O=O0 + np.array([0, 0, 0.001])[None, None, :] * np.array([[[1], [0]], [[0], [0]]])),
     r"observation\[0\]\[0\]: row \(next state 0, action 0\) sums to 1.001"),
    (dict(r=np.array([[1.0, np.inf], [0, 0]])), r"reward\[0\]\[1\]: value is not finite"),
    (dict(gamma=1.5), r"discount: must satisfy 0 <= gamma <= 1 \(1: a finite horizon only\), got 1.5"),
    (dict(gamma=-0.1), r"discount: must satisfy 0 <= gamma <= 1"),
    (dict(gamma=float("nan")), r"discount: must be a finite number"),
    (dict(gamma="fast"), r"discount: must be a number"),
    (dict(w=[1.0, 2.0, 3.0]), r"uncertainty.weights: expected 2 weights"),
    (dict(w=[1.0, np.nan]), r"uncertainty.weights\[1\]: weight is not finite"),
    (dict(w=["a", 1]), r"uncertainty.weights\[0\]: must be a number, got a string 'a'"),
    (dict(epsilon=0.5), r"uncertainty.epsilon: must satisfy 0 < epsilon < 1/S = 0.5"),
    (dict(epsilon="x"), r"uncertainty.epsilon: must be a number"),
    (dict(uncertainty="tsallis"), r"uncertainty.function: unknown function 'tsallis'"),
    (dict(state_names=["a"]), r"states: 1 names given for 2 entries"),
    (dict(observation_names=["x", "y", "x"]), r"observations: names are not unique"),
    (dict(P=[[["a", "b"]]]), r"model matrices must be numeric"),
])
def test_validation_errors_name_the_field(overrides, pattern):
    with pytest.raises(ModelError, match=pattern):
        POMDP(**base(**overrides))


def test_row_sum_tolerance_is_the_documented_one():
    P = P0.copy()
    P[0, 0] = [0.9 + STOCHASTIC_ATOL / 2, 0.1]
    POMDP(**base(P=P))
    P[0, 0] = [0.9 + STOCHASTIC_ATOL * 2, 0.1]
    with pytest.raises(ModelError, match=r"transition\[0\]\[0\]"):
        POMDP(**base(P=P))


def test_scalar_weight_broadcasts_and_default_weights_are_zero():
    assert POMDP(**base(w=2.0)).w.tolist() == [2.0, 2.0]
    assert POMDP(**base(w=None, uncertainty="none")).w.tolist() == [0.0, 0.0]


def test_rho_matches_eq3_written_out():
    m = POMDP(**base())
    for b in ([0.3, 0.7], [1.0, 0.0], [0.5, 0.5]):
        renyi = -math.log(sum(p * p for p in b))
        for a in range(2):
            expected = sum(m.r[s, a] * b[s] for s in range(2)) - m.w[a] * renyi
            assert m.rho(np.array(b))[a] == pytest.approx(expected, abs=1e-14)
    B = np.array([[0.3, 0.7], [0.9, 0.1]])
    assert m.rho(B).shape == (2, 2)
    np.testing.assert_allclose(m.rho(B), np.stack([m.rho(b) for b in B]), rtol=0, atol=1e-15)
    linear = POMDP(**base(uncertainty="none"))
    np.testing.assert_allclose(linear.rho(B), B @ linear.r, rtol=0, atol=1e-15)


@pytest.mark.parametrize("unc", ["shannon", "renyi2", "none"])
def test_rho_gradient_against_finite_differences(unc):
    m = POMDP(**base(uncertainty=unc))
    rng = np.random.default_rng(0)
    B = rng.dirichlet(np.ones(2), size=5) * 0.9 + 0.05
    G = m.rho_gradient(B)
    assert G.shape == (5, 2, 2)
    h = 1e-6
    for n, b in enumerate(B):
        for s in range(2):
            e = np.zeros(2)
            e[s] = h
            fd = (m.rho(b + e) - m.rho(b - e)) / (2 * h)  # (A,)
            np.testing.assert_allclose(G[n, :, s], fd, rtol=1e-6, atol=1e-7)


def test_priorities():
    assert priority_of(0) == 1 and priority_of(2) == 3
    np.testing.assert_array_equal(priority_of(np.array([0, 1])), [1, 2])
    assert [action_of_priority(p, 3) for p in (1, 2, 3)] == [0, 1, 2]
    for p in (0, 4, -1, 1.0, "1", True):
        with pytest.raises(BeliefError, match=r"action: priority: must be an integer in 1\.\.3, got"):
            action_of_priority(p, 3)
