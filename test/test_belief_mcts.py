"""Tests of the belief-space MCTS (``core/belief_mcts.py``) against independent computations.

The references here are written from the paper's formulas with their own Bayes update and
reward (Eqs. 1-3), not with the package's filter: a brute-force expectimax recursion over
actions and observations (Eqs. 4-6, leaf ``max_a rho``) and the exact expectation of a greedy
rollout over all observation paths.
"""

from __future__ import annotations

import gc
import json
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core.belief import BeliefError, update
from pomdp_planner.core.belief_mcts import (
    BeliefMCTS,
    BeliefMCTSPolicy,
    average_greedy_reward,
    expansion_bytes,
    make_belief_mcts_policy,
    rho_range,
)
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.simulate import simulate

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"


@pytest.fixture(scope="module")
def s3() -> POMDP:
    return load_model(MODELS / "tracking_s3_info.yaml")


def random_model(seed: int, S: int = 3, A: int = 2, Z: int = 2, uncertainty: str = "shannon",
                 gamma: float = 0.9, zeros: bool = False) -> POMDP:
    """A random model whose every possible observation has probability >= 1/(2 S Z) at any belief;
    ``zeros``: each state emits one observation only (the others are impossible)."""
    rng = np.random.default_rng(seed)
    P = 0.5 * rng.dirichlet(np.ones(S), size=(A, S)) + 0.5 / S
    O = 0.5 * rng.dirichlet(np.ones(Z), size=(A, S)) + 0.5 / Z
    if zeros:
        O = np.zeros((A, S, Z))
        for a in range(A):
            for s in range(S):
                O[a, s, (s + a) % Z] = 1.0  # each state emits one observation only
    r = rng.uniform(-1.0, 2.0, size=(S, A))
    return POMDP(P, O, r, gamma, uncertainty=uncertainty, w=rng.uniform(0.2, 1.5, size=A))


def with_gamma(model: POMDP, gamma: float) -> POMDP:
    return POMDP(model.P, model.O, model.r, gamma, uncertainty=model.uncertainty, w=model.w)


# ----------------------------------------------------------------- independent references
def f_ref(model: POMDP, b: np.ndarray) -> float:
    name = model.uncertainty.name
    if name == "renyi2":
        return -math.log(sum(x * x for x in b))
    if name == "shannon":
        return -sum(x * math.log(x) for x in b if x > 0.0)
    return 0.0


def rho_ref(model: POMDP, b: np.ndarray) -> np.ndarray:
    """Eq. 3 written out: ``sum_s r(s, a) b(s) - w_a f(b)``."""
    f = f_ref(model, b)
    return np.array([sum(model.r[s, a] * b[s] for s in range(model.S)) - model.w[a] * f for a in range(model.A)])


def bayes_ref(model: POMDP, b: np.ndarray, a: int, z: int) -> tuple[float, np.ndarray | None]:
    """Eqs. 1-2 with loops: ``(eta(z | b, a), tau(b, a, z))``; ``tau`` is None when ``eta`` is 0."""
    S = model.S
    pred = [sum(b[i] * model.P[a, i, j] for i in range(S)) for j in range(S)]
    unnorm = np.array([pred[j] * model.O[a, j, z] for j in range(S)])
    eta = float(unnorm.sum())
    return eta, (unnorm / eta if eta > 0.0 else None)


def expectimax_ref(model: POMDP, b: np.ndarray, depth: int) -> np.ndarray:
    """``Q_depth(b, a)`` of Eqs. 4-6 with leaves ``max_a rho`` (``depth`` action-observation levels)."""
    rho = rho_ref(model, b)
    Q = np.empty(model.A)
    for a in range(model.A):
        total = 0.0
        for z in range(model.Z):
            eta, tau = bayes_ref(model, b, a, z)
            if tau is None:
                continue
            v = rho_ref(model, tau).max() if depth == 1 else expectimax_ref(model, tau, depth - 1).max()
            total += eta * v
        Q[a] = rho[a] + model.gamma * total
    return Q


