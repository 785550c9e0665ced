"""The peer comparison (issues 6 and 12): chunks of seeded episodes that can run in parallel
processes and be resumed from a cache must give exactly the rows of one plain sequential run,
checked against a direct simulation; the regret pairs episodes; the optimal reference, the
sanity check and the probes of B&B against exhaustive search do what the report says."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.bench.experiments import peer_policies, peers
from pomdp_planner.bench.experiments.peer_policies import ProbeConfig, ReferenceSpec, make_peer
from pomdp_planner.bench.experiments.peers import PeerChunk, PeerPlan, PeerResult, add_regret, compare_peers
from pomdp_planner.bench.experiments.report_peers import section_peers
from pomdp_planner.bench.experiments.sanity import known_optimum, run_sanity, state_reward_only
from pomdp_planner.core.belief import update
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.reference import alpha_vector_value_iteration
from pomdp_planner.core.simulate import simulate

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"
S3 = load_model(MODELS / "tracking_s3_info.yaml")
S8 = load_model(MODELS / "tracking_s8_info.yaml")
CHEAP = ("greedy", "lower-bound", "random")


def _plan(**kw) -> PeerPlan:
    base = dict(budgets=(0.01,), planners=("bnb", "exhaustive", *CHEAP), episodes_cheap=5,
                episodes_by_budget={0.01: 2}, steps=6, max_depth=3, seed=77, chunk=2,
                probes=ProbeConfig(episodes=0))
    base.update(kw)
    return PeerPlan(**base)


def _cheap(results):
    return {(r.model, r.planner): r.returns for r in results if r.budget is None}


def test_chunks_cover_every_episode_once_cheapest_cells_first() -> None:
    plan = _plan()
    chunks = plan.chunks(["m"])
    cells = {}
    for c in chunks:
        cells.setdefault((c.planner, c.budget), []).extend(range(c.start, c.stop))
    assert cells == {("greedy", None): list(range(5)), ("lower-bound", None): list(range(5)),
                     ("random", None): list(range(5)), ("bnb", 0.01): [0, 1], ("exhaustive", 0.01): [0, 1]}
    assert [c.budget for c in chunks][:9] == [None] * 9  # budget-free cells come first
    assert plan.total_units(["m"]) == 3 * 5 + 2 * 2


def test_reference_runs_as_many_episodes_as_the_largest_cell_of_its_model() -> None:
    plan = _plan(planners=("bnb", "optimal", "greedy"), episodes_cheap=3, episodes_by_budget={0.01: 4},
                 model_episodes={"a": {0.01: 7}}, references={"a": ReferenceSpec("grid", 4)})
    cells = {(m, p, b): n for m, p, b, n in plan.cells(["a", "b"])}
    assert cells == {("a", "optimal", None): 7, ("a", "greedy", None): 3, ("b", "greedy", None): 3,
                     ("a", "bnb", 0.01): 7, ("b", "bnb", 0.01): 4}  # model b has no reference: no optimal row


def test_greedy_rows_equal_a_direct_simulation() -> None:
    plan = _plan()
    (res,) = [r for r in compare_peers({"s3": S3}, plan) if r.planner == "greedy"]

    class Greedy:
        def act(self, b):
            return int(np.argmax(S3.rho(b)))

    direct = [simulate(S3, Greedy(), plan.steps, seed=plan.seed + k).discounted_return for k in range(5)]
    np.testing.assert_allclose(res.returns, direct, rtol=0, atol=0)
    assert res.episodes == 5 and res.ci[0] <= res.mean <= res.ci[1]


def test_parallel_and_resumed_runs_match_the_sequential_run(tmp_path, monkeypatch) -> None:
    plan = _plan()
    sequential = _cheap(compare_peers({"s3": S3}, plan))
    parallel = _cheap(compare_peers({"s3": S3}, _plan(jobs=2), cache_dir=tmp_path))
    assert parallel == sequential
    files = sorted(tmp_path.glob("*.json"))
    assert len(files) == len(plan.chunks(["s3"]))
    # an interrupted run: one chunk missing; resuming recomputes only that one
    victim = PeerChunk("s3", "random", None, 2, 4)
    (tmp_path / victim.filename).unlink()
    ran = []
    real = peers.run_chunk
    monkeypatch.setattr(peers, "run_chunk", lambda c, m, p: ran.append(c) or real(c, m, p))
    resumed = _cheap(compare_peers({"s3": S3}, plan, cache_dir=tmp_path))
    assert ran == [victim]
    assert resumed == sequential
    # a cache written under another plan (different steps) is not reused
    ran.clear()
    compare_peers({"s3": S3}, _plan(steps=4), cache_dir=tmp_path)
    assert len(ran) == len(plan.chunks(["s3"]))


def test_regret_pairs_the_episodes_of_a_row_with_the_reference() -> None:
    """The regret of a row is the mean of ref(k) - row(k) over the row's episodes k = 0..n-1 only."""
    def row(planner, returns):
        return PeerResult("m", planner, None, len(returns), 5, float(np.mean(returns)), (0.0, 0.0), 0.0, 0.0, 0.0,
                          0.0, 0.0, None, None, None, returns=list(returns))

    ref = row("optimal", [10.0, 11.0, 12.0, 30.0])
    short = row("greedy", [9.0, 10.0, 11.0])  # episode 3 (ref 30) is not in this row
    same = row("bnb", [10.0, 11.0, 12.0, 30.0])
    add_regret([ref, short, same])
    assert short.regret == pytest.approx(1.0) and short.regret_ci == pytest.approx((1.0, 1.0))
    assert same.regret == 0.0 and ref.regret == 0.0


