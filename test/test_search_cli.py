"""Tests of ``pomdp-planner plan``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
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
