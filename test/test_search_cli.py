"""Tests of ``pomdp-planner plan``, ``pomdp-planner bench search`` and the search policies."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.bench.search_bench import BenchConfig, bench_model, format_report, run_search_bench
from pomdp_planner.cli import main
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.policies import make_policy, policy_names
from pomdp_planner.core.search import complete_tree_nodes

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"
S3 = str(MODELS / "tracking_s3_info.yaml")


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    assert main(list(argv)) == 0
    return json.loads(capsys.readouterr().out)


def test_plan_json_fixed_depth(capsys: pytest.CaptureFixture[str]) -> None:
    out = run_json(capsys, "plan", S3, "--belief", "0.2,0.5,0.3", "--depth", "3", "--json")
    model = load_model(S3)
    ref = build_planner(model).planner.search(np.array([0.2, 0.5, 0.3]), 3)
    assert out["action"] == ref.priority and 1 <= out["action"] <= 3
    assert out["depth"] == 3 and out["mode"] == "fixed-depth"
    assert out["nodes_expanded"] == list(ref.nodes_expanded)
    assert out["nodes_complete"] == [complete_tree_nodes(3, 3, d) for d in (1, 2, 3)]
    assert out["bounds"]["feasible"] is True and out["certified"] == ref.certified


def test_plan_json_exhaustive_and_anytime(capsys: pytest.CaptureFixture[str]) -> None:
    out = run_json(capsys, "plan", S3, "--belief", "0.2,0.5,0.3", "--depth", "2", "--exhaustive", "--json")
    assert out["root_bounds"] is None and out["bounds"] is None
    assert out["nodes_expanded"] == [10, 91] and all(q is not None for q in out["q_values"])
    out = run_json(capsys, "plan", S3, "--belief", "uniform", "--time-budget", "0.05", "--max-depth", "4",
                   "--exhaustive", "--json")
    assert out["mode"] == "anytime" and 1 <= out["depth"] <= 4
    assert isinstance(out["predicted_stop"], bool)
    assert out["deadline_hit"] or not out["predicted_stop"]  # a predicted stop is a budget-limited depth


def test_plan_text(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", S3, "--belief", "0.2,0.5,0.3", "--depth", "2"]) == 0
    text = capsys.readouterr().out
    assert "action: priority" in text and "% pruned" in text


@pytest.mark.parametrize(("belief", "message"), [
    ("0.2,0.5", "expected 3 probabilities"),
    ("0.2,0.5,0.4", "sum to"),
    ("-0.2,0.7,0.5", "non-negative"),
    ("a,b,c", "comma-separated"),
])
def test_plan_bad_belief_exits_2(capsys: pytest.CaptureFixture[str], belief: str, message: str) -> None:
    assert main(["plan", S3, f"--belief={belief}", "--json"]) == 2
    assert message in capsys.readouterr().err


def test_plan_bad_depth_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", S3, "--depth", "0"]) == 2
    assert "--depth" in capsys.readouterr().err


def test_bench_model_small_config() -> None:
    model = load_model(S3)
    cfg = BenchConfig(beliefs=4, deep_beliefs=2, timed=2, depths=(2, 3, 4), timed_max_depth=3)
    res = bench_model(model, cfg)
    rows = {p["depth"]: p for p in res["pruning"]}
    assert rows[4]["beliefs"] == 2 and rows[2]["beliefs"] == 4
    planner = build_planner(model).planner
    b = np.random.default_rng(0).dirichlet(np.ones(3), size=4)
    mean = np.mean([sum(planner.count_nodes(x, 2)) for x in b])
    assert rows[2]["bnb_nodes_mean"] == pytest.approx(mean)
    assert rows[2]["percent_pruned_mean"] == pytest.approx(100 * (1 - mean / 91))
    assert [t["depth"] for t in res["timing"]] == [2, 3]
    assert all(0.0 <= t["agreement"] <= 1.0 and t["speedup"] > 0 for t in res["timing"])


def test_bench_cli_writes_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "search", "--model", S3, "--beliefs", "2", "--timed", "1", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["benchmark"] == "search" and data["models"][0]["S"] == 3
    assert "paper Table II" in capsys.readouterr().out
    report = format_report(run_search_bench([S3], BenchConfig(beliefs=1, deep_beliefs=1, timed=1, depths=(2,),
                                                                timed_max_depth=2)))
    assert "26.3%" not in report  # the paper's row belongs to the S = Z = 8, A = 3 problem only


def test_search_policies_registered() -> None:
    model = load_model(S3)
    assert {"bnb", "exhaustive", "lower", "upper"} <= set(policy_names())
    b = np.array([0.2, 0.5, 0.3])
    planner = build_planner(model).planner
    assert make_policy("bnb", model, depth=2).act(b) == planner.search(b, 2).action
    assert make_policy("exhaustive", model, depth=2).act(b) == planner.search(b, 2, use_bounds=False).action
    lo, up = planner.root_bounds(b)
    assert make_policy("lower", model).act(b) == lo and make_policy("upper", model).act(b) == up
    assert 0 <= make_policy("bnb", model, time_budget=0.01).act(b) < 3
