"""Tests of the vectorised branch-and-bound search (paper Sec. V, Algorithm 1; Table II counting).

The vectorised search is checked against a naive recursive reference written plainly from
Algorithm 1 (one belief at a time, with ``core/belief.py``'s single-belief ``update``), which
lives only here. Depth ``d`` of the planner is ``Search(b, d + 1)`` of Algorithm 1.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.belief import ImpossibleObservation, update
from pomdp_planner.core.domains.tracking import tracking_transitions
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.myopic import MyopicBounds
from pomdp_planner.core.search import Planner, SearchResult, complete_tree_nodes, next_depth_cannot_finish

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"


# ----------------------------------------------------------------- the naive reference
def reference_search(model: POMDP, b: np.ndarray, d: int, bounds: MyopicBounds | None):
    """Algorithm 1 written plainly: ``Search(b, d + 1)``.

    Returns ``(V, Q, nodes)``: the value, the root Q values (nan if not expanded) and the
    number of belief nodes in the tree (root included). Impossible observations
    (``update`` raises) are skipped. Crossed bounds (lower > upper) keep all actions.
    """
    rho = model.rho(b)
    if d == 0:  # the leaf: Search(b, 1) = max_a rho(b, a)
        return float(np.max(rho)), None, 1
    if bounds is None:
        actions = range(model.A)
    else:
        lo, up = int(bounds.lower(b[None, :])[0]), int(bounds.upper(b[None, :])[0])
        actions = range(lo, up + 1) if lo <= up else range(model.A)
    Q = np.full(model.A, np.nan)
    nodes = 1
    for a in actions:
        total = 0.0
        for z in range(model.Z):
            try:
                child = update(model, b, a, z)
            except ImpossibleObservation:
                continue
            eta = float(np.sum((b @ model.P[a]) * model.O[a, :, z]))
            v, _, n = reference_search(model, child, d - 1, bounds)
            total += eta * v
            nodes += n
        Q[a] = rho[a] + model.gamma * total
    return float(np.nanmax(Q)), Q, nodes


def reference_trace(model: POMDP, b: np.ndarray, d: int, bounds: MyopicBounds) -> bool:
    """Whether, in the exhaustive tree, some node on the exhaustive-optimal subtree (argmax
    action at every node, all observations) has its exhaustive argmax outside the bounds."""
    if d == 0:
        return False
    _, Q, _ = reference_search(model, b, d, None)
    a_star = int(np.nanargmax(Q))
    lo, up = int(bounds.lower(b[None, :])[0]), int(bounds.upper(b[None, :])[0])
    if lo <= up and not lo <= a_star <= up:
        return True
    for z in range(model.Z):
        try:
            child = update(model, b, a_star, z)
        except ImpossibleObservation:
            continue
        if reference_trace(model, child, d - 1, bounds):
            return True
    return False


# ----------------------------------------------------------------------------- models
def random_model(seed: int, S: int, A: int, Z: int, uncertainty: str) -> POMDP:
    """A random POMDP (no structure needed for the equality with the reference)."""
    rng = np.random.default_rng(seed)
    P = rng.dirichlet(np.ones(S), size=(A, S))
    O = rng.dirichlet(np.ones(Z), size=(A, S))
    O[O < 0.05] = 0.0  # some zero observation probabilities
    O[:, :, 0] += 1.0 - O.sum(axis=2)
    return POMDP(P=P, O=O, r=rng.uniform(0, 2, (S, A)), gamma=0.9, uncertainty=uncertainty,
                 w=rng.uniform(0.2, 1.5, A), name=f"random{seed}")


def random_bounds(model: POMDP, seed: int) -> MyopicBounds:
    rng = np.random.default_rng(seed + 1000)
    return MyopicBounds(model, rng.normal(0, 2, model.S), rng.normal(0, 2, model.S))


def tracking(S: int, uncertainty: str = "renyi2") -> POMDP:
    m = load_model(MODELS / f"tracking_s{S}_info.yaml")
    if uncertainty == m.uncertainty.name:
        return m
    return POMDP(P=m.P, O=m.O, r=m.r, gamma=m.gamma, uncertainty=uncertainty, w=m.w, name=m.name)


def no_prune_bounds(model: POMDP, M: float = 1e4) -> MyopicBounds:
    """Genuine MyopicBounds that keep every action on tracking models: with ``g`` steeply
    increasing the lower bound is always action 0, with ``h`` steeply decreasing the upper
    bound is always A-1 (``P[a]`` moves the state up more for larger ``a``)."""
    s = np.arange(model.S, dtype=float)
    return MyopicBounds(model, M * s, -M * s)


def model_bounds(model: POMDP) -> MyopicBounds:
    from pomdp_planner.core.bounds import solve_bounds

    sol = solve_bounds(model, variant="feasible")
    assert sol.feasible, sol.message
    return sol.myopic


_S3 = tracking(3)
_S8 = tracking(8)


# ------------------------------------------------------------------ reference equality
# ``fused``: with the fused leaf table, or without it (the planner's way beyond FUSED_TABLE_MAX_BYTES)
@pytest.mark.parametrize("fused", [True, False], ids=["fused", "unfused"])
@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_naive_reference_random_models(uncertainty: str, seed: int, fused: bool, engine: str) -> None:
    model = random_model(seed, S=3, A=3, Z=3, uncertainty=uncertainty)
    bounds = random_bounds(model, seed)
    planner = Planner(model, bounds, fused=fused, kernel=engine)
    rng = np.random.default_rng(seed)
    for depth in (1, 2, 3):
        b = rng.dirichlet(np.ones(model.S))
        for use_bounds in (False, True):
            res = planner.search(b, depth, use_bounds=use_bounds)
            v, Q, nodes = reference_search(model, b, depth, bounds if use_bounds else None)
            np.testing.assert_array_equal(np.isnan(res.q_values), np.isnan(Q))
            np.testing.assert_allclose(res.q_values, Q, rtol=1e-11, atol=1e-11, equal_nan=True)
            assert res.value == pytest.approx(v, rel=1e-11, abs=1e-11)
            assert res.nodes_expanded[-1] == nodes
            assert res.action == int(np.nanargmax(Q)) or math.isclose(Q[res.action], v, rel_tol=1e-11)


@pytest.mark.parametrize("fused", [True, False], ids=["fused", "unfused"])
@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
def test_matches_naive_reference_tracking(uncertainty: str, fused: bool) -> None:
    model = tracking(3, uncertainty)
    planner = Planner(model, random_bounds(model, 7), fused=fused)
    rng = np.random.default_rng(3)
    for depth in (1, 2, 3):
        b = rng.dirichlet(np.ones(3) * 0.5)
        for use_bounds in (False, True):
            res = planner.search(b, depth, use_bounds=use_bounds)
            _, Q, nodes = reference_search(model, b, depth, planner.bounds if use_bounds else None)
            np.testing.assert_allclose(res.q_values, Q, rtol=1e-11, atol=1e-11, equal_nan=True)
            assert res.nodes_expanded[-1] == nodes


@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
def test_small_chunks_give_the_same_answer(uncertainty: str) -> None:
    """Chunking the levels (memory bound) must not change values or counts. Small chunks take
    the batched all-actions leaf path, large ones the per-action path: this compares them."""
    model = tracking(8, uncertainty)
    bounds = random_bounds(model, 3)
    big, small = Planner(model, bounds), Planner(model, bounds, chunk_bytes=4096)
    unfused = Planner(model, bounds, fused=False)
    b = np.random.default_rng(5).dirichlet(np.ones(8))
    for use_bounds in (False, True):
        r1, r2, r3 = big.search(b, 3, use_bounds), small.search(b, 3, use_bounds), unfused.search(b, 3, use_bounds)
        np.testing.assert_allclose(r1.q_values, r2.q_values, rtol=1e-13, atol=1e-13, equal_nan=True)
        np.testing.assert_allclose(r1.q_values, r3.q_values, rtol=1e-13, atol=1e-13, equal_nan=True)
        assert r1.level_sizes == r2.level_sizes == r3.level_sizes


# -------------------------------------------------------------- B&B versus exhaustive
@pytest.mark.parametrize("S", [3, 8])
def test_bounds_that_prune_nothing_equal_exhaustive_exactly(S: int) -> None:
    model = tracking(S)
    planner = Planner(model, no_prune_bounds(model))
    rng = np.random.default_rng(S)
    for depth in (1, 2, 3):
        b = rng.dirichlet(np.ones(S))
        bnb = planner.search(b, depth, use_bounds=True)
        exh = planner.search(b, depth, use_bounds=False)
        assert bnb.root_bounds == (0, model.A - 1) and exh.root_bounds is None
        np.testing.assert_array_equal(bnb.q_values, exh.q_values)
        assert bnb.action == exh.action and bnb.value == exh.value
        assert bnb.nodes_expanded == exh.nodes_expanded == tuple(
            complete_tree_nodes(model.A, model.Z, i) for i in range(1, depth + 1))
        assert bnb.nodes_pruned == (0,) * depth


def test_agreeing_root_bounds_return_their_action() -> None:
    model = _S3
    s = np.arange(3.0)
    bounds = MyopicBounds(model, 1e4 * s, 1e4 * s)  # lower = upper = action 0 everywhere
    planner = Planner(model, bounds, guaranteed=True)  # declared valid: tests the certification mechanics
    b = np.array([0.05, 0.15, 0.8])
    exh = planner.search(b, 3, use_bounds=False)
    assert exh.action != 0  # the exhaustive search would choose otherwise: the bounds decide
    for res in (planner.search(b, 3), planner.plan(b, max_depth=5)):
        assert res.certified and res.root_bounds == (0, 0)
        assert res.action == 0 and res.priority == 1
        assert np.isnan(res.q_values[1:]).all() and np.isfinite(res.q_values[0])
    quick = planner.plan(b, max_depth=5)
    assert quick.depth == 1 and quick.nodes_expanded == (1 + model.Z,)


def test_bounds_without_guarantee_certify_nothing_and_do_not_stop_early() -> None:
    """The constructor's default: bounds not known to be valid prune but never certify, so agreeing
    root bounds do not end the anytime search; crossed root bounds are flagged."""
    model = _S3
    s = np.arange(3.0)
    planner = Planner(model, MyopicBounds(model, 1e4 * s, 1e4 * s))
    b = np.array([0.05, 0.15, 0.8])
    res = planner.plan(b, max_depth=3)
    assert res.root_bounds == (0, 0) and res.action == 0 and not res.certified and not res.guaranteed
    assert res.depth == 3 and not res.crossed
    crossed = Planner(model, MyopicBounds(model, -1e4 * s, 1e4 * s)).search(b, 2)  # lower = A-1 > upper = 0
    assert crossed.root_bounds == (2, 0) and crossed.crossed and not crossed.certified
    assert crossed.to_dict()["root_bounds_crossed"] is True
    assert crossed.nodes_pruned[0] == 0  # crossed bounds keep every action


def test_agreeing_real_bounds_certify_the_exhaustive_action() -> None:
    """With bounds from the LP, wherever lower == upper the exhaustive search agrees."""
    model = _S3
    planner = Planner(model, model_bounds(model), guaranteed=True)  # Assumption 1 holds for the shipped S = 3
    rng = np.random.default_rng(11)
    certified = 0
    for _ in range(40):
        b = rng.dirichlet(np.ones(3))
        lo, up = planner.root_bounds(b)
        if lo != up:
            continue
        certified += 1
        res = planner.plan(b, max_depth=3)
        assert res.certified and res.action == lo
        assert planner.search(b, 3, use_bounds=False).action == lo
    assert certified >= 5


@pytest.mark.parametrize(("S", "depth", "count", "kind"), [(3, 3, 25, "lp"), (8, 2, 8, "lp"), (3, 3, 25, "random")])
def test_disagreements_are_traced_to_pruning(S: int, depth: int, count: int, kind: str) -> None:
    """B&B value <= exhaustive value always; they differ only if, somewhere on the exhaustive
    optimal subtree, the bounds excluded that node's exhaustive argmax. With the LP's bounds
    no such node occurs on these beliefs; arbitrary (invalid) bounds produce traced
    disagreements, so both branches of the check are exercised."""
    model = tracking(S)
    bounds = model_bounds(model) if kind == "lp" else random_bounds(model, 5)
    planner = Planner(model, bounds)
    rng = np.random.default_rng(100 + S)
    pruned_somewhere = disagreements = 0
    for _ in range(count):
        b = rng.dirichlet(np.ones(S))
        bnb = planner.search(b, depth)
        exh = planner.search(b, depth, use_bounds=False)
        pruned_somewhere += bnb.nodes_expanded[-1] < exh.nodes_expanded[-1]
        assert bnb.value <= exh.value + 1e-12
        violated = reference_trace(model, b, depth, bounds)
        if not violated:
            assert bnb.value == pytest.approx(exh.value, rel=1e-12, abs=1e-12)
            assert bnb.action == exh.action or math.isclose(
                exh.q_values[bnb.action], exh.value, rel_tol=1e-12)
        if bnb.action != exh.action:
            disagreements += 1
            assert violated, f"unexplained disagreement at b={b.tolist()}"
    assert pruned_somewhere > 0  # the test exercises pruning
    if kind == "random":
        assert disagreements > 0


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3).filter(lambda x: sum(x) > 1e-3),
       st.integers(1, 3))
def test_bnb_value_never_exceeds_exhaustive(x: list[float], depth: int) -> None:
    b = np.asarray(x) / sum(x)
    planner = Planner(_S3, random_bounds(_S3, 1))
    bnb, exh = planner.search(b, depth), planner.search(b, depth, use_bounds=False)
    assert bnb.value <= exh.value + 1e-12
    assert all(e <= c for e, c in zip(bnb.nodes_expanded, exh.nodes_expanded, strict=True))


# ------------------------------------------------------------------------ node counting
def test_complete_tree_formula() -> None:
    assert complete_tree_nodes(3, 8, 2) == 1 + 24 + 576
    assert complete_tree_nodes(3, 8, 6) == sum(24**i for i in range(7))


@pytest.mark.parametrize("S", [3, 8])
def test_exhaustive_counts_equal_formula(S: int) -> None:
    model = tracking(S)
    planner = Planner(model)
    b = np.random.default_rng(0).dirichlet(np.ones(S))
    depth = 4 if S == 3 else 3
    res = planner.search(b, depth, use_bounds=False)
    assert res.nodes_expanded == tuple(complete_tree_nodes(model.A, model.Z, i) for i in range(1, depth + 1))
    assert res.level_sizes == tuple((model.A * model.Z) ** i for i in range(depth + 1))
    assert res.percent_pruned == (0.0,) * depth


def test_fast_bound_actions_equal_myopic_bounds(engine: str) -> None:
    """The planner's rewards and bound actions equal ``MyopicBounds.actions`` (ties included), with
    either engine."""
    bounds = model_bounds(_S8)
    planner = Planner(_S8, bounds, kernel=engine)
    rng = np.random.default_rng(21)
    B = np.vstack([rng.dirichlet(np.ones(8) * 0.3, size=500), np.eye(8), np.full((1, 8), 1 / 8)])
    np.testing.assert_allclose(planner.q_values_batch(B, 0), _S8.rho(B), rtol=1e-12, atol=1e-12)
    lo_ref, up_ref = bounds.actions(B)
    got = np.array([planner.root_bounds(b) for b in B])
    np.testing.assert_array_equal(got[:, 0], lo_ref)
    np.testing.assert_array_equal(got[:, 1], up_ref)
    flat = POMDP(P=_S3.P, O=_S3.O, r=np.ones((3, 3)), gamma=0.9)  # all actions tie
    tie = MyopicBounds(flat, np.zeros(3), np.zeros(3))
    assert Planner(flat, tie, kernel=engine).root_bounds(np.full(3, 1 / 3)) == (0, 2)


def test_count_nodes_matches_search_and_nested_depths() -> None:
    planner = Planner(_S8, model_bounds(_S8))
    b = np.random.default_rng(2).dirichlet(np.ones(8))
    res = planner.search(b, 3)
    assert planner.count_nodes(b, 3) == res.level_sizes
    assert planner.count_nodes(b, 4)[:4] == res.level_sizes  # deeper trees contain shallower ones
    for d in (1, 2):
        assert planner.search(b, d).nodes_expanded == res.nodes_expanded[:d]
    assert all(e + p == complete_tree_nodes(3, 8, i + 1)
               for i, (e, p) in enumerate(zip(res.nodes_expanded, res.nodes_pruned, strict=True)))


# ------------------------------------------------------------------ impossible branches
def perfect_sensor_model(uncertainty: str) -> POMDP:
    """Identity transitions and observations: most observation branches have eta = 0."""
    S = A = 3
    eye = np.broadcast_to(np.eye(S), (A, S, S))
    return POMDP(P=eye, O=eye, r=np.arange(9.0).reshape(3, 3) / 9, gamma=0.95, uncertainty=uncertainty,
                 w=np.ones(A))


def test_custom_uncertainty_uses_the_generic_path() -> None:
    """An uncertainty function the planner does not know is evaluated from explicit posteriors (by
    the numpy engine: the kernel values Shannon, Renyi-2 and none)."""
    from pomdp_planner.core.uncertainty import RENYI2, Uncertainty

    custom = Uncertainty("my_renyi", RENYI2.value, RENYI2.gradient)
    m = tracking(3)
    mc = POMDP(P=m.P, O=m.O, r=m.r, gamma=m.gamma, uncertainty=custom, w=m.w)
    b = np.array([0.3, 0.3, 0.4])
    assert Planner(mc).kernel == "numpy"
    r1, r2 = Planner(m).search(b, 3, use_bounds=False), Planner(mc).search(b, 3, use_bounds=False)
    np.testing.assert_allclose(r2.q_values, r1.q_values, rtol=1e-11)
    assert r1.nodes_expanded == r2.nodes_expanded


@pytest.mark.parametrize("fused", [True, False], ids=["fused", "unfused"])
@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
def test_zero_probability_branches_are_skipped(uncertainty: str, fused: bool, engine: str) -> None:
    model = perfect_sensor_model(uncertainty)
    planner = Planner(model, fused=fused, kernel=engine)
    for b in (np.array([0.5, 0.5, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([1.0, 1e-250, 0.0]) / (1 + 1e-250)):
        with np.errstate(divide="raise", invalid="raise", over="raise"):
            res = planner.search(b, 3, use_bounds=False)
        _, Q, nodes = reference_search(model, b, 3, None)
        assert np.all(np.isfinite(res.q_values))
        np.testing.assert_allclose(res.q_values, Q, rtol=1e-12, atol=1e-12)
        assert res.nodes_expanded[-1] == nodes < complete_tree_nodes(3, 3, 3)
        assert planner.count_nodes(b, 3) == res.level_sizes
        assert res.nodes_pruned[-1] == complete_tree_nodes(3, 3, 3) - nodes


@pytest.mark.parametrize("fused", [True, False], ids=["fused", "unfused"])
def test_tiny_eta_leaves_use_the_safe_path(fused: bool, engine: str) -> None:
    """eta ~ 1e-200 at the leaves (u_s^2 underflows): values stay finite and exact."""
    model = perfect_sensor_model("renyi2")
    b = np.array([0.5, 0.5 - 1e-200, 1e-200])
    res = Planner(model, fused=fused, kernel=engine).search(b, 2, use_bounds=False)
    _, Q, nodes = reference_search(model, b, 2, None)
    np.testing.assert_allclose(res.q_values, Q, rtol=1e-12, atol=1e-12)
    assert res.nodes_expanded[-1] == nodes


# ----------------------------------------------------------------------------- anytime
class FakeClock:
    """A clock that advances by one unit per reading (deterministic deadlines)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        self.t += 1.0
        return self.t


