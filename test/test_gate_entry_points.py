"""From every entry point, a model failing Assumption 1 never gets a certificate, the
search falls back to exhaustive with the reason, and the explicit override says no guarantee.

The model is ``test/models/fails_assumption1_s3.yaml`` (see test_gate.py); before the gate,
``pomdp-planner plan MODEL --belief 0.3,0.4,0.3 --depth 6`` printed "priority 2 (certified: the
root bounds agree)", and at (0.1, 0.8, 0.1) "root bounds: priorities 2..1". The planner node's
side is in test_nodes_gate.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pomdp_planner.cli import main

REPO = Path(__file__).resolve().parents[1]
FAILING = str(REPO / "test" / "models" / "fails_assumption1_s3.yaml")
S3 = str(REPO / "config" / "models" / "tracking_s3_info.yaml")
AGREE, CROSS = "0.3,0.4,0.3", "0.1,0.8,0.1"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# ------------------------------------------------------------------------ pomdp-planner plan
@pytest.mark.parametrize("belief", [AGREE, CROSS])
def test_plan_text_falls_back_and_says_why(capsys: pytest.CaptureFixture[str], belief: str) -> None:
    code, out, _ = run(capsys, "plan", FAILING, "--belief", belief, "--depth", "6")
    assert code == 0
    assert "certified" not in out
    assert "search: exhaustive search: Assumption 1 fails (A1 fails, A2 fails" in out
    assert "root bounds: none (exhaustive search)" in out and "action: priority 1" in out


def test_plan_json_falls_back_and_says_why(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "plan", FAILING, "--belief", AGREE, "--time-budget", "0.2", "--max-depth", "4",
                         "--json")
    d = json.loads(out)
    assert code == 0 and d["certified"] is False and d["root_bounds"] is None and d["used_bounds"] is False
    assert d["gate"]["mode"] == "exhaustive" and d["gate"]["assumptions_hold"] is False
    assert "Assumption 1 fails" in d["gate"]["reason"] and "Assumption 1 fails" in err


def test_plan_override_says_no_guarantee_and_certifies_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "plan", FAILING, "--belief", AGREE, "--depth", "6", "--prune-without-guarantee")
    assert code == 0 and "certified" not in out
    assert "WITHOUT GUARANTEE" in out and "no guarantee holds" in out
    assert "priorities 2..2 (bounds without guarantee: they certify nothing)" in out
    code, out, _ = run(capsys, "plan", FAILING, "--belief", CROSS, "--depth", "3", "--prune-without-guarantee")
    assert "crossed bounds: no guarantee" in out and "priorities 2..1" not in out
    code, out, _ = run(capsys, "plan", FAILING, "--belief", AGREE, "--time-budget", "5", "--max-depth", "3",
                       "--prune-without-guarantee", "--json")
    d = json.loads(out)
    assert d["certified"] is False and d["guaranteed"] is False and d["gate"]["forced"] is True
    assert d["root_bounds"] == [2, 2] and d["depth"] == 3  # agreeing but unguaranteed: no early stop
    code, out, _ = run(capsys, "plan", FAILING, "--belief", CROSS, "--depth", "2", "--prune-without-guarantee",
                       "--json")
    assert json.loads(out)["root_bounds_crossed"] is True


def test_plan_on_a_valid_model_still_certifies(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "plan", S3, "--belief", "0.2,0.5,0.3", "--depth", "4")
    assert code == 0 and "(certified: the root bounds agree)" in out and "search: valid bounds" in out


# ------------------------------------------------------------------------ simulate policies
def _simulate(capsys: pytest.CaptureFixture[str], policy: str, *options: str) -> tuple[int, dict | None, str]:
    argv = ["simulate", FAILING, "--policy", policy, "--steps", "4", "--json"]
    for opt in options:
        argv += ["--option", opt]
    code, out, err = run(capsys, *argv)
    return code, (json.loads(out) if code == 0 else None), err


@pytest.mark.parametrize("options", [("depth=3",), ("time_budget=0.05", "max_depth=3")])
def test_simulate_bnb_falls_back_with_the_reason(capsys: pytest.CaptureFixture[str], options: tuple) -> None:
    code, d, _ = _simulate(capsys, "bnb", *options)
    assert code == 0 and d["planner"]["mode"] == "exhaustive" and d["planner"]["certified_decisions"] == 0
    assert "Assumption 1 fails" in d["planner"]["reason"]
    code, out, _ = run(capsys, "simulate", FAILING, "--policy", "bnb", "--steps", "2", "--option", "depth=2")
    assert "# planner: exhaustive search: Assumption 1 fails" in out


@pytest.mark.parametrize("policy", ["bnb", "lower", "upper"])
def test_simulate_override_says_no_guarantee(capsys: pytest.CaptureFixture[str], policy: str) -> None:
    code, d, _ = _simulate(capsys, policy, "prune_without_guarantee=1")
    assert code == 0 and d["planner"]["mode"] == "prune" and d["planner"]["guaranteed"] is False
    assert "no guarantee holds" in d["planner"]["reason"]
    assert d["planner"]["certified_decisions"] in (0, None)


@pytest.mark.parametrize("policy", ["lower", "upper"])
def test_simulate_bound_policies_refuse_a_failing_model(capsys: pytest.CaptureFixture[str], policy: str) -> None:
    code, _, err = _simulate(capsys, policy)
    assert code == 2
    assert f"policy {policy}: no valid bounds: Assumption 1 fails" in err and "prune_without_guarantee=1" in err


def test_simulate_exhaustive_says_bounds_are_off(capsys: pytest.CaptureFixture[str]) -> None:
    code, d, _ = _simulate(capsys, "exhaustive", "depth=2")
    assert code == 0 and d["planner"]["mode"] == "exhaustive" and d["planner"]["certified_decisions"] == 0


# ------------------------------------------------------------------------ benchmark and experiments
def test_search_bench_skips_a_failing_model_with_the_reason(capsys: pytest.CaptureFixture[str]) -> None:
    from pomdp_planner.bench.search import BenchConfig, bench_model, format_report
    from pomdp_planner.core.io.model_yaml import load_model

    model = load_model(FAILING)
    cfg = BenchConfig(beliefs=3, deep_beliefs=1, timed=1, depths=(2, 3), timed_max_depth=2)
    res = bench_model(model, cfg)
    assert "pruning" not in res and res["gate"]["mode"] == "exhaustive"
    report = format_report({"config": {"beliefs": 3, "seed": 0, "timed": 1}, "models": [res], "total_time": 0.0,
                            "python": "3", "numpy": "2", "cpu_count": 1})
    assert "skipped: Assumption 1 fails" in report and "certified" not in report
    forced = bench_model(model, BenchConfig(**{**cfg.__dict__, "prune_without_guarantee": True}))
    assert forced["gate"]["guaranteed"] is False and forced["pruning"]
    report = format_report({"config": {"beliefs": 3, "seed": 0, "timed": 1}, "models": [forced], "total_time": 0.0,
                            "python": "3", "numpy": "2", "cpu_count": 1})
    assert "WITHOUT GUARANTEE" in report and "(action certified)" not in report
    code, out, _ = run(capsys, "bench", "search", "--model", FAILING, "--beliefs", "2", "--timed", "1", "--quick")
    assert code == 0 and "skipped: Assumption 1 fails" in out


def test_experiments_use_the_gate() -> None:
    from pomdp_planner.bench.experiments import peer_policies, peers
    from pomdp_planner.bench.experiments.pruning import pruning_cell
    from pomdp_planner.bench.experiments.runner import valid_bounds
    from pomdp_planner.core.io.model_yaml import load_model

    model = load_model(FAILING)
    cell = pruning_cell(3, 2, 10, 0, model=model)
    assert not cell.feasible and cell.pct is None and "Assumption 1 fails" in cell.message
    with pytest.raises(ValueError, match="Assumption 1 fails"):
        valid_bounds(model)
    setup = peer_policies.gate_setup(model)
    assert setup.mode == "exhaustive" and not setup.planner.has_bounds
    chunk = peers.PeerChunk("failing", "lower-bound", None, 0, 1)
    with pytest.raises(ValueError, match="no valid bounds: Assumption 1 fails"):
        peers.run_chunk(chunk, model, peers.PeerPlan(budgets=(0.01,), episodes_cheap=1, episodes_by_budget={0.01: 1},
                                                     steps=1, max_depth=2, seed=0))
    bnb = peer_policies.make_peer("bnb", model, 0.01, max_depth=2, seed=0)  # B&B falls back to exhaustive search
    assert not bnb.use_bounds and not bnb.planner.has_bounds
