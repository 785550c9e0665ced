"""Cassandra .POMDP import/export (pomdp_planner/core/io/cassandra.py)."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pomdp_planner.core.io.cassandra import (
    export_pomdp,
    is_safe_name,
    load_pomdp_file,
    parse_pomdp,
    safe_names,
    save_pomdp_file,
)
from pomdp_planner.core.io.model_yaml import load_model, save_model
from pomdp_planner.core.model import POMDP, ModelError

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted((ROOT / "config" / "models").glob("*.yaml"))

TIGER = """\
# The classic tiger problem (Kaelbling, Littman, Cassandra 1998), as in pomdp.org's tiger.95.POMDP
discount: 0.95
values: reward
states: tiger-left tiger-right
actions: listen open-left open-right
observations: tiger-left tiger-right
start: uniform

T: listen
identity

T: open-left
uniform

T: open-right
uniform

O: listen
0.85 0.15
0.15 0.85

O: open-left
uniform

O: open-right
uniform

R: listen : * : * : * -1
R: open-left : tiger-left : * : * -100
R: open-left : tiger-right : * : * 10
R: open-right : tiger-left : * : * 10
R: open-right : tiger-right : * : * -100
"""


def assert_same_model(m1: POMDP, m2: POMDP, tol: float = 1e-12) -> None:
    assert (m1.S, m1.A, m1.Z) == (m2.S, m2.A, m2.Z)
    np.testing.assert_allclose(m1.P, m2.P, atol=tol, rtol=0)
    np.testing.assert_allclose(m1.O, m2.O, atol=tol, rtol=0)
    np.testing.assert_allclose(m1.r, m2.r, atol=tol, rtol=0)
    assert abs(m1.gamma - m2.gamma) <= tol


# ------------------------------------------------------------------ hand-written files
def test_tiger_matrices():
    m = parse_pomdp(TIGER)
    assert m.state_names == ("tiger-left", "tiger-right")
    assert m.action_names == ("listen", "open-left", "open-right")
    assert m.observation_names == ("tiger-left", "tiger-right")
    assert m.gamma == 0.95
    np.testing.assert_array_equal(m.P[0], [[1, 0], [0, 1]])
    np.testing.assert_array_equal(m.P[1], [[0.5, 0.5], [0.5, 0.5]])
    np.testing.assert_array_equal(m.P[2], [[0.5, 0.5], [0.5, 0.5]])
    np.testing.assert_array_equal(m.O[0], [[0.85, 0.15], [0.15, 0.85]])
    np.testing.assert_array_equal(m.O[1], [[0.5, 0.5], [0.5, 0.5]])
    # r[s, a]: listening costs 1; opening the tiger's door -100, the other door +10.
    np.testing.assert_array_equal(m.r, [[-1, -100, 10], [-1, 10, -100]])
    assert m.metadata["start"] == [0.5, 0.5]
    assert m.uncertainty.name == "none"


def test_element_form_with_indices_and_wildcards_and_override():
    text = """
    discount: 0.9
    states: 3
    actions: 2
    observations: 2
    T: * : * : * 0.0          # clear, then fill
    T: * : * : 0 0.5
    T: * : * : 1 0.5
    T: 1 : 2 : 1 0.0
    T: 1 : 2 : 2 0.5           # override the last row of action 1: (0.5, 0, 0.5)
    O: * : * : 0 0.25
    O: * : * : 1 0.75
    O: 0 : 2 : 0 1.0
    O: 0 : 2 : 1 0.0
    R: * : * : * : * 2.5
    R: 1 : 0 : * : * -1
    """
    m = parse_pomdp(text)
    expected_P = np.array([[0.5, 0.5, 0.0]] * 3)
    np.testing.assert_array_equal(m.P[0], expected_P)
    np.testing.assert_array_equal(m.P[1], [[0.5, 0.5, 0], [0.5, 0.5, 0], [0.5, 0, 0.5]])
    np.testing.assert_array_equal(m.O[0], [[0.25, 0.75], [0.25, 0.75], [1.0, 0.0]])
    np.testing.assert_array_equal(m.O[1], [[0.25, 0.75]] * 3)
    np.testing.assert_array_equal(m.r, [[2.5, -1.0], [2.5, 2.5], [2.5, 2.5]])
    assert m.state_names is None and m.action_names is None


def test_row_and_matrix_forms_and_keywords():
    text = """
    discount: 0.5
    states: a b
    actions: go stay
    observations: x y z
    T: go : a
    0.2 0.8
    T: go : b
    uniform
    T: stay
    identity
    O: go
    0.1 0.2 0.7
    0.3 0.3 0.4
    O: stay : a
    1 0 0
    O: stay : b
    uniform
    R: * : * : * : * 0
    """
    m = parse_pomdp(text)
    np.testing.assert_array_equal(m.P[0], [[0.2, 0.8], [0.5, 0.5]])
    np.testing.assert_array_equal(m.P[1], np.eye(2))
    np.testing.assert_array_equal(m.O[0], [[0.1, 0.2, 0.7], [0.3, 0.3, 0.4]])
    np.testing.assert_allclose(m.O[1], [[1, 0, 0], [1 / 3, 1 / 3, 1 / 3]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(m.r, 0)


def test_matrix_may_span_lines_freely_and_uniform_matrix():
    text = "discount: 0.5 states: 2 actions: 1 observations: 2\nT: 0 0.1 0.9\n0.3\n0.7 O: 0 uniform R: 0 : * 1"
    # 'R: 0 : *' followed by a 2 x 2 matrix would need 4 numbers: use the element form instead.
    with pytest.raises(ModelError, match=r"line 4.*R: matrix.*expected 4 numbers, got 1 before end of file"):
        parse_pomdp(text)
    m = parse_pomdp(text.replace("R: 0 : * 1", "R: 0 : * : * : * 1"))
    np.testing.assert_array_equal(m.P[0], [[0.1, 0.9], [0.3, 0.7]])
    np.testing.assert_array_equal(m.O[0], 0.5)
    np.testing.assert_array_equal(m.r, [[1.0], [1.0]])


def _reward_file() -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    P = np.array([[[0.6, 0.4], [0.1, 0.9]], [[0.3, 0.7], [0.8, 0.2]]])
    O = np.array([[[0.5, 0.25, 0.25], [0.2, 0.3, 0.5]], [[0.9, 0.05, 0.05], [0.0, 0.5, 0.5]]])
    R = np.zeros((2, 2, 2, 3))  # R[a, s, s', z]
    R[:, :, :, :] = 1.0          # R: * : * : * : * 1
    R[0, 1, :, :] = 4.0          # R: 0 : 1 : * : * 4
    R[1, :, 1, 2] = -3.0         # R: 1 : * : 1 : 2 -3
    R[0, 0, 0, :] = [7, 8, 9]    # R: 0 : 0 : 0 (row over observations)
    R[1, 1, :, :] = [[1, 2, 3], [4, 5, 6]]  # R: 1 : 1 (matrix s' x z)
    text = """
    discount: 0.99
    values: reward
    states: 2
    actions: 2
    observations: 3
    T: 0
    0.6 0.4
    0.1 0.9
    T: 1
    0.3 0.7
    0.8 0.2
    O: 0
    0.5 0.25 0.25
    0.2 0.3 0.5
    O: 1
    0.9 0.05 0.05
    0.0 0.5 0.5
    R: * : * : * : * 1
    R: 0 : 1 : * : * 4
    R: 1 : * : 1 : 2 -3
    R: 0 : 0 : 0
    7 8 9
    R: 1 : 1
    1 2 3
    4 5 6
    """
    return text, P, O, R


def test_reward_reduced_by_expectation_over_next_state_and_observation():
    text, P, O, R = _reward_file()
    m = parse_pomdp(text)
    np.testing.assert_array_equal(m.P, P)
    np.testing.assert_array_equal(m.O, O)
    expected = np.zeros((2, 2))
    for a in range(2):
        for s in range(2):
            total = 0.0
            for s2 in range(2):
                for z in range(3):
                    total += P[a, s, s2] * O[a, s2, z] * R[a, s, s2, z]
            expected[s, a] = total
    np.testing.assert_allclose(m.r, expected, rtol=0, atol=1e-12)
    cost = parse_pomdp(text.replace("values: reward", "values: cost"))
    np.testing.assert_allclose(cost.r, -expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("line", "expected"), [
    ("start: 0.2 0.3 0.5", [0.2, 0.3, 0.5]),
    ("start: uniform", [1 / 3, 1 / 3, 1 / 3]),
    ("start: mid", [0, 1, 0]),
    ("start: 2", [0, 0, 1]),
    ("start include: low high", [0.5, 0, 0.5]),
    ("start exclude: low", [0, 0.5, 0.5]),
])
def test_start_forms(line, expected):
    text = f"discount: 0.9\nstates: low mid high\nactions: 1\nobservations: 1\n{line}\n" \
           "T: 0 identity\nO: 0 uniform\nR: * : * : * : * 0\n"
    m = parse_pomdp(text)
    np.testing.assert_allclose(m.metadata["start"], expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize(("text", "pattern"), [
    ("states: 2\nactions: 1\nobservations: 1\nT: 0 identity\nO: 0 uniform\n", "'discount:' is missing"),
    ("discount: 1.5\n", r"line 1: discount: must satisfy 0 <= discount <= 1 \(1: a finite horizon only\)"),
    ("discount: 0.9\nvalues: utility\n", "line 2: values: expected 'reward' or 'cost'"),
    ("discount: 0.9\nT: 0 identity\n", "line 2: 'states:' must be declared"),
    ("discount: 0.9\nstates: 1 2 3\n", "line 2: states: name '1' is a bare number"),
    ("discount: 0.9\nstates: a b a\n", "line 2: states: name 'a' appears twice"),
    ("discount: 0.9\nstates: 2\nstates: 2\n", "line 3: 'states:' declared twice"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 5 : 0 1.0\n",
     r"line 5: state index 5 out of range 0..1"),
    ("discount: 0.9\nstates: a b\nactions: 1\nobservations: 1\nT: 0 : c : a 1.0\n",
     "line 5: unknown state 'c'; known names: a b"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0\n0.5 0.5\n0.5\nO: 0 uniform\n",
     r"line 8: T: matrix: expected 4 numbers, got 3 before 'O' \(entry starting on line 5\)"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0\n0.5 0.5 0.5\n",
     "line 6: T: row: more than the expected 2 numbers"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0 : 1 1.5\n",
     "line 5: T: entry: probability 1.5 is outside"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity\nT: 0 : 1 : 0 0.5\nO: 0 uniform\n",
     r"line 6: T: transition row for action 0, start state 1 sums to 1.5"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity\nO: 0 : 0\n1\n",
     "O: no probabilities given for action 0, end state 1"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity\nfoo: 1\n",
     "line 6: unexpected 'foo'"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 3\nT: 0 identity\nO: 0 identity\n",
     "line 6: O: 'identity' needs as many observations as states"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT 0 identity\n", "line 5: expected ':' after T"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nstart: 0.5 0.6\n", "line 5: start: probabilities"),
    ("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0 : 1", "line 5: unexpected end of file"),
])
def test_errors_name_line_and_problem(text, pattern):
    with pytest.raises(ModelError, match=pattern):
        parse_pomdp(text)


def test_comments_and_load_model_dispatch(tmp_path):
    path = tmp_path / "tiger.POMDP"
    path.write_text(TIGER.replace("discount: 0.95", "discount: 0.95   # trailing comment\n# full line"))
    for m in (load_pomdp_file(path), load_model(path)):
        assert m.gamma == 0.95 and m.name == "tiger"
        np.testing.assert_array_equal(m.r, [[-1, -100, 10], [-1, 10, -100]])
    with pytest.raises(ModelError, match="cannot read"):
        load_pomdp_file(tmp_path / "missing.pomdp")


# ------------------------------------------------------------------ export and round trips
@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_shipped_models_round_trip_with_their_uncertainty_term(path):
    model = load_model(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        text = export_pomdp(model)
    meta = json.loads(next(line for line in text.splitlines() if line.startswith("# pomdp_planner: "))[17:])
    assert meta["uncertainty"] == {"function": model.uncertainty.name, "weights": model.w.tolist(),
                                   "epsilon": model.epsilon}
    assert "other readers see the linear reward r(s, a) only" in text
    back = parse_pomdp(text)
    assert_same_model(back, model)
    assert back.uncertainty.name == model.uncertainty.name and back.epsilon == model.epsilon
    np.testing.assert_array_equal(back.w, model.w)
    b = np.random.default_rng(0).dirichlet(np.ones(model.S), size=5)
    np.testing.assert_allclose(back.rho(b), model.rho(b), rtol=1e-12)


def test_export_without_uncertainty_does_not_warn_and_writes_start(tmp_path):
    m = parse_pomdp(TIGER, source="tiger.POMDP")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        text = export_pomdp(m)
    assert "start: 0.5 0.5" in text
    assert "R: listen : tiger-left : * : * -1.0" in text
    path = tmp_path / "t.pomdp"
    save_pomdp_file(m, path)
    back = load_pomdp_file(path)
    assert_same_model(back, m)
    assert back.metadata["start"] == [0.5, 0.5] and back.name == "tiger"
    assert back.state_names == m.state_names


def test_yaml_to_pomdp_to_model(tmp_path):
    model = load_model(ROOT / "config" / "models" / "tracking_s3_info.yaml")
    plain = POMDP(P=model.P, O=model.O, r=model.r, gamma=model.gamma, name="plain",
                  state_names=["low", "mid", "high"], action_names=["p1", "p2", "p3"],
                  metadata={"start": [0.2, 0.3, 0.5]})
    save_model(plain, tmp_path / "m.yaml")
    loaded = load_model(tmp_path / "m.yaml")
    save_pomdp_file(loaded, tmp_path / "m.pomdp")
    back = load_model(tmp_path / "m.pomdp")
    assert_same_model(back, plain)
    assert back.state_names == ("low", "mid", "high") and back.action_names == ("p1", "p2", "p3")
    assert back.observation_names is None
    np.testing.assert_allclose(back.metadata["start"], [0.2, 0.3, 0.5], rtol=0, atol=1e-15)


def _tiny(S: int, names: list[str]) -> POMDP:
    return POMDP(P=np.tile(np.eye(S), (1, 1, 1)), O=np.ones((1, S, 1)), r=np.arange(S, dtype=float)[:, None],
                 gamma=0.5, state_names=names)


def test_bare_number_state_name_is_not_read_as_a_count():
    m = _tiny(1, ["5"])
    text = export_pomdp(m)
    assert "states: s_5\n" in text and "states: 5" not in text
    back = parse_pomdp(text)
    assert back.S == 1 and back.state_names == ("5",)   # restored from the comment
    # A reader that ignores our comment still gets one state, named s_5.
    stripped = "\n".join(line for line in text.splitlines() if not line.startswith("# pomdp_planner:"))
    other = parse_pomdp(stripped)
    assert other.S == 1 and other.state_names == ("s_5",)


def test_numeric_keyword_and_odd_names():
    names = ["1", "2", "uniform", "T", "a b", "a_b", "ok-name"]
    m = _tiny(len(names), names)
    text = export_pomdp(m)
    header = next(line for line in text.splitlines() if line.startswith("states:"))
    written = header.split()[1:]
    assert written == ["s_1", "s_2", "s_uniform", "s_T", "a_b_2", "a_b", "ok-name"]
    assert all(is_safe_name(n) for n in written)
    back = parse_pomdp(text)
    assert back.state_names == tuple(names)
    assert_same_model(back, m)


def test_safe_names_rule():
    assert safe_names(["x", "7", "x y", "x_y", "start"], "states") == ["x", "s_7", "x_y_2", "x_y", "s_start"]
    assert safe_names(["0", "-"], "actions") == ["a_0", "a_-"]
    assert safe_names(["é"], "observations") == ["o__"]


@st.composite
def random_models(draw):
    S = draw(st.integers(1, 4))
    A = draw(st.integers(1, 3))
    Z = draw(st.integers(1, 4))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)

    def stoch(shape):
        M = rng.dirichlet(np.ones(shape[-1]), size=shape[:-1])
        M[rng.random(M.shape) < 0.2] = 0.0       # some exact zeros
        M[M.sum(axis=-1) == 0, 0] = 1.0
        return M / M.sum(axis=-1, keepdims=True)

    name_alphabet = st.sampled_from(["1", "10", "x", "x y", "uniform", "O", "s-1", "3.5", "q_"])

    def names(n):
        return draw(st.one_of(st.none(), st.lists(name_alphabet, min_size=n, max_size=n, unique=True)))

    start = draw(st.booleans())
    return POMDP(
        P=stoch((A, S, S)), O=stoch((A, S, Z)), r=rng.normal(scale=10, size=(S, A)),
        gamma=float(draw(st.floats(0, 0.999))), name="random",
        state_names=names(S), action_names=names(A), observation_names=names(Z),
        metadata={"start": stoch((S,)).tolist()} if start else {},
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_models())
def test_round_trip_random_models(model):
    back = parse_pomdp(export_pomdp(model))
    assert_same_model(back, model)
    assert back.state_names == model.state_names
    assert back.action_names == model.action_names
    assert back.observation_names == model.observation_names
    if "start" in model.metadata:
        np.testing.assert_allclose(back.metadata["start"], model.metadata["start"], rtol=0, atol=1e-12)


def test_spaces_around_colons_and_trailing_wildcards():
    # The style some writers use (e.g. pomdp-py's to_pomdp_file): spaces before ':' and element forms only.
    text = """discount: 0.950000000
