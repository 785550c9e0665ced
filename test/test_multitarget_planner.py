"""Decisions of the multi-target planner and of every joint policy (``core/multitarget``).

Budget: no joint policy ever exceeds it (hypothesis over random problems, rational efforts and
beliefs). Decoupling: with a budget that cannot bind the planner's decision is exactly that of K
independent single-target planners (each target's own ``Planner.search``). Knapsack plumbing:
the chosen joint action maximises the reported per-target values within the budget (brute
force). Price: warm start, a fixed price, the ceiling. Anytime: one deadline for all targets.
"""

from __future__ import annotations

import itertools
import json
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.belief import BeliefError
from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.multitarget.dual import lambda_ceiling
from pomdp_planner.core.multitarget.joint_exact import ExactJointPlanner
from pomdp_planner.core.multitarget.planner import DEFAULT_JOINT_DEPTH, MultiTargetPlanner
from pomdp_planner.core.multitarget.policies import joint_policy_names, make_joint_policy
from pomdp_planner.core.multitarget.problem import make_problem

PERIMETER = load_model_file("perimeter_s3")
TRACKING = load_model_file("tracking_s3_info")
TRACKING2 = load_model_file("tracking_s2_info")
POOL = (PERIMETER, TRACKING, TRACKING2)
BELIEFS = st.integers(0, 2**32 - 1)


def _beliefs(problem, seed):
    rng = np.random.default_rng(seed)
    return [rng.dirichlet(np.ones(m.S)) for m in problem.models]


@settings(max_examples=40)
@given(st.data())
def test_no_joint_policy_ever_exceeds_the_budget(data):
    K = data.draw(st.integers(1, 3))
    models = [POOL[data.draw(st.integers(0, 2))] for _ in range(K)]
    efforts = [[data.draw(st.sampled_from([0, 1, 2, "0.5", "1.25", "1/3"])) for _ in range(m.A)] for m in models]
    least = sum(min(Fraction(str(e)) for e in row) for row in efforts)
    most = sum(max(Fraction(str(e)) for e in row) for row in efforts)
    budget = data.draw(st.sampled_from(sorted({least, (least + most) / 2, most})))
    problem = make_problem(models, budget=budget, efforts=efforts, discount=0.95)
    seed = data.draw(BELIEFS)
    for name in joint_policy_names():
        opts = {"depth": 1} if name in ("lagrangian", "fixed_price", "equal_split", "exact_joint") else {}
        policy = make_joint_policy(name, problem, **opts)
        for t in range(2):
            actions = policy.act(_beliefs(problem, seed + t))
            assert problem.within_budget(actions), (name, actions)


@pytest.mark.parametrize("search", ("bnb", "exhaustive"))
def test_a_budget_that_cannot_bind_gives_k_independent_planners(search):
    models = [PERIMETER, TRACKING, PERIMETER]
    problem = make_problem(models, budget=6, discount=0.95)
    assert not problem.budget_binds
    planner = MultiTargetPlanner(problem, search=search, depth=3)
    singles = [build_planner(m, use_bounds=search == "bnb").planner for m in problem.models]
    rng = np.random.default_rng(4)
    for depth in (1, 2, 3):
        planner = MultiTargetPlanner(problem, search=search, depth=depth)
        for _ in range(15):
            bs = [rng.dirichlet(np.ones(3)) for _ in models]
            dec = planner.decide(bs)
            alone = [p.search(b, depth, use_bounds=search == "bnb") for p, b in zip(singles, bs, strict=True)]
            assert dec.actions == tuple(r.action for r in alone)
            assert dec.lam == 0.0 and dec.gap == 0.0
            assert dec.dual_bound == pytest.approx(sum(r.value for r in alone), rel=1e-12)


def test_the_price_of_a_budget_that_cannot_bind_is_zero():
    """``U(lambda) >= U(0)`` when every joint action is within the budget (docs/THEORY.md)."""
    problem = make_problem([PERIMETER, PERIMETER], budget=4)
    planner = MultiTargetPlanner(problem, search="exhaustive", depth=2)
    for seed in range(10):
        bs = _beliefs(problem, seed)
        u0 = planner.evaluate(bs, 0.0, 2).dual_bound
        for lam in (0.01, 0.3, 2.0, 40.0):
            assert planner.evaluate(bs, lam, 2).dual_bound >= u0 - 1e-12


