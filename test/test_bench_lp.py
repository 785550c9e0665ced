"""``python -m pomdp_planner.bench.lp``: the bound LP benchmark runs, reports both paths, errors cleanly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pomdp_planner.bench import lp


def test_lp_bench_table_and_json(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "lp.json"
    assert lp.main(["--models", "tracking_s3_info", "comparison:6,4", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "old/new" in text and "tracking_s3_info" in text and "comparison_s6_a4" in text
    rows = json.loads(out.read_text())
    # Renyi model: both constants and both variants; f = none: the constants coincide, one row each
    assert [(r["model"], r["variant"], r["constant"]) for r in rows] == [
        ("tracking_s3_info", "tight", "mlr"), ("tracking_s3_info", "tight", "fosd"),
        ("tracking_s3_info", "feasible", "mlr"), ("tracking_s3_info", "feasible", "fosd"),
        ("comparison_s6_a4", "tight", "mlr"), ("comparison_s6_a4", "feasible", "mlr")]
    for r in rows:
        assert r["new_feasible"] and r["old_feasible"]
        assert r["new_worst_margin"] >= 0 and r["old_worst_margin"] >= 0
        assert r["new_time"] > 0 and r["old_time"] > 0
        if r["variant"] == "tight":  # the least elements are the tightest feasible vectors
            assert r["new_agreement"] >= r["old_agreement"]


def test_lp_bench_new_path_only_and_bad_model(capsys: pytest.CaptureFixture) -> None:
    assert lp.main(["--models", "comparison:4,3", "--no-old"]) == 0
    assert " - " in capsys.readouterr().out  # no old time
    assert lp.main(["--models", "no_such_model.yaml"]) == 2
    assert "--models" in capsys.readouterr().err
