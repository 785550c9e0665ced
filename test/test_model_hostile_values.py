"""Hostile values in model files: every model ``check`` accepts is one that ``plan``, ``bounds`` and
``simulate`` handle, and what would make the bound LP or the search non-finite is refused at load
time, in one line naming the field. Also: YAML 1.2 scalars only (no YAML 1.1 number forms), no
duplicate keys, counts in ASCII digits, and the epsilon of Cassandra files.

Every run here turns warnings into errors: a numpy warning never reaches the user.
"""

from __future__ import annotations

import io
import math
import warnings
from contextlib import redirect_stderr, redirect_stdout
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main
from pomdp_planner.core.bounds import shannon_constant, solve_bounds
from pomdp_planner.core.checks import option_value
from pomdp_planner.core.errors import ModelError
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.cassandra import export_pomdp, parse_pomdp
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import MAX_REWARD_MAGNITUDE, MAX_WEIGHT_MAGNITUDE, POMDP, default_epsilon
from pomdp_planner.core.simulate import simulate

TRACKING = """name: hostile
discount: 0.9
generator: {domain: tracking, S: 3, A: 3, q: 0.8}
reward: [[0.5, 0.2, 0.0], [0.1, 0.3, 0.2], [0.0, 0.1, 0.6]]
uncertainty: {function: shannon, weights: [1, 1, 1], epsilon: 0.001}
"""


