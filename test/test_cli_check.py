"""``pomdp-planner check``: text and JSON reports, exit codes, malformed models."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main
from pomdp_planner.core.io.model_yaml import load_model, save_model
from pomdp_planner.core.model import POMDP

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"
S3 = str(MODELS / "tracking_s3_info.yaml")
S8 = str(MODELS / "tracking_s8_info.yaml")


@pytest.fixture
def failing_model_file(tmp_path):
    """The S = 8 tracking model with the priorities reversed: (A2) and (A3) fail."""
    good = load_model(S8)
    bad = POMDP(P=good.P[::-1], O=good.O, r=good.r, gamma=good.gamma, uncertainty=good.uncertainty,
                w=good.w, name="reversed_priorities")
    path = tmp_path / "reversed.yaml"
    save_model(bad, path)
    return path


@pytest.mark.parametrize("path", [S3, S8])
def test_check_shipped_models_text(path, capsys):
    assert main(["check", path]) == 0
    out = capsys.readouterr().out
    model = load_model(path)
    assert f"model: {model.name}" in out
    assert f"S={model.S} states, A={model.A} actions" in out and "gamma=0.99" in out
    assert "uncertainty: renyi2, weights per priority [1.1, 1.6, 1]" in out
    for k in ("(A1)", "(A2)", "(A3)"):
        line = next(x for x in out.splitlines() if x.strip().startswith(k))
        assert "HOLDS" in line
    assert "Assumption 1 holds" in out


def test_check_json(capsys):
    assert main(["check", S8, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["valid"] is True
    assert d["model"] == {"name": "tracking_s8_info", "S": 8, "A": 3, "Z": 8, "gamma": 0.99,
                          "uncertainty": "renyi2", "weights": [1.1, 1.6, 1.0], "epsilon": 0.001}
    a = d["assumptions"]
    assert a["holds"] is True and a["status"] == {"A1": "holds", "A2": "holds", "A3": "holds"}
    assert a["A2_copositivity"]["counts"]["proven_elementwise"] == 2 * 7 * 8
    assert a["A3_dominance"]["worst_margin"] >= 0


def test_check_failing_model(failing_model_file, capsys):
    assert main(["check", str(failing_model_file)]) == 1
    out = capsys.readouterr().out
    assert "(A2) copositivity: FAILS" in out and "(A3) observation dominance: FAILS" in out
    assert "counterexample" in out and "NOT guaranteed" in out
    assert main(["check", str(failing_model_file), "--json"]) == 1
    d = json.loads(capsys.readouterr().out)["assumptions"]
    assert d["holds"] is False and d["status"] == {"A1": "holds", "A2": "fails", "A3": "fails"}
    assert d["A2_copositivity"]["counts"]["refuted"] > 0
    x = np.array(d["A2_copositivity"]["not_proven"][0]["x"])
    assert np.all(x >= 0) and x.sum() == pytest.approx(1.0)
    assert d["A3_dominance"]["worst_margin"] < 0


def test_check_malformed_model(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text("name: bad\ndiscount: 0.9\nstates: 2\nactions: 1\nobservations: 1\n"
                    "transition: [[[0.5, 0.6], [0.5, 0.5]]]\nobservation: [[[1.0], [1.0]]]\nreward: [[0], [0]]\n")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "transition[0][0]" in err and "sums to 1.1" in err
    assert main(["check", str(tmp_path / "missing.yaml")]) == 2
    assert "MODEL: file " + str(tmp_path / "missing.yaml") + " does not exist" in capsys.readouterr().err
