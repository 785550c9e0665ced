"""CLI: export and simulate subcommands (in-process), the shared helpers, python -m."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pomdp_planner.cli import main
from pomdp_planner.cli._common import emit_json, format_table, parse_belief, to_jsonable
from pomdp_planner.core.belief import BeliefError
from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.cassandra import parse_pomdp
from pomdp_planner.core.io.model_yaml import load_model, model_from_dict
from pomdp_planner.core.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
S3 = str(ROOT / "config/models/tracking_s3_info.yaml")


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_simulate_table(capsys):
    code, out, err = run(capsys, "simulate", S3, "--steps", "6", "--seed", "4")
    assert code == 0, err
    lines = out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("step"))
    assert lines[header].split() == ["step", "state", "priority", "obs", "entropy", "reward", "r(s,a)"]
    rows = [line.split() for line in lines[header + 2: header + 8]]
    assert [int(r[0]) for r in rows] == list(range(6))
    assert all(1 <= int(r[2]) <= 3 for r in rows)
    assert "mean reward" in lines[-1] and "discounted return" in lines[-1]


def test_simulate_json_matches_core(capsys):
    code, out, _ = run(capsys, "simulate", S3, "--steps", "7", "--seed", "9", "--policy", "random", "--json")
    assert code == 0
    data = json.loads(out)
    trace = simulate(load_model(S3), "random", steps=7, seed=9)
    assert [row["priority"] for row in data["steps"]] == (trace.actions + 1).tolist()
    assert [row["state"] for row in data["steps"]] == trace.states.tolist()
    assert data["summary"]["discounted_return"] == pytest.approx(trace.discounted_return, abs=1e-12)
    assert data["policy"] == "random" and data["seed"] == 9


def test_simulate_policy_options(capsys, monkeypatch):
    from pomdp_planner.core import policies

    seen = {}

    def factory(model, opts):
        seen.update(opts)
        return lambda b: int(opts["fixed"]) - 1

    monkeypatch.setitem(policies.POLICIES, "fixed",
                        policies.PolicyEntry(factory, "test policy", ("fixed", "seed", "label")))
    code, out, _ = run(capsys, "simulate", S3, "--steps", "3", "--policy", "fixed", "--option", "fixed=3",
                       "--option", "seed=11", "--option", "label=x", "--json")
    assert code == 0 and [row["priority"] for row in json.loads(out)["steps"]] == [3, 3, 3]
    assert seen == {"fixed": 3, "seed": 11, "label": "x"}


def test_simulate_initial_belief_and_state(capsys):
    code, out, _ = run(capsys, "simulate", S3, "--steps", "2", "--belief", "0,0,1", "--initial-state", "2", "--json")
    data = json.loads(out)
    assert code == 0 and data["initial_belief"] == [0.0, 0.0, 1.0] and data["steps"][0]["state"] == 2


@pytest.mark.parametrize(("argv", "message"), [
    (["simulate", "missing.yaml"], "MODEL: 'missing.yaml' not found (looked in "),
    (["simulate", S3, "--policy", "nope"], "--policy: unknown policy 'nope'"),
    (["simulate", S3, "--belief", "0.5,0.5"], "--belief: expected 3 probabilities"),
    (["simulate", S3, "--initial-state", "9"], "--initial-state: index 9 out of range"),
    (["simulate", S3, "--steps", "-1"], "argument --steps: must be an integer in 0..1000000000000"),
    (["simulate", S3, "--steps", "1" + "0" * 12 + "1"], "argument --steps: must be an integer in 0..1000000000000"),
])
def test_errors_exit_2_with_message(capsys, argv, message):
    code, _, err = run(capsys, *argv)
    assert code == 2 and message in err


def test_export_pomdp_stdout_round_trips_with_the_uncertainty_term(capsys):
    code, out, err = run(capsys, "export", S3, "--format", "pomdp")
    assert code == 0 and err == ""  # the uncertainty term travels in the pomdp_planner comment
    back, model = parse_pomdp(out), load_model(S3)
    np.testing.assert_allclose(back.P, model.P, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.r, model.r, rtol=0, atol=1e-12)
    assert back.uncertainty.name == "renyi2" and back.w.tolist() == model.w.tolist()


def test_export_to_file_yaml_and_json(capsys, tmp_path):
    target = tmp_path / "m.pomdp"
    code, out, _ = run(capsys, "export", S3, "-o", str(target))
    assert code == 0 and out == "" and load_model(target).S == 3
    code, out, _ = run(capsys, "export", S3, "--format", "yaml")
    m = model_from_dict(yaml.safe_load(out))
    assert m.uncertainty.name == "renyi2" and m.w.tolist() == [1.1, 1.6, 1.0]
    code, out, _ = run(capsys, "export", S3, "--json")
    data = json.loads(out)
    assert data["format"] == "pomdp" and "T: 0" in data["text"] and data["warnings"] == []
    # a .POMDP file is a model for every subcommand too
    code, out, _ = run(capsys, "simulate", str(target), "--steps", "2", "--json")
    assert code == 0 and len(json.loads(out)["steps"]) == 2


def test_common_helpers():
    table = format_table(["name", "x"], [["a", 1.5], ["bb", float("nan")]], digits=2)
    assert table.splitlines() == ["name     x", "----  ----", "a     1.50", "bb       -"]
    with pytest.raises(ValueError, match="row has 1 cells"):
        format_table(["a", "b"], [[1]])
    assert to_jsonable({"a": np.arange(2), "b": np.float64("inf"), "c": (np.int64(3), np.bool_(True))}) == \
        {"a": [0, 1], "b": None, "c": [3, True]}
    buf = io.StringIO()
    emit_json({"v": np.array([0.5])}, buf)
    assert json.loads(buf.getvalue()) == {"v": [0.5]}
    m = load_model(S3)
    np.testing.assert_allclose(parse_belief("uniform", m), 1 / 3)
    np.testing.assert_allclose(parse_belief("0.2, 0.3, 0.5", m), [0.2, 0.3, 0.5])
    for bad in ("a,b,c", "0.5,0.6,0.1", "-0.5,1,0.5", "1"):
        with pytest.raises((OptionError, BeliefError), match="--belief"):  # text, or the core's belief rule
            parse_belief(bad, m)


def test_python_dash_m_subprocess():
    proc = subprocess.run([sys.executable, "-m", "pomdp_planner", "simulate", S3, "--steps", "3", "--json"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert len(json.loads(proc.stdout)["steps"]) == 3
