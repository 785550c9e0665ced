"""The explicit policy table (core/policies.py): every policy listed always, options checked, no cycle."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.policies import POLICIES, make_policy, policy_names
from pomdp_planner.core.simulate import simulate

REPO = Path(__file__).resolve().parents[1]
S3 = str(REPO / "config" / "models" / "tracking_s3_info.yaml")
PLANNERS = {"random", "myopic", "bnb", "exhaustive", "lower", "upper", "mcts"}


def test_the_table_holds_every_planner() -> None:
    assert set(policy_names()) == set(POLICIES) >= PLANNERS
    assert policy_names() == sorted(policy_names())
    assert all(entry.help for entry in POLICIES.values())


def test_simulate_help_lists_every_policy_in_a_fresh_interpreter() -> None:
    """Nothing but the CLI is imported first: the list cannot depend on import order."""
    out = subprocess.run([sys.executable, "-m", "pomdp_planner", "simulate", "--help"], cwd=REPO,
                         capture_output=True, text=True, timeout=120, check=True).stdout
    listed = out.split("policies (--policy NAME):", 1)[1]
    for name in POLICIES:
        assert f"  {name} " in listed, name
        assert POLICIES[name].help in " ".join(listed.split())


def _module_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            names.add(("." * node.level) + (node.module or ""))
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def test_no_import_cycle_between_search_and_simulate() -> None:
    core = REPO / "pomdp_planner" / "core"
    assert not {".simulate", ".policies", "importlib"} & _module_imports(core / "search.py")
    assert not {".simulate", "importlib"} & _module_imports(core / "policies.py")
    assert ".policies" in _module_imports(core / "simulate.py")
    assert "importlib" not in _module_imports(core / "simulate.py")


def test_a_name_and_the_built_policy_give_the_same_run() -> None:
    model = load_model(S3)
    by_name = simulate(model, "random", 12, seed=5)
    by_object = simulate(model, make_policy("random", model, seed=6), 12, seed=5)
    np.testing.assert_array_equal(by_name.actions, by_object.actions)


def test_unknown_policy_and_option_are_errors_naming_them() -> None:
    model = load_model(S3)
    with pytest.raises(OptionError, match=r"unknown policy 'bogus'.*bnb"):
        make_policy("bogus", model)
    with pytest.raises(OptionError, match=r"policy bnb: unknown option 'dpth' \(known: .*depth"):
        make_policy("bnb", model, dpth=2)
    with pytest.raises(OptionError, match="variant"):
        make_policy("lower", model, variant="loose")
    with pytest.raises(OptionError, match=r"option depth: must be an integer in 1\.\.50"):
        make_policy("exhaustive", model, depth=0)
    with pytest.raises(OptionError, match=r"option time_budget: must be a number of seconds in 0\.001\.\.60"):
        make_policy("bnb", model, time_budget=-1)
    with pytest.raises(OptionError, match="option prune_without_guarantee: must be 1/0"):
        make_policy("bnb", model, prune_without_guarantee="maybe")


def test_planner_policies_act_like_their_planner() -> None:
    model = load_model(S3)
    assert {"bnb", "exhaustive", "lower", "upper"} <= set(policy_names())
    b = np.array([0.2, 0.5, 0.3])
    planner = build_planner(model).planner
    assert make_policy("bnb", model, depth=2).act(b) == planner.search(b, 2).action
    assert make_policy("exhaustive", model, depth=2).act(b) == planner.search(b, 2, use_bounds=False).action
    lo, up = planner.root_bounds(b)
    assert make_policy("lower", model).act(b) == lo and make_policy("upper", model).act(b) == up
    assert 0 <= make_policy("bnb", model, time_budget=0.01).act(b) < 3


def test_mcts_by_name_is_the_core_planner_and_its_option_errors_name_the_option() -> None:
    model = load_model(S3)
    policy = make_policy("mcts", model, simulations=200, seed=3)
    run = simulate(model, policy, 5, seed=2)
    again = simulate(model, make_policy("mcts", model, simulations=200, seed=3), 5, seed=2)
    assert list(run.actions) == list(again.actions)  # seeded: the same decisions
    assert policy.last.simulations == 200
    with pytest.raises(OptionError, match=r"^policy mcts: option max_depth: "):
        make_policy("mcts", model, max_depth=0)
    with pytest.raises(OptionError, match=r"^policy mcts: unknown option 'depth'"):
        make_policy("mcts", model, depth=3)


def test_the_bound_policies_take_the_constant_option(capsys: pytest.CaptureFixture[str]) -> None:
    """``bnb``, ``lower``, ``upper`` take ``constant=mlr|fosd``: the policies act with that constant's
    bounds (on the natural S = 8 model, where the two differ), the gate records it, ``simulate --json``
    reports it, and a bad value is an error naming the option."""
    import json

    from pomdp_planner.cli import main
    from pomdp_planner.core.bounds import sample_beliefs, solve_bounds

    path = str(REPO / "config" / "models" / "tracking_s8_natural.yaml")
    model = load_model(path)
    B = sample_beliefs(model, 200, seed=5)
    bounds = {c: solve_bounds(model, constant=c).myopic.actions(B) for c in ("mlr", "fosd")}
    (lo_m, up_m), (lo_f, _) = bounds["mlr"], bounds["fosd"]
    k = int(np.flatnonzero((lo_m == up_m) & (lo_f < lo_m))[0])  # the lower bounds differ, MLR certifies
    for c, (lo, up) in bounds.items():
        assert make_policy("lower", model, constant=c).act(B[k]) == lo[k]
        assert make_policy("upper", model, constant=c).act(B[k]) == up[k]
        bnb = make_policy("bnb", model, depth=2, constant=c)
        assert bnb.setup.constant == c and bnb.act(B[k]) == make_policy("exhaustive", model, depth=2).act(B[k])
        assert bnb.last.certified == (c == "mlr")
    assert make_policy("bnb", model, depth=2).setup.constant == "mlr"  # the default
    assert main(["simulate", path, "--steps", "2", "--policy", "upper", "--option", "constant=fosd", "--json"]) == 0
    planner = json.loads(capsys.readouterr().out)["planner"]
    assert planner["constant"] == planner["bounds"]["constant"] == "fosd"
    for name in ("bnb", "lower", "upper"):
        with pytest.raises(OptionError, match=r"option constant: expected one of mlr, fosd, got 'paper'"):
            make_policy(name, model, constant="paper")
    with pytest.raises(OptionError, match=r"policy exhaustive: unknown option 'constant'"):
        make_policy("exhaustive", model, constant="fosd")