def test_grid_reference_row_certifies_its_decisions_and_gives_every_row_a_regret() -> None:
    """The optimal row (grid policy iteration on S = 3): regret 0, most decisions outside the tie margin."""
    plan = _plan(planners=("optimal", "greedy"), episodes_cheap=6, steps=10, references={"s3": ("grid", 10)})
    rows = {r.planner: r for r in compare_peers({"s3": S3}, plan)}
    assert rows["optimal"].regret == 0.0
    assert rows["optimal"].certified_fraction is not None and rows["optimal"].certified_fraction > 0.5
    g = rows["greedy"]
    diff = np.array(rows["optimal"].returns) - np.array(g.returns)
    assert g.regret == pytest.approx(diff.mean()) and g.regret_ci[0] <= g.regret <= g.regret_ci[1]


def test_unknown_peer_is_rejected() -> None:
    with pytest.raises(ValueError, match="planner"):
        peers.run_chunk(PeerChunk("s3", "oracle", None, 0, 1), S3, _plan())
    with pytest.raises(ValueError, match="reference"):
        make_peer("optimal", S3, None, max_depth=2, seed=0)


def test_budgets_are_measured_on_the_process_cpu_clock() -> None:
    """The searches' deadlines run on the coarse process-time clock, whose every reading is a process-time
    reading at most one resolution (of wall time, hence of CPU time) old."""
    import time

    for bounds in (True, False):
        assert peer_policies.gate_setup(S8, use_bounds=bounds).planner.clock is peer_policies.BUDGET_CLOCK
    clock = peer_policies.coarse_cpu_clock(resolution=1e-3)
    x, readings = 0.0, []
    for i in range(200_000):  # burn CPU, reading both clocks
        x += i * 1e-9
        if i % 1000 == 0:
            readings.append((clock(), time.process_time()))
    lag = [cpu - coarse for coarse, cpu in readings]
    assert min(lag) >= 0.0 and max(lag) <= 1e-3 + 1e-4
    assert readings[-1][0] > readings[0][0]  # it does advance with the CPU time


def test_planner_cache_follows_the_model_not_the_label() -> None:
    p3 = peer_policies.gate_setup(S3)
    assert peer_policies.gate_setup(pickle.loads(pickle.dumps(S3))) is p3  # a worker's copy: reused
    p8 = peer_policies.gate_setup(S8)
    assert p8 is not p3 and p8.planner.model.S == 8


