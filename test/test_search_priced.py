"""The search's additions for the multi-target planner: an action-only price, every root action,
and a deadline for a fixed-depth search (``core/search.py``: ``Planner.priced``,
``search(all_root_actions=..., deadline=...)``).

The priced planner is checked against a planner built from scratch on the priced model
(``r[s, a] - c[a]`` written into a new :class:`POMDP`), for every uncertainty function, both with
and without pruning; every root action's Q value against the backup of the children's values
(a second formula); Theorem P of docs/THEORY.md (the price changes neither Assumption 1 nor the
bound LP) on the shipped models.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from model_factory import ModelSpec, random_candidate

from pomdp_planner.core.belief import posteriors_all
from pomdp_planner.core.bounds import solve_bounds
from pomdp_planner.core.errors import BeliefError, OptionError
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.myopic import MyopicBounds
from pomdp_planner.core.search import DeadlineExceeded, Planner
from pomdp_planner.core.structure import check_assumptions

SHIPPED = ("perimeter_s3", "tracking_s3_info", "perimeter_s8", "tracking_s2_info")


def _random_models() -> list:
    rng = np.random.default_rng(5)
    return [random_candidate(rng, ModelSpec(3, 3, 3, u, 0.9)) for u in ("renyi2", "shannon", "none")]


@pytest.mark.parametrize("fused", [None, False])
@pytest.mark.parametrize("name", SHIPPED)
def test_priced_planner_equals_a_planner_of_the_priced_model(name, fused):
    """Both leaf-table layouts (``fused=False`` is what models above the fused-table limit get)."""
    model = load_model_file(name)
    setup = build_planner(model)
    base = Planner(model, MyopicBounds(model, setup.bounds.g, setup.bounds.h),
                   guaranteed=setup.guaranteed, fused=fused)
    assert base.fused == (fused is None)
    rng = np.random.default_rng(1)
    for _ in range(4):
        c = rng.normal(size=model.A) * 3.0
        priced_model = replace(model, r=model.r - c[None, :])
        fresh = Planner(priced_model, MyopicBounds(priced_model, setup.bounds.g, setup.bounds.h), guaranteed=True)
        priced = base.priced(c)
        assert priced.guaranteed == setup.guaranteed
        b = rng.dirichlet(np.ones(model.S))
        for depth in (1, 2, 3):
            for use_bounds in (True, False):
                want, got = fresh.search(b, depth, use_bounds), priced.search(b, depth, use_bounds)
                np.testing.assert_allclose(np.nan_to_num(got.q_values, nan=-1e9),
                                           np.nan_to_num(want.q_values, nan=-1e9), rtol=1e-12, atol=1e-12)
                assert got.nodes_expanded == want.nodes_expanded
                assert got.root_bounds == want.root_bounds


def test_priced_planner_for_every_uncertainty_function():
    for model in _random_models():
        plain = Planner(model)
        c = np.array([0.7, -0.2, 1.9])
        fresh = Planner(replace(model, r=model.r - c[None, :]))
        b = np.array([0.2, 0.5, 0.3])
        for depth in (1, 2, 3):
            np.testing.assert_allclose(plain.priced(c).search(b, depth).q_values, fresh.search(b, depth).q_values,
                                       rtol=1e-12, atol=1e-12)


def test_price_zero_changes_nothing_and_the_original_is_untouched():
    model = load_model_file("perimeter_s3")
    planner = build_planner(model).planner
    b = np.array([0.3, 0.3, 0.4])
    before = planner.search(b, 3, all_root_actions=True).q_values.copy()
    np.testing.assert_array_equal(planner.priced(np.zeros(3)).search(b, 3, all_root_actions=True).q_values, before)
    planner.priced([5.0, 1.0, 0.0]).search(b, 3)
    np.testing.assert_array_equal(planner.search(b, 3, all_root_actions=True).q_values, before)


def test_price_is_checked():
    planner = Planner(load_model_file("perimeter_s3"))
    for bad in ([1.0, 2.0], [np.nan, 0.0, 0.0], "abc"):
        with pytest.raises(OptionError, match="action_cost"):
            planner.priced(bad)


@pytest.mark.parametrize("name", ("perimeter_s3", "tracking_s3_info", "perimeter_s8"))
def test_all_root_actions_backs_up_the_children(name):
    """Every root action's Q value is rho + gamma sum_z eta V(child), V from a depth-1-shallower
    search of the same planner (pruning below the root included); the root-pruned search agrees
    on the actions it expands."""
    model = load_model_file(name)
    planner = build_planner(model).planner
    rng = np.random.default_rng(2)
    for _ in range(5):
        b = rng.dirichlet(np.ones(model.S))
        for depth in (2, 3):
            full = planner.search(b, depth, all_root_actions=True)
            assert np.all(np.isfinite(full.q_values))
            tau, eta = posteriors_all(model, b[None, :])
            for a in range(model.A):
                ok = eta[0, a] > 1e-300
                cont = sum(eta[0, a, z] * planner.search(tau[0, a, z], depth - 1).value
                           for z in np.flatnonzero(ok))
                assert full.q_values[a] == pytest.approx(model.rho(b)[a] + model.gamma * cont, rel=1e-10, abs=1e-10)
            pruned = planner.search(b, depth)
            kept = np.isfinite(pruned.q_values)
            np.testing.assert_allclose(full.q_values[kept], pruned.q_values[kept], rtol=1e-12)


def test_deadline_of_a_fixed_depth_search():
    ticks = iter(range(10**6))
    planner = Planner(load_model_file("perimeter_s8"), clock=lambda: float(next(ticks)))
    b = np.full(8, 1 / 8)
    with pytest.raises(DeadlineExceeded):
        planner.search(b, 3, deadline=0.5)
    assert planner.search(b, 2, deadline=1e9).depth == 2


@pytest.mark.parametrize("name", ("perimeter_s3", "tracking_s3_info", "perimeter_s8"))
def test_batched_q_values_equal_one_search_per_belief(name):
    model = load_model_file(name)
    planner = build_planner(model).planner.priced(np.linspace(0.5, 0.0, model.A))
    B = np.random.default_rng(3).dirichlet(np.ones(model.S), size=7)
    for depth in (1, 2, 3):
        for use_bounds in (True, False):
            got = planner.q_values_batch(B, depth, use_bounds)
            want = np.array([planner.search(b, depth, use_bounds, all_root_actions=True).q_values for b in B])
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(planner.q_values_batch(B, 0), model.rho(B) - np.linspace(0.5, 0.0, model.A))
    assert planner.q_values_batch(B[:0], 2).shape == (0, model.A)
    with pytest.raises(BeliefError, match="beliefs"):
        planner.q_values_batch(B[:, :2], 2)


@pytest.mark.parametrize("name", SHIPPED)
def test_the_price_changes_neither_assumption_1_nor_the_lp(name):
    """Theorem P (a), (c) (docs/THEORY.md): the priced model has the same Assumption 1 verdicts and
    the same least-element bound vectors."""
    model = load_model_file(name)
    plain = solve_bounds(model, "tight")
    for c in (np.linspace(3.0, 0.0, model.A), np.array([-1.0, 4.0, 0.5][:model.A])):
        priced = replace(model, r=model.r - c[None, :])
        assert check_assumptions(priced).status == check_assumptions(model).status
        sol = solve_bounds(priced, "tight")
        assert sol.feasible == plain.feasible and sol.covers == plain.covers
        np.testing.assert_allclose(sol.g, plain.g, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(sol.h, plain.h, rtol=1e-9, atol=1e-9)
