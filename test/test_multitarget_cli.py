"""Closed-loop runs of several targets and their command line: ``simulate --targets ... --budget B``
and ``bench multitarget`` (``core/multitarget/simulate.py``, ``cli/simulate_targets.py``,
``bench/multitarget.py``).

Common random numbers: every target's randomness is its own stream, consumed alike whatever the
actions, so two policies that act alike see the same run, and the initial states do not depend
on the policy. The command line resolves target models like every model argument (a shipped
name or a path), refuses bad input with one line and exit code 2, and prints the planner's price,
dual bound and gap; the benchmark's JSON has the figures the issue asks for, with zero
violations on a small configuration.
"""

from __future__ import annotations

import io
import json
import re
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

from pomdp_planner.bench.multitarget import BOUND_CASES, REGRET_CASES, MultiBenchConfig, run_multitarget_bench
from pomdp_planner.cli import main
from pomdp_planner.cli.simulate_targets import _Row, bound_line
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.multitarget.policies import make_joint_policy
from pomdp_planner.core.multitarget.problem import make_problem
from pomdp_planner.core.multitarget.simulate import simulate_targets

ROOT = Path(__file__).resolve().parents[1]
PERIMETER = load_model_file("perimeter_s3")
TRACKING = load_model_file("tracking_s3_info")


class Fixed:
    """A joint policy that always takes the same joint action."""

    last = None

    def __init__(self, actions):
        self.actions = tuple(actions)

    def act(self, beliefs):
        return self.actions


def run_cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def test_common_random_numbers():
    problem = make_problem([PERIMETER, TRACKING], budget=1, discount=0.95)
    a, _ = simulate_targets(problem, Fixed((2, 1)), 25, seed=3)
    b, _ = simulate_targets(problem, Fixed((2, 2)), 25, seed=3)
    c, _ = simulate_targets(problem, make_joint_policy("round_robin", problem), 25, seed=3)
    assert a[0].states == b[0].states == c[0].states  # the initial states do not depend on the policy
    # Target 0 acts alike under (2, 1) and (2, 2): its states and observations are the same, whatever target 1 does.
    assert [s.states[0] for s in a] == [s.states[0] for s in b]
    assert [s.observations[0] for s in a] == [s.observations[0] for s in b]
    assert [s.actions[1] for s in a] != [s.actions[1] for s in b]
    again, _ = simulate_targets(problem, Fixed((2, 1)), 25, seed=3)
    assert [s.reward for s in again] == [s.reward for s in a]
    other, _ = simulate_targets(problem, Fixed((2, 1)), 25, seed=4)
    assert [s.states for s in a] != [s.states for s in other]


def test_the_run_counts_epochs_over_budget():
    problem = make_problem([PERIMETER, PERIMETER], budget=2)
    steps, summary = simulate_targets(problem, Fixed((0, 0)), 5, seed=0)  # effort 4 > 2
    assert summary["budget_violations"] == 5 and not any(s.within_budget for s in steps)
    steps, summary = simulate_targets(problem, Fixed((0, 2)), 5, seed=0)
    assert summary["budget_violations"] == 0
    rewards = [s.reward for s in steps]
    assert summary["discounted_return"] == pytest.approx(sum(0.95 ** t * r for t, r in enumerate(rewards)))


def test_simulate_targets_text_and_json():
    code, out, err = run_cli("simulate", "--targets", "perimeter_s3,perimeter_s3,tracking_s3_info", "--budget", "3",
                             "--discount", "0.95", "--steps", "4", "--option", "depth=2")
    assert code == 0, err
    assert "3 targets: perimeter_s3(e=2,1,0)" in out and "ESTIMATE, not a bound" in out
    assert "epochs over budget 0" in out
    rows = [line.split() for line in out.splitlines() if line[:4].strip().isdigit()]
    assert len(rows) == 4 and all(r[4] == "3/3" or r[4].endswith("/3") for r in rows)
    code, out, err = run_cli("simulate", "--targets", "perimeter_s3,perimeter_s3", "--budget", "1.5",
                             "--efforts", "1,0.5,0", "--steps", "3", "--json", "--option", "search=exhaustive",
                             "--option", "depth=1")
    assert code == 0, err
    data = json.loads(out)
    assert data["planner"]["bound_guaranteed"] is True and data["efforts"] == [[1.0, 0.5, 0.0]] * 2
    assert all(s["effort"] <= 1.5 and s["within_budget"] for s in data["steps"])
    assert all({"lambda", "dual_bound", "gap", "priorities"} <= set(s) for s in data["steps"])
    assert data["summary"]["budget_violations"] == 0


def test_every_bound_in_the_text_output_names_its_depth():
    """Fixed depth: the header names the lookahead (depth and decisions) and every row's depth
    column is that depth. Anytime: the header says the depth varies (the deepest completed within
    the time budget) and every row's depth column is its decision's own depth."""
    code, out, err = run_cli("simulate", "--targets", "perimeter_s3,perimeter_s3", "--budget", "2", "--steps", "3",
                             "--option", "search=exhaustive")
    assert code == 0, err
    assert "upper bound on the optimal value of the depth-2 joint lookahead (3 decisions" in out
    header = next(line.split() for line in out.splitlines() if line.startswith("step"))
    rows = [line.split() for line in out.splitlines() if line[:4].strip().isdigit()]
    depth = header.index("depth") + 1  # the priorities take K = 2 cells
    assert len(rows) == 3 and all(r[depth] == "2" for r in rows)
    problem = make_problem([PERIMETER, TRACKING], budget=1, discount=0.95)
    policy = make_joint_policy("lagrangian", problem, time_budget=0.02, max_depth=4)
    line = _Row(problem, 5)
    assert "deepest depth completed within the time budget of 0.02 s" in bound_line(policy.planner)
    steps, _ = simulate_targets(problem, policy, 5, seed=1)
    for st in steps:
        assert line.line(st).split()[depth] == str(st.decision.depth)