def test_tiny_budget_returns_a_valid_depth_one_action() -> None:
    planner = Planner(_S8, model_bounds(_S8))
    b = np.random.default_rng(9).dirichlet(np.ones(8))
    for use_bounds in (False, True):
        res = planner.plan(b, max_depth=8, time_budget=1e-6, use_bounds=use_bounds)
        assert res.depth >= 1 and 0 <= res.action < 3 and res.priority == res.action + 1
        assert np.isfinite(res.q_values[res.action])
        if not res.certified:
            assert res.deadline_hit


def test_deadline_is_checked_inside_a_depth_and_interrupted_depths_are_discarded() -> None:
    b = np.random.default_rng(4).dirichlet(np.ones(8))
    full = Planner(_S8, chunk_bytes=4096, clock=FakeClock()).plan(b, max_depth=3, use_bounds=False)
    assert full.depth == 3 and not full.deadline_hit
    readings = []  # (budget in clock ticks, depth returned, deadline hit)
    for budget in range(1, 5000):
        planner = Planner(_S8, chunk_bytes=4096, clock=FakeClock())
        res = planner.plan(b, max_depth=3, time_budget=float(budget), use_bounds=False, predict_stop=False)
        readings.append((budget, res.depth, res.deadline_hit))
        reference = planner.search(b, res.depth, use_bounds=False)
        if res.partial:  # depth 1 interrupted: the root actions it finished, in decreasing rho
            assert res.depth == 1 and res.deadline_hit
            searched = np.isfinite(res.q_values)
            order = np.argsort(-_S8.rho(b), kind="stable")
            assert searched[order].tolist() == sorted(searched.tolist(), reverse=True) and searched.any()
            np.testing.assert_array_equal(res.q_values[searched], reference.q_values[searched])
            assert res.action == int(np.nanargmax(res.q_values))
            assert res.nodes_expanded[0] < reference.nodes_expanded[0]
            continue
        np.testing.assert_array_equal(res.q_values, reference.q_values)
        assert res.action == reference.action and res.nodes_expanded == reference.nodes_expanded
        assert res.depth >= 1
        if not res.deadline_hit:
            break
    depths = [d for _, d, _ in readings]
    assert depths == sorted(depths) and depths[-1] == 3
    # depth 3 has many chunks: several budgets end inside it (so the check is not only between depths)
    inside = [bud for bud, d, hit in readings if d == 2 and hit]
    assert len(inside) >= 3


