"""The compiled search kernel (``core/search_kernel.c``) against its numpy reference
(``core/search_reference.py``): equal root values (1e-12, relative to ``max(1, |Q|)``), equal node
counts per level, equal root bounds, on every shipped model and on random ones, for Shannon,
Renyi-2 and no uncertainty, depths 1-5, with and without bounds, at beliefs with zero entries and
with impossible observation branches, and under deadlines (a clock that counts its readings: the
two engines read it at the same steps, so they stop at the same point). The CSR layout of ``P`` and
``O`` against the dense one, the kernel's logarithm against numpy's, its belief rule against
:func:`~pomdp_planner.core.belief.check_belief`.

Under ``make test`` (``POMDP_PLANNER_REQUIRE_KERNEL=1``) the kernel must be installed and used:
:func:`test_the_compiled_kernel_is_installed_and_used` fails otherwise, so a run cannot silently
test the numpy engine twice.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_search import FakeClock  # one unit per reading: both engines read it at the same steps

from pomdp_planner.core import search_kernel
from pomdp_planner.core.belief import check_belief
from pomdp_planner.core.bounds import solve_bounds
from pomdp_planner.core.errors import BeliefError
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.myopic import MyopicBounds
from pomdp_planner.core.search import DeadlineExceeded, Planner, SearchResult

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "config" / "models").glob("*.yaml")) + sorted((ROOT / "test" / "models").glob("*"))

pytestmark = pytest.mark.skipif(not search_kernel.available() and os.environ.get("POMDP_PLANNER_REQUIRE_KERNEL") != "1",
                                reason=search_kernel.load()[1] or "kernel available")


def test_the_compiled_kernel_is_installed_and_used() -> None:
    assert search_kernel.available(), search_kernel.load()[1]
    model = load_model(ROOT / "config" / "models" / "perimeter_s8.yaml")
    assert build_planner(model).planner.kernel == "c"  # what every entry point gets
    assert Planner(model).kernel == "c" and Planner(model, kernel="numpy").kernel == "numpy"


# ------------------------------------------------------------------------------- helpers
def close(got: np.ndarray, want: np.ndarray) -> bool:
    """Equal NaN patterns and values within 1e-12 relative to max(1, |want|)."""
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    if not np.array_equal(np.isnan(got), np.isnan(want)):
        return False
    ok = ~np.isnan(want)
    return bool(np.all(np.abs(got[ok] - want[ok]) <= 1e-12 * np.maximum(1.0, np.abs(want[ok]))))


def same(rk: SearchResult, rr: SearchResult) -> None:
    """Kernel result ``rk`` equals reference result ``rr`` (values, counts, bounds, decision)."""
    assert close(rk.q_values, rr.q_values), (rk.q_values, rr.q_values)
    assert rk.level_sizes == rr.level_sizes and rk.nodes_expanded == rr.nodes_expanded
    assert rk.root_bounds == rr.root_bounds and rk.depth == rr.depth and rk.partial == rr.partial
    assert rk.deadline_hit == rr.deadline_hit and rk.certified == rr.certified
    assert rk.action == rr.action or math.isclose(rr.q_values[rk.action], rr.value, rel_tol=1e-12, abs_tol=1e-12)


def pair(model: POMDP, bounds: MyopicBounds | None, **kw) -> tuple[Planner, Planner]:
    return Planner(model, bounds, kernel="c", **kw), Planner(model, bounds, kernel="numpy", **kw)


def some_bounds(model: POMDP, seed: int = 0) -> MyopicBounds:
    """The LP's bounds when it is feasible, else arbitrary ones (they still prune, maybe crossed)."""
    try:
        sol = solve_bounds(model, "tight")
        if sol.feasible:
            return sol.myopic
    except ValueError:
        pass
    rng = np.random.default_rng(seed)
    return MyopicBounds(model, rng.normal(0, 2, model.S), rng.normal(0, 2, model.S))


