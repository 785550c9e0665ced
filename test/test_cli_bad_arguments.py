"""Every option's bad value is a clean exit 2 with one line naming the option.

Table-driven: each case runs ``pomdp_planner.cli.main([...])`` in-process and must return 2 (not
raise: no ``SystemExit``, no traceback) with exactly one line on stderr that names the option
(or the file) and nothing on stdout. The cases go through every subcommand and every option:
numbers out of range, NaN and infinity, negative counts, wrong types, unknown ``--option`` keys
and bad ``--option`` values for a policy, binary, non-UTF-8, empty and oversized ``--beliefs``
files, a directory or ``/dev/zero`` where a file is expected, output paths that cannot be
written. None of them may start the work: the cases that would run a benchmark or an experiment
if accepted fail in well under a second.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pomdp_planner.cli import main
from pomdp_planner.cli.bounds import MAX_BELIEFS, MAX_BELIEFS_FILE_BYTES

ROOT = Path(__file__).resolve().parents[1]
S2 = str(ROOT / "config/models/tracking_s2_info.yaml")
S3 = str(ROOT / "config/models/tracking_s3_info.yaml")
S8 = str(ROOT / "config/models/tracking_s8_info.yaml")
CPUS = os.cpu_count() or 1


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    d = tmp_path_factory.mktemp("bad-args")
    out = {"dir": str(d / "adir"), "empty_dir": str(d / "empty")}
    Path(out["dir"]).mkdir()
    Path(out["empty_dir"]).mkdir()
    contents: dict[str, bytes] = {
        "binary": b"\x00\x01\xff\xfe\x80binary",
        "latin1": "0,5;0,5 \u00e9t\u00e9\n".encode("latin-1"),
        "empty": b"",
        "comments": b"# nothing but a comment\n\n",
        "text_row": b"0.5,0.5\nhello,world\n",
        "nan_row": b"nan,1\n",
        "short_row": b"1\n",
        "bad_sum": b"0.5,0.6\n",
        "huge_field": b"0." + b"1" * 200_000 + b",0.5\n",  # over the csv module's field limit
        "regular": b"0.5,0.5\n",
        "too_many": b"0.5,0.5\n" * (MAX_BELIEFS + 1),
    }
    for name, data in contents.items():
        p = d / f"{name}.csv"
        p.write_bytes(data)
        out[name] = str(p)
    big = d / "big.csv"
    with open(big, "wb") as fh:  # sparse: no disk space used
        fh.truncate(MAX_BELIEFS_FILE_BYTES + 1)
    out["big"] = str(big)
    out["missing"] = str(d / "missing" / "out.txt")
    out["under_file"] = str(d / "regular.csv" / "out.txt")
    return out


# (argv with {placeholders} for the files above, a fragment the error line must contain)
CASES: list[tuple[list[str], str]] = [
    # ------------------------------------------------------------------ global
    ([], "COMMAND"),
    (["frobnicate"], "invalid choice"),
    (["plan"], "MODEL"),
    (["check", S2, "--bogus"], "--bogus"),
    (["simulate", S2, "--steps", "3", "stray"], "stray"),
    # ------------------------------------------------------------------ check
    (["check", S2, "--tol", "nan"], "--tol"),
    (["check", S2, "--tol", "inf"], "--tol"),
    (["check", S2, "--tol=-1e-9"], "--tol"),
    (["check", S2, "--tol", "0.5"], "--tol"),
    (["check", S2, "--tol", "abc"], "--tol"),
    (["check", S2, "--sdp-max-states", "-1"], "--sdp-max-states"),
    (["check", S2, "--sdp-max-states", "1.5"], "--sdp-max-states"),
    (["check", S2, "--exact-max-states", "x"], "--exact-max-states"),
    (["check", S2, "--seed", "-1"], "--seed"),
    (["check", S2, "--seed", "1e3"], "--seed"),
    (["check", S2, "--seed", str(2**63)], "--seed"),
    (["check", "{dir}"], "{dir}"),
    (["check", "/dev/zero"], "/dev/zero"),
    (["check", "{binary}"], "{binary}"),
    (["check", "{empty}"], "{empty}"),
    # ------------------------------------------------------------------ export
    (["export", S2, "--format", "xml"], "--format"),
    (["export", S2, "--format", "yaml", "-o", "{dir}"], "-o/--output"),
    (["export", S2, "--format", "yaml", "-o", "{missing}"], "-o/--output"),
    (["export", S2, "--format", "yaml", "-o", "{under_file}"], "-o/--output"),
    (["export", S2, "--format", "yaml", "-o", ""], "-o/--output"),
    (["export", S2, "--format", "yaml", "-o", "/dev/full"], "-o/--output"),
    # ------------------------------------------------------------------ simulate
    (["simulate", S2, "--steps", "-1"], "--steps"),
    (["simulate", S2, "--steps", "abc"], "--steps"),
    (["simulate", S2, "--steps", "1.5"], "--steps"),
    (["simulate", S2, "--steps", "nan"], "--steps"),
    (["simulate", S2, "--seed", "-1"], "--seed"),
    (["simulate", S2, "--seed", "x"], "--seed"),
    (["simulate", S2, "--policy", "nope"], "--policy"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=abc"], "option depth"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=-1"], "option depth"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=0"], "option depth"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=51"], "option depth"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=2.5"], "option depth"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=1e400"], "option depth"),
    (["simulate", S3, "--policy", "exhaustive", "--option", "depth=11"], "option depth"),  # 3.5e10 nodes
    (["simulate", S2, "--policy", "bnb", "--option", "time_budget=nan"], "option time_budget"),
    (["simulate", S2, "--policy", "bnb", "--option", "time_budget=inf"], "option time_budget"),
    (["simulate", S2, "--policy", "bnb", "--option", "time_budget=-1"], "option time_budget"),
    (["simulate", S2, "--policy", "bnb", "--option", "time_budget=0"], "option time_budget"),
    (["simulate", S2, "--policy", "exhaustive", "--option", "time_budget=abc"], "option time_budget"),
    (["simulate", S2, "--policy", "bnb", "--option", "time_budget=1", "--option", "max_depth=0"], "option max_depth"),
    (["simulate", S2, "--policy", "random", "--option", "seed=-1"], "option seed"),
    (["simulate", S2, "--policy", "random", "--option", "seed=1.5"], "option seed"),
    (["simulate", S2, "--policy", "bnb", "--option", "seed=abc"], "option seed"),
    (["simulate", S2, "--policy", "lower", "--option", "variant=x"], "option variant"),
    (["simulate", S2, "--policy", "upper", "--option", "constant=paper"], "option constant"),
    (["simulate", S2, "--policy", "bnb", "--option", "constant=1"], "option constant"),
    (["simulate", S2, "--policy", "exhaustive", "--option", "constant=fosd"], "'constant'"),  # no bounds: no constant
    (["simulate", S2, "--policy", "bnb", "--option", "prune_without_guarantee=maybe"],
     "option prune_without_guarantee"),
    (["simulate", S2, "--policy", "exhaustive", "--option", "no_limit=2"], "option no_limit"),
    (["simulate", S2, "--policy", "bnb", "--option", "foo=1"], "'foo'"),
    (["simulate", S2, "--policy", "myopic", "--option", "depth=3"], "'depth'"),
    (["simulate", S2, "--policy", "mcts", "--option", "simulations=0"], "option simulations"),
    (["simulate", S2, "--policy", "mcts", "--option", "simulations=10000000"], "option simulations"),
    (["simulate", S2, "--policy", "mcts", "--option", "time_budget=1e9"], "option time_budget"),
    (["simulate", S2, "--policy", "mcts", "--option", "max_depth=100000"], "option max_depth"),
    (["simulate", S2, "--policy", "mcts", "--option", "rollout_depth=100000000"], "option rollout_depth"),
    (["simulate", S2, "--policy", "mcts", "--option", "exploration=nan"], "option exploration"),
    (["simulate", S2, "--policy", "mcts", "--option", "reuse=2"], "option reuse"),
    (["simulate", S2, "--option", "=1"], "--option"),
    (["simulate", S2, "--option", "depth"], "--option"),
    (["simulate", S2, "--belief", "0.5"], "--belief"),
    (["simulate", S2, "--belief", "nan,0.5"], "--belief"),
    (["simulate", S2, "--belief", "1,,0"], "--belief"),
    (["simulate", S2, "--belief", "0.5,0.5,"], "--belief"),
    (["simulate", S2, "--belief=-0.5,1.5"], "--belief"),
    (["simulate", S2, "--initial-state", "5"], "--initial-state"),
    (["simulate", S2, "--initial-state", "-1"], "--initial-state"),
    (["simulate", S2, "--initial-state", "xyz"], "--initial-state"),
    (["simulate", S2, "--initial-state", "9" * 5000], "--initial-state"),
    (["simulate", "/dev/zero"], "/dev/zero"),
    # ------------------------------------------------------------------ bounds
    (["bounds", S2, "--samples", "0"], "--samples"),
    (["bounds", S2, "--samples", "-1"], "--samples"),
    (["bounds", S2, "--samples", str(MAX_BELIEFS + 1)], "--samples"),
    (["bounds", S2, "--samples", "1e11"], "--samples"),
    (["bounds", S2, "--seed", "-1"], "--seed"),
    (["bounds", S2, "--variant", "x"], "--variant"),
    (["bounds", S2, "--constant", "x"], "--constant"),
    (["bounds", S2, "--beliefs", "{binary}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{latin1}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{empty}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{comments}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{big}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{too_many}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{huge_field}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{text_row}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{nan_row}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{short_row}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{bad_sum}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{dir}"], "--beliefs"),
    (["bounds", S2, "--beliefs", "/dev/zero"], "--beliefs"),
    (["bounds", S2, "--beliefs", "{missing}"], "--beliefs"),
    # ------------------------------------------------------------------ plan
    (["plan", S2, "--depth", "0"], "--depth"),
    (["plan", S2, "--depth", "51"], "--depth"),
    (["plan", S2, "--depth", "abc"], "--depth"),
    (["plan", S3, "--depth", "11"], "--depth"),  # 3.5e10 belief nodes: hours of search
    (["plan", S8, "--depth", "5", "--memory-budget", "1"], "--depth"),  # 5.9 MiB estimated
    (["plan", S2, "--time-budget", "nan"], "--time-budget"),
    (["plan", S2, "--time-budget", "0"], "--time-budget"),
    (["plan", S2, "--time-budget", "61"], "--time-budget"),
    (["plan", S2, "--time-budget", "abc"], "--time-budget"),
    (["plan", S2, "--time-budget", "1", "--depth", "2"], "--depth"),
    (["plan", S2, "--time-budget", "1", "--max-depth", "0"], "--max-depth"),
    (["plan", S2, "--max-depth", "51"], "--max-depth"),
    (["plan", S2, "--memory-budget", "0"], "--memory-budget"),
    (["plan", S2, "--memory-budget", "nan"], "--memory-budget"),
    (["plan", S2, "--memory-budget", "-5"], "--memory-budget"),
    (["plan", S2, "--memory-budget", "1e9"], "--memory-budget"),
    (["plan", S2, "--memory-budget", "lots"], "--memory-budget"),
    (["plan", S2, "--belief", "abc"], "--belief"),
    (["plan", S2, "--belief", "0.5,0.6"], "--belief"),
    (["plan", S2, "--belief", ""], "--belief"),
    (["plan", S2, "--variant", "x"], "--variant"),
    (["plan", S2, "--constant", "MLR"], "--constant"),
    # ------------------------------------------------------------------ bench search
    (["bench", "search", "--beliefs", "0"], "--beliefs"),
    (["bench", "search", "--beliefs", "10001"], "--beliefs"),
    (["bench", "search", "--beliefs", "x"], "--beliefs"),
    (["bench", "search", "--timed", "0"], "--timed"),
    (["bench", "search", "--seed", "-1"], "--seed"),
    (["bench", "search", "--variant", "x"], "--variant"),
    (["bench", "search", "--constant", "x"], "--constant"),
    (["bench", "search", "--model", "{dir}"], "--model"),
    (["bench", "search", "--model", "/dev/zero"], "--model"),
    (["bench", "search", "--model", "{missing}"], "--model"),
    (["bench", "search", "--model", S2, "--model", "{binary}"], "{binary}"),  # every model loaded first
    (["bench", "search", "--model", S2, "--json", "{dir}"], "--json"),
    (["bench", "search", "--model", S2, "--json", "{missing}"], "--json"),
    (["bench", "nope"], "invalid choice"),
    (["bench"], "BENCH"),
    # ------------------------------------------------------------------ bench all
    (["bench", "all", "--jobs", "0"], "--jobs"),
    (["bench", "all", "--jobs", str(CPUS + 1)], "--jobs"),
    (["bench", "all", "--jobs", "abc"], "--jobs"),
    (["bench", "all", "--only", "bogus"], "--only"),
    (["bench", "all", "--output", "/dev/null"], "--output"),
    (["bench", "all", "--output", "{under_file}"], "--output"),
    (["bench", "all", "--report-only", "--output", "{empty_dir}"], "--report-only"),
    # ------------------------------------------------------------------ counts: ASCII digits only
    # (int() and float() take digit-group underscores and any Unicode digit: "1_0" is 10, so is "\u0661\u0660")
    (["plan", S2, "--depth", "1_0"], "--depth"),
    (["plan", S2, "--depth", "\u0662"], "--depth"),  # ARABIC-INDIC DIGIT TWO
    (["plan", S2, "--depth", "\uff12"], "--depth"),  # FULLWIDTH DIGIT TWO
    (["plan", S2, "--time-budget", "1", "--max-depth", "1_0"], "--max-depth"),
    (["plan", S2, "--time-budget", "0_1"], "--time-budget"),
    (["plan", S2, "--time-budget", "\u0661"], "--time-budget"),
    (["plan", S2, "--memory-budget", "1_024"], "--memory-budget"),
    (["simulate", S2, "--steps", "1_0"], "--steps"),
    (["simulate", S2, "--steps", "\u0663"], "--steps"),
    (["simulate", S2, "--seed", "1_0"], "--seed"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=1_0"], "option depth"),
    (["simulate", S2, "--policy", "bnb", "--option", "depth=\u0662"], "option depth"),
    (["simulate", S2, "--policy", "bnb", "--option", "time_budget=0_1"], "option time_budget"),
    (["simulate", S2, "--initial-state", "\u0661"], "--initial-state"),
    (["simulate", S2, "--belief", "0_5,0.5"], "--belief"),
    (["bounds", S2, "--samples", "1_0"], "--samples"),
    (["check", S2, "--sdp-max-states", "\u0663"], "--sdp-max-states"),
    (["check", S2, "--tol", "1e-1_0"], "--tol"),
    (["bench", "search", "--beliefs", "1_0"], "--beliefs"),
    (["bench", "search", "--timed", "\u0661"], "--timed"),
    (["bench", "search", "--seed", "1_0"], "--seed"),
    (["bench", "all", "--jobs", "\u0661"], "--jobs"),
    # ------------------------------------------------------------------ outputs: regular files, checked first
    (["export", S2, "-o", "/proc/version"], "-o/--output"),
    (["export", S2, "-o", "/dev/null"], "-o/--output"),
    (["bench", "search", "--model", S2, "--json", "/proc/version"], "--json"),  # refused before the run
    (["bench", "search", "--model", S2, "--json", "/dev/null"], "--json"),
    (["bench", "structure", "--models", S2, "--json", "/proc/version"], "--json"),
    (["bench", "structure", "--repeat", "1_0"], "--repeat"),
    (["simulate", S2, "--record", "-"], "--record"),  # the steps go to stdout
    (["simulate", S2, "--record", "/proc/version"], "--record"),
    (["plot", "{regular}", "-o", "-"], "--output"),
]


def _fill(text: str, files: dict[str, str]) -> str:
    return text.format(**files) if "{" in text else text


@pytest.mark.parametrize(("argv", "fragment"), CASES, ids=[" ".join(Path(a).name for a in c[0])[:70] for c in CASES])
def test_bad_argument_is_one_line_exit_2(capsys: pytest.CaptureFixture[str], files: dict[str, str],
                                         argv: list[str], fragment: str) -> None:
    if "/dev/full" in argv and not Path("/dev/full").exists():
        pytest.skip("no /dev/full on this system")
    argv = [_fill(a, files) for a in argv]
    code = main(argv)
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2, (argv, out[-500:], err[-500:])
    assert "Traceback" not in err
    assert len(lines) == 1, err
    assert "error" in lines[0] and _fill(fragment, files) in lines[0], lines[0]
    assert out == ""


def test_help_exits_0_and_the_parser_never_raises(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["--help"], ["plan", "--help"], ["bench", "all", "--help"]):
        assert main(argv) == 0
        assert "usage:" in capsys.readouterr().out


def test_error_lines_stay_one_line_whatever_the_value(capsys: pytest.CaptureFixture[str]) -> None:
    """Values with line breaks are shown escaped; long values are cut (core.model.short_repr)."""
    assert main(["simulate", S2, "--steps", "1\n2"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--steps" in err
    assert main(["plan", S2, "--belief", "x" * 100_000]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and len(err) < 400
    assert main(["check", "/no/such\nfile.yaml"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