def test_probes_compare_bnb_with_exhaustive_search_on_the_same_belief() -> None:
    """Probes are taken at the configured decisions of the first episodes, and the fixed-depth exhaustive
    search they report agrees with a direct search at B&B's depth."""
    plan = _plan(planners=("bnb",), steps=6, probes=ProbeConfig(episodes=1, steps=(1, 4)))
    (row,) = compare_peers({"s8": S8}, plan)
    assert [p["step"] for p in row.probes] == [1, 4]  # episode 0 only
    for p in row.probes:
        assert p["anytime_depth"] >= 1 and p["anytime_time"] >= 0
        if p["fixed_time"] is not None:
            assert p["fixed_action"] in range(S8.A)


# ------------------------------------------------------------------------------ sanity check
def test_state_reward_only_model_has_linear_rho() -> None:
    m = state_reward_only(S3)
    B = np.random.default_rng(3).dirichlet(np.ones(3), 50)
    np.testing.assert_allclose(m.rho(B), B @ S3.r)
    assert (m.P is S3.P or np.array_equal(m.P, S3.P)) and "w = 0" in m.name


def test_known_optimum_of_the_s3_state_reward_model_is_priority_2_with_the_exact_gap() -> None:
    """The Bellman-inequality proof and its gap against exact alpha-vector value iteration."""
    m = state_reward_only(S3)
    B = np.vstack([np.eye(3), np.random.default_rng(4).dirichlet(np.ones(3), 30)])
    opt = known_optimum(m, B)
    assert np.all(opt.actions == 1) and opt.certified.all()
    sol = alpha_vector_value_iteration(m, 1500)
    Q = sol.q_values(B)
    assert np.all(np.argmax(Q, axis=1) == 1)
    gaps = Q[:, 1] - np.max(np.delete(Q, 1, axis=1), axis=1)
    assert opt.min_gap == pytest.approx(gaps.min(), abs=2 * sol.error_bound + 1e-6)


def test_sanity_check_fails_a_planner_that_misses_the_optimum(monkeypatch) -> None:
    """A planner that always picks priority 1 fails; random fails but is not required."""
    real = peer_policies.make_peer

    def fake(name, model, budget, **kw):
        if name == "greedy":
            return peer_policies.TimedPolicy("greedy", lambda b: (0, {}))
        return real(name, model, budget, **kw)

    import pomdp_planner.bench.experiments.sanity as sanity

    monkeypatch.setattr(sanity, "make_peer", fake)
    out = run_sanity({"s3": S3}, ("bnb", "greedy", "random"), (0.01,), max_depth=3, reachable=4, seed=0)
    res = {r.planner: r for r in out["results"]}
    assert res["bnb"].passed and res["bnb"].required
    assert not res["greedy"].passed and res["greedy"].correct == 0
    assert not res["random"].required
    assert res["bnb"].worst_loss == 0.0
    # the loss of always playing priority 1 at the check beliefs, from exact alpha vectors
    from pomdp_planner.bench.experiments.sanity import check_beliefs

    m = state_reward_only(S3)
    sol = alpha_vector_value_iteration(m, 1500)
    Q = sol.q_values(check_beliefs(m, 4, 0))
    assert res["greedy"].worst_loss == pytest.approx(np.max(Q[:, 1] - Q[:, 0]), abs=2 * sol.error_bound + 1e-6)


def test_report_says_when_pouct_and_models_are_missing() -> None:
    d = {"results": [], "plan": {**_plan().__dict__, "budgets": (0.01,), "pouct": {}, "probes": {}},
         "pouct": False, "mcts": False, "missing": ["perimeter_s3"], "facts": {}, "models": []}
    text = "\n".join(section_peers(d, {}))
    assert "POUCT was skipped" in text and "`perimeter_s3`" in text and "belief MCTS" in text


# ------------------------------------------------------------------------------ POUCT
def _pouct():
    pytest.importorskip("pomdp_py")
    from pomdp_planner.bench.experiments import pouct

    return pouct


