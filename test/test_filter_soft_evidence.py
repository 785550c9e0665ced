"""Soft evidence in the per-epoch filter (core/filter.py) and in the filter's loop (core/loop):
``b'(s) ∝ l(s) b^a(s)`` after the prediction of Eq. 1.

Expected beliefs are fractions worked out by hand, or Bayes' rule as sums over the joint
distribution, and a likelihood equal to a column of ``O`` must give the hard observation's belief.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_filter import O_HAND, P_HAND, bayes_by_sums, hand_model, random_rows

from pomdp_planner.core.belief import BeliefError, check_likelihood
from pomdp_planner.core.filter import EpochFilter
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import FilterLoop, LikelihoodSample, Liveness, ObservationSample, StallLimits
from pomdp_planner.core.model import POMDP, ModelError

REPO = Path(__file__).resolve().parents[1]


def test_soft_evidence_by_hand():
    """b = (1/2, 1/2, 0); b P = (1/8 + 0, 1/4, 1/8) + (1/2, 0, 0) -> (0.625, 0.25, 0.125).
    l = (0.2, 1, 4): unnormalised (0.125, 0.25, 0.5), sum 0.875 -> (1/7, 2/7, 4/7)."""
    f = EpochFilter(hand_model(), [O_HAND], likelihoods=1)
    b = np.array([0.5, 0.5, 0.0])
    np.testing.assert_allclose(b @ P_HAND[0], [0.625, 0.25, 0.125])
    step = f.step(b, 0, {1: (0.2, 1.0, 4.0)})
    np.testing.assert_allclose(step.belief, [1 / 7, 2 / 7, 4 / 7], rtol=1e-14)
    assert step.restarted == () and step.dropped == ()


def test_soft_evidence_is_scale_free_and_finite_at_any_scale():
    f = EpochFilter(hand_model(), [], likelihoods=1)
    b = np.array([0.5, 0.5, 0.0])
    for scale in (1e-300, 1e-3, 1.0, 1e6, 1e300):
        step = f.step(b, 0, {0: tuple(scale * np.array([0.2, 1.0, 4.0]))})
        np.testing.assert_allclose(step.belief, [1 / 7, 2 / 7, 4 / 7], rtol=1e-13)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_a_column_of_the_observation_matrix_as_soft_evidence_equals_the_hard_observation(data):
    S, A, Z = data.draw(st.integers(2, 5)), data.draw(st.integers(1, 3)), data.draw(st.integers(2, 4))
    P, O = random_rows(data.draw, (A, S, S)), random_rows(data.draw, (A, S, Z))
    model = POMDP(P=P, O=O, r=np.zeros((S, A)), gamma=0.5)
    b, a, z = random_rows(data.draw, (S,)), data.draw(st.integers(0, A - 1)), data.draw(st.integers(0, Z - 1))
    hard = EpochFilter(model).step(b, a, {0: z})
    soft = EpochFilter(model, [], likelihoods=1).step(b, a, {0: tuple(O[a, :, z])})
    np.testing.assert_allclose(soft.belief, hard.belief, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(soft.belief, bayes_by_sums(P, [O], b, a, {0: z}), rtol=1e-10, atol=1e-14)


def test_hard_and_soft_readings_of_one_epoch_multiply():
    """A hard reading z = 1 (column (0, 0.4, 0.8)) and soft evidence (1, 1, 0.5): from b P =
    (0.625, 0.25, 0.125) the product is (0, 0.1, 0.05) -> (2/3, 1/3) on states 1, 2."""
    f = EpochFilter(hand_model(), [O_HAND], likelihoods=1)
    step = f.step(np.array([0.5, 0.5, 0.0]), 0, {0: 1, 1: (1.0, 1.0, 0.5)})
    np.testing.assert_allclose(step.belief, [0.0, 2 / 3, 1 / 3], rtol=1e-14, atol=1e-16)


def test_soft_evidence_impossible_under_the_belief_restarts_and_impossible_everywhere_is_dropped():
    f = EpochFilter(hand_model(), [], likelihoods=1)
    # certain of state 0 (absorbing), evidence only for state 2: restart from u P = (5/12, 1/3, 1/4) * l
    step = f.step(np.array([1.0, 0.0, 0.0]), 0, {0: (0.0, 0.0, 1.0)})
    np.testing.assert_allclose(step.belief, [0.0, 0.0, 1.0], atol=1e-15)
    assert step.restarted == (0,)
    # evidence only for a state no state reaches (state 2 under this P): contradicts the model, dropped
    P = np.array([[[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.5, 0.5, 0.0]]])
    model = POMDP(P=P, O=O_HAND, r=np.zeros((3, 1)), gamma=0.5)
    step = EpochFilter(model, [], likelihoods=1).step(np.array([0.5, 0.5, 0.0]), 0, {0: (0.0, 0.0, 1.0)})
    assert step.dropped == (0,)
    np.testing.assert_allclose(step.belief, np.array([0.5, 0.5, 0.0]) @ P[0])


@pytest.mark.parametrize("values, problem", [
    ((1.0, 1.0), "expected 3 values"), ((1.0, float("nan"), 1.0), "non-finite"),
    ((1.0, -0.1, 1.0), "entry 1 is negative"), ((0.0, 0.0, 0.0), "every entry is 0"),
])
def test_bad_soft_evidence_names_the_problem(values, problem):
    with pytest.raises(BeliefError, match=problem):
        check_likelihood(3, values)
    with pytest.raises(BeliefError, match=problem):
        EpochFilter(hand_model(), [], likelihoods=1).step(np.full(3, 1 / 3), 0, {0: values})


def test_a_filter_needs_a_sensor_of_some_kind():
    with pytest.raises(ModelError, match="at least one"):
        EpochFilter(hand_model(), [], likelihoods=0)


# ----------------------------------------------------------------- the filter's loop
MODEL = load_model_file(str(REPO / "config" / "models" / "tracking_s3_info.yaml"))
LIVE = Liveness(epoch_window=50, resend_period=1.0, stall=StallLimits(2.0, 10.0))


def test_the_loop_applies_likelihood_topics_as_sensors_after_the_observation_topics():
    """One observation topic and one likelihood topic; an epoch waits for both and applies
    ``b P[a] * O[a][:, z] * l`` normalised, written out here."""
    prior = np.full(3, 1 / 3)
    loop = FilterLoop(MODEL, [MODEL.O], prior, ["observation"], LIVE, now=0.0, epoch_timeout=5.0,
                      likelihood_topics=["likelihood"])
    loop.start(0.0)
    assert loop.topics == ["observation", "likelihood"]
    lik = (0.5, 2.0, 1.0)
    assert loop.observation(1, LikelihoodSample(1, 2, lik), 0.1).beliefs == []  # waits for the other sensor
    (out,) = loop.observation(0, ObservationSample(1, 2, 0), 0.2).beliefs
    post = prior @ MODEL.P[1] * MODEL.O[1][:, 0] * np.array(lik)
    np.testing.assert_allclose(out.belief, post / post.sum(), rtol=1e-12)
    # a repeat is a duplicate, different values for the same epoch a conflict
    loop.observation(1, LikelihoodSample(2, 1, lik), 0.3)
    loop.observation(1, LikelihoodSample(2, 1, lik), 0.3)
    loop.observation(1, LikelihoodSample(2, 1, (1.0, 1.0, 1.0)), 0.3)
    assert loop.health.counts["duplicates"] == 1 and loop.health.counts["conflicts"] == 1
    with pytest.raises(ValueError, match="does not take"):
        loop.observation(0, LikelihoodSample(3, 1, lik), 0.4)


def test_an_impossible_likelihood_is_named_by_its_topic_in_the_log():
    """Certain of the absorbing state 0, evidence only for state 2: the restart rule, logged by topic."""
    loop = FilterLoop(hand_model(), [], np.array([1.0, 0.0, 0.0]), [], LIVE, now=0.0, likelihood_topics=["radar"])
    loop.start(0.0)
    out = loop.observation(0, LikelihoodSample(1, 1, (0.0, 0.0, 1.0)), 0.1)
    assert any("radar likelihood impossible under the belief" in line.text for line in out.logs)
    np.testing.assert_allclose(out.beliefs[0].belief, [0.0, 0.0, 1.0], atol=1e-15)
    assert loop.health.counts["impossible_observations"] == 1
