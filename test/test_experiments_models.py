"""Unit tests of the experiments' building blocks, each against an independent computation."""

from __future__ import annotations

import io

import numpy as np
import pytest
from scipy import stats

from pomdp_planner.bench.experiments.pbvi import pbvi, single_action_optimal
from pomdp_planner.bench.experiments.progress import Progress
from pomdp_planner.bench.experiments.pruning import pruned_percentages
from pomdp_planner.bench.experiments.sampling import reachable_beliefs
from pomdp_planner.bench.stats import mean_ci
from pomdp_planner.core.domains.comparison import comparison_model, comparison_y
from pomdp_planner.core.model import ModelError
from pomdp_planner.core.reference import alpha_vector_value_iteration


@pytest.mark.parametrize("S", [4, 5])
def test_natural_sequences_make_lowest_priority_optimal_everywhere(S):
    """The paper's sequences stretched to S: always-A is optimal (exact certificate)..."""
    m = comparison_model(S, 4, natural=True)
    assert single_action_optimal(m) == 3
    # ... and independently: the exact finite-horizon value equals the value of always playing A.
    alpha = np.linalg.solve(np.eye(S) - m.gamma * m.P[3], m.r[:, 3])
    sol = alpha_vector_value_iteration(m, 300)
    B = np.random.default_rng(0).dirichlet(np.ones(S), 200)
    assert np.max(np.abs(sol.value(B) - B @ alpha)) <= sol.error_bound + 1e-9
    assert np.all(np.argmax(sol.q_values(B), axis=1) == 3)


@pytest.mark.parametrize("S", [4, 5])
def test_our_sequences_need_several_actions(S):
    """No single action is optimal everywhere (the certificate is necessary and sufficient)."""
    m = comparison_model(S, 4)
    assert single_action_optimal(m) is None
    # and the point-based reference indeed picks two different actions on random beliefs
    B = np.random.default_rng(1).dirichlet(np.ones(S), 300)
    acts = pbvi(m, np.vstack([np.eye(S), B]), tol=1e-5).actions(B)
    assert len(np.unique(acts)) >= 2


def test_single_action_certificate_agrees_with_brute_force_on_an_mdp_like_model():
    """A model where action 0 dominates (same dynamics, larger reward) is certified; a mixed one is not."""
    m = comparison_model(4, 3)
    r = np.tile(np.array([1.0, 0.5, 0.2]), (4, 1))
    from pomdp_planner.core.model import POMDP

    dom = POMDP(P=np.broadcast_to(m.P[0], m.P.shape), O=m.O, r=r, gamma=0.9)
    assert single_action_optimal(dom) == 0


def test_pbvi_matches_exact_alpha_vectors():
    """PBVI's greedy actions equal the exact solver's where the exact Q gap is clear; its value is a lower bound."""
    m = comparison_model(4, 4)
    B = np.random.default_rng(2).dirichlet(np.ones(4), 200)
    pol = pbvi(m, np.vstack([np.eye(4), B]), tol=1e-7)
    exact = alpha_vector_value_iteration(m, 1200)
    Q = exact.q_values(B)
    srt = np.sort(Q, axis=1)
    clear = srt[:, -1] - srt[:, -2] > 2 * exact.error_bound + 1e-6
    assert clear.sum() > 100
    assert np.all(pol.actions(B)[clear] == np.argmax(Q, axis=1)[clear])
    assert np.all(pol.values(B) <= exact.value(B) + exact.error_bound + 1e-6)


def test_comparison_model_is_validated_and_documented_choice():
    y = comparison_y(4, 4)
    assert y[0] == -2.0 and y[-1] == 2.0 and np.all(np.diff(y) > 0)
    with pytest.raises(ModelError, match="S >= 2"):
        comparison_model(1, 4)
    with pytest.raises(ModelError, match="y_spread"):
        comparison_y(4, 4, spread=0.0)


def test_pruned_percentage_formulas():
    lo = np.array([0, 0, 1, 0])
    up = np.array([0, 1, 3, 3])
    paper, count = pruned_percentages(lo, up, 4)
    assert paper.tolist() == [100.0, 75.0, 50.0, 25.0]
    # literal count of skipped actions: A - (upper - lower + 1), by enumeration
    skipped = [sum(1 for a in range(4) if not lo[i] <= a <= up[i]) for i in range(4)]
    assert count.tolist() == [100.0 * k / 4 for k in skipped]


def test_reachable_beliefs_are_beliefs_and_reproducible():
    m = comparison_model(8, 4)
    B1 = reachable_beliefs(m, 50, np.random.default_rng(3))
    B2 = reachable_beliefs(m, 50, np.random.default_rng(3))
    assert B1.shape == (50, 8) and np.all(B1 >= 0) and np.allclose(B1.sum(axis=1), 1.0)
    assert np.array_equal(B1, B2)


def test_mean_ci_matches_scipy_t_interval():
    x = np.random.default_rng(4).normal(3.0, 2.0, size=40)
    m, (lo, hi) = mean_ci(x)
    ref = stats.t.interval(0.95, len(x) - 1, loc=np.mean(x), scale=stats.sem(x))
    assert m == pytest.approx(np.mean(x))
    assert lo == pytest.approx(ref[0], rel=1e-9) and hi == pytest.approx(ref[1], rel=1e-9)
    y = x[:7]
    _, (lo7, hi7) = mean_ci(y)
    ref7 = stats.t.interval(0.95, 6, loc=np.mean(y), scale=stats.sem(y))
    assert lo7 == pytest.approx(ref7[0], rel=1e-9) and hi7 == pytest.approx(ref7[1], rel=1e-9)
    assert mean_ci(np.array([2.5])) == (2.5, (2.5, 2.5))


def test_progress_bar_writes_to_its_stream():
    buf = io.StringIO()
    with Progress("demo", 4, stream=buf) as p:
        for _ in range(4):
            p.advance()
    text = buf.getvalue()
    assert "demo [" in text and "4/4" in text
    silent = io.StringIO()
    with Progress("x", 3, stream=silent, enabled=False) as p:
        p.advance()
    assert silent.getvalue() == ""