def test_above_the_ceiling_the_dual_bound_does_not_decrease():
    problem = make_problem([PERIMETER, TRACKING], budget=1, discount=0.95)
    planner = MultiTargetPlanner(problem, search="exhaustive", depth=2)
    ceiling = lambda_ceiling(problem.models, list(planner.efforts), 2)
    for seed in range(10):
        bs = _beliefs(problem, seed)
        values = [planner.evaluate(bs, lam, 2).dual_bound for lam in (ceiling, 1.5 * ceiling, 3 * ceiling)]
        assert values[0] <= values[1] + 1e-9 and values[1] <= values[2] + 1e-9


def test_the_joint_action_maximises_the_reported_values_within_the_budget():
    problem = make_problem([PERIMETER, PERIMETER, TRACKING], budget=3, discount=0.95,
                           efforts=[[2, 1, 0], ["1.5", "0.5", 0], [3, 1, 0]])
    planner = MultiTargetPlanner(problem, depth=2)
    for seed in range(10):
        dec = planner.decide(_beliefs(problem, seed))
        best = max((sum(t.q_values[a] for t, a in zip(dec.targets, joint, strict=True)), joint)
                   for joint in itertools.product(range(3), repeat=3) if problem.within_budget(joint))
        assert sum(t.q_values[a] for t, a in zip(dec.targets, dec.actions, strict=True)) == pytest.approx(best[0])
        assert dec.effort <= problem.budget


def test_the_price_is_warm_started_from_the_previous_decision():
    problem = make_problem([PERIMETER, PERIMETER], budget=2)
    planner = MultiTargetPlanner(problem, depth=2)
    first = planner.decide(_beliefs(problem, 0))
    assert first.prices[0][0] == 0.0 and planner.price == first.lam > 0.0
    second = planner.decide(_beliefs(problem, 1))
    assert second.prices[0][0] == first.lam
    assert second.dual_bound == min(u for _, u in second.prices)
    planner.reset()
    assert planner.decide(_beliefs(problem, 2)).prices[0][0] == 0.0


def test_a_fixed_price_is_used_as_given():
    problem = make_problem([PERIMETER, PERIMETER], budget=2)
    planner = MultiTargetPlanner(problem, depth=2, price=0.25)
    for seed in range(3):
        dec = planner.decide(_beliefs(problem, seed))
        assert dec.lam == 0.25 and len(dec.prices) == 1
    policy = make_joint_policy("fixed_price", problem, depth=2)
    assert policy.planner.fixed_price == pytest.approx(
        MultiTargetPlanner(problem, depth=2).decide([np.full(3, 1 / 3)] * 2).lam)


def test_one_time_budget_for_all_targets():
    """A clock that jumps past the deadline once depth 1 is done gives the depth-1 decision;
    a clock that never moves lets the search deepen to max_depth."""
    problem = make_problem([PERIMETER, PERIMETER, TRACKING], budget=3, discount=0.95)
    bs = _beliefs(problem, 0)
    dec = MultiTargetPlanner(problem, time_budget=0.5, max_depth=3, clock=lambda: 0.0).decide(bs)
    assert dec.depth == 3 and not dec.deadline_hit
    calls = [0]

    def counting() -> float:
        calls[0] += 1
        return 0.0

    MultiTargetPlanner(problem, time_budget=0.5, max_depth=1, clock=counting).decide(bs)
    depth_one = calls[0]  # clock readings of a decision that stops after depth 1
    calls[0] = 0

    def jumping() -> float:
        calls[0] += 1
        return 0.0 if calls[0] < depth_one else 10.0

    dec = MultiTargetPlanner(problem, time_budget=0.5, max_depth=3, clock=jumping).decide(bs)
    assert dec.deadline_hit and dec.depth == 1
    assert problem.within_budget(dec.actions)


def test_decisions_are_json_ready_with_priorities():
    problem = make_problem([PERIMETER, PERIMETER], budget=2)
    dec = MultiTargetPlanner(problem, depth=2).decide(_beliefs(problem, 0))
    data = json.loads(json.dumps(dec.to_dict()))
    assert data["priorities"] == [a + 1 for a in dec.actions]
    assert data["effort"] <= data["budget"] == 2.0
    assert set(data) >= {"lambda", "dual_bound", "gap", "lower_bound", "bound_guaranteed", "budget_use"}