def test_results_are_deterministic() -> None:
    planner = Planner(_S8, model_bounds(_S8))
    b = np.random.default_rng(12).dirichlet(np.ones(8))
    r1, r2 = planner.search(b, 3), planner.search(b, 3)
    np.testing.assert_array_equal(r1.q_values, r2.q_values)
    assert (r1.action, r1.nodes_expanded) == (r2.action, r2.nodes_expanded)
    p1, p2 = planner.plan(b, max_depth=3), planner.plan(b, max_depth=3)
    np.testing.assert_array_equal(p1.q_values, r1.q_values)
    assert p1.depth == p2.depth == 3 and p1.action == p2.action == r1.action


# ------------------------------------------------------------------------ result/input
def test_to_dict_is_json_with_priorities() -> None:
    planner = Planner(_S3, random_bounds(_S3, 0))
    res = planner.search(np.array([0.2, 0.5, 0.3]), 2)
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["action"] == res.action + 1
    assert d["root_bounds"] == [x + 1 for x in res.root_bounds]
    assert [q is None for q in d["q_values"]] == np.isnan(res.q_values).tolist()
    assert d["nodes_expanded"] == list(res.nodes_expanded) and d["depth"] == 2
    assert isinstance(res, SearchResult)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_bad_depth_is_rejected(bad: object) -> None:
    with pytest.raises(ValueError, match="depth"):
        Planner(_S3).search(np.ones(3) / 3, bad)  # type: ignore[arg-type]


