"""The search benchmark (pomdp_planner/bench/search.py): ``pomdp-planner bench search``,
``python -m pomdp_planner.bench.search``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.bench.search import BenchConfig, bench_model, format_report, run_search_bench
from pomdp_planner.cli import main
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model

REPO = Path(__file__).resolve().parents[1]
S3 = str(REPO / "config" / "models" / "tracking_s3_info.yaml")


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
    assert main(["bench", "search", "--model", S3, "--beliefs", "2", "--timed", "1", "--no-engines",
                 "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["benchmark"] == "search" and data["models"][0]["S"] == 3
    assert "paper Table II" in capsys.readouterr().out
    report = format_report(run_search_bench([S3], BenchConfig(beliefs=1, deep_beliefs=1, timed=1, depths=(2,),
                                                                timed_max_depth=2, engines=False)))
    assert "26.3%" not in report  # the paper's row belongs to the S = Z = 8, A = 3 problem only


def test_module_entry_point_and_bad_model(tmp_path: Path) -> None:
    """``python -m pomdp_planner.bench.search`` is the same benchmark; a missing model is exit 2, no traceback."""
    proc = subprocess.run([sys.executable, "-m", "pomdp_planner.bench.search", "--model", str(tmp_path / "no.yaml")],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "no.yaml" in proc.stderr and "Traceback" not in proc.stderr
    assert main(["bench", "search", "--model", "no_such_model"]) == 2


def test_shipped_models_resolve_by_bare_name() -> None:
    res = run_search_bench(["tracking_s3_info.yaml"], BenchConfig(beliefs=1, deep_beliefs=1, timed=1, depths=(2,),
                                                                  timed_max_depth=2, engines=False))
    assert res["models"][0]["model"] == "tracking_s3_info"


def test_bench_search_constant_is_used_and_reported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``bench search --constant fosd``: the JSON and the report name the constant, and the pruning
    counted is that of the chosen bounds (on the natural S = 8 model, whose FOSD constraints are
    stricter, FOSD bounds prune less than the MLR-exact default)."""
    for constant in ("mlr", "fosd"):
        out = tmp_path / f"{constant}.json"
        assert main(["bench", "search", "--model", S3, "--beliefs", "2", "--timed", "1", "--constant", constant,
                     "--no-engines", "--json", str(out)]) == 0
        assert f"bounds: tight, constant {constant}," in capsys.readouterr().out
        data = json.loads(out.read_text())
        m = data["models"][0]
        assert data["config"]["constant"] == m["constant"] == m["gate"]["constant"] == constant
    model = load_model(REPO / "config" / "models" / "tracking_s8_natural.yaml")
    b = np.random.default_rng(0).dirichlet(np.ones(8), size=3)
    nodes = {}
    for constant in ("mlr", "fosd"):
        cfg = BenchConfig(beliefs=3, deep_beliefs=3, timed=1, depths=(2, 3), timed_max_depth=2, constant=constant)
        row = next(p for p in bench_model(model, cfg)["pruning"] if p["depth"] == 3)
        planner = build_planner(model, constant=constant).planner
        nodes[constant] = np.mean([sum(planner.count_nodes(x, 3)) for x in b])
        assert row["bnb_nodes_mean"] == pytest.approx(nodes[constant])
    assert nodes["mlr"] < nodes["fosd"]


def test_the_engine_comparison(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The engines section: kernel, numpy and the C yardstick (compiled here; it checks its root values
    and node count against the kernel's before it is timed) on the same trees; the B&B efficiency is
    the ratio of the speed-up to the node ratio, recomputed here from the row's times and counts."""
    from pomdp_planner.bench.engines import run_engines

    model = load_model(S3)
    res = run_engines([model], depths=(2, 3), beliefs=1, rounds=1, seed=0)
    tiny = np.array([2.2250738585072014e-308])
    assert (tiny / 2)[0] > 0.0  # loading the yardstick left the process's floating point as it was
    rows = res["models"][0]["rows"]
    assert [r["depth"] for r in rows] == [2, 3] and rows[1]["exhaustive_nodes"] == 820
    for r in rows:
        for k in ("c", "numpy"):
            speedup = r[f"{k}_exh_seconds"] / r[f"{k}_bnb_seconds"]
            assert r[f"{k}_bnb_efficiency"] == pytest.approx(speedup * r["bnb_nodes"] / r["exhaustive_nodes"])
        if "cref_seconds" in r:
            assert r["cref_max_rel_diff"] < 1e-10
            assert r["kernel_over_cref"] == pytest.approx(r["cref_seconds"] / r["c_exh_seconds"])
    out = tmp_path / "engines.json"
    assert main(["bench", "search", "--model", S3, "--beliefs", "1", "--timed", "1", "--quick",
                 "--engine-model", S3, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "== engines: the compiled kernel, the numpy reference and the C yardstick" in text
    assert json.loads(out.read_text())["engines"]["models"][0]["model"] == "tracking_s3_info"
