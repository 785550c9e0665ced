"""``pomdp-planner bench scale``: load, set-up (estimate beside the stages), memory and decisions per
model, each in its own process (pomdp_planner/bench/scale.py)."""

from __future__ import annotations

import json

import pytest

from pomdp_planner.bench.scale import grid_document, model_file
from pomdp_planner.cli import main
from pomdp_planner.core.io.model_yaml import load_model, model_from_dict


def test_generated_files_are_the_documented_models(tmp_path):
    grid = load_model(model_file("grid:12x9", tmp_path))
    assert grid.name == "grid_12x9" and (grid.S, grid.A, grid.Z) == (108, 3, 109)
    assert grid.uncertainty.name == "renyi2" and grid.metadata["grid"]["rows"] == 12
    assert grid_document(12, 9)["generator"]["cols"] == 9
    same = model_from_dict(grid_document(12, 9))
    assert (same.P_csr.nnz, same.O_csr.nnz) == (grid.P_csr.nnz, grid.O_csr.nnz)
    track = load_model(model_file("tracking:16,3", tmp_path))
    assert (track.S, track.A, track.Z) == (16, 3, 16) and track.metadata["generator"]["domain"] == "tracking"


def test_bench_scale_rows_and_table(capsys):
    code = main(["bench", "scale", "--models", "tracking:8,3", "grid:6x6", "--json", "-"])
    out, err = capsys.readouterr()
    assert code == 0
    rows = json.loads(out)
    assert [r["model"] for r in rows] == ["tracking_s8_a3", "grid_6x6"]
    tracking, grid = rows
    assert tracking["mode"] == "prune" and tracking["lp"] > 0 and tracking["no_lp"] == ""
    assert grid["mode"] == "exhaustive" and grid["est_lp"] == 0 and grid["no_lp"].startswith("(A1) fails")
    for r in rows:
        assert r["est_total"] > 0 and r["total"] > 0 and r["cpu"] > 0 and r["rss"] > 0
        assert r["decide_1"] > 0 and r["decide_2"] > 0
        assert r["total"] == pytest.approx(r["check"] + r["lp"] + r["tables"])
    assert "est/CPU" in err and "Machine load" in err and "grid_6x6" in err


def test_bench_scale_setup_suite_reports_a_refusal(capsys):
    code = main(["bench", "scale", "--suite", "setup", "--models", "perimeter:100", "--json", "-"])
    out, err = capsys.readouterr()
    row = json.loads(out)[0]
    assert code == 0 and row["refused"].startswith("the planner's set-up for S=100, A=3, Z=100 is expected to take")
    assert "refused:" in err and "d1 ms" not in err
