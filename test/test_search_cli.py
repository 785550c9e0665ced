"""Tests of ``pomdp-planner plan``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main, plan
from pomdp_planner.core import search_kernel, search_time
from pomdp_planner.core.bounds import BOUND_CONSTANTS, BOUND_VARIANTS, DEFAULT_CONSTANT, sample_beliefs, solve_bounds
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.search import (
    MAX_DEPTH_RANGE,
    TIME_BUDGET_RANGE,
    check_depth,
    check_time_budget,
    complete_tree_nodes,
)
from pomdp_planner.core.search_time import ANNOUNCE_SECONDS, MAX_SEARCH_SECONDS, search_notice, search_seconds

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"
S3 = str(MODELS / "tracking_s3_info.yaml")
S8_NATURAL = str(MODELS / "tracking_s8_natural.yaml")


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
    ("0.2,0.5,0.4", "sums to 1.1, not 1"),
    ("-0.2,0.7,0.5", "entry 0 is negative"),
    ("a,b,c", "comma-separated"),
])
def test_plan_bad_belief_exits_2(capsys: pytest.CaptureFixture[str], belief: str, message: str) -> None:
    assert main(["plan", S3, f"--belief={belief}", "--json"]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["--depth", "0"], "--depth: must be an integer in 1..50, got 0"),
    (["--depth", "51"], "--depth: must be an integer in 1..50"),
    (["--time-budget", "0.5", "--max-depth", "0"], "--max-depth: must be an integer in 1..50"),
    (["--time-budget", "0"], "--time-budget: must be a number of seconds in 0.001..60"),
    (["--time-budget", "nan"], "--time-budget: must be a number of seconds in 0.001..60"),
    (["--time-budget", "61"], "--time-budget: must be a number of seconds in 0.001..60"),
])
def test_plan_search_parameters_use_the_cores_ranges(capsys: pytest.CaptureFixture[str], argv: list[str],
                                                     message: str) -> None:
    """The ranges are the core's (``core.search.MAX_DEPTH_RANGE``, ``TIME_BUDGET_RANGE``), the same the
    planner node's parameters use."""
    assert (MAX_DEPTH_RANGE, TIME_BUDGET_RANGE) == ((1, 50), (0.001, 60.0))
    assert main(["plan", S3, *argv]) == 2
    assert message in capsys.readouterr().err


def test_variant_choices_come_from_the_core() -> None:
    from pomdp_planner.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for command in ("plan", "bounds"):
        variant = next(a for a in sub.choices[command]._actions if a.dest == "variant")
        assert tuple(variant.choices) == BOUND_VARIANTS
        constant = next(a for a in sub.choices[command]._actions if a.dest == "constant")
        assert tuple(constant.choices) == BOUND_CONSTANTS and constant.default == DEFAULT_CONSTANT == "mlr"


def test_core_validators_are_the_last_guard() -> None:
    assert check_depth(3) == 3 and check_depth(np.int64(7), "d", MAX_DEPTH_RANGE) == 7
    assert check_time_budget(0) == 0.0 and check_time_budget(np.float32(0.25)) == 0.25
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="depth"):
            check_depth(bad)
    for bad in (-1.0, float("inf"), "x", "0.25", None, True):
        with pytest.raises(ValueError, match="time_budget"):
            check_time_budget(bad)
    with pytest.raises(ValueError, match=r"in 1\.\.50"):
        check_depth(51, allowed=MAX_DEPTH_RANGE)


