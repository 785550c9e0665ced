"""No entry point claims a guarantee on a model whose bounds the assumption gate does not vouch for.

Table-driven: every command that prints bounds, certificates or agreement (``bounds`` text and
JSON, ``plan``, ``simulate`` with every planner policy, ``bench search``, ``bench lp``, ``bench
mcts``, ``check``), also with the explicit override ``--prune-without-guarantee``, runs on each
failing fixture of ``test/models/``:

* ``fails_assumption1_s3.yaml``: Assumption 1 fails (the LP is feasible all the same);
* ``shannon_uncovered_s3.yaml``: Assumption 1 holds, the LP is feasible, but the Shannon
  guarantee covers no domain (posteriors leave ``B_epsilon``).

Nothing printed may claim a guarantee (:func:`claims`), and where the output is JSON no value
may say so (:func:`json_claims`). The experiments of ``bench all`` take no model argument: their
use of the gate is tested in test_gate_entry_points.py. A shipped model whose bounds are valid is
the control: there the same detectors must fire, so that they cannot pass by missing the words.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from pomdp_planner.bench import lp as lp_bench
from pomdp_planner.bench import mcts as mcts_bench
from pomdp_planner.cli import main as cli_main

REPO = Path(__file__).resolve().parents[1]
FAILING = {name: str(REPO / "test" / "models" / f"{name}.yaml")
           for name in ("fails_assumption1_s3", "shannon_uncovered_s3")}
VALID = str(REPO / "config" / "models" / "tracking_s3_info.yaml")

#: Words with which an output claims a guarantee (the forms every entry point uses for one).
CLAIMS = re.compile(
    r"^guaranteed:"                    # bounds: the gate's verdict
    r"|(?<!no )valid bounds"           # plan, simulate, bench search: the gate's decision
    r"|guarantee covers: (?!nothing)"  # bounds: the domain of a guarantee
    r"|\(certified"                    # plan: "(certified: the root bounds agree)"; bounds: "agree (certified)"
    r"|action certified"               # bench search
    r"|^\w+ +\d+ +\d+ +(?:tight|feasible) .* yes$",  # bench lp: a row, "yes" in its last column "guaranteed"
    re.MULTILINE)


def claims(text: str) -> list[str]:
    """The claims of a guarantee in ``text``."""
    return [m.group(0) for m in CLAIMS.finditer(text)]


def json_claims(data: Any, where: str = "$") -> list[str]:
    """The places in a JSON value that claim a guarantee: a true ``guaranteed`` or ``certified``,
    certified decisions, a ``covers`` that names a domain."""
    found = []
    if isinstance(data, dict):
        for key, value in data.items():
            here = f"{where}.{key}"
            if key in ("guaranteed", "certified") and value is True:
                found.append(here)
            elif key == "certified_decisions" and isinstance(value, int) and value > 0:
                found.append(here)
            elif key == "covers" and isinstance(value, str) and not value.startswith("none"):
                found.append(here)
            else:
                found += json_claims(value, here)
    elif isinstance(data, list):
        for i, value in enumerate(data):
            found += json_claims(value, f"{where}[{i}]")
    return found


def _run(capsys: pytest.CaptureFixture[str], entry: Callable[[list[str]], int], argv: list[str]
         ) -> tuple[int, str, str]:
    code = entry(argv)
    out, err = capsys.readouterr()
    return code, out, err


# (id, entry point, argv with {model}, output is JSON, exit codes allowed on a failing model)
ENTRY_POINTS: list[tuple[str, Callable[[list[str]], int], list[str], bool, set[int]]] = [
    ("check", cli_main, ["check", "{model}"], False, {0, 1}),
    ("check --json", cli_main, ["check", "{model}", "--json"], True, {0, 1}),
    ("bounds", cli_main, ["bounds", "{model}", "--samples", "30"], False, {1}),
    ("bounds feasible", cli_main, ["bounds", "{model}", "--samples", "30", "--variant", "feasible"], False, {1}),
    ("bounds --json", cli_main, ["bounds", "{model}", "--samples", "30", "--json"], True, {1}),
    ("plan", cli_main, ["plan", "{model}", "--belief", "0.3,0.4,0.3", "--depth", "4"], False, {0}),
    ("plan anytime --json", cli_main, ["plan", "{model}", "--belief", "0.3,0.4,0.3", "--time-budget", "0.1",
                                       "--max-depth", "3", "--json"], True, {0}),
    ("plan forced", cli_main, ["plan", "{model}", "--belief", "0.3,0.4,0.3", "--depth", "4",
                               "--prune-without-guarantee"], False, {0}),
    ("plan forced --json", cli_main, ["plan", "{model}", "--belief", "0.3,0.4,0.3", "--depth", "4",
                                      "--prune-without-guarantee", "--json"], True, {0}),
    ("simulate bnb", cli_main, ["simulate", "{model}", "--policy", "bnb", "--steps", "4", "--option", "depth=2"],
     False, {0}),
    ("simulate bnb --json", cli_main, ["simulate", "{model}", "--policy", "bnb", "--steps", "4", "--option",
                                       "depth=2", "--json"], True, {0}),
    ("simulate bnb forced --json", cli_main, ["simulate", "{model}", "--policy", "bnb", "--steps", "4", "--option",
                                              "depth=2", "--option", "prune_without_guarantee=1", "--json"],
     True, {0}),
    ("simulate exhaustive --json", cli_main, ["simulate", "{model}", "--policy", "exhaustive", "--steps", "3",
                                              "--option", "depth=2", "--json"], True, {0}),
    ("simulate lower", cli_main, ["simulate", "{model}", "--policy", "lower", "--steps", "3"], False, {2}),
    ("simulate upper forced", cli_main, ["simulate", "{model}", "--policy", "upper", "--steps", "3", "--option",
                                         "prune_without_guarantee=1"], False, {0}),
    ("simulate lower forced --json", cli_main, ["simulate", "{model}", "--policy", "lower", "--steps", "3",
                                                "--option", "prune_without_guarantee=1", "--json"], True, {0}),
    ("bench search", cli_main, ["bench", "search", "--model", "{model}", "--beliefs", "3", "--timed", "1",
                                "--quick"], False, {0}),
    ("bench search forced", cli_main, ["bench", "search", "--model", "{model}", "--beliefs", "3", "--timed", "1",
                                       "--quick", "--prune-without-guarantee"], False, {0}),
    ("bench search --json -", cli_main, ["bench", "search", "--model", "{model}", "--beliefs", "3", "--timed", "1",
                                         "--quick", "--prune-without-guarantee", "--json", "-"], True, {0}),
    ("bench lp", lp_bench.main, ["--models", "{model}", "--no-old"], False, {0}),
    ("bench lp --json -", lp_bench.main, ["--models", "{model}", "--no-old", "--json", "-"], True, {0}),
    ("bench mcts", mcts_bench.main, ["--model", "{model}", "--simulations", "30", "--beliefs", "1", "--quiet"],
     False, {0}),
]


@pytest.mark.parametrize("model", sorted(FAILING))
@pytest.mark.parametrize(("name", "entry", "argv", "is_json", "codes"), ENTRY_POINTS, ids=[e[0] for e in ENTRY_POINTS])
def test_no_entry_point_claims_a_guarantee(capsys: pytest.CaptureFixture[str], model: str, name: str,
                                           entry: Callable[[list[str]], int], argv: list[str], is_json: bool,
                                           codes: set[int]) -> None:
    code, out, err = _run(capsys, entry, [a.replace("{model}", FAILING[model]) for a in argv])
    assert code in codes, f"{name}: exit {code}\n{err}"
    assert "Traceback" not in err
    assert not claims(out) and not claims(err), f"{name} claims a guarantee: {claims(out) + claims(err)}"
    if is_json:
        found = json_claims(json.loads(out))
        assert not found, f"{name}: JSON claims a guarantee at {found}"


def test_the_detectors_fire_on_a_model_whose_bounds_are_valid(capsys: pytest.CaptureFixture[str]) -> None:
    """The control: the words and values the detectors look for are those the entry points use."""
    for argv, is_json in ((["bounds", VALID, "--samples", "30"], False), (["bounds", VALID, "--json"], True),
                          (["plan", VALID, "--belief", "0.2,0.5,0.3", "--depth", "3"], False),
                          (["plan", VALID, "--belief", "0.2,0.5,0.3", "--depth", "3", "--json"], True),
                          (["simulate", VALID, "--policy", "bnb", "--steps", "3", "--option", "depth=2"], False),
                          (["simulate", VALID, "--policy", "bnb", "--steps", "3", "--option", "depth=2", "--json"],
                           True),
                          (["bench", "search", "--model", VALID, "--beliefs", "3", "--timed", "1", "--quick"],
                           False)):
        code, out, _ = _run(capsys, cli_main, argv)
        assert code == 0
        assert (json_claims(json.loads(out)) if is_json else claims(out)), f"no claim detected: {argv}"
    code, out, _ = _run(capsys, lp_bench.main, ["--models", VALID, "--no-old"])
    assert code == 0 and claims(out)


@pytest.mark.parametrize("model", sorted(FAILING))
def test_bounds_says_first_that_the_bounds_are_not_guaranteed_and_why(capsys: pytest.CaptureFixture[str],
                                                                      model: str) -> None:
    from pomdp_planner.core.bounds import solve_bounds
    from pomdp_planner.core.gate import build_planner
    from pomdp_planner.core.io.model_yaml import load_model

    code, out, _ = _run(capsys, cli_main, ["bounds", FAILING[model], "--samples", "10"])
    reason = build_planner(load_model(FAILING[model])).reason  # the planner's own fallback reason
    first = out.splitlines()[0]
    assert code == 1 and first.startswith("NOT GUARANTEED: ") and first.removeprefix("NOT GUARANTEED: ") in reason
    assert "agree (NOT GUARANTEED)" in out and "agreement rate (NOT GUARANTEED: certifies nothing)" in out
    assert "feasible: yes" in out  # the LP solution is still shown, as a diagnostic
    code, out, _ = _run(capsys, cli_main, ["bounds", FAILING[model], "--samples", "10", "--json"])
    d = json.loads(out)
    assert code == 1 and d["guaranteed"] is False and d["reason"] in reason and d["feasible"] is True
    sol = solve_bounds(load_model(FAILING[model]), "tight", samples=400, seed=0)
    assert d["g"] == pytest.approx(sol.g.tolist()) and d["h"] == pytest.approx(sol.h.tolist())
    assert all(it["certified"] is False for it in d["beliefs"]) and any(it["agree"] for it in d["beliefs"])


def test_bounds_on_a_valid_model_says_guaranteed_and_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, cli_main, ["bounds", VALID, "--samples", "5"])
    assert code == 0 and out.startswith("guaranteed: Assumption 1 holds and the bound LP (tight, constant mlr) "
                                        "is feasible; the guarantee covers the simplex\n")
    code, out, _ = _run(capsys, cli_main, ["bounds", VALID, "--samples", "5", "--json"])
    d = json.loads(out)
    assert code == 0 and d["guaranteed"] is True and d["covers"] == "simplex"
    assert all(it["certified"] == it["agree"] for it in d["beliefs"])


@pytest.mark.parametrize("model", sorted(FAILING))
@pytest.mark.parametrize("force", [False, True])
def test_a_run_record_certifies_no_decision(capsys: pytest.CaptureFixture[str], tmp_path: Path, model: str,
                                            force: bool) -> None:
    """``simulate --record``: the ``certified`` column (agreeing guaranteed bounds) stays 0, and root
    bounds used by forced pruning are written labelled ``guaranteed`` 0 (and drawn as not guaranteed)."""
    from pomdp_planner.core.io.run_record import read_run_record

    record = tmp_path / "run.csv"
    argv = ["simulate", FAILING[model], "--policy", "bnb", "--steps", "6", "--option", "depth=2",
            "--record", str(record)] + (["--option", "prune_without_guarantee=1"] if force else [])
    code, out, _ = _run(capsys, cli_main, argv)
    rec = read_run_record(record)
    assert code == 0 and len(rec.epoch) == 6 and not rec.certified.any() and not claims(out)
    assert not rec.guaranteed.any()
    assert rec.has_bounds.all() == force and (rec.unguaranteed_bounds == rec.has_bounds).all()