@pytest.fixture(autouse=True)
def warnings_are_errors():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def write(tmp_path: Path, text: str, name: str = "m.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def refused(path: Path, pattern: str) -> str:
    with pytest.raises(ModelError, match=pattern) as info:
        load_model(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg
    code, _, err = cli("check", str(path))  # the command line says the same, in one line
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err and msg in err
    return msg


def handled_by_every_entry_point(path: Path) -> None:
    """``check`` accepts ``path``: then ``plan``, ``bounds`` and ``simulate`` (bnb, lower) end
    normally, with finite numbers and nothing on stderr but their own one-line notes."""
    model = load_model(path)
    assert cli("check", str(path))[0] in (0, 1)
    for argv in (("plan", str(path), "--depth", "2"), ("plan", str(path), "--time-budget", "0.05"),
                 ("bounds", str(path)), ("simulate", str(path), "--policy", "bnb", "--steps", "3"),
                 ("simulate", str(path), "--policy", "lower", "--steps", "3")):
        code, out, err = cli(*argv)
        assert "Traceback" not in err and "Warning" not in err, (argv, code, err)
        if argv[-3:-2] == ("lower",) and code == 2:  # the gate's refusal (bounds not guaranteed), one line
            assert err.startswith("pomdp-planner: error: policy lower: no valid bounds:") and err.count("\n") == 1
            continue
        assert code in (0, 1), (argv, code, err)
        assert "nan" not in out.split() and "inf" not in out.split(), (argv, out)
    sol = solve_bounds(model)
    assert sol.feasible and np.all(np.isfinite(sol.g)) and np.all(np.isfinite(sol.h))
    res = build_planner(model).planner.search(np.full(model.S, 1.0 / model.S), 2)
    assert np.isfinite(res.value) and not np.any(np.isinf(res.q_values))  # nan: pruned at the root
    assert np.isfinite(simulate(model, "bnb", 3, seed=0).discounted_return)


# ------------------------------------------------------------------ what the LP and the search need
def test_a_huge_weight_is_refused_naming_it(tmp_path):
    path = write(tmp_path, TRACKING.replace("weights: [1, 1, 1]", "weights: [1e308, 1, 1]"))
    refused(path, r"uncertainty\.weights\[0\]: magnitude must be at most 1e\+09 \(MAX_WEIGHT_MAGNITUDE: searches "
                  r"and the bound LP must stay finite\), got 1e\+308")


def test_weights_and_rewards_at_their_limits_are_handled(tmp_path):
    text = TRACKING.replace("shannon", "renyi2")
    text = text.replace("weights: [1, 1, 1]", f"weights: [{MAX_WEIGHT_MAGNITUDE:g}, 1, 1]")
    text = text.replace("[0.5, 0.2, 0.0]", f"[{MAX_REWARD_MAGNITUDE:g}, 0.2, {-MAX_REWARD_MAGNITUDE:g}]")
    handled_by_every_entry_point(write(tmp_path, text))


def test_a_subnormal_epsilon_is_handled(tmp_path):
    path = write(tmp_path, TRACKING.replace("epsilon: 0.001", "epsilon: 1e-320"))
    assert load_model(path).epsilon == 1e-320
    # log((1 - (S-1) eps) / eps) = log(1 - 2 eps) - log(eps), eps the subnormal double nearest 1e-320
    # (an exact fraction); the ratio itself would overflow to infinity
    eps = Fraction(1e-320)
    assert shannon_constant(3, 1e-320) == pytest.approx(math.log(eps.denominator) - math.log(eps.numerator), rel=1e-14)
    handled_by_every_entry_point(path)


def test_a_huge_reward_generator_parameter_is_refused_without_a_numpy_warning(tmp_path):
    text = TRACKING.replace("reward: [[0.5, 0.2, 0.0], [0.1, 0.3, 0.2], [0.0, 0.1, 0.6]]",
                            "reward_generator: {kind: tracking_comparison, c_a: 1e308}")
    refused(write(tmp_path, text), r"reward_generator\.c_a: magnitude must be at most 1e\+12 \(MAX_REWARD_MAGNITUDE")


def test_a_huge_reward_is_refused_naming_the_entry(tmp_path):
    refused(write(tmp_path, TRACKING.replace("[0.1, 0.3, 0.2]", "[0.1, -1e300, 0.2]")),
            r"reward\[1\]\[1\]: magnitude must be at most 1e\+12 \(MAX_REWARD_MAGNITUDE.*got -1e\+300")


# ------------------------------------------------------------------ YAML: duplicate keys, 1.2 numbers
def test_a_duplicate_key_is_an_error(tmp_path):
    refused(write(tmp_path, TRACKING.replace("discount: 0.9\n", "discount: 0.5\ndiscount: 0.2\n")),
            r"line 3, column 1: duplicate key 'discount' \(first given on line 2\): give each field once")
    refused(write(tmp_path, TRACKING.replace("q: 0.8}", "q: 0.8, q: 0.7}")),
            r"line 3, column \d+: duplicate key 'q' \(first given on line 3\)")


@pytest.mark.parametrize(("old", "new", "pattern"), [
    ("S: 3,", "S: 1:00,", r"generator\.S: must be an integer count, got a string '1:00' \(a YAML 1\.1 number form"),
    ("A: 3,", "A: 0b11,", r"generator\.A: must be an integer count, got a string '0b11' \(a YAML 1\.1 number form"),
    ("S: 3,", "S: 03,", r"generator\.S: must be an integer count, got a string '03' \(a YAML 1\.1 number form"),
    ("S: 3,", "S: 0x3,", r"generator\.S: must be an integer count, got a string '0x3'"),
    ("S: 3,", "S: 1_000,", r"generator\.S: must be an integer count, got a string '1_000' \(a YAML 1\.1"),
    ("S: 3,", "S: ３,", r"generator\.S: must be an integer count, got a string '３'"),
    ("S: 3,", "S: !!int 0b11,", r"'0b11' is not a plain decimal integer"),
    ("discount: 0.9", "discount: 0_.9", r"discount: must be a number, got a string '0_.9' \(a YAML 1\.1"),
    ("discount: 0.9", "discount: !!float 1:30.0", r"'1:30\.0' is not a plain decimal number"),
    ("q: 0.8", "q: 0:01", r"generator\.q: must be a number, got a string '0:01' \(a YAML 1\.1"),
    ("[0.5, 0.2, 0.0]", "[0.5, 0.2, 1_0]", r"reward\[0\]\[2\]: must be a number, got a string '1_0'"),
])
def test_yaml_1_1_number_forms_are_errors_naming_the_field(tmp_path, old, new, pattern):
    assert old in TRACKING
    refused(write(tmp_path, TRACKING.replace(old, new, 1)), pattern)


def test_yaml_1_1_forms_are_strings_where_strings_are_wanted(tmp_path):
    text = TRACKING.replace("name: hostile", "name: 1:00").replace("generator:", "states: [yes, no, 0b11]\ngenerator:")
    model = load_model(write(tmp_path, text))
    assert model.name == "1:00" and model.state_names == ("yes", "no", "0b11")


def test_counts_given_as_options_are_ascii_digits(tmp_path):
    assert option_value("10") == 10 and option_value("-2") == -2 and option_value("0.5") == 0.5
    assert option_value("1_0") == "1_0" and option_value("٣") == "٣" and option_value("0x10") == "0x10"
    path = write(tmp_path, TRACKING)
    for text in ("1_0", "٣", "0x3"):
        code, _, err = cli("simulate", str(path), "--policy", "exhaustive", "--steps", "1", "--option", f"depth={text}")
        assert code == 2 and err.count("\n") == 1
        assert "option depth: must be an integer in 1..50, got" in err, err


# ------------------------------------------------------------------ Cassandra files: epsilon
def _cassandra(S: int, comment: str = "") -> str:
    return (f"{comment}discount: 0.9\nvalues: reward\nstates: {S}\nactions: 1\nobservations: 1\n"
            "T: 0 identity\nO: 0 uniform\nR: 0 : * : * : * 1.0\n")


def test_cassandra_files_of_any_size_get_the_default_epsilon():
    assert default_epsilon(3) == 1e-3 and default_epsilon(500) == 1e-3
    assert default_epsilon(1000) == 1 / 2000 and default_epsilon(4096) == 1 / 8192
    for S in (3, 1000, 1500):
        m = parse_pomdp(_cassandra(S), "big.POMDP")
        assert m.S == S and m.epsilon == default_epsilon(S) and 0 < m.epsilon < 1 / S


def test_cassandra_epsilon_from_the_comment_or_the_option():
    m = parse_pomdp(_cassandra(1000, '# pomdp_planner: {"epsilon": 1e-5}\n'), "c.POMDP")
    assert m.epsilon == 1e-5
    commented = _cassandra(1000, '# pomdp_planner: {"epsilon": 1e-5}\n')
    assert parse_pomdp(commented, "c.POMDP", epsilon=2e-4).epsilon == 2e-4  # the option wins
    with pytest.raises(ModelError, match=r"^c\.POMDP: uncertainty\.epsilon: must satisfy 0 < epsilon < 1/S = 0\.001"):
        parse_pomdp(_cassandra(1000, '# pomdp_planner: {"epsilon": 0.01}\n'), "c.POMDP")
    with pytest.raises(ModelError, match=r"^c\.POMDP: epsilon \(# pomdp_planner: comment\): must be a number"):
        parse_pomdp(_cassandra(3, '# pomdp_planner: {"epsilon": "small"}\n'), "c.POMDP")


def test_export_keeps_an_epsilon_other_than_the_default():
    base = parse_pomdp(_cassandra(3), "c.POMDP")
    m = POMDP(P=base.P, O=base.O, r=base.r, gamma=base.gamma, epsilon=1e-4, name="c")
    assert parse_pomdp(export_pomdp(m), "c.POMDP").epsilon == 1e-4
    assert '"epsilon"' not in export_pomdp(base)