def test_bad_belief_and_budget_are_rejected() -> None:
    planner = Planner(_S3)
    with pytest.raises(ValueError, match="belief"):
        planner.search(np.array([0.5, 0.6, 0.0]), 1)
    with pytest.raises(ValueError, match="belief"):
        planner.search(np.array([0.5, 0.5]), 1)
    with pytest.raises(ValueError, match="time_budget"):
        planner.plan(np.ones(3) / 3, 2, time_budget=-1.0)


def test_tracking_transitions_are_used_unchanged() -> None:
    """Guard for the no-prune construction: P[a] moves the state up more for larger a."""
    P = tracking_transitions(8, 3)
    expected = P @ np.arange(8.0)
    assert np.all(np.diff(expected, axis=0) > 0)


def test_stop_rule_predicts_from_the_growth_of_the_last_two_depths() -> None:
    # next depth predicted at t_d * max(1, t_d / t_{d-1}); hopeless beyond margin * remaining
    assert not next_depth_cannot_finish([0.01], remaining=1e-9)  # one depth: no growth known
    assert next_depth_cannot_finish([0.01, 0.1], remaining=0.6, margin=1.5)  # predicted 1.0 > 1.5 * 0.6
    assert not next_depth_cannot_finish([0.01, 0.1], remaining=0.7, margin=1.5)  # 1.0 < 1.5 * 0.7
    assert not next_depth_cannot_finish([0.2, 0.1], remaining=0.06, margin=2.0)  # shrinking: 0.1 < 0.12
    assert next_depth_cannot_finish([0.2, 0.1], remaining=0.04, margin=2.0)
    assert next_depth_cannot_finish([0.0, 0.1], remaining=0.0)


