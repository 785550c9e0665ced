"""The multi-target problem, the knapsack and the price search (``core/multitarget``).

The knapsack is checked against brute force over every joint action, and its vectorised tree
against the target-by-target dynamic programme kept as its reference (the same optimum, and with
exactly representable values the same joint action: the same tie rule); the price search against
a dense grid on convex piecewise-linear functions; the problem's budget arithmetic is exact.
"""

from __future__ import annotations

import itertools
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.multitarget.dual import lambda_ceiling, minimise_convex, reward_range_bound
from pomdp_planner.core.multitarget.knapsack import (
    _checked,
    _solve_tree,
    _tree_pays,
    knapsack_optimum,
    near_optimal,
    padded,
    solve_knapsack,
    solve_knapsack_reference,
    solve_padded,
)
from pomdp_planner.core.multitarget.problem import default_efforts, make_problem

PERIMETER = load_model_file("perimeter_s3")
TRACKING = load_model_file("tracking_s3_info")


# ----------------------------------------------------------------------------- problem
def test_default_efforts_cost_most_at_the_highest_priority():
    assert default_efforts(PERIMETER) == (2, 1, 0)
    p = make_problem([PERIMETER, PERIMETER], budget=0)
    assert p.within_budget((2, 2)) and not p.within_budget((1, 2))


def test_rational_efforts_are_exact():
    p = make_problem([PERIMETER, PERIMETER, PERIMETER], budget="0.3",
                     efforts=[[0.2, 0.1, 0], [0.2, 0.1, 0], ["1/3", 0.1, 0]])
    assert p.efforts[0][1] == Fraction(1, 10)
    assert p.within_budget((1, 1, 1))  # 0.1 + 0.1 + 0.1 <= 0.3 exactly (in floats 0.30000000000000004)
    assert p.within_budget((0, 1, 2)) and not p.within_budget((0, 0, 2))
    assert not p.within_budget((2, 2, 0))  # 1/3 > 0.3
    assert p.scale == 30 and p.capacity == 9


@pytest.mark.parametrize("kwargs, field", [
    ({"budget": -1}, "budget"),
    ({"budget": "x"}, "budget"),
    ({"budget": 0, "efforts": [[1, 1, 1], None]}, "budget"),
    ({"budget": 1, "efforts": [[1, 2], None]}, r"efforts\[0\]"),
    ({"budget": 1, "efforts": [[1, -2, 0], None]}, r"efforts\[0\]\[1\]"),
    ({"budget": 1, "efforts": [[1, 0.1234567891, 0], None]}, r"efforts\[0\]\[1\]"),
    ({"budget": 1, "efforts": [None]}, "efforts"),
    ({"budget": 10**9, "efforts": [["0.000001", 0, 0], None]}, "budget"),
])
def test_bad_problems_name_the_field(kwargs, field):
    with pytest.raises(OptionError, match=rf"^{field}") as info:
        make_problem([PERIMETER, TRACKING], discount=0.95, **kwargs)
    assert "\n" not in str(info.value)


def test_different_discounts_need_an_explicit_joint_discount():
    with pytest.raises(OptionError, match=r"^discount: .*different discounts"):
        make_problem([PERIMETER, TRACKING], budget=1)
    p = make_problem([PERIMETER, TRACKING], budget=1, discount=0.9)
    assert p.gamma == 0.9 and all(m.gamma == 0.9 for m in p.models)
    with pytest.raises(OptionError, match=r"^discount"):
        make_problem([PERIMETER], budget=1, discount=1.5)
    assert make_problem([PERIMETER], budget=1, discount=1.0).gamma == 1.0  # a finite lookahead


def test_a_budget_that_cannot_bind():
    assert not make_problem([PERIMETER, PERIMETER], budget=4).budget_binds
    assert make_problem([PERIMETER, PERIMETER], budget="3.99").budget_binds


# ----------------------------------------------------------------------------- knapsack
def brute_force(values, weights, capacity):
    best, arg = -np.inf, None
    for joint in itertools.product(*(range(len(v)) for v in values)):
        w = sum(int(weights[k][a]) for k, a in enumerate(joint))
        v = sum(values[k][a] for k, a in enumerate(joint))
        if w <= capacity and v > best:
            best, arg = v, joint
    return best, arg


def reverse_lexicographic_optimum(values, weights, capacity):
    """The documented tie rule by brute force: of the optimal joint actions, the one whose last
    target's action is the smallest, then the next-to-last's, ... (exact for integer values)."""
    best, _ = brute_force(values, weights, capacity)
    optimal = [j for j in itertools.product(*(range(len(v)) for v in values))
               if sum(int(weights[k][a]) for k, a in enumerate(j)) <= capacity
               and sum(values[k][a] for k, a in enumerate(j)) == best]
    return best, min(optimal, key=lambda j: tuple(reversed(j)))


