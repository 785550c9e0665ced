"""The peer comparison's units of work (issue 6): chunks of seeded episodes that can run in
parallel processes and be resumed from a cache must give exactly the rows of one plain
sequential run, episode by episode, which is also checked against a direct simulation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.bench.experiments import peers
from pomdp_planner.bench.experiments.peers import PeerChunk, PeerPlan, compare_peers
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.simulate import simulate

S3 = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "tracking_s3_info.yaml")


def _plan(**kw) -> PeerPlan:
    base = dict(budgets=(0.01,), episodes_cheap=5, episodes_by_budget={0.01: 2}, steps=6, max_depth=3, seed=77,
                with_pouct=False, chunk=2)
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
    assert plan.total_units(1) == 3 * 5 + 2 * 2


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
    files = sorted(tmp_path.glob("*.pickle"))
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


def test_unknown_peer_is_rejected() -> None:
    with pytest.raises(ValueError, match="planner"):
        peers.run_chunk(PeerChunk("s3", "oracle", None, 0, 1), S3, _plan())


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


def test_planner_cache_follows_the_model_not_the_label() -> None:
    import pickle

    s8 = load_model(Path(__file__).resolve().parents[1] / "config" / "models" / "tracking_s8_info.yaml")
    p3 = peers._planner_for("m", S3)
    assert peers._planner_for("m", pickle.loads(pickle.dumps(S3))) is p3  # a worker's copy: reused
    p8 = peers._planner_for("m", s8)  # same label, another model: its own planner
    assert p8 is not p3 and p8.planner.model.S == 8