def test_the_next_depth_is_predicted_from_the_leaves_it_must_value() -> None:
    # depth 1 of S = 1024, A = 4 took 30 ms for 1 024 children: depth 2 values at least one action
    # of each child, at least about 1 024 / 4 / 8 times depth 1's time
    assert next_depth_cannot_finish([0.03], remaining=0.07, level_sizes=(1, 1024), A=4)
    assert not next_depth_cannot_finish([0.03], remaining=0.07)  # without the sizes: no prediction
    # a small model: depth 1 in 20 us with 24 children of 3 actions: depth 2 about 160 us, well within
    assert not next_depth_cannot_finish([2e-5], remaining=0.05, level_sizes=(1, 24), A=3)
    # the larger of the two predictions counts: growth 2 gives 0.2 s, the leaves
    # 0.1 * 4 000 / (3 * 24) / 8 = 0.69 s (0.069 s with 400 leaves); hopeless above 1.5 * 0.3 s
    assert next_depth_cannot_finish([0.05, 0.1], remaining=0.3, level_sizes=(1, 24, 4000), A=3)
    assert not next_depth_cannot_finish([0.05, 0.1], remaining=0.3, level_sizes=(1, 24, 400), A=3)
    assert next_depth_cannot_finish([0.05, 0.1], remaining=0.1, level_sizes=(1, 24, 400), A=3)  # growth


def test_predicted_stop_returns_the_same_decision_without_costing_depth() -> None:
    """Over a sweep of deadlines (deterministic clock), the predictive stop never returns a
    shallower depth than running into the deadline, returns the same decision, and when it
    stops it saves the time of the hopeless depth."""
    b = np.random.default_rng(4).dirichlet(np.ones(8))
    stopped = 0
    for budget in range(1, 3000, 7):
        kw = dict(max_depth=3, time_budget=float(budget), use_bounds=False)
        plain = Planner(_S8, chunk_bytes=4096, clock=FakeClock()).plan(b, predict_stop=False, **kw)
        pred = Planner(_S8, chunk_bytes=4096, clock=FakeClock()).plan(b, **kw)
        assert pred.depth == plain.depth
        assert pred.action == plain.action
        np.testing.assert_array_equal(pred.q_values, plain.q_values)
        assert pred.time_used <= plain.time_used
        if pred.predicted_stop:
            stopped += 1
            assert pred.deadline_hit and pred.time_used < plain.time_used
    assert stopped > 0  # the rule did fire somewhere in the sweep
    assert pred.depth == 3 and not pred.deadline_hit and not pred.predicted_stop  # big budgets: no stop
