"""``pomdp-planner bench structure``: one run times both paths and compares their verdicts."""

from __future__ import annotations

import json

from pomdp_planner.cli import main


def test_bench_structure_prints_both_paths_and_their_verdicts(tmp_path, capsys):
    out_file = tmp_path / "rows.json"
    code = main(["bench", "structure", "--models", "perimeter:12", "tracking_s3_info.yaml", "--json", str(out_file)])
    out, _ = capsys.readouterr()
    assert code == 0
    rows = json.loads(out_file.read_text())
    assert [(r["model"], r["S"], r["A"], r["Z"]) for r in rows] == [("perimeter_s12", 12, 3, 12),
                                                                    ("tracking_s3_info", 3, 3, 3)]
    for r in rows:
        assert r["same"] is True and r["old_verdict"] == r["new_verdict"] == "holds/holds/holds"
        assert r["old_time"] > 0 and r["new_time"] > 0
        line = next(x for x in out.splitlines() if x.startswith(r["model"]))
        assert line.split()[-1] == "yes" and f"{r['new_time']:.3f}" in line and f"{r['old_time']:.3f}" in line
    assert rows[0]["new_counts"]["proven_dominated"] > 0  # one sensor for all priorities: dominance used


def test_bench_structure_refuses_a_bad_model_in_one_line(capsys):
    assert main(["bench", "structure", "--models", "nonexistent_model.yaml", "--no-old"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("pomdp-planner bench structure: error: ")