def test_plan_constant_fosd_vs_mlr_on_the_natural_s8_model(capsys: pytest.CaptureFixture[str]) -> None:
    """``plan --constant``: on the natural S = 8 model the MLR-exact bounds (C = 1) are tighter than the
    FOSD ones (C_S = 1.82). At a reachable belief where the MLR bounds agree and the FOSD bounds do
    not, the JSON root bounds differ accordingly (the MLR interval inside the FOSD one), MLR certifies
    and FOSD does not, and both choose the action of exhaustive search (both bounds are valid)."""
    model = load_model(S8_NATURAL)
    B = sample_beliefs(model, 200, seed=5)
    lo_m, up_m = solve_bounds(model, constant="mlr").myopic.actions(B)
    lo_f, up_f = solve_bounds(model, constant="fosd").myopic.actions(B)
    assert np.all((lo_f <= lo_m) & (up_m <= up_f))  # fewer constraints, tighter bounds at every belief
    where = np.flatnonzero((lo_m == up_m) & (lo_f < up_f))
    assert where.size, "no sampled belief where the two constants' bounds differ"
    b = B[where[0]]
    text = ",".join(repr(float(x)) for x in b)
    out = {c: run_json(capsys, "plan", S8_NATURAL, "--belief", text, "--depth", "2", "--constant", c, "--json")
           for c in ("mlr", "fosd")}
    rm, rf = out["mlr"]["root_bounds"], out["fosd"]["root_bounds"]
    assert rm != rf and rf[0] <= rm[0] <= rm[1] <= rf[1]
    assert rm == [int(lo_m[where[0]]) + 1, int(up_m[where[0]]) + 1]  # priorities, 1-based
    assert rf == [int(lo_f[where[0]]) + 1, int(up_f[where[0]]) + 1]
    assert out["mlr"]["certified"] and not out["fosd"]["certified"]
    exhaustive = build_planner(model, use_bounds=False).planner.search(b, 2).priority
    assert out["mlr"]["action"] == out["fosd"]["action"] == exhaustive
    for c, d in out.items():
        assert d["bounds"]["constant"] == d["gate"]["constant"] == c and d["bounds"]["why"].startswith(c + ":")
    assert main(["plan", S8_NATURAL, "--belief", text, "--depth", "2", "--constant", "fosd"]) == 0
    assert "constant fosd" in capsys.readouterr().out  # the text output says which constant



def test_a_long_default_search_is_announced_and_one_beyond_the_limit_refused(monkeypatch, capsys):
    """``plan`` with the default depth on a model where it takes long: one line on stderr with the
    expected time before the search (above ANNOUNCE_SECONDS), a refusal with the estimate above
    MAX_SEARCH_SECONDS unless --no-limit. The thresholds are lowered here, so that a small model
    shows both without a long search."""
    model = S3
    monkeypatch.setattr(search_time, "ANNOUNCE_SECONDS", 0.0)
    assert main(["plan", model, "--belief", "uniform"]) == 0
    out, err = capsys.readouterr()
    engine = "compiled" if search_kernel.load()[0] is not None else "numpy"
    expected = search_time.search_seconds(3, 3, 3, 3, engine)
    node, state = search_time.ENGINE_SECONDS[engine]
    assert expected == complete_tree_nodes(3, 3, 3) * (node + 3 * state)
    assert err.splitlines() == [
        f"pomdp-planner plan: a search of depth 3 on this model (S=3, A=3, Z=3) is expected to take up to about "
        f"{expected:.0f} s (820 belief nodes in the complete tree; branch-and-bound prunes some); --time-budget S "
        "bounds it"]
    assert out.startswith("action: priority ")
    monkeypatch.setattr(plan, "MAX_SEARCH_SECONDS", 1e-6)
    assert main(["plan", model, "--belief", "uniform"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pomdp-planner: error: --depth: a search of depth 3 on this model ")
    assert "more than the limit of 0 s; use --time-budget S (anytime search, stopped in time)" in err[0]
    assert main(["plan", model, "--belief", "uniform", "--no-limit"]) == 0
    assert main(["plan", model, "--belief", "uniform", "--time-budget", "0.05"]) == 0  # the anytime search: bounded


def test_the_expected_time_tells_seconds_from_minutes_on_the_model_that_ran_98_s():
    """S = 60, A = 8, Z = 60 at the default depth 3 (98 s with the numpy search, 21 s with the
    compiled kernel, unannounced before): announced on either engine; at depth 2 (0.04-0.14 s) not."""
    for engine, text in (("numpy", "78 s"), ("compiled", "29 s")):
        assert ANNOUNCE_SECONDS < search_seconds(60, 8, 60, 3, engine) < MAX_SEARCH_SECONDS
        assert f"is expected to take up to about {text} (1.11e+08 belief nodes" in search_notice(
            60, 8, 60, 3, "--depth", engine=engine)
        assert search_notice(60, 8, 60, 2, "--depth", engine=engine) == ""
