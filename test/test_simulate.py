"""Closed-loop simulation (core/simulate.py): consistency, sampling statistics, policies."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pomdp_planner.core.belief import update
from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.policies import MyopicPolicy, RandomPolicy, make_policy, policy_names
from pomdp_planner.core.simulate import simulate

S3 = "config/models/tracking_s3_info.yaml"


@pytest.fixture(scope="module")
def s3():
    return load_model(S3)


def test_trace_is_consistent_with_the_model(s3):
    tr = simulate(s3, "myopic", steps=60, seed=5)
    assert tr.steps == 60 and tr.beliefs.shape == (61, 3)
    np.testing.assert_allclose(tr.beliefs[0], 1 / 3)
    ret = 0.0
    for t in range(60):
        b, a, z, s = tr.beliefs[t], tr.actions[t], tr.observations[t], tr.states[t]
        np.testing.assert_allclose(tr.beliefs[t + 1], update(s3, b, a, z), rtol=0, atol=1e-15)
        renyi = -math.log(sum(p * p for p in b))
        rho = sum(s3.r[k, a] * b[k] for k in range(3)) - s3.w[a] * renyi
        assert tr.rewards[t] == pytest.approx(rho, abs=1e-12)
        assert tr.state_rewards[t] == s3.r[s, a]
        shannon = -sum(p * math.log(p) for p in tr.beliefs[t + 1] if p > 0)
        assert tr.entropies[t] == pytest.approx(shannon, abs=1e-12)
        assert s3.P[a, s, tr.next_states[t]] > 0 and s3.O[a, tr.next_states[t], z] > 0
        if t + 1 < 60:
            assert tr.states[t + 1] == tr.next_states[t]
        ret += s3.gamma ** t * tr.rewards[t]
        # myopic = argmax_a rho(b, a), brute force over actions
        rhos = [sum(s3.r[k, aa] * b[k] for k in range(3)) - s3.w[aa] * renyi for aa in range(3)]
        assert a == int(np.argmax(rhos))
    assert tr.discounted_return == pytest.approx(ret, abs=1e-10)
    assert tr.mean_reward == pytest.approx(tr.rewards.mean())
    assert not tr.recovered.any()


def test_same_seed_same_run_different_seed_different_run(s3):
    a = simulate(s3, "random", steps=40, seed=1)
    b = simulate(s3, "random", steps=40, seed=1)
    c = simulate(s3, "random", steps=40, seed=2)
    for field in ("states", "actions", "observations", "beliefs", "rewards"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not (np.array_equal(a.actions, c.actions) and np.array_equal(a.observations, c.observations))


def test_sampling_frequencies_match_the_model():
    P = np.array([[[0.3, 0.7], [0.6, 0.4]]])
    O = np.array([[[0.9, 0.1], [0.2, 0.8]]])
    m = POMDP(P=P, O=O, r=np.zeros((2, 1)), gamma=0.9)
    tr = simulate(m, lambda b: 0, steps=6000, seed=0)
    for s in range(2):
        nxt = tr.next_states[tr.states == s]
        assert abs(np.mean(nxt == 1) - P[0, s, 1]) < 0.04
    for s in range(2):
        z = tr.observations[tr.next_states == s]
        assert abs(np.mean(z == 1) - O[0, s, 1]) < 0.04


def test_initial_state_and_belief_and_start(s3):
    tr = simulate(s3, "myopic", steps=3, seed=0, initial_state=2, initial_belief=[0.1, 0.2, 0.7])
    assert tr.states[0] == 2
    np.testing.assert_allclose(tr.beliefs[0], [0.1, 0.2, 0.7])
    with_start = POMDP(P=s3.P, O=s3.O, r=s3.r, gamma=s3.gamma, metadata={"start": [0.0, 0.0, 1.0]})
    tr = simulate(with_start, "random", steps=2, seed=3)
    np.testing.assert_array_equal(tr.beliefs[0], [0, 0, 1])
    assert tr.states[0] == 2  # sampled from the start belief
    with pytest.raises(ValueError, match="initial_state"):
        simulate(s3, "myopic", steps=1, initial_state=3)
    with pytest.raises(ValueError, match="initial_belief"):
        simulate(s3, "myopic", steps=1, initial_belief=[0.5, 0.5])
    with pytest.raises(ValueError, match="steps"):
        simulate(s3, "myopic", steps=-1)
    assert simulate(s3, "myopic", steps=0).steps == 0


def test_impossible_observation_recovers_from_the_likelihood():
    m = POMDP(P=np.eye(2)[None], O=np.eye(2)[None], r=np.zeros((2, 1)), gamma=0.5)
    tr = simulate(m, lambda b: 0, steps=3, seed=0, initial_state=1, initial_belief=[1.0, 0.0])
    assert tr.recovered.tolist() == [True, False, False]
    np.testing.assert_array_equal(tr.beliefs[1], [0.0, 1.0])
    assert tr.summary()["recovered_steps"] == 1


def test_policies_callable_object_and_registry(s3):
    calls = []

    def always_last(b):
        calls.append(b.copy())
        return 2

    tr = simulate(s3, always_last, steps=4, seed=0)
    assert tr.actions.tolist() == [2, 2, 2, 2] and len(calls) == 4 and tr.policy == "always_last"

    class Obj:
        def act(self, b):
            return 1

    assert simulate(s3, Obj(), steps=2, seed=0).actions.tolist() == [1, 1]
    rp = RandomPolicy(s3, seed=4)
    assert {rp.act(np.ones(3) / 3) for _ in range(60)} == {0, 1, 2}
    assert MyopicPolicy(s3).act(np.array([1.0, 0.0, 0.0])) == int(np.argmax(s3.r[0] - 0.0))
    assert {"random", "myopic"} <= set(policy_names())
    with pytest.raises(OptionError, match="policy: unknown policy 'nope'"):
        make_policy("nope", s3)
    with pytest.raises(ValueError, match="policy returned 7"):
        simulate(s3, lambda b: 7, steps=1)
    with pytest.raises(TypeError, match="policy: expected a callable"):
        simulate(s3, 42, steps=1)


def test_to_dict_uses_priorities(s3):
    named = POMDP(P=s3.P, O=s3.O, r=s3.r, gamma=s3.gamma, state_names=["lo", "mid", "hi"])
    d = simulate(named, "random", steps=5, seed=2).to_dict(named.state_names, None)
    assert len(d["steps"]) == 5
    assert all(1 <= row["priority"] <= 3 for row in d["steps"])
    assert all(row["state_name"] in ("lo", "mid", "hi") for row in d["steps"])
    assert set(d["summary"]) >= {"mean_reward", "discounted_return", "steps"}
