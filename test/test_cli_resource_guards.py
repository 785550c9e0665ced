"""Resource guards of ``plan`` and the ``simulate`` search policies.

* A fixed depth whose complete tree exceeds ``MAX_TREE_NODES`` is refused with the node count,
  the limit and the deepest depth within it (computed here by summing ``(A Z)^i``), unless
  ``--no-limit`` (``no_limit=1``); the anytime search is not limited by it.
* A depth over the memory budget (``--memory-budget`` MiB) is refused with the estimate; the
  anytime search's ``--max-depth`` is capped at the deepest depth within the budget instead,
  and the output says so. The budget reaches the planner through the gate.
* Every refusal happens before the gate's Assumption 1 check and LP (checked with a gate that
  must not be called).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import pomdp_planner.core.search as search
from pomdp_planner.cli import main
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.search import MAX_TREE_NODES, SearchSizeError, check_tree_size, search_memory_estimate

ROOT = Path(__file__).resolve().parents[1]
S2 = str(ROOT / "config/models/tracking_s2_info.yaml")
S3 = str(ROOT / "config/models/tracking_s3_info.yaml")
S8 = str(ROOT / "config/models/tracking_s8_info.yaml")
MIB = 2**20


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def tree(A: int, Z: int, depth: int) -> int:
    """Belief nodes of the complete tree, level by level (independent of the core's formula)."""
    total, level = 0, 1
    for _ in range(depth + 1):
        total += level
        level *= A * Z
    return total


# ------------------------------------------------------------------------ tree size
def test_the_issues_example_is_refused_with_the_figures() -> None:
    """Exhaustive depth 8 on S = 8 (A = 3, Z = 8): 1.1e11 leaves, hours of search."""
    assert MAX_TREE_NODES == 10**10
    with pytest.raises(SearchSizeError) as info:
        check_tree_size(3, 8, 8, "--depth", hint="use --time-budget")
    msg = str(info.value)
    deepest = max(d for d in range(1, 9) if tree(3, 8, d) <= MAX_TREE_NODES)
    assert msg.startswith("--depth: a search of depth 8 has up to ")
    assert f"{tree(3, 8, 8):.3g} belief nodes" in msg and "1e+10" in msg
    assert f"the deepest depth within it is {deepest}" in msg and msg.endswith("; use --time-budget")
    assert check_tree_size(3, 8, deepest) == tree(3, 8, deepest)


def test_plan_refuses_a_hopeless_depth_before_the_gate(capsys: pytest.CaptureFixture[str],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    import pomdp_planner.cli.plan as plan_cli

    def no_gate(*args, **kwargs):
        raise AssertionError("the gate ran before the guard")

    monkeypatch.setattr(plan_cli, "build_planner", no_gate)
    code, out, err = run(capsys, "plan", S8, "--depth", "8", "--exhaustive")
    assert code == 2 and out == ""
    assert f"--depth: a search of depth 8 has up to {tree(3, 8, 8):.3g} belief nodes" in err
    assert "use --time-budget S (anytime search, stopped in time) or --no-limit" in err
    code, _, err = run(capsys, "plan", S8, "--depth", "20", "--memory-budget", "1")
    assert code == 2 and "--depth: a search of depth 20 has up to" in err


def test_no_limit_lifts_the_node_limit(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """With the limit lowered to 1000 nodes, S = 2 (A = Z = 2) depth 5 (1365 nodes) is refused,
    and runs with --no-limit, expanding exactly the complete tree (exhaustive)."""
    monkeypatch.setattr(search, "MAX_TREE_NODES", 1000)
    code, _, err = run(capsys, "plan", S2, "--depth", "5", "--exhaustive")
    assert code == 2 and f"{tree(2, 2, 5):.3g} belief nodes" in err and "the deepest depth within it is 4" in err
    code, out, err = run(capsys, "plan", S2, "--depth", "5", "--exhaustive", "--no-limit", "--json")
    assert code == 0, err
    assert json.loads(out)["nodes_expanded"][-1] == tree(2, 2, 5)
    code, out, _ = run(capsys, "plan", S2, "--time-budget", "0.5", "--max-depth", "6", "--exhaustive", "--json")
    assert code == 0  # the anytime search is stopped by its deadline, not by the node limit
    # the same rule for the simulate search policies, and the same way out
    code, _, err = run(capsys, "simulate", S2, "--policy", "exhaustive", "--option", "depth=5", "--steps", "1")
    assert code == 2 and "option depth: a search of depth 5" in err and "no_limit=1" in err
    code, out, err = run(capsys, "simulate", S2, "--policy", "exhaustive", "--option", "depth=5",
                         "--option", "no_limit=1", "--steps", "1", "--json")
    assert code == 0, err
    assert len(json.loads(out)["steps"]) == 1


# ------------------------------------------------------------------------ memory
def test_memory_budget_refuses_a_fixed_depth_with_the_estimate(capsys: pytest.CaptureFixture[str]) -> None:
    need = search_memory_estimate(8, 3, 8, 5)
    assert 1 * MIB < need and search_memory_estimate(8, 3, 8, 4) <= 1 * MIB
    code, out, err = run(capsys, "plan", S8, "--depth", "5", "--memory-budget", "1")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert f"--depth: a search of depth 5 needs about {need / MIB:.3g} MiB" in err
    assert "more than the memory budget of 1 MiB; the deepest depth within it is 4" in err
    code, out, err = run(capsys, "plan", S8, "--depth", "2", "--memory-budget", "1", "--json")
    assert code == 0 and json.loads(out)["memory_budget_bytes"] == MIB


def test_anytime_max_depth_is_capped_by_the_memory_budget(capsys: pytest.CaptureFixture[str]) -> None:
    """S = 3: depth 8 needs more than 1 MiB, depth 7 fits; the anytime search stops at 7 and says so."""
    assert search_memory_estimate(3, 3, 3, 7) <= MIB < search_memory_estimate(3, 3, 3, 8)
    argv = ["plan", S3, "--time-budget", "2", "--max-depth", "10", "--memory-budget", "1", "--exhaustive"]
    code, out, err = run(capsys, *argv, "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["max_depth"] == 7 and d["max_depth_capped_from"] == 10 and d["depth"] <= 7
    assert "--max-depth capped at 7 (asked 10)" in err
    code, out, _ = run(capsys, *argv)
    assert "max depth: --max-depth capped at 7 (asked 10): a deeper search needs more than the memory budget of " \
           "1 MiB" in out
    code, out, _ = run(capsys, "plan", S3, "--time-budget", "0.2", "--max-depth", "3", "--json")
    assert json.loads(out)["max_depth_capped_from"] is None  # the default budget caps nothing here


def test_simulate_policy_caps_its_max_depth_too(capsys: pytest.CaptureFixture[str]) -> None:
    from pomdp_planner.core.policies import SearchPolicy

    model = load_model(S3)
    setup = build_planner(model, use_bounds=False, memory_budget=MIB)
    assert setup.planner.memory_budget == MIB  # the gate passes the budget on
    policy = SearchPolicy(setup, time_budget=1.0, max_depth=10)
    assert policy.max_depth == 7 and "max_depth capped at 7" in policy.note
    with pytest.raises(search.SearchMemoryError, match="option depth: a search of depth 8 needs"):
        SearchPolicy(setup, depth=8)
    with pytest.raises(search.SearchMemoryError, match=r"option max_depth: .*not even depth 1 fits"):
        SearchPolicy(build_planner(model, use_bounds=False, memory_budget=1000), time_budget=1.0)