def test_beliefs_are_validated_once_at_the_boundary(monkeypatch):
    """A decision validates its K beliefs once, one vectorised check per group of targets with the
    same model (``check_belief_rows``), and never again inside the searches: not in any price's
    evaluation, not for the posteriors of the lower bound."""
    import pomdp_planner.core.multitarget.planner as planner_module
    import pomdp_planner.core.search as search_module

    singles, rows = [], []
    real_single, real_rows = search_module.check_belief, planner_module.check_belief_rows
    monkeypatch.setattr(search_module, "check_belief", lambda *a, **k: singles.append(1) or real_single(*a, **k))
    monkeypatch.setattr(planner_module, "check_belief_rows", lambda *a, **k: rows.append(1) or real_rows(*a, **k))
    problem = make_problem([PERIMETER, TRACKING] * 4, budget=4, discount=0.95)
    for search in ("bnb", "exhaustive"):
        planner = MultiTargetPlanner(problem, search=search, depth=2)
        dec = planner.decide(_beliefs(problem, 3))
        assert len(dec.prices) > 1 and singles == [] and len(rows) == 2  # two groups: one check each
        rows.clear()
    assert planner.evaluate(_beliefs(problem, 4), 0.5, 2).gap >= -1e-9 and singles == [] and len(rows) == 2


def test_every_joint_policy_looks_ahead_to_one_default_depth():
    """The planner, the fixed price, the equal split and the exact joint planner compare like with
    like unless told otherwise: one default depth."""
    problem = make_problem([PERIMETER, TRACKING], budget=1, discount=0.95)
    depths = {"lagrangian": make_joint_policy("lagrangian", problem).planner.depth,
              "fixed_price": make_joint_policy("fixed_price", problem, price=0.5).planner.depth,
              "equal_split": make_joint_policy("equal_split", problem).depth,
              "exact_joint": make_joint_policy("exact_joint", problem).planner.depth,
              "library": MultiTargetPlanner(problem).depth}
    assert set(depths.values()) == {DEFAULT_JOINT_DEPTH}, depths


def test_lower_bound_tie_break_chooses_among_near_ties_and_keeps_the_bound():
    """``tie_break="lower_bound"``: the dual bound is the knapsack rule's; the joint action is within
    the tolerance of the knapsack's optimum at the price, its lower bound at least the knapsack
    choice's, and with exhaustive searches the gap still bounds its exact shortfall. On the three
    targets of RESULTS it changes some decisions (the case where it helps)."""
    problem = make_problem([PERIMETER, PERIMETER, TRACKING], budget=2, discount=0.95)
    plain = MultiTargetPlanner(problem, search="exhaustive", depth=1)
    ties = MultiTargetPlanner(problem, search="exhaustive", depth=1, tie_break="lower_bound", tie_tolerance=1e-2)
    joint = ExactJointPlanner(problem, 1)
    changed = 0
    for seed in range(40):
        bs = _beliefs(problem, seed)
        a, b = plain.decide(bs), ties.decide(bs)
        assert b.lam == a.lam and b.dual_bound == a.dual_bound and b.prices == a.prices
        value = sum(t.q_values[x] for t, x in zip(b.targets, b.actions, strict=True))
        best = sum(t.q_values[x] for t, x in zip(a.targets, a.actions, strict=True))
        assert value >= best - 1e-2 - 1e-12 and problem.within_budget(b.actions)
        assert b.lower_bound >= a.lower_bound and b.gap == pytest.approx(b.dual_bound - b.lower_bound)
        q = joint.q_values(bs)
        assert q.max() - q[joint.actions.index(b.actions)] <= b.gap + 1e-9
        changed += b.actions != a.actions
    assert changed > 0
    with pytest.raises(OptionError, match=r"^tie_break: expected one of knapsack, lower_bound"):
        MultiTargetPlanner(problem, tie_break="random")
    with pytest.raises(OptionError, match=r"^tie_tolerance"):
        MultiTargetPlanner(problem, tie_tolerance=-1)
    with pytest.raises(OptionError, match=r"^option tie_break"):
        make_joint_policy("lagrangian", problem, tie_break="x")


def test_bad_input_names_the_field():
    problem = make_problem([PERIMETER, PERIMETER], budget=2)
    planner = MultiTargetPlanner(problem, depth=2)
    with pytest.raises(BeliefError, match=r"^beliefs: 1 beliefs for 2 targets"):
        planner.decide([np.full(3, 1 / 3)])
    with pytest.raises(BeliefError, match=r"beliefs\[1\]"):
        planner.decide([np.full(3, 1 / 3), np.array([0.5, 0.6, -0.1])])
    with pytest.raises(OptionError, match=r"^search"):
        MultiTargetPlanner(problem, search="mcts")
    with pytest.raises(OptionError, match=r"^price"):
        MultiTargetPlanner(problem, price=-1)
    with pytest.raises(OptionError, match=r"^depth"):
        MultiTargetPlanner(problem, depth=0)
    with pytest.raises(OptionError, match=r"^policy: unknown joint policy"):
        make_joint_policy("bnb", problem)
    with pytest.raises(OptionError, match=r"^policy greedy: unknown option"):
        make_joint_policy("greedy", problem, depth=3)