def test_target_models_resolve_like_every_model_argument():
    path = str(ROOT / "config/models/perimeter_s3.yaml")
    code, _, err = run_cli("simulate", "--targets", f"{path},perimeter_s3", "--budget", "2", "--steps", "2",
                             "--policy", "greedy")
    assert code == 0, err


@pytest.mark.parametrize("argv, field", [
    (["--targets", "perimeter_s3,perimeter_s3"], "--budget"),
    (["--targets", "perimeter_s3,nope_model", "--budget", "1"], r"--targets\[1\]"),
    (["--targets", "perimeter_s3,,perimeter_s3", "--budget", "1"], "--targets"),
    (["--targets", "perimeter_s3,tracking_s3_info", "--budget", "1"], "^pomdp-planner: error: --discount: "),
    (["--targets", "perimeter_s3", "--budget", "-1"], "^pomdp-planner: error: --budget: "),
    (["--targets", "perimeter_s3,perimeter_s3", "--budget", "1", "--efforts", "2,1,1;2,1,1"],
     "^pomdp-planner: error: --budget: 1 is below the least effort"),
    (["--targets", "perimeter_s3,perimeter_s3", "--budget", "1", "--efforts", "1,0"], r"--efforts\[0\]"),
    (["--targets", "perimeter_s3,perimeter_s3", "--budget", "1", "--efforts", "1,0,0;1,0,0;1,0,0"], "--efforts"),
    (["--targets", "perimeter_s3", "--budget", "1", "--policy", "bnb"], "--policy"),
    (["--targets", "perimeter_s3", "--budget", "1", "--option", "search=mcts"], "option search"),
    (["--targets", "perimeter_s3", "--budget", "1", "--option", "depth=0"], "depth"),
    (["--targets", "perimeter_s3", "--budget", "1", "--belief", "uniform"], "--belief"),
    (["--targets", "perimeter_s3", "--budget", "1", "--discount", "x"], "--discount"),
    (["config/models/perimeter_s3.yaml", "--budget", "1"], "--budget"),
    ([], "MODEL"),
])
def test_bad_multitarget_input_is_one_line_naming_the_field(argv, field):
    code, _, err = run_cli("simulate", *argv, "--steps", "1")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert re.search(field, lines[0]), lines[0]


def test_bench_json_has_the_figures_with_zero_violations():
    tiny = MultiBenchConfig(bound_beliefs=3, bound_prices=1, episodes=2, steps=3, scaling_targets=(2, 4),
                            scaling_decisions=1, time_budget=0.05, tie_episodes=1,
                            bound_cases=(BOUND_CASES[0],), regret_cases=(REGRET_CASES[1],))
    result = run_multitarget_bench(tiny)
    assert result["budget_violations"] == 0
    assert result["dual_bound_violations"] == 0 and result["bound_checks"] >= 3 * 3
    assert result["lower_bound_violations"] == 0 and result["gap_violations"] == 0
    assert all(result["sanity"]["passed"].values())
    regret = result["regret_vs_exact"][REGRET_CASES[1].name]
    assert regret["exact_joint"]["mean"] == 0.0
    assert set(regret) >= {"lagrangian (bnb)", "greedy", "round_robin", "equal_split", "fixed_price"}
    assert all(len(r["ci"]) == 2 for r in regret.values())
    assert set(result["decision_ms"]) == {"2", "4"}
    assert all(r["decision_cpu_ms"] > 0 and r["decision_wall_ms"] > 0 for r in result["scaling"])
    assert result["machine"]["cores"] >= 1 and len(result["machine"]["load_average"]) == 3
    case = result["regret"][0]
    assert [(p["first"], p["second"]) for p in case["paired"]] == [
        ("fixed_price", "lagrangian (exhaustive)"), ("lagrangian (lower-bound ties)", "lagrangian (exhaustive)"),
        ("lagrangian (lower-bound ties)", "fixed_price")]
    returns = {label: row["return"]["mean"] for label, row in case["policies"].items()}
    assert case["paired"][0]["difference"]["mean"] == pytest.approx(returns["fixed_price"]
                                                                    - returns["lagrangian (exhaustive)"])
    assert case["ties"]["decisions"] == 1 * 3 and case["ties"]["differing"] >= 0
    json.dumps(result)
    only = run_multitarget_bench(tiny, parts=("scaling",))
    assert "scaling" in only and "regret" not in only and "bounds" not in only


def test_bench_command_line_refuses_bad_options(tmp_path):
    code, _, err = run_cli("bench", "multitarget", "--quick", "--episodes", "1")
    assert code == 2 and "--episodes" in err
    code, _, err = run_cli("bench", "multitarget", "--quick", "--json", str(tmp_path / "missing" / "x.json"))
    assert code == 2 and "--json" in err
    code, _, err = run_cli("bench", "multitarget", "--quick", "--only", "scaling,nope")
    assert code == 2 and "--only" in err
    code, _, err = run_cli("bench", "multitarget", "--quick", "--only", "bounds", "--plot", str(tmp_path / "p.png"))
    assert code == 2 and "--plot" in err
