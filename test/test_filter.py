"""The per-epoch belief filter (core/filter.py): Eqs. 1-2 per epoch, several sensors, recovery, gaps.

Expected beliefs come from an independent computation: Bayes' rule written out as sums over the
joint distribution of (previous state, next state, readings), or fractions worked out by hand.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pomdp_planner.core.belief import BeliefError
from pomdp_planner.core.filter import EpochFilter
from pomdp_planner.core.model import POMDP, ModelError

# S = 3, one action. State 0 is absorbing, so a belief on state 0 predicts state 0 only.
P_HAND = np.array([[[1.0, 0.0, 0.0], [0.25, 0.5, 0.25], [0.0, 0.5, 0.5]]])
# Sensor 0 never reads 1 in state 0; sensor 1 is uninformative about states 0 and 1.
O_HAND = np.array([[[1.0, 0.0], [0.6, 0.4], [0.2, 0.8]]])
O2_HAND = np.array([[[0.5, 0.5], [0.5, 0.5], [0.9, 0.1]]])
O_NEVER_1 = np.array([[[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]]])  # reading 1 is impossible from every state


def hand_model() -> POMDP:
    return POMDP(P=P_HAND, O=O_HAND, r=np.zeros((3, 1)), gamma=0.5)


def bayes_by_sums(P, sensors, b, a, readings):
    """Posterior over the next state by summing the joint P(s, s', z_1..z_n) (independent formula)."""
    S = len(b)
    joint = np.zeros(S)
    for s in range(S):
        for s2 in range(S):
            p = b[s] * P[a, s, s2]
            for k, z in readings.items():
                p *= sensors[k][a, s2, z]
            joint[s2] += p
    return joint / joint.sum()


def random_rows(draw, shape):
    x = draw(arrays(float, shape, elements=st.floats(0.05, 1.0)))
    return x / x.sum(axis=-1, keepdims=True)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_epoch_is_bayes_rule_for_any_order_of_independent_readings(data):
    S, A = data.draw(st.integers(2, 4)), data.draw(st.integers(1, 3))
    P = random_rows(data.draw, (A, S, S))
    sensors = [random_rows(data.draw, (A, S, data.draw(st.integers(2, 4))))
               for _ in range(data.draw(st.integers(1, 3)))]
    model = POMDP(P=P, O=sensors[0], r=np.zeros((S, A)), gamma=0.5)
    b = random_rows(data.draw, (S,))
    a = data.draw(st.integers(0, A - 1))
    readings = {k: data.draw(st.integers(0, O.shape[2] - 1)) for k, O in enumerate(sensors)}
    step = EpochFilter(model, sensors).step(b, a, readings)
    assert step.predicted and step.restarted == () and step.dropped == ()
    np.testing.assert_allclose(step.belief, bayes_by_sums(P, sensors, b, a, readings), rtol=1e-10, atol=1e-13)
    # the sensors in the reverse order (their readings with them): the same belief
    rev = EpochFilter(model, sensors[::-1]).step(b, a, {len(sensors) - 1 - k: z for k, z in readings.items()})
    np.testing.assert_allclose(rev.belief, step.belief, rtol=1e-10, atol=1e-13)


def test_impossible_reading_restarts_from_the_uniform_prior_pushed_through_the_transition():
    flt = EpochFilter(hand_model())
    step = flt.step(np.array([1.0, 0.0, 0.0]), 0, {0: 1})
    # prediction [1, 0, 0]; reading 1 has likelihood [0, 0.4, 0.8]: eta = 0. Restart:
    # u @ P = [1.25, 1.0, 0.75] / 3; times [0, 0.4, 0.8] = [0, 0.4, 0.6] / 3 -> [0, 0.4, 0.6]
    np.testing.assert_allclose(step.belief, [0.0, 0.4, 0.6], rtol=1e-12)
    assert step.restarted == (0,) and step.dropped == () and step.predicted
    # not the likelihood alone ([0, 1/3, 2/3], the transition ignored), not the prediction ([1, 0, 0])


def test_restart_keeps_the_epochs_other_readings_whatever_their_order():
    model = hand_model()
    # sensor O_HAND reads 1 (impossible under [1, 0, 0]), sensor O2_HAND reads 0 (possible).
    # Restart with both: [1.25, 1.0, 0.75] / 3 * [0, 0.4, 0.8] * [0.5, 0.5, 0.9] = [0, 0.2, 0.54] / 3
    expected = np.array([0.0, 0.2, 0.54]) / 0.74
    b = np.array([1.0, 0.0, 0.0])
    first = EpochFilter(model, [O_HAND, O2_HAND]).step(b, 0, {0: 1, 1: 0})   # impossible one first
    second = EpochFilter(model, [O2_HAND, O_HAND]).step(b, 0, {0: 0, 1: 1})  # possible one first
    np.testing.assert_allclose(first.belief, expected, rtol=1e-12)
    np.testing.assert_allclose(second.belief, expected, rtol=1e-12)
    assert first.restarted == (0,) and second.restarted == (1,)


def test_reading_that_contradicts_the_model_is_dropped_and_the_rest_applied():
    model = hand_model()
    flt = EpochFilter(model, [O_NEVER_1, O2_HAND])
    b = np.array([0.2, 0.3, 0.5])
    predicted = np.array([0.2 + 0.3 * 0.25, 0.3 * 0.5 + 0.5 * 0.5, 0.3 * 0.25 + 0.5 * 0.5])  # b @ P by hand
    step = flt.step(b, 0, {0: 1})
    assert step.dropped == (0,) and step.restarted == ()
    np.testing.assert_allclose(step.belief, predicted, rtol=1e-12)
    both = flt.step(b, 0, {0: 1, 1: 1})  # the contradicting reading dropped, the other one applied
    expected = predicted * O2_HAND[0, :, 1]
    np.testing.assert_allclose(both.belief, expected / expected.sum(), rtol=1e-12)
    assert both.dropped == (0,)


def test_restart_gets_a_wrong_belief_unstuck_where_discarding_would_not():
    """Static target in state 1, perfect sensor, belief certain of state 0: every reading is
    impossible. Discarding them would keep [1, 0] for ever; the restart follows the readings."""
    eye = np.eye(2)[None]
    flt = EpochFilter(POMDP(P=eye, O=eye, r=np.zeros((2, 1)), gamma=0.5))
    step = flt.step(np.array([1.0, 0.0]), 0, {0: 1})
    np.testing.assert_array_equal(step.belief, [0.0, 1.0])
    again = flt.step(step.belief, 0, {0: 1})
    assert again.restarted == () and again.belief.tolist() == [0.0, 1.0]


def test_gap_predicts_with_a_known_action_and_holds_otherwise():
    flt = EpochFilter(hand_model())
    b = np.array([0.0, 1.0, 0.0])
    predicted = flt.step(b, 0, {})
    np.testing.assert_allclose(predicted.belief, [0.25, 0.5, 0.25])
    assert predicted.predicted
    held = flt.step(b, None, {})
    assert not held.predicted and held.belief.tolist() == b.tolist()
    with pytest.raises(BeliefError, match="action"):
        flt.step(b, None, {0: 1})


def test_bad_arguments_name_the_problem():
    model = hand_model()
    flt = EpochFilter(model)
    b = np.full(3, 1 / 3)
    with pytest.raises(BeliefError, match=r"sensor: must be an integer in 0\.\.0, got 1"):
        flt.step(b, 0, {1: 0})
    with pytest.raises(BeliefError, match=r"observation \(sensor 0\): must be an integer in 0\.\.1, got 2"):
        flt.step(b, 0, {0: 2})
    with pytest.raises(BeliefError, match="action"):
        flt.step(b, 1, {0: 0})
    with pytest.raises(BeliefError, match="belief: contains non-finite"):  # the defensive check of the result
        flt.step(np.array([np.nan, 0.5, 0.5]), 0, {})
    with pytest.raises(ModelError, match=r"sensors\[1\]: observation model has shape"):
        EpochFilter(model, [O_HAND, np.ones((1, 2, 2)) / 2])