def greedy_rollout_ref(model: POMDP, b: np.ndarray, steps: int, tail: float) -> float:
    """Exact expectation over observation paths of ``steps`` greedy rewards plus ``gamma^steps tail``."""
    if steps == 0:
        return tail
    rho = rho_ref(model, b)
    a = int(np.argmax(rho))
    if steps == 1:
        return rho[a] + model.gamma * tail
    total = 0.0
    for z in range(model.Z):
        eta, tau = bayes_ref(model, b, a, z)
        if tau is not None:
            total += eta * greedy_rollout_ref(model, tau, steps - 1, tail)
    return rho[a] + model.gamma * total


def beliefs(S: int, n: int, seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).dirichlet(np.ones(S), size=n)


# ----------------------------------------------------------------- convergence to expectimax
def depth_one_moments(model: POMDP, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact ``Q_1(b, a) = rho + gamma E_z max rho(tau)`` and the standard deviation of its
    one-sample estimate ``rho + gamma max rho(tau_z)``, ``z ~ eta`` (per action)."""
    Q, sd = np.empty(model.A), np.empty(model.A)
    for a in range(model.A):
        pairs = [bayes_ref(model, b, a, z) for z in range(model.Z)]
        eta = np.array([e for e, _ in pairs])
        v = np.array([rho_ref(model, t).max() if t is not None else 0.0 for _, t in pairs])
        mean = float(eta @ v)
        Q[a] = rho_ref(model, b)[a] + model.gamma * mean
        sd[a] = model.gamma * math.sqrt(max(float(eta @ (v - mean) ** 2), 0.0))
    return Q, sd


def test_depth_one_mean_backup_is_within_its_standard_error(s3):
    """Depth 1, leaf max rho, Monte Carlo means: Q(b, a) is a sample mean of ``rho + gamma max
    rho(tau_z)`` over the sampled z, so its error is within 5 standard errors (computed exactly
    from eta) and shrinks as the simulations grow."""
    for b in beliefs(3, 3):
        exact, sd = depth_one_moments(s3, b)
        for sims in (300, 3000, 30000):
            res = BeliefMCTS(s3, leaf="rho", max_depth=1, backup="mean", exploration=50.0, seed=1).search(b, sims)
            se = sd / np.sqrt(res.visits)
            assert np.all(np.abs(res.q_values - exact) <= 5.0 * se + 1e-12), (sims, res.q_values, exact, se)


def test_depth_one_bellman_backup_converges_to_expectimax(s3):
    """Depth 1, Bellman backups: Q(b, a) = rho + gamma sum eta V / sum eta over the sampled
    observations; it is exact once every observation of an action has been seen, so the error
    comes from the rarest observations only and falls as the simulations grow."""
    for b in beliefs(3, 3):
        exact, _ = depth_one_moments(s3, b)
        errors = [np.max(np.abs(BeliefMCTS(s3, leaf="rho", max_depth=1, backup="bellman", exploration=50.0, seed=1)
                                .search(b, sims).q_values - exact)) for sims in (30, 300, 30000)]
        assert errors[-1] < 1e-3
        assert errors[-1] < errors[0]


def test_depth_two_bellman_q_values_converge_to_expectimax(s3):
    """Depth 2 (S = 3): every root Q value converges to the brute-force expectimax Q."""
    for b in beliefs(3, 3, seed=5):
        exact = expectimax_ref(s3, b, 2)
        errors = []
        for sims in (200, 2000, 20000):
            res = BeliefMCTS(s3, leaf="rho", max_depth=2, backup="bellman", exploration=20.0, seed=2).search(b, sims)
            errors.append(np.max(np.abs(res.q_values - exact)))
        assert errors[-1] < 5e-3
        assert errors[-1] < errors[0]


def test_depth_two_mean_backup_best_action_converges(s3):
    """Monte Carlo means converge to expectimax more slowly (the inner max is learnt by UCB1);
    the Q of the action the search picks (most of the simulations) is close after 20000."""
    for b in beliefs(3, 3, seed=5):
        exact = expectimax_ref(s3, b, 2)
        res = BeliefMCTS(s3, leaf="rho", max_depth=2, backup="mean", seed=2).search(b, 20000)
        assert abs(res.q_values[res.action] - exact[res.action]) < 0.05
        assert res.visits[res.action] == res.visits.max()


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon"])
def test_bellman_matches_expectimax_with_impossible_observations(uncertainty):
    """Observations with eta = 0 (here one per action: Z = 4 > S = 3 states, each emitting one
    observation) are never sampled, do not bias the estimate (depth 2) and raise no warning."""
    model = random_model(4, S=3, A=2, Z=4, zeros=True, uncertainty=uncertainty)
    for b in beliefs(3, 3):
        assert any(bayes_ref(model, b, a, z)[1] is None for a in range(2) for z in range(4))
        exact = expectimax_ref(model, b, 2)
        res = BeliefMCTS(model, leaf="rho", max_depth=2, backup="bellman", exploration=20.0, seed=0).search(b, 4000)
        assert np.max(np.abs(res.q_values - exact)) < 1e-9 * (1 + np.abs(exact).max())
        for a in range(2):
            for z in range(4):
                if bayes_ref(model, b, a, z)[1] is None:
                    assert res.root.kids[a * 4 + z] is None


@pytest.mark.parametrize("uncertainty", ["shannon", "renyi2", "none"])
def test_bellman_exact_once_the_depth_two_tree_is_complete(uncertainty):
    """With every observation likely enough to be sampled, the Bellman backups of a complete
    depth-2 tree are the expectimax values up to rounding (Shannon, Renyi and no uncertainty)."""
    model = random_model(7, S=3, A=2, Z=2, uncertainty=uncertainty)
    for b in beliefs(3, 3, seed=8):
        exact = expectimax_ref(model, b, 2)
        res = BeliefMCTS(model, leaf="rho", max_depth=2, backup="bellman", exploration=20.0, seed=0).search(b, 5000)
        np.testing.assert_allclose(res.q_values, exact, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("backup", ["bellman", "mean"])
def test_one_visit_per_action_is_a_one_sample_estimate(s3, backup):
    """After one simulation per action (depth 1), Q(b, a) = rho(b, a) + gamma max rho(tau(b, a, z))
    for the one sampled z: the Bellman backup normalises over the visited observations."""
    b = np.array([0.3, 0.3, 0.4])
    res = BeliefMCTS(s3, leaf="rho", max_depth=1, backup=backup, seed=0).search(b, s3.A)
    assert np.all(res.visits == 1)
    for a in range(s3.A):
        candidates = [rho_ref(s3, b)[a] + s3.gamma * rho_ref(s3, tau).max()
                      for tau in (bayes_ref(s3, b, a, z)[1] for z in range(s3.Z))]
        assert min(abs(res.q_values[a] - c) for c in candidates) < 1e-12


def test_zero_leaf_depth_one_is_rho(s3):
    b = np.array([0.2, 0.5, 0.3])
    for backup in ("mean", "bellman"):
        res = BeliefMCTS(s3, leaf="zero", max_depth=1, backup=backup, seed=0).search(b, 50)
        np.testing.assert_allclose(res.q_values, rho_ref(s3, b), rtol=1e-12)


@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
def test_rollout_leaf_converges_to_exact_greedy_rollout_value(uncertainty):
    """Depth 1 with greedy rollouts of 2 steps and a constant tail: Q(b, a) = rho(b, a) +
    gamma E_z[rollout value of tau(b, a, z)], the rollout value computed exactly over all paths."""
    model = random_model(11, S=3, A=3, Z=3, uncertainty=uncertainty, gamma=0.6)
    planner = BeliefMCTS(model, max_depth=1, leaf="rollout", rollout_depth=2, tail="average", backup="bellman",
                         exploration=50.0, seed=3)
    tail = average_greedy_reward(model) / (1 - model.gamma)
    b = np.array([0.5, 0.3, 0.2])
    exact = np.empty(model.A)
    rho = rho_ref(model, b)
    for a in range(model.A):
        total = 0.0
        for z in range(model.Z):
            eta, tau = bayes_ref(model, b, a, z)
            total += eta * greedy_rollout_ref(model, tau, 2, tail)
        exact[a] = rho[a] + model.gamma * total
    res = planner.search(b, 30000)
    # observed error ~1.5e-3 (sampling); a tail 10 % off would add gamma^3 0.1 tail ~ 0.02
    assert np.max(np.abs(res.q_values - exact)) < 5e-3


def test_leaf_tail_of_a_rollout_is_the_last_greedy_reward_held_forever():
    """``tail="leaf"``: rollout depth 0 values a leaf at ``max_a rho(b, a) / (1 - gamma)``."""
    model = random_model(12, S=3, A=2, Z=2, gamma=0.5)
    b = np.array([0.3, 0.3, 0.4])
    res = BeliefMCTS(model, max_depth=1, rollout_depth=0, tail="leaf", backup="bellman", exploration=50.0,
                     seed=0).search(b, 3000)
    exact = np.empty(model.A)
    for a in range(model.A):
        exact[a] = rho_ref(model, b)[a] + model.gamma * sum(
            eta * rho_ref(model, tau).max() / (1 - model.gamma)
            for eta, tau in (bayes_ref(model, b, a, z) for z in range(model.Z)))
    np.testing.assert_allclose(res.q_values, exact, rtol=1e-9)


def test_average_greedy_reward_is_a_mean_of_rho_values(s3):
    """The tail's long-run greedy reward lies between the smallest and largest rho."""
    B = np.vstack([np.eye(3), beliefs(3, 500)])
    rho = s3.rho(B).max(axis=1)
    value = average_greedy_reward(s3)
    assert rho.min() <= value <= rho.max()
    assert average_greedy_reward(s3) == value  # cached, deterministic


# ----------------------------------------------------------------- decisions
def test_action_matches_exhaustive_search_where_the_gap_is_large(s3):
    """On beliefs where the depth-2 expectimax Q gap exceeds 0.1, both backups choose its action."""
    checked = 0
    for b in beliefs(3, 30, seed=9):
        exact = expectimax_ref(s3, b, 2)
        top2 = np.sort(exact)[-2:]
        if top2[1] - top2[0] < 0.1:
            continue
        checked += 1
        for backup in ("bellman", "mean"):
            res = BeliefMCTS(s3, leaf="rho", max_depth=2, backup=backup, seed=0).search(b, 3000)
            assert res.action == int(np.argmax(exact)), (b, backup, res.q_values, exact)
    assert checked >= 10


def test_untried_actions_have_nan_q_and_are_never_chosen(s3):
    res = BeliefMCTS(s3, seed=0).search(np.full(3, 1 / 3), simulations=1)
    assert res.simulations == 1
    assert np.isnan(res.q_values).sum() == 2
    assert res.visits.sum() == 1
    assert res.visits[res.action] == 1 and np.isfinite(res.q_values[res.action])


# ----------------------------------------------------------------- determinism, budget
@pytest.mark.parametrize("backup", ["mean", "bellman"])
def test_same_seed_same_simulations_same_result(s3, backup):
    b = np.array([0.1, 0.6, 0.3])
    r1 = BeliefMCTS(s3, seed=42, backup=backup).search(b, 700)
    r2 = BeliefMCTS(s3, seed=42, backup=backup).search(b, 700)
    assert r1.action == r2.action
    np.testing.assert_array_equal(r1.q_values, r2.q_values)
    np.testing.assert_array_equal(r1.visits, r2.visits)
    assert (r1.depth, r1.nodes, r1.simulations) == (r2.depth, r2.nodes, r2.simulations)


def test_fake_clock_deadline_stops_the_simulations(s3):
    """Each clock reading advances 1 s: the search starts at t = 0 and the clock is read after
    every simulation, so a 10 s budget allows exactly 10 simulations."""
    ticks = iter(range(10**6))
    planner = BeliefMCTS(s3, seed=0, clock=lambda: float(next(ticks)))
    res = planner.search(np.full(3, 1 / 3), time_budget=10.0)
    assert res.simulations == 10
    assert res.deadline_hit
    assert res.visits.sum() == 10
    ticks2 = iter(range(10**6))
    res = BeliefMCTS(s3, seed=0, clock=lambda: float(next(ticks2))).search(np.full(3, 1 / 3), simulations=4,
                                                                            time_budget=10.0)
    assert res.simulations == 4 and not res.deadline_hit


def test_zero_budget_still_runs_one_simulation(s3):
    res = BeliefMCTS(s3, seed=0).search(np.full(3, 1 / 3), time_budget=0.0)
    assert res.simulations == 1
    assert 0 <= res.action < 3


# ----------------------------------------------------------------- tree reuse
def test_tree_reuse_when_the_next_belief_is_a_child_posterior(s3):
    """After acting, the filter's posterior (``core.belief.update``) is a stored child: its
    subtree, with its visit counts, becomes the new root; a belief that is not a child is not reused."""
    planner = BeliefMCTS(s3, seed=0)
    b0 = np.array([0.2, 0.5, 0.3])
    first = planner.search(b0, 3000)
    a = first.action
    z = int(np.argmax([np.sum((b0 @ s3.P[a]) * s3.O[a, :, zz]) for zz in range(s3.Z)]))
    b1 = update(s3, b0, a, z)
    child = first.root.kids[a * s3.Z + z]
    assert child is not None
    before = child.n
    second = planner.search(b1, 10, previous=first, action=a)
    assert second.reused
    assert second.visits.sum() == before - 1 + 10  # the child's first visit was as a leaf
    other = planner.search(np.array([0.9, 0.05, 0.05]), 10, previous=first, action=a)
    assert not other.reused and other.visits.sum() == 10


def test_policy_runs_in_closed_loop_and_reuses_its_tree(s3):
    policy = make_belief_mcts_policy(s3, {"simulations": 200, "seed": 1})
    trace = simulate(s3, policy, 6, seed=0)
    assert np.all((trace.actions >= 0) & (trace.actions < s3.A))
    assert policy.last is not None and policy.last.reused
    policy2 = make_belief_mcts_policy(s3, {"simulations": 200, "seed": 1})
    np.testing.assert_array_equal(simulate(s3, policy2, 6, seed=0).actions, trace.actions)
    no_reuse = make_belief_mcts_policy(s3, {"simulations": 200, "seed": 1, "reuse": False})
    simulate(s3, no_reuse, 3, seed=0)
    assert not no_reuse.last.reused


def test_result_to_dict_is_json(s3):
    res = BeliefMCTS(s3, seed=0).search(np.full(3, 1 / 3), simulations=2)
    d = json.loads(json.dumps(res.to_dict()))
    assert d["action"] == res.action + 1
    assert d["simulations"] == 2
    assert sum(x is None for x in d["q_values"]) == 1


# ----------------------------------------------------------------- options and errors
@pytest.mark.parametrize(("option", "value"), [
    ("time_budget", -1.0), ("time_budget", "fast"), ("time_budget", math.nan), ("simulations", 0),
    ("simulations", 2.5), ("max_depth", 0), ("max_depth", True), ("exploration", -0.1),
    ("exploration", math.inf), ("exploration_scale", -1), ("leaf", "random"), ("rollout_depth", -1),
    ("tail", "forever"), ("backup", "max"), ("seed", -3), ("seed", "x"), ("reuse", "maybe"), ("reuse", 2),
])
def test_bad_option_raises_value_error_naming_it(s3, option, value):
    with pytest.raises(ValueError, match=option):
        make_belief_mcts_policy(s3, {option: value})


def test_bad_belief_is_rejected(s3):
    with pytest.raises(BeliefError, match="belief"):
        BeliefMCTS(s3).search(np.array([0.5, 0.6, 0.1]), 10)


def test_reuse_option_accepts_command_line_spellings(s3):
    assert make_belief_mcts_policy(s3, {"reuse": "false"}).reuse is False
    assert make_belief_mcts_policy(s3, {"reuse": "True"}).reuse is True
    assert make_belief_mcts_policy(s3, {"reuse": 0}).reuse is False


def test_unknown_options_are_ignored_and_defaults_apply(s3):
    policy = make_belief_mcts_policy(s3, {"depth": 3, "variant": "tight"})
    assert isinstance(policy, BeliefMCTSPolicy)
    assert policy.simulations is None and policy.time_budget is None
    assert policy.planner.exploration == pytest.approx(policy.planner.exploration_scale * rho_range(s3))


def test_rho_range_covers_the_vertices(s3):
    rho = np.array([rho_ref(s3, e) for e in np.eye(3)])
    assert rho_range(s3) >= np.ptp(rho) - 1e-12


# ----------------------------------------------------------------- the benchmark (smoke)
def test_benchmark_prints_a_row_per_model_and_configuration(capsys):
    from pomdp_planner.bench import mcts as bench

    assert bench.main(["--simulations", "20", "--beliefs", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    for label, _ in bench.THROUGHPUT_CONFIGS:
        assert out.count(label) == len(bench.DEFAULT_MODELS)
    rows = bench.throughput(["tracking_s3_info"], simulations=20, beliefs=1)
    assert all(r["sims_per_s"] > 0 and 1 <= r["depth"] <= 50 for r in rows)


def test_benchmark_closed_loop_and_tuning_rows_are_sane():
    from pomdp_planner.bench import mcts as bench

    rows = bench.closed_loop("tracking_s3_info", (0.002,), episodes=2, steps=3)
    assert [r["policy"] for r in rows] == ["greedy", "mcts"]
    assert all(math.isfinite(r["mean"]) and math.isfinite(r["ci"]) and 0.0 <= r["agree"] <= 1.0 for r in rows)
    rows = bench.tune(budgets=(0.002,), count=5, configs=bench.TUNE_CONFIGS[:1])
    assert [r["config"] for r in rows] == ["greedy", bench.TUNE_CONFIGS[0][0]]
    assert all(r["loss"] >= -1e-12 and 0.0 <= r["optimal"] <= 1.0 for r in rows)


def test_benchmark_rejects_bad_arguments():
    from pomdp_planner.bench import mcts as bench

    with pytest.raises(SystemExit) as exc:
        bench.main(["--simulations", "0"])
    assert exc.value.code == 2


def test_policy_decides_with_the_cyclic_collector_paused_and_restores_it(s3):
    """A generation-2 collection of the rest of the process must not land inside a decision
    (core/gc_pause.py): the collector is off while the policy searches, and back on afterwards
    (left off if the caller had turned it off)."""
    seen: list[bool] = []

    def clock() -> float:
        seen.append(gc.isenabled())
        return float(len(seen))

    policy = BeliefMCTSPolicy(BeliefMCTS(s3, seed=0, clock=clock), simulations=50)
    assert gc.isenabled()
    policy.act(np.full(3, 1 / 3))
    assert seen and not any(seen)
    assert gc.isenabled()
    gc.disable()
    try:
        policy.act(np.full(3, 1 / 3))
        assert not gc.isenabled()
    finally:
        gc.enable()


@pytest.mark.parametrize("name", ["tracking_s3_info", "tracking_s8_info"])
def test_expansion_bytes_bounds_the_measured_tree_memory(name):
    """The per-expansion estimate behind the memory cap is an upper bound of what a tree really
    holds (tracemalloc, deep tree, many expansions)."""
    model = load_model(MODELS / f"{name}.yaml")
    planner = BeliefMCTS(model, seed=1, max_depth=30, leaf="rho")
    b = np.full(model.S, 1.0 / model.S)
    planner.search(b, simulations=10)  # warm up caches outside the measurement
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        res = planner.search(b, simulations=3000)
        held = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    assert res.expanded > 500
    assert held <= res.expanded * expansion_bytes(model.S, model.A, model.Z)
    assert held >= 0.2 * res.expanded * expansion_bytes(model.S, model.A, model.Z)  # not absurdly loose


def test_memory_budget_caps_the_tree_and_the_search_goes_on(s3):
    per = expansion_bytes(s3.S, s3.A, s3.Z)
    planner = BeliefMCTS(s3, seed=0, max_depth=50, leaf="rho", memory_budget=40 * per)
    assert planner.max_expansions == 40
    res = planner.search(np.full(3, 1 / 3), simulations=5000)
    assert res.simulations == 5000 and res.expanded == 40 and res.memory_capped
    free = BeliefMCTS(s3, seed=0, max_depth=50, leaf="rho").search(np.full(3, 1 / 3), simulations=5000)
    assert free.expanded > 40 and not free.memory_capped
    # reuse counts the old tree: a reused subtree cannot push the total past the cap
    b1 = res.root.post[res.action * s3.Z]
    again = planner.search(b1, simulations=500, previous=res, action=res.action)
    assert again.reused and again.expanded == 40 and again.memory_capped
    with pytest.raises(ValueError, match="memory_budget"):
        BeliefMCTS(s3, memory_budget=0)
