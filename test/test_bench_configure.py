"""``pomdp-planner bench configure``: the planner node's configure, stage by stage, and the decisions
with and without the fused leaf table, in one run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pomdp_planner.bench.configure import comparison_file
from pomdp_planner.cli import main
from pomdp_planner.core import search
from pomdp_planner.core.domains.comparison import comparison_model
from pomdp_planner.core.gate import STAGES
from pomdp_planner.core.io.sensors import load_model_file


def test_the_comparison_model_file_is_the_comparison_model(tmp_path):
    got, want = load_model_file(str(comparison_file(6, 4, tmp_path))), comparison_model(6, 4)
    for x, y in ((got.P, want.P), (got.O, want.O), (got.r, want.r)):
        np.testing.assert_array_equal(x, y)
    assert got.gamma == want.gamma and got.uncertainty.name == want.uncertainty.name == "none"


def test_bench_configure_prints_every_stage_and_compares_the_fused_table(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(search, "FUSED_TABLE_MAX_BYTES", 0)  # the planner does without the table on these sizes
    out_file = tmp_path / "rows.json"
    code = main(["bench", "configure", "--models", "comparison:8,3", "tracking_s3_info.yaml", "--beliefs", "2",
                 "--json", str(out_file)])
    out, _ = capsys.readouterr()
    assert code == 0
    rows = json.loads(out_file.read_text())
    assert [(r["model"], r["S"], r["A"], r["Z"]) for r in rows] == [("comparison_s8_a3", 8, 3, 8),
                                                                    ("tracking_s3_info", 3, 3, 3)]
    for r in rows:
        assert r["mode"] == "prune" and not r["fused"] and r["same"] is True
        assert all(r[s] >= 0 for s in ("load", *STAGES, "decision", "old_tables", "old_total"))
        assert r["total"] >= r["load"] + sum(r[s] for s in STAGES) - 1e-9
        line = next(x for x in out.splitlines() if x.startswith(r["model"]))
        assert f"{r['total']:.2f}" in line and line.split()[-1] == "yes"


@pytest.mark.parametrize("argv,message", [(["--models", "nonexistent_model.yaml"], "--models: "),
                                          (["--beliefs", "0"], "--beliefs: must be >= 1, got 0")])
def test_bench_configure_refuses_bad_input_in_one_line(argv, message, capsys):
    assert main(["bench", "configure", "--no-old", *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith(f"pomdp-planner bench configure: error: {message}")


def test_bench_configure_json_on_stdout_puts_the_table_on_stderr(capsys):
    assert main(["bench", "configure", "--models", "tracking_s3_info.yaml", "--no-old", "--beliefs", "1",
                 "--json", "-"]) == 0
    out, err = capsys.readouterr()
    assert [r["model"] for r in json.loads(out)] == ["tracking_s3_info"]
    assert any(line.split()[:4] == ["model", "S", "A", "Z"] for line in err.splitlines())  # the table