def draw_problem(data, max_targets=4, max_weight=6, integer=True):
    K = data.draw(st.integers(1, max_targets))
    values, weights = [], []
    for _ in range(K):
        A = data.draw(st.integers(1, 4))
        if integer:  # few distinct values: many exact ties
            row = data.draw(st.lists(st.integers(-3, 3), min_size=A, max_size=A))
        else:
            row = data.draw(st.lists(st.floats(-20, 20, allow_nan=False), min_size=A, max_size=A))
        values.append(np.array(row, dtype=float))
        weights.append(np.array(data.draw(st.lists(st.integers(0, max_weight), min_size=A, max_size=A)),
                                dtype=np.int64))
    if data.draw(st.booleans()):  # an action that may not be taken
        k = data.draw(st.integers(0, K - 1))
        values[k][data.draw(st.integers(0, values[k].size - 1))] = -np.inf
    least = sum(int(w.min()) for w in weights)
    return values, weights, data.draw(st.integers(least, least + 12))


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_knapsack_equals_brute_force_with_its_tie_rule(data):
    values, weights, capacity = draw_problem(data)
    want, joint = reverse_lexicographic_optimum(values, weights, capacity)
    for method in ("tree", "reference", "auto"):
        if not np.isfinite(want):
            with pytest.raises(ValueError, match="no joint action"):
                solve_knapsack(values, weights, capacity, method)
            continue
        assert solve_knapsack(values, weights, capacity, method) == (want, joint)
        V, W = padded(values, weights)
        assert knapsack_optimum(V, W, capacity, method) == want


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_tree_equals_reference_on_many_targets(data):
    """Up to 40 targets (brute force is out of reach): the tree against the reference, exactly
    with integer values, to rounding with real ones (their sums are added in another order)."""
    integer = data.draw(st.booleans())
    values, weights, capacity = draw_problem(data, max_targets=40, max_weight=3, integer=integer)
    try:
        want = solve_knapsack_reference(values, weights, capacity)
    except ValueError:
        with pytest.raises(ValueError, match="no joint action"):
            solve_knapsack(values, weights, capacity, "tree")
        return
    got = solve_knapsack(values, weights, capacity, "tree")
    V, W = padded(values, weights)
    assert knapsack_optimum(V, W, capacity, "tree") == got[0]  # the same sums, in the same order
    if integer:
        assert got == want
    else:
        assert got[0] == pytest.approx(want[0], rel=1e-12, abs=1e-12)
        assert sum(values[k][a] for k, a in enumerate(got[1])) == pytest.approx(want[0], rel=1e-12, abs=1e-12)
    assert sum(int(weights[k][a]) for k, a in enumerate(got[1])) <= capacity
    # The path's answer where it finds the only optimum, the ranks' where not: the same joint action.
    assert _solve_tree(*_checked(V, W, capacity, "tree")[:3]) == got
    value, path = solve_padded(V, W, capacity, "tree", ties=False)  # any optimum: the root's path only
    assert value == got[0] and sum(int(weights[k][a]) for k, a in enumerate(path)) <= capacity
    assert sum(values[k][a] for k, a in enumerate(path)) == pytest.approx(value, rel=1e-12, abs=1e-12)


def test_identical_targets_tie_as_documented():
    """64 identical targets, room for 10 at priority 1: the last ten get it (the tie rule), by
    both algorithms."""
    values = [np.array([1.0, 0.0])] * 64
    weights = [np.array([1, 0])] * 64
    want = (10.0, (1,) * 54 + (0,) * 10)
    assert solve_knapsack(values, weights, 10, "tree") == want == solve_knapsack(values, weights, 10, "reference")


def test_the_tree_runs_where_it_pays_and_the_reference_elsewhere():
    assert _tree_pays(256, 3, 2, 256)  # the planner's case: small efforts, budget about K
    assert not _tree_pays(4, 3, 10**5, 2 * 10**5)  # four targets with fine fractional efforts
    values = [np.array([3.0, 1.0, 0.0]), np.array([2.0, 1.5, 0.0])] * 2
    weights = [np.array([10**5, 40000, 0]), np.array([10**5, 70000, 0])] * 2
    want = (8.0, (0, 2, 0, 0))  # (0, 0, 0, 2) ties: the last target takes the smallest action
    assert solve_knapsack(values, weights, 300000) == solve_knapsack_reference(values, weights, 300000) == want


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_near_optimal_joint_actions_are_exactly_those_within_the_tolerance(data):
    values, weights, capacity = draw_problem(data)
    tolerance = data.draw(st.sampled_from([0.0, 0.5, 1.0, 2.5]))
    try:
        best, first = reverse_lexicographic_optimum(values, weights, capacity)
    except ValueError:
        return
    if not np.isfinite(best):
        return
    want = {j for j in itertools.product(*(range(len(v)) for v in values))
            if sum(int(weights[k][a]) for k, a in enumerate(j)) <= capacity
            and sum(values[k][a] for k, a in enumerate(j)) >= best - tolerance}
    V, W = padded(values, weights)
    got = near_optimal(V, W, capacity, tolerance, 10**6)
    assert got[0] == first and len(set(got)) == len(got) and set(got) == want
    assert near_optimal(V, W, capacity, tolerance, 2) == got[:2]  # the limit keeps the search's first ones


