"""``pomdp-planner bounds``: text and JSON output, belief files, infeasible models, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main
from pomdp_planner.core.bounds import solve_bounds
from pomdp_planner.core.io.model_yaml import load_model, save_model
from pomdp_planner.core.model import POMDP

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted((ROOT / "config" / "models").glob("*.yaml"))
S3 = ROOT / "config" / "models" / "tracking_s3_info.yaml"


def _run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("path", [p for p in MODELS if not p.stem.startswith("grid_")], ids=lambda p: p.stem)
def test_json_on_every_shipped_model(capsys: pytest.CaptureFixture, path: Path) -> None:
    code, out, _ = _run(capsys, "bounds", str(path), "--samples", "6", "--seed", "2", "--json")
    assert code == 0
    d = json.loads(out)
    model = load_model(path)
    assert d["feasible"] is True and d["variant"] == "tight"
    assert len(d["g"]) == model.S and len(d["h"]) == model.S
    assert d["solve_time"] >= 0 and len(d["beliefs"]) == 6
    # independent recomputation of the per-belief answers from the library
    mb = solve_bounds(model, "tight", samples=400, seed=2).myopic
    B = np.array([it["belief"] for it in d["beliefs"]])
    lo, up = mb.actions(B)
    assert [it["lower"] for it in d["beliefs"]] == list(lo + 1)
    assert [it["upper"] for it in d["beliefs"]] == list(up + 1)
    for it in d["beliefs"]:
        assert 1 <= it["lower"] <= it["upper"] <= model.A
        assert it["agree"] == (it["lower"] == it["upper"])
    assert d["agreement_rate"] == pytest.approx(np.mean(lo == up))


def test_grid_model_bounds_are_not_guaranteed(capsys: pytest.CaptureFixture) -> None:
    """A shipped grid model fails Assumption 1: the LP may be feasible, but ``bounds`` says the
    bounds certify nothing and exits 1 (docs/models.md, "Grid target search")."""
    code, out, _ = _run(capsys, "bounds", str(ROOT / "config/models/grid_10x10.yaml"), "--samples", "4", "--json")
    d = json.loads(out)
    assert code == 1 and d["guaranteed"] is False and "Assumption 1 fails" in d["reason"]


def test_text_output_and_belief_file(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    f = tmp_path / "beliefs.csv"
    f.write_text("p1,p2,p3\n# a comment\n1,0,0\n0.2,0.3,0.5\n\n0,0,1\n")
    code, out, _ = _run(capsys, "bounds", str(S3), "--beliefs", str(f), "--variant", "feasible")
    assert code == 0
    assert "feasible: yes" in out and "g = [0," in out and "h = [0," in out and "solve time:" in out
    assert "constant: mlr, K_f = 2 " in out and "FOSD C_S = 1.20711" in out and "agreement rate:" in out
    assert "why: mlr: steps >= 2|w_a| is exact for the MLR monotonicity Corollary 1 needs" in out
    table = [ln for ln in out.splitlines() if ln[:1].isdigit()]
    assert len(table) == 3
    code, out, _ = _run(capsys, "bounds", str(S3), "--beliefs", str(f), "--json")
    d = json.loads(out)
    assert [it["belief"] for it in d["beliefs"]] == [[1, 0, 0], [0.2, 0.3, 0.5], [0, 0, 1]]


@pytest.mark.parametrize("content,fragment", [
    ("0.5,0.5\n", "expected 3 probabilities"),
    ("0.5,0.6,0.1\n", "sum to"),
    ("1,0,0\n0.5,x,0.5\n", ":2: not a row of numbers"),
    ("-0.1,0.6,0.5\n", "non-negative"),
    ("# nothing\n", "contains no beliefs"),
])
def test_bad_belief_file(capsys: pytest.CaptureFixture, tmp_path: Path, content: str, fragment: str) -> None:
    f = tmp_path / "b.csv"
    f.write_text(content)
    code, _, err = _run(capsys, "bounds", str(S3), "--beliefs", str(f))
    assert code == 2
    assert "--beliefs" in err and fragment in err


def test_missing_belief_file_and_bad_samples(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    code, _, err = _run(capsys, "bounds", str(S3), "--beliefs", str(tmp_path / "nope.csv"))
    assert code == 2 and "cannot read" in err
    code, _, err = _run(capsys, "bounds", str(S3), "--samples", "0")
    assert code == 2 and "--samples" in err


def test_infeasible_model_exit_code_and_report(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    P = np.zeros((2, 3, 3))
    P[0, 0, 0] = P[0, 1, 2] = P[0, 2, 2] = 1.0
    P[1, 0, 0] = P[1, 1, 0] = P[1, 2, 2] = 1.0
    m = POMDP(P=P, O=np.broadcast_to(np.eye(3), (2, 3, 3)).copy(),
              r=np.array([[2.0, 2.0], [1.0, 1.0], [0.0, 0.0]]), gamma=0.9, name="infeasible")
    path = tmp_path / "infeasible.yaml"
    save_model(m, path)
    code, out, _ = _run(capsys, "bounds", str(path), "--samples", "3")
    assert code == 1
    assert "feasible: NO" in out and "most violated (g)" in out and "must search all actions" in out
    code, out, _ = _run(capsys, "bounds", str(path), "--json")
    d = json.loads(out)
    assert code == 1 and d["feasible"] is False and d["g"] is None and d["agreement_rate"] is None
    assert d["most_violated"]["g"]["violation"] == pytest.approx(1.0, abs=1e-6)


def test_json_reports_the_mlr_constant_by_default(capsys: pytest.CaptureFixture) -> None:
    """The issue's acceptance check: ``bounds tracking_s3_info.yaml --json`` reports the MLR constant."""
    code, out, _ = _run(capsys, "bounds", str(S3), "--json", "--samples", "2")
    d = json.loads(out)
    assert code == 0 and d["constant"] == "mlr"
    c = d["constants"]
    assert c["constant"] == "mlr" and c["K_f"] == 2.0 and c["C_used"] == 1.0
    assert c["why"].startswith("mlr: steps >= 2|w_a| is exact for the MLR monotonicity")
    assert c["C_fosd"] == pytest.approx((1 + np.sqrt(2)) / 2)


@pytest.mark.parametrize("constant", ["mlr", "fosd"])
def test_constant_option_changes_the_vectors_as_the_library_does(capsys: pytest.CaptureFixture,
                                                                 constant: str) -> None:
    code, out, _ = _run(capsys, "bounds", str(S3), "--json", "--samples", "2", "--constant", constant,
                        "--variant", "feasible")
    d = json.loads(out)
    assert code == 0 and d["constant"] == constant and d["constants"]["why"].startswith(constant + ":")
    sol = solve_bounds(load_model(S3), "feasible", constant=constant, samples=400, seed=0)
    assert np.allclose(d["g"], sol.g) and np.allclose(d["h"], sol.h)
    # the FOSD constant is larger, so its g must rise faster: the two answers differ
    other = solve_bounds(load_model(S3), "feasible", constant="fosd" if constant == "mlr" else "mlr")
    assert not np.allclose(d["g"], other.g)
    code, out, _ = _run(capsys, "bounds", str(S3), "--samples", "2", "--constant", constant)
    assert f"constant: {constant}, K_f = " in out and f"why: {constant}:" in out


def test_bad_constant_is_a_usage_error(capsys: pytest.CaptureFixture) -> None:
    assert main(["bounds", str(S3), "--constant", "paper"]) == 2  # main returns the code, never SystemExit
    assert "--constant" in capsys.readouterr().err