def test_pouct_leaf_value_solves_the_rollout_policys_bellman_equation() -> None:
    """``V_pi`` against plain value iteration of the greedy-on-state-reward policy (second formula)."""
    pouct = _pouct()
    for m in (S3, S8):
        v = pouct.rollout_values(m, "greedy-state")
        pi = np.argmax(m.r, axis=1)
        u = np.zeros(m.S)
        for _ in range(4000):
            u = np.array([m.r[s, pi[s]] + m.gamma * m.P[pi[s], s] @ u for s in range(m.S)])
        np.testing.assert_allclose(v, u, rtol=1e-9, atol=1e-6)
        assert pouct.return_spread(m) == pytest.approx(np.ptp(m.r) + m.gamma * np.ptp(u))


def test_pouct_budget_is_read_on_the_injected_clock() -> None:
    """With a clock that advances 1 per reading, a budget of 5 gives the same number of simulations."""
    pouct = _pouct()
    ticks = iter(range(10**6))
    pol = pouct.POUCTPolicy(S3, 5.0, pouct.TUNED, seed=0, clock=lambda: float(next(ticks)))
    pol.act(np.full(3, 1 / 3))
    assert pol.last_sims == 5


def test_pouct_reuses_the_subtree_of_the_observed_posterior() -> None:
    pouct = _pouct()
    pol = pouct.POUCTPolicy(S3, 0.01, pouct.TUNED, seed=1)
    b = np.full(3, 1 / 3)
    a = pol.act(b)
    child_visits = {z: (pol.agent.tree[pol.actions[a]][pol.observations[z]].num_visits
                        if pol.agent.tree[pol.actions[a]][pol.observations[z]] is not None else 0) for z in range(3)}
    z = max(child_visits, key=child_visits.get)
    pol.act(update(S3, b, a, z))
    assert pol.reused == 1
    assert pol.agent.tree.num_visits >= child_visits[z] + pol.last_sims - 1  # old statistics kept
    pol2 = pouct.POUCTPolicy(S3, 0.01, pouct.TUNED, seed=1)
    pol2.act(b)
    pol2.act(np.array([0.2, 0.3, 0.5]))  # not a posterior of the last decision: fresh tree
    assert pol2.reused == 0


def test_tuned_pouct_passes_the_sanity_check_on_the_s3_state_reward_model() -> None:
    _pouct()
    out = run_sanity({"s3": S3}, ("pouct",), (0.05,), max_depth=3, reachable=8, seed=0, pouct_defaults=False)
    (r,) = out["results"]
    assert r.passed, (r.correct, r.checked)


def test_tree_depth_counts_action_observation_levels() -> None:
    class Node:
        def __init__(self, children=None):
            self.children = children or {}

    leaf = Node()
    assert peers.tree_depth(leaf) == 0
    # root -a0-> q -z1-> v1 -a1-> q -z0-> v2 (depth 2); a sibling branch stops at depth 1
    v2 = Node()
    v1 = Node({"a1": Node({"z0": v2})})
    root = Node({"a0": Node({"z1": v1, "z2": Node()}), "a1": Node({"z0": Node()})})
    assert peers.tree_depth(root) == 2


def test_report_names_the_reference_policy_and_does_not_call_a_depth_search_optimal() -> None:
    """A regret is against the model's reference policy; where that is a fixed-depth exhaustive
    search (the S = 8 models) the report says it is not the optimum, and no row is called 'optimal'."""
    d = {"results": [], "plan": {**_plan(planners=("optimal", "greedy")).__dict__, "budgets": (0.01,), "pouct": {},
                                 "probes": {}},
         "pouct": False, "mcts": False, "missing": [], "facts": {}, "models": []}
    text = "\n".join(section_peers(d, {}))
    assert "- `reference`:" in text and "- `optimal`" not in text
    assert "not always the optimum" in text and "not the optimum" in text
    assert "optimal reference" not in text