def beliefs(S: int, seed: int) -> list[np.ndarray]:
    """Two random beliefs, one with zero entries, a vertex and the uniform belief."""
    rng = np.random.default_rng(seed)
    sparse = rng.dirichlet(np.ones(S))
    sparse[rng.permutation(S)[: S // 2]] = 0.0
    return [rng.dirichlet(np.ones(S)), rng.dirichlet(np.full(S, 0.3)), sparse / sparse.sum(),
            np.eye(S)[S - 1], np.full(S, 1.0 / S)]


def random_model(seed: int, S: int, A: int, Z: int, uncertainty: str, zeros: float = 0.3) -> POMDP:
    """A random model with zero entries in P and O (impossible branches, beliefs with zeros)."""
    rng = np.random.default_rng(seed)
    P = rng.dirichlet(np.ones(S), size=(A, S))
    P[P < zeros / S] = 0.0
    P[:, :, 0] += 1.0 - P.sum(axis=2)
    O = rng.dirichlet(np.ones(Z), size=(A, S))
    O[O < zeros / Z] = 0.0
    O[:, :, -1] += 1.0 - O.sum(axis=2)
    return POMDP(P=P, O=O, r=rng.uniform(-1, 2, (S, A)), gamma=0.9, uncertainty=uncertainty,
                 w=rng.uniform(0.0, 1.5, A), name=f"random{seed}")


# ------------------------------------------------------------------------- shipped models
@pytest.mark.parametrize("path", [p for p in SHIPPED if "grid" not in p.name], ids=lambda p: p.name)
def test_shipped_models(path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = load_model(path)
    kernel, reference = pair(model, some_bounds(model))
    small = model.S * model.A * model.Z <= 32
    for i, b in enumerate(beliefs(model.S, 1)):
        for depth in range(1, 6):
            for use_bounds in (True, False):
                if depth == 5 and not small and (not use_bounds or i > 1):
                    continue  # the exhaustive S = 8 tree of depth 5 has 8.3 M nodes: numpy takes seconds
                same(kernel.search(b, depth, use_bounds), reference.search(b, depth, use_bounds))
        assert kernel.count_nodes(b, 4) == reference.count_nodes(b, 4) == kernel.search(b, 4).level_sizes
        for use_bounds in (True, False):
            assert close(kernel.q_values_batch(np.array(beliefs(model.S, 2)), 2, use_bounds),
                         reference.q_values_batch(np.array(beliefs(model.S, 2)), 2, use_bounds))


@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
@pytest.mark.parametrize("fused", [True, False], ids=["fused", "unfused"])
def test_tracking_model_for_every_uncertainty_function(uncertainty: str, fused: bool) -> None:
    """The S = 8 model with each uncertainty function, with and without the fused leaf table."""
    m = load_model(ROOT / "config" / "models" / "tracking_s8_info.yaml")
    model = POMDP(P=m.P, O=m.O, r=m.r, gamma=m.gamma, uncertainty=uncertainty, w=m.w)
    kernel, reference = pair(model, some_bounds(model, 3), fused=fused)
    assert kernel._kernel.fused == fused
    for b in beliefs(8, 4)[:3]:
        for depth in (1, 2, 3, 4):
            for use_bounds in (True, False):
                same(kernel.search(b, depth, use_bounds), reference.search(b, depth, use_bounds))


@pytest.mark.parametrize("path", [p for p in SHIPPED if "grid" in p.name], ids=lambda p: p.name)
def test_shipped_grid_models(path: Path) -> None:
    """The grids (S = 100 and 1 600, stored sparse when that is smaller: the kernel searches their
    non-zeros, the reference their dense form) at the depths a grid is planned at, from the uniform
    belief and from a point belief."""
    model = load_model(path)
    kernel, reference = pair(model, None)
    assert kernel._kernel.sparse == (model.sparse, model.sparse)
    point = np.eye(model.S)[model.S // 2 + 3]
    for b, depths in ((np.full(model.S, 1 / model.S), (1, 2) if model.S <= 100 else (1,)), (point, (1, 2))):
        for depth in depths:
            same(kernel.search(b, depth, False), reference.search(b, depth, False))


# -------------------------------------------------------------------------- random models
@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), S=st.integers(1, 5), A=st.integers(1, 4), Z=st.integers(1, 4),
       uncertainty=st.sampled_from(["renyi2", "shannon", "none"]), depth=st.integers(1, 3),
       zeros=st.sampled_from([0.0, 0.5, 1.5]), fused=st.booleans())
def test_random_models(seed: int, S: int, A: int, Z: int, uncertainty: str, depth: int, zeros: float,
                       fused: bool) -> None:
    model = random_model(seed, S, A, Z, uncertainty, zeros)
    rng = np.random.default_rng(seed)
    bounds = MyopicBounds(model, rng.normal(0, 2, S), rng.normal(0, 2, S))  # arbitrary: crossed ones too
    kernel, reference = pair(model, bounds, fused=fused)
    for b in beliefs(S, seed)[:3]:
        for use_bounds in (True, False):
            same(kernel.search(b, depth, use_bounds), reference.search(b, depth, use_bounds))
            same(kernel.search(b, depth, use_bounds, all_root_actions=True),
                 reference.search(b, depth, use_bounds, all_root_actions=True))
    price = rng.normal(size=A)
    for use_bounds in (True, False):
        same(kernel.priced(price).search(b, depth, use_bounds), reference.priced(price).search(b, depth, use_bounds))


def test_impossible_branches_and_tiny_eta() -> None:
    """Identity transitions and observations: most branches have eta = 0, and eta ~ 1e-200 takes the
    safe leaf path in both engines."""
    S = A = 3
    eye = np.broadcast_to(np.eye(S), (A, S, S))
    for uncertainty in ("renyi2", "shannon", "none"):
        model = POMDP(P=eye, O=eye, r=np.arange(9.0).reshape(3, 3) / 9, gamma=0.95, uncertainty=uncertainty,
                      w=np.ones(A))
        kernel, reference = pair(model, None)
        for b in (np.array([0.5, 0.5, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.5, 0.5 - 1e-200, 1e-200])):
            for depth in (1, 2, 3):
                rk, rr = kernel.search(b, depth, False), reference.search(b, depth, False)
                same(rk, rr)
                assert rk.nodes_pruned[-1] > 0 or b.all()  # a full-support belief reaches every branch


# ------------------------------------------------------------------------------ deadlines
@pytest.mark.parametrize("name", ["tracking_s8_info", "perimeter_s3"])
def test_deadlines_stop_both_engines_at_the_same_step(name: str) -> None:
    """Over a sweep of budgets (in clock readings), the anytime search returns the same depth,
    partial depth-1 results, values and counts from both engines, after the same number of readings."""
    model = load_model(ROOT / "config" / "models" / f"{name}.yaml")
    bounds = some_bounds(model)
    b = beliefs(model.S, 5)[0]
    partial = depths = 0
    for budget in range(1, 400, 3):
        out = []
        for kernel in ("c", "numpy"):
            clock = FakeClock()
            planner = Planner(model, bounds, kernel=kernel, clock=clock, chunk_bytes=2048)
            out.append((planner.plan(b, 4, float(budget), use_bounds=budget % 2 == 0, predict_stop=False), clock.t))
        (rk, tk), (rr, tr) = out
        same(rk, rr)
        assert tk == tr
        partial += rk.partial
        depths |= 1 << rk.depth
    assert partial > 0 and depths.bit_count() >= 3  # budgets ending inside depth 1 and inside deeper ones


def test_a_fixed_depth_search_under_a_deadline_raises_at_the_same_reading() -> None:
    model = load_model(ROOT / "config" / "models" / "perimeter_s8.yaml")
    b = np.full(8, 1 / 8)
    for deadline in (0.5, 3.5, 20.5):
        readings = []
        for kernel in ("c", "numpy"):
            clock = FakeClock()
            with pytest.raises(DeadlineExceeded):
                Planner(model, kernel=kernel, clock=clock, chunk_bytes=2048).search(b, 3, False, deadline=deadline)
            readings.append(clock.t)
        assert readings[0] == readings[1] == max(2, math.floor(deadline) + 1)  # the start, then one per step


def test_a_clock_that_raises_stops_the_kernel_with_its_error() -> None:
    model = load_model(ROOT / "config" / "models" / "perimeter_s3.yaml")

    def broken() -> float:
        raise OSError("clock gone")

    planner = Planner(model, clock=broken)
    with pytest.raises(OSError, match="clock gone"):
        planner.search(np.full(3, 1 / 3), 2, deadline=10.0)


def test_depth_one_is_interrupted_between_root_actions_in_decreasing_rho() -> None:
    """A deadline already passed when the anytime search starts: depth 1 finishes only the root
    action with the largest rho(b0, a) (the first one taken), marked partial."""
    model = load_model(ROOT / "config" / "models" / "tracking_s8_info.yaml")
    b = beliefs(8, 6)[0]
    for kernel in ("c", "numpy"):
        res = Planner(model, kernel=kernel).plan(b, 5, time_budget=0.0, use_bounds=False)
        assert res.partial and res.deadline_hit and res.depth == 1
        assert np.flatnonzero(np.isfinite(res.q_values)).tolist() == [int(np.argmax(model.rho(b)))]
        assert res.action == int(np.argmax(model.rho(b))) and res.to_dict()["partial"] is True


# ------------------------------------------------------------------------------ layouts
@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon", "none"])
def test_csr_transitions_and_observations_equal_dense(uncertainty: str) -> None:
    """The CSR variant of the prediction and observation steps (search_kernel.csr_rows), each
    matrix alone and both together, against the dense kernel."""
    model = random_model(7, 6, 3, 5, uncertainty, zeros=1.5)
    assert (model.P == 0).any() and (model.O == 0).any()
    bounds = some_bounds(model, 7)
    dense = Planner(model, bounds)
    for P, O in ((True, False), (False, True), (True, True)):
        sparse = Planner(model, bounds)
        rows = search_kernel.csr_rows
        sparse._kernel = search_kernel.KernelEngine(model, bounds, False, P=rows(model.P) if P else None,
                                                    O=rows(model.O) if O else None)
        assert sparse._kernel.sparse == (P, O)
        for b in beliefs(6, 8):
            for depth in (1, 2, 3):
                for use_bounds in (True, False):
                    same(sparse.search(b, depth, use_bounds), dense.search(b, depth, use_bounds))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10**6), S=st.integers(1, 6), A=st.integers(1, 3), Z=st.integers(1, 5),
       uncertainty=st.sampled_from(["renyi2", "shannon", "none"]), depth=st.integers(1, 3),
       zeros=st.sampled_from([0.5, 1.5, 3.0]))
