"""One check per concept: the kinds of error, the strict integer and number checks, the one yes/no
parser, the bound variant and constant, the ranges every entry point takes from the core, and a
load error that names its file once."""

from __future__ import annotations

import numpy as np
import pytest

from pomdp_planner.core import options, search
from pomdp_planner.core.belief import BeliefError as BeliefErrorFromBelief
from pomdp_planner.core.belief_mcts import make_belief_mcts_policy
from pomdp_planner.core.bounds import BOUND_CONSTANTS, BOUND_VARIANTS, check_constant, check_variant, solve_bounds
from pomdp_planner.core.checks import FLAG_WORDS, check_choice, check_int, check_number, parse_flag
from pomdp_planner.core.errors import BeliefError, InputError, ModelError, OptionError, prefixed
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.model import ModelError as ModelErrorFromModel
from pomdp_planner.core.policies import SEED_RANGE, make_policy
from pomdp_planner.core.search import SearchMemoryError, SearchSizeError

S3 = "config/models/tracking_s3_info.yaml"


def test_three_kinds_of_bad_input_share_one_base_and_keep_their_old_names():
    assert ModelErrorFromModel is ModelError and BeliefErrorFromBelief is BeliefError
    for kind in (ModelError, OptionError, BeliefError):
        assert issubclass(kind, InputError) and issubclass(kind, ValueError)
    assert not issubclass(OptionError, ModelError) and not issubclass(ModelError, OptionError)
    assert issubclass(SearchSizeError, OptionError) and issubclass(SearchMemoryError, OptionError)
    assert str(OptionError("depth: bad\nvalue\r\nhere")) == "depth: bad value here"  # always one line


def test_prefixed_keeps_the_kind_of_error():
    for kind in (ModelError, OptionError, BeliefError):
        with pytest.raises(kind, match=r"^file\.yaml: field: problem$"), prefixed("file.yaml"):
            raise kind("field: problem")


@pytest.mark.parametrize("bad", [True, np.bool_(False), 2.0, "3", None, [1], 10**100])
def test_the_integer_check_is_strict_about_types(bad):
    with pytest.raises(OptionError, match=r"^n: must be an integer in 1\.\.5, got "):
        check_int(bad, "n", 1, 5)


def test_the_integer_and_number_checks():
    assert check_int(np.int64(3), "n", 1, 5) == 3 and type(check_int(np.int64(3), "n")) is int
    with pytest.raises(ModelError, match=r"^S: must be an integer >= 2, got 1 \(why\)$"):
        check_int(1, "S", 2, error=ModelError, note="(why)")
    assert check_number(np.float32(0.5), "x", 0, 1) == 0.5 and check_number(3, "x") == 3.0
    for bad in (float("nan"), float("inf"), "0.5", True, 10**400, 2):
        with pytest.raises(OptionError, match=r"^x: must be a number in 0\.\.1, got"):
            check_number(bad, "x", 0, 1)


def test_one_yes_no_parser_for_every_option():
    for value, expected in [*FLAG_WORDS.items(), ("YES", True), (" Off ", False), (1, True), (0, False),
                            (True, True), (np.bool_(False), False)]:
        assert parse_flag(value, "f") is expected
    for bad in ("maybe", "", 2, -1, 0.5, None):
        with pytest.raises(OptionError, match=r"^f: must be 1/0 \(true/false, yes/no, on/off\)"):
            parse_flag(bad, "f")
    model = load_model(S3)
    # the same words in the search policies and in the MCTS policy
    for word in ("yes", "on", "true", "1"):
        assert make_policy("bnb", model, no_limit=word, depth=1) is not None
        assert make_belief_mcts_policy(model, {"reuse": word}).reuse is True
    for word in ("no", "off", "false", "0"):
        assert make_belief_mcts_policy(model, {"reuse": word}).reuse is False


@pytest.mark.parametrize("call", [
    lambda m, v, c: check_variant(v) and check_constant(c),
    lambda m, v, c: build_planner(m, variant=v, constant=c),
    lambda m, v, c: solve_bounds(m, v, constant=c),
    lambda m, v, c: make_policy("lower", m, variant=v, constant=c),
], ids=["check", "gate", "bounds", "policy"])
def test_one_check_of_the_bound_variant_and_constant(call):
    model = load_model(S3)
    with pytest.raises(OptionError, match=r"variant: expected one of tight, feasible, got 'loose'$"):
        call(model, "loose", "mlr")
    with pytest.raises(OptionError, match=r"constant: expected one of mlr, fosd, got 'paper'$"):
        call(model, "tight", "paper")
    assert check_variant(BOUND_VARIANTS[0]) == "tight" and check_constant(BOUND_CONSTANTS[1]) == "fosd"
    with pytest.raises(OptionError, match=r"^choice: expected one of a, b, got \['a'\]$"):
        check_choice(["a"], ("a", "b"), "choice")


def test_the_ranges_are_stated_once_in_the_core():
    assert options.MAX_DEPTH_RANGE == (1, 50) and options.TIME_BUDGET_RANGE == (0.001, 60.0)
    assert search.MAX_DEPTH_RANGE is options.MAX_DEPTH_RANGE  # still importable from core.search
    assert search.TIME_BUDGET_RANGE is options.TIME_BUDGET_RANGE and SEED_RANGE is options.SEED_RANGE
    model = load_model(S3)
    with pytest.raises(OptionError, match=r"option depth: must be an integer in 1\.\.50, got 51"):
        make_policy("bnb", model, depth=51)
    with pytest.raises(OptionError, match=r"policy mcts: option max_depth: must be an integer in 1\.\.50, got 51"):
        make_policy("mcts", model, max_depth=51)
    with pytest.raises(OptionError, match=r"option time_budget: must be a number of seconds in 0\.001\.\.60, got 61"):
        make_policy("bnb", model, time_budget=61)


def test_a_load_error_names_the_parameter_and_the_file_once(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("discount: 0.9\nstates: 2\n")
    with pytest.raises(ModelError) as info:
        load_model_file(str(bad))
    msg = str(info.value)
    assert msg == f"model_file: {bad}: transition: missing (give transition and observation, or generator)"
    pomdp = tmp_path / "bad.POMDP"
    pomdp.write_text("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity\n")
    with pytest.raises(ModelError) as info:
        load_model_file(str(pomdp), "observation_model_files[0]")
    assert str(info.value) == (f"observation_model_files[0]: {pomdp}: O: no probabilities given for action 0, "
                               "end state 0 (observation row sums to 0)")
