"""Random argument strings at every subcommand: exit code 0, 1 or 2, never a traceback.

Hypothesis draws, for each subcommand, a few of its options (and some unknown ones) with values
from a pool of troublesome strings (negative, zero, NaN, infinity, overflow, hex, empty, text,
line breaks, a NUL) and short random text, plus stray positional tokens, and runs
``pomdp_planner.cli.main`` in-process. Any exception escaping ``main`` fails the test, as does
an exit code outside {0, 1, 2}; an exit code 2 must come with exactly one error line on stderr (besides warnings).

To keep it fast the models are tiny (S = 2, 3), the pools hold only small valid values for the
options that set the amount of work (steps, samples, depths, budgets), ``MAX_TREE_NODES`` is
lowered to 1e5 for the test (its own rule is tested in test_cli_resource_guards.py), the process
works in a temporary folder (so ``-o`` with a random name writes there), and ``bench all``
always gets ``--report-only`` with an output folder holding no results (so it never runs the
experiments; its other options are still parsed and checked).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pomdp_planner.core.search as search
from pomdp_planner.cli import main

ROOT = Path(__file__).resolve().parents[1]
S2 = str(ROOT / "config/models/tracking_s2_info.yaml")
S3 = str(ROOT / "config/models/tracking_s3_info.yaml")

NASTY = ["-1", "0", "nan", "inf", "-inf", "1e400", "1.5", "abc", "", "0x10", "1e3", "9" * 25, " ", "\n",
         "a\x00b", "-", "--", "true", "\u0661"]
SMALL = ["1", "2", "3"]
TEXT = st.text(alphabet=st.characters(blacklist_categories=("Cs", "Nd")), max_size=6)


def values(*valid: str) -> st.SearchStrategy[str]:
    return st.one_of(st.sampled_from(list(valid) + NASTY), TEXT)


def option_values(*valid: str) -> st.SearchStrategy[str]:
    keys = st.sampled_from(["depth", "time_budget", "max_depth", "seed", "variant", "constant",
                            "prune_without_guarantee", "no_limit", "simulations", "rollout_depth", "reuse", "leaf",
                            "bogus", ""])
    vals = st.sampled_from(list(valid) + NASTY)
    return st.builds(lambda k, v: f"{k}={v}", keys, vals) | TEXT


# Options of each subcommand (flags map to None) and the base arguments it always gets.
COMMANDS: dict[str, tuple[list[str], dict[str, st.SearchStrategy[str] | None]]] = {
    "check": ([S2], {"--tol": values("1e-9", "0", "1e-3"), "--sdp-max-states": values(*SMALL),
                     "--exact-max-states": values(*SMALL), "--seed": values(*SMALL), "--json": None}),
    "export": ([S2], {"--format": values("pomdp", "yaml"), "-o": values("out.txt", ".", "missing/x", "/dev/full"),
                      "--json": None}),
    "simulate": ([S2], {"--steps": values(*SMALL), "--seed": values(*SMALL),
                        "--policy": values("myopic", "random", "bnb", "exhaustive", "lower", "upper", "mcts"),
                        "--option": option_values("0.01", "tight", "feasible", "mlr", "fosd", *SMALL),
                        "--belief": values("uniform", "0.5,0.5", "1,0", "0.5,0.6"),
                        "--initial-state": values("0", "1"), "--json": None}),
    "bounds": ([S2], {"--samples": values(*SMALL), "--seed": values(*SMALL), "--variant": values("tight", "feasible"),
                      "--constant": values("mlr", "fosd"),
                      "--beliefs": values("beliefs.csv", "/dev/zero", "."), "--json": None}),
    "plan": ([S3], {"--belief": values("uniform", "0.2,0.5,0.3"), "--depth": values(*SMALL),
                    "--time-budget": values("0.01", "0.05"), "--max-depth": values(*SMALL),
                    "--memory-budget": values("1", "0.5", "1024"), "--exhaustive": None, "--no-limit": None,
                    "--variant": values("tight", "feasible"), "--constant": values("mlr", "fosd"),
                    "--prune-without-guarantee": None, "--json": None}),
    "bench search": ([ "--quick", "--model", S2, "--beliefs", "2", "--timed", "1"],
                     {"--beliefs": values(*SMALL), "--timed": values(*SMALL), "--seed": values(*SMALL),
                      "--variant": values("tight", "feasible"), "--constant": values("mlr", "fosd"),
                      "--model": values(S2, "/dev/zero", "."),
                      "--json": values("bench.json", "."), "--full": None, "--prune-without-guarantee": None}),
    "bench all": (["--report-only", "--output", "empty"],
                  {"--output": values("empty", "/dev/null", "beliefs.csv/sub"), "--jobs": values("1"),
                   "--only": values("fig1", "peers"), "--quick": None, "--resume": None, "--no-progress": None}),
}
UNKNOWN = {"--bogus": values(), "-x": None, "--": None}


@st.composite
def argv_for(draw: st.DrawFn, command: str) -> list[str]:
    base, options = COMMANDS[command]
    argv = command.split() + list(base)
    pool = {**options, **UNKNOWN}
    for name in draw(st.lists(st.sampled_from(sorted(pool, key=str)), max_size=4)):
        argv.append(name)
        if pool[name] is not None:
            argv.append(draw(pool[name]))
    if draw(st.booleans()) and draw(st.booleans()):
        argv.append(draw(TEXT))  # a stray positional token
    return argv


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fuzz-args")
    (d / "empty").mkdir()
    (d / "beliefs.csv").write_text("0.5,0.5\n0.9,0.1\n")
    return d


@pytest.mark.parametrize("command", list(COMMANDS))
def test_random_arguments_never_crash(command: str, workdir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    @settings(max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(argv=argv_for(command))
    def check(argv: list[str]) -> None:
        code = main(argv)
        err = capsys.readouterr().err
        assert code in (0, 1, 2), (argv, code)
        assert "Traceback" not in err, (argv, err)
        if code == 2:  # one error line (export's warning that the uncertainty term is dropped may come first)
            lines = [line for line in err.splitlines() if line and not line.startswith("pomdp-planner: warning:")]
            assert len(lines) == 1, (argv, err)

    old = os.getcwd()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(search, "MAX_TREE_NODES", 10**5)
        os.chdir(workdir)
        try:
            check()
        finally:
            os.chdir(old)