def test_models_stored_sparse_are_searched_through_their_non_zeros(seed: int, S: int, A: int, Z: int,
                                                                   uncertainty: str, depth: int, zeros: float) -> None:
    """A model stored sparse (``POMDP(storage="sparse")``) is searched by the kernel on its CSR rows
    (no dense P or O is built) and agrees with the numpy reference on the dense form."""
    dense = random_model(seed, S, A, Z, uncertainty, zeros)
    model = POMDP(P=dense.P, O=dense.O, r=dense.r, gamma=dense.gamma, uncertainty=uncertainty, w=dense.w,
                  storage="sparse")
    rng = np.random.default_rng(seed)
    bounds = MyopicBounds(model, rng.normal(0, 2, S), rng.normal(0, 2, S))
    kernel = Planner(model, bounds)
    assert kernel.kernel == "c" and kernel._kernel.sparse == (True, True) and not kernel.fused
    assert "P" not in vars(model) and "O" not in vars(model)
    reference = Planner(dense, MyopicBounds(dense, bounds.g, bounds.h), kernel="numpy")
    for b in beliefs(S, seed)[:4]:
        for use_bounds in (True, False):
            same(kernel.search(b, depth, use_bounds), reference.search(b, depth, use_bounds))


@pytest.mark.parametrize("uncertainty", ["renyi2", "shannon"])
def test_a_sparse_grid_is_searched_as_the_reference_searches_its_dense_form(uncertainty: str) -> None:
    from pomdp_planner.core.domains.grid import grid_model

    model = grid_model(6, 7, uncertainty=uncertainty, storage="sparse")
    dense = grid_model(6, 7, uncertainty=uncertainty, storage="dense")
    kernel, reference = Planner(model), Planner(dense, kernel="numpy")
    assert kernel._kernel.sparse == (True, True)
    point = np.eye(model.S)[17]
    for b, depths in ((np.full(model.S, 1 / model.S), (1, 2)), (point, (1, 2, 3))):
        for depth in depths:
            same(kernel.search(b, depth, False), reference.search(b, depth, False))


