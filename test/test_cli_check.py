"""``pomdp-planner check``: text and JSON reports, exit codes, malformed models."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from pomdp_planner.cli import main
from pomdp_planner.core.io.model_yaml import load_model, save_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.structure import short_belief

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


def test_a_counterexample_belief_of_many_states_is_printed_by_its_nonzero_entries(tmp_path, capsys):
    """A model of 30 states failing (A2): the counterexample's belief is its nonzero entries (a
    counterexample of the exact small-support test has two), not 30 numbers over several lines."""
    rng = np.random.default_rng(1)
    S, A, Z = 30, 2, 3
    doc = {"name": "random_s30", "discount": 0.9, "states": S, "actions": A, "observations": Z,
           "transition": rng.dirichlet(np.ones(S) * 0.3, size=(A, S)).tolist(),
           "observation": rng.dirichlet(np.ones(Z), size=(A, S)).tolist(),
           "reward": rng.uniform(0, 1, size=(S, A)).tolist(), "uncertainty": {"function": "renyi2",
                                                                             "weights": [0.5, 0.5]}}
    path = tmp_path / "random_s30.yaml"
    path.write_text(yaml.safe_dump(doc))
    main(["check", str(path)])
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "counterexample:" in ln]
    assert len(lines) == 1 and "(S=30, the other 28 entries 0)" in lines[0] and len(lines[0]) < 300, lines
    x = np.zeros(12)
    x[[1, 5]] = [0.25, 0.75]
    assert short_belief(x) == "{1: 0.25, 5: 0.75} (S=12, the other 10 entries 0)"
    x = np.full(20, 0.05)
    assert short_belief(x) == ("{0: 0.05, 1: 0.05, 2: 0.05, 3: 0.05, 4: 0.05, 5: 0.05} (S=20; the other 14 entries "
                               "sum to 0.7)")
    assert short_belief(np.array([0.5, 0.5, 0.0])) == "[0.5 0.5 0. ]"