values: reward
states: tl tr
actions: listen open
observations: hl hr
start: 0.300000000 0.700000000
T : listen : tl : tl 1.000000000
T : listen : tr : tr 1.000000000
T : open : * : * 0.500000000
O : listen : tl : hl 0.850000000
O : listen : tl : hr 0.150000000
O : listen : tr : hl 0.150000000
O : listen : tr : hr 0.850000000
O : open : * : * 0.500000000
R : listen : * : * : *  -1.000000000
R : open : tl : * : *  -100.000000000
R : open : tr : * : *  10.000000000
"""
    m = parse_pomdp(text)
    np.testing.assert_array_equal(m.P, [np.eye(2), np.full((2, 2), 0.5)])
    np.testing.assert_array_equal(m.O[0], [[0.85, 0.15], [0.15, 0.85]])
    np.testing.assert_array_equal(m.r, [[-1, -100], [-1, 10]])
    assert m.metadata["start"] == [0.3, 0.7]


def test_exported_numbers_follow_the_pomdp_solve_rule():
    """pomdp-solve: every float has a digit before and after the decimal point."""
    model = parse_pomdp(TIGER)
    tiny = POMDP(P=model.P, O=model.O, r=model.r * 1e-7, gamma=0.95)
    checked = 0
    for m in (model, tiny):
        for line in export_pomdp(m).splitlines():
            tokens = line.split("#", 1)[0].split()
            if not tokens:
                continue
            if tokens[0] in ("discount:", "R:"):
                numbers = tokens[-1:]
            elif tokens[0] == "start:":
                numbers = tokens[1:]
            elif tokens[0].endswith(":"):
                continue  # header or T:/O: line (names or indices)
            else:
                numbers = tokens  # a matrix row
            for tok in numbers:
                assert re.fullmatch(r"-?\d+\.\d+(e[+-]\d+)?", tok), (line, tok)
                checked += 1
    assert checked > 20