def test_csr_rows_hold_the_non_zeros() -> None:
    M = np.array([[[0.0, 2.0], [3.0, 0.0]], [[0.0, 0.0], [5.0, 6.0]]])
    rows = search_kernel.csr_rows(M)
    assert rows.indptr.tolist() == [0, 1, 2, 2, 2, 4]
    assert rows.indices.tolist() == [1, 0, 0, 1] and rows.data.tolist() == [2.0, 3.0, 5.0, 6.0]


# -------------------------------------------------------------------- logarithm, belief rule
def test_the_kernels_logarithm_is_within_one_ulp() -> None:
    rng = np.random.default_rng(0)
    x = np.concatenate([np.exp(rng.uniform(-745, 709, 200_000)), rng.uniform(0.5, 2.0, 200_000),
                        1.0 + rng.normal(0, 1e-8, 10_000), [5e-324, 2.2250738585072014e-308, 1.0, 2.0, 1e-300]])
    out = np.empty_like(x)
    search_kernel.load()[0].log_array(x, out)
    want = np.log(x)
    assert np.all(np.abs(out - want) <= np.spacing(np.abs(want)) + 1e-300)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-2e-6, 1.0) | st.sampled_from([math.nan, math.inf]), min_size=3, max_size=3),
       st.floats(-3e-6, 3e-6))