def test_knapsack_refuses_an_impossible_capacity():
    with pytest.raises(ValueError, match="no joint action"):
        solve_knapsack([np.zeros(2)], [np.array([3, 4])], 2)


@pytest.mark.parametrize("values, weights, capacity, match", [
    ([np.array([np.nan, 1.0])], [np.array([0, 1])], 1, r"values\[0\]: NaN"),
    ([np.zeros(2), np.array([np.inf, 1.0])], [np.array([0, 1])] * 2, 1, r"values\[1\]: \+inf"),
    ([np.zeros(2)], [np.array([0, -1])], 1, "non-negative integers"),
    ([np.zeros(2)], [np.array([0.0, 1.0])], 1, "non-negative integers"),
    ([np.zeros(2)], [np.array([0, 1])], -1, "capacity"),
    ([np.zeros(2)], [np.array([0, 1, 2])], 1, "one value and one weight"),
])
def test_knapsack_input_errors(values, weights, capacity, match):
    with pytest.raises(ValueError, match=match):
        solve_knapsack(values, weights, capacity)


def test_padded_tables_mark_missing_actions_as_never_taken():
    V, W = padded([np.array([1.0, 2.0, 3.0]), np.array([5.0])], [np.array([0, 1, 2]), np.array([0])])
    assert V.shape == W.shape == (2, 3) and np.all(V[1, 1:] == -np.inf) and np.all(W[1, 1:] == 0)
    assert solve_padded(V, W, 1) == (7.0, (1, 0))


# ----------------------------------------------------------------------------- price search
@settings(max_examples=200)
@given(st.lists(st.tuples(st.floats(-5, 5), st.floats(-10, 10)), min_size=1, max_size=6), st.floats(0, 20))
def test_minimise_convex_finds_the_minimum_of_a_convex_piecewise_linear_function(lines, x0):
    slope_up = 3.0  # a line rising to the right keeps the minimum inside [0, ceiling]
    pieces = [*lines, (slope_up, -30.0)]

    def f(x):
        return max(s * x + c for s, c in pieces)

    ceiling = 25.0
    grid = np.linspace(0.0, ceiling, 20001)
    true_min = float(np.max([s * grid + c for s, c in pieces], axis=0).min())
    found = minimise_convex(f, ceiling, x0, max_evals=60)
    assert found.value == f(found.x)
    assert found.value <= true_min + 1e-3 * (1 + abs(true_min))
    assert 0.0 <= found.x <= ceiling
    assert len(found.evaluations) <= 60


def test_minimise_convex_never_exceeds_its_evaluations_and_keeps_the_best():
    calls = []

    def f(x):
        calls.append(x)
        return (x - 7.3) ** 2

    for budget in (2, 3, 5, 8):
        calls.clear()
        found = minimise_convex(f, 100.0, 0.0, budget)
        assert len(calls) <= budget
        assert found.value == min((x - 7.3) ** 2 for x in calls)


def test_minimise_convex_prefers_the_smallest_price_of_a_flat_minimum():
    found = minimise_convex(lambda x: max(0.0, x - 5.0), 10.0, 2.0, 30)
    assert found.value == 0.0
    assert found.x == min(x for x, v in found.evaluations if v == 0.0)


def test_lambda_ceiling_and_reward_range():
    # rho = b . r_a - w_a f(b), 0 <= f <= log S
    r, w = PERIMETER.r, PERIMETER.w
    assert reward_range_bound(PERIMETER) == pytest.approx(r.max() - r.min() + np.log(3) * w.max())
    assert lambda_ceiling([PERIMETER], [np.zeros(3)], 3) == 0.0  # equal efforts: the price cannot matter
    c = lambda_ceiling([PERIMETER], [np.array([2.0, 1.0, 0.0])], 2)
    assert c == pytest.approx(reward_range_bound(PERIMETER) * (1 + 0.95 + 0.95 ** 2))
