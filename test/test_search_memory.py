"""Memory guard of the search: the estimate bounds what a search allocates, and a
search that would exceed the planner's budget is refused before it starts, with the figures.

The estimate (``core.search.search_memory_estimate``) is checked against an independent
measurement: the ``tracemalloc`` peak of real searches (numpy reports its buffers to it), for
exhaustive and branch-and-bound search, default and small chunks. Its growth with the depth is
what makes deep searches dangerous (memory grows with the depth, the tree with ``(A Z)^depth``).
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP, format_bytes
from pomdp_planner.core.search import (
    DEFAULT_MEMORY_BUDGET,
    MAX_SEARCH_DEPTH,
    Planner,
    SearchMemoryError,
    check_search_memory,
    search_memory_estimate,
)

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"


def traced_peak(fn, *args, **kwargs) -> int:
    tracemalloc.start()
    try:
        fn(*args, **kwargs)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.fixture(scope="module")
def s8():
    return load_model(MODELS / "tracking_s8_info.yaml")


@pytest.fixture(scope="module")
def s3():
    return load_model(MODELS / "tracking_s3_info.yaml")


@pytest.mark.parametrize(("name", "chunk", "use_bounds", "depths"), [
    ("s8", 4 * 2**20, False, range(1, 5)),
    ("s8", 4 * 2**20, True, range(1, 6)),
    ("s3", 16 * 2**10, False, range(1, 8)),
    ("s3", 64 * 2**10, True, range(1, 7)),
])
def test_estimate_bounds_the_measured_peak(request, name, chunk, use_bounds, depths, engine):
    """Both engines (the kernel allocates through PyMem_RawMalloc, which tracemalloc sees); the
    numpy engine, the larger, comes within a factor 4 where the levels dominate."""
    model = request.getfixturevalue(name)
    setup = build_planner(model, use_bounds=use_bounds, chunk_bytes=chunk)
    assert setup.mode == ("prune" if use_bounds else "exhaustive")
    planner = Planner(model, setup.planner.bounds, chunk_bytes=chunk, kernel=engine)
    b = np.full(model.S, 1.0 / model.S)
    for d in depths:
        peak = traced_peak(planner.search, b, d, use_bounds=use_bounds)
        est = planner.memory_estimate(d)
        assert peak <= est, (d, peak, est)
        if d >= 3 and not use_bounds and engine == "numpy":  # not vacuous where the levels dominate
            assert est <= 4 * peak, (d, peak, est)


def test_memory_grows_with_the_depth_not_the_tree(s3, engine):
    """Saturated levels add a constant amount: the measured growth per level stays below the
    estimate's, while the tree grows nine-fold per level."""
    planner = Planner(s3, None, chunk_bytes=16 * 2**10, kernel=engine)
    b = np.full(3, 1.0 / 3)
    peaks = [traced_peak(planner.search, b, d, use_bounds=False) for d in (5, 6, 7)]
    steps = np.diff(peaks)
    assert np.all(steps > 0)
    est_step = planner.memory_estimate(7) - planner.memory_estimate(6)
    assert np.all(steps <= est_step) and est_step <= 3 * steps.max()


def test_search_over_budget_is_refused_before_allocating(s8):
    budget = search_memory_estimate(8, 3, 8, 3)
    planner = Planner(s8, None, memory_budget=budget)
    b = np.full(8, 1.0 / 8)
    assert planner.search(b, 3, use_bounds=False).depth == 3
    tracemalloc.start()
    try:
        with pytest.raises(SearchMemoryError) as info:
            planner.search(b, 6, use_bounds=False)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**10
    msg = str(info.value)
    need = planner.memory_estimate(6)
    assert msg.startswith("depth: a search of depth 6 needs about ")
    assert f"needs about {format_bytes(need)} " in msg and f"memory budget of {format_bytes(budget)};" in msg
    assert "S=8, A=3, Z=8" in msg and f"{sum(24**i for i in range(7)):.3g} belief nodes" in msg
    assert msg.endswith("the deepest depth within it is 3")
    assert isinstance(info.value, ValueError)


def test_plan_and_count_nodes_are_guarded_too(s8):
    planner = Planner(s8, None, memory_budget=search_memory_estimate(8, 3, 8, 2))
    b = np.full(8, 1.0 / 8)
    with pytest.raises(SearchMemoryError, match=r"^max_depth: a search of depth 4 needs .* within it is 2"):
        planner.plan(b, max_depth=4, time_budget=10.0, use_bounds=False)
    with pytest.raises(SearchMemoryError, match=r"^depth: a search of depth 3 needs"):
        planner.count_nodes(b, 3, use_bounds=False)
    assert planner.plan(b, max_depth=2, use_bounds=False).depth == 2
    tiny = Planner(s8, None, memory_budget=1000)
    with pytest.raises(SearchMemoryError, match="not even depth 1 fits"):
        tiny.search(b, 1)


def test_depth_beyond_the_recursion_cap_is_refused():
    """A chain model (A = Z = 1) needs almost no memory per level; depth 2000 used to end in
    RecursionError. Every depth up to MAX_SEARCH_DEPTH still runs."""
    m = POMDP(P=np.full((1, 2, 2), 0.5), O=np.ones((1, 2, 1)), r=np.array([[1.0], [0.0]]), gamma=0.9)
    planner = Planner(m)
    b = np.array([0.5, 0.5])
    res = planner.search(b, MAX_SEARCH_DEPTH, use_bounds=False)
    assert res.q_values[0] == pytest.approx(0.5 * sum(0.9**k for k in range(MAX_SEARCH_DEPTH + 1)))
    for depth in (MAX_SEARCH_DEPTH + 1, 2000):
        with pytest.raises(SearchMemoryError, match=rf"depth: {depth} is deeper than MAX_SEARCH_DEPTH = 100"):
            planner.search(b, depth)


def test_default_budget_admits_the_paper_depths(s8):
    assert DEFAULT_MEMORY_BUDGET == 2**30
    planner = Planner(s8, None)
    for d in range(1, 11):
        planner.check_memory(d)
    # a step of a large model is one parent under one action, but its children fill a level: Z S floats
    with pytest.raises(SearchMemoryError, match=r"depth: a search of depth 90 needs .* GiB .*S=1600, A=2, Z=1600"):
        check_search_memory(1600, 2, 1600, 90, DEFAULT_MEMORY_BUDGET)