def test_the_kernels_belief_rule_is_check_belief(values: list[float], shift: float) -> None:
    """Accepted by the kernel iff by check_belief (same message when not), normalised alike."""
    model = load_model(ROOT / "config" / "models" / "perimeter_s3.yaml")
    b = np.array(values)
    if np.all(np.isfinite(b)) and b.sum() > 0:
        b = b / b.sum() + shift / 3  # near the tolerance of the sum
    try:
        want = check_belief(model, b)
    except BeliefError as exc:
        with pytest.raises(BeliefError) as got:
            Planner(model).search(b, 1)
        assert str(got.value) == str(exc)
        return
    same(Planner(model).search(b, 2), Planner(model, kernel="numpy").search(want, 2, checked=True))


def test_batched_beliefs_are_checked_with_their_row() -> None:
    planner = Planner(load_model(ROOT / "config" / "models" / "perimeter_s3.yaml"))
    B = np.array([[0.2, 0.3, 0.5], [0.5, 0.6, 0.0]])
    with pytest.raises(BeliefError, match=r"^beliefs\[1\]: sums to"):
        planner.q_values_batch(B, 2)
    np.testing.assert_array_equal(planner.q_values_batch(B[:1], 2, checked=True), planner.q_values_batch(B[:1], 2))


def test_without_the_kernel_planners_use_numpy_and_warn_once(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(search_kernel, "_loaded", (None, "the compiled search kernel is not installed (test)"))
    monkeypatch.setattr(search_kernel, "_warned", False)
    model = load_model(ROOT / "config" / "models" / "perimeter_s3.yaml")
    with pytest.warns(RuntimeWarning, match="not installed .*numpy reference"):
        planner = Planner(model)
    assert planner.kernel == "numpy"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert Planner(model).kernel == "numpy"  # once per process
    with pytest.raises(ValueError, match="kernel: the compiled kernel cannot be used"):
        Planner(model, kernel="c")
