"""Peer model files (Cassandra ``.POMDP``, as pomdp-solve reads them): rows within pomdp-solve's
tolerance, wildcard rewards, and a discount of 1 for finite-horizon use.

The values are checked against hand computations written out here (the fixtures are in
``test/models/``): pomdp-solve's expected reward ``r(s, a) = sum_{s', z} P O R`` with the rows as
written, and a depth-1 expectimax on a two-state model.
"""

from __future__ import annotations

import io
import warnings
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main
from pomdp_planner.core.belief_mcts import make_belief_mcts_policy
from pomdp_planner.core.bounds import solve_bounds
from pomdp_planner.core.errors import InputWarning, ModelError, OptionError
from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.cassandra import PEER_ROW_TOLERANCE, export_pomdp, parse_pomdp
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.policies import make_policy
from pomdp_planner.core.reference import alpha_vector_value_iteration, reference_policy, solve_grid
from pomdp_planner.core.simulate import simulate

MODELS = Path(__file__).resolve().parent / "models"
ROWS = MODELS / "peer_rows_off_5e-6.POMDP"
COST = MODELS / "finite_horizon_cost.POMDP"


def _load_with_warnings(path: Path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = load_model(path)
    return model, [w for w in caught if issubclass(w.category, InputWarning)], caught


def _cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


# ------------------------------------------------------------------ rows within the tolerance
def test_rows_within_pomdp_solves_tolerance_are_renormalised_with_one_warning_naming_the_row():
    m, ours, _ = _load_with_warnings(ROWS)
    assert len(ours) == 1
    text = str(ours[0].message)
    assert "\n" not in text
    assert text.startswith(f"{ROWS}: line 10: T: transition row for action stay, start state low sums to 1.000005")
    assert "within pomdp-solve's tolerance 1e-05: renormalised (2 more rows likewise; in all 2 T, 1 O)" in text
    # each changed row is the written row over its sum; the exact rows are untouched
    np.testing.assert_allclose(m.P[0, 0], np.array([0.7, 0.300005]) / 1.000005, rtol=0, atol=1e-16)
    np.testing.assert_allclose(m.P[1, 1], np.array([0.399995, 0.6]) / 0.999995, rtol=0, atol=1e-16)
    np.testing.assert_allclose(m.O[1, 0], np.array([0.9, 0.100005]) / 1.000005, rtol=0, atol=1e-16)
    assert m.P[0, 1].tolist() == [0.2, 0.8] and m.O[0].tolist() == [[0.9, 0.1], [0.25, 0.75]]
    np.testing.assert_allclose(m.P.sum(axis=-1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(m.O.sum(axis=-1), 1.0, rtol=0, atol=1e-15)


def test_wildcard_rewards_are_pomdp_solves_unnormalised_expectation():
    m, _, _ = _load_with_warnings(ROWS)
    # r(s, a) = v * sum_{s'} P(s'|s,a) sum_z O(z|s',a), with the rows as written:
    stay_low = 2.0 * (0.7 * (0.9 + 0.1) + 0.300005 * (0.25 + 0.75))          # = 2.00001
    move_low = 1.0 * (0.5 * (0.9 + 0.100005) + 0.5 * (0.25 + 0.75))         # = 1.0000025
    move_high = -4.0 * (0.399995 * (0.9 + 0.100005) + 0.6 * (0.25 + 0.75))  # = -3.9999879999
    assert stay_low == pytest.approx(2.00001, abs=1e-12)
    assert move_low == pytest.approx(1.0000025, abs=1e-12)
    assert move_high == pytest.approx(-3.9999879999, abs=1e-12)
    np.testing.assert_allclose(m.r, [[stay_low, move_low], [0.0, move_high]], rtol=0, atol=1e-14)


def test_rows_beyond_the_tolerance_are_still_refused():
    text = ROWS.read_text().replace("0.7 0.300005", "0.7 0.30002")
    with pytest.raises(ModelError, match=r"^peer\.POMDP: line 10: T: transition row for action stay, start state low "
                                         r"sums to 1\.00002 over states, not 1 \(tolerance 1e-05;"):
        parse_pomdp(text, "peer.POMDP")
    assert PEER_ROW_TOLERANCE == 1e-5


def test_rows_within_the_models_own_tolerance_load_unchanged_and_silently():
    text = ROWS.read_text().replace("0.300005", "0.3000005").replace("0.399995", "0.3999995").replace(
        "0.100005", "0.1000005")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = parse_pomdp(text, "close.POMDP")
    assert m.P[0, 0].tolist() == [0.7, 0.3000005]  # as written: values agree with pomdp-solve's exactly


def test_the_command_line_prints_the_renormalisation_as_one_warning_line():
    code, _, err = _cli("check", str(ROWS))
    assert code in (0, 1) and "Traceback" not in err
    lines = [line for line in err.splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith(f"pomdp-planner: warning: {ROWS}: line 10: T: transition row")


# ------------------------------------------------------------------ discount 1
def _hand_depth1_q(b_ok: float) -> tuple[float, float]:
    """Depth-1 expectimax of finite_horizon_cost.POMDP at belief (b_ok, 1 - b_ok), gamma = 1:
    ``Q(b, a) = rho(b, a) + sum_z eta(z | b, a) max_a' rho(tau(b, a, z), a')``, rewards = -costs."""
    b_br = 1.0 - b_ok
    cost = {"wait": (0.0, 10.0), "repair": (4.0, 4.0)}
    O = ((0.9, 0.1), (0.2, 0.8))  # O[state][z]

    def rho(p_ok: float, a: str) -> float:
        return -(p_ok * cost[a][0] + (1.0 - p_ok) * cost[a][1])

    def backup(pred_ok: float) -> float:
        total = 0.0
        for z in range(2):
            u_ok, u_br = pred_ok * O[0][z], (1.0 - pred_ok) * O[1][z]
            eta = u_ok + u_br
            total += eta * max(rho(u_ok / eta, "wait"), rho(u_ok / eta, "repair"))
        return total

    q_wait = rho(b_ok, "wait") + backup(0.8 * b_ok)  # wait: ok stays ok w.p. 0.8, broken stays broken
    q_repair = rho(b_ok, "repair") + backup(1.0 * b_ok + 1.0 * b_br)  # repair: always ok next
    return q_wait, q_repair


def test_discount_one_cost_file_plans_at_a_finite_depth_with_the_hand_computed_values():
    m = load_model(COST)
    assert m.gamma == 1.0 and "finite horizon only" in m.describe()
    np.testing.assert_array_equal(m.r, [[0.0, -4.0], [-10.0, -4.0]])  # values: cost -> rewards = -costs
    q_wait, q_repair = _hand_depth1_q(0.5)
    assert (q_wait, q_repair) == (pytest.approx(-8.28, abs=1e-12), pytest.approx(-4.0, abs=1e-12))
    setup = build_planner(m)
    assert setup.mode == "exhaustive" and not setup.guaranteed
    assert setup.reason.startswith("discount: the bound LP (Theorem 2) needs discount < 1")
    res = setup.planner.search(np.array([0.5, 0.5]), 1, use_bounds=False)
    np.testing.assert_allclose(res.q_values, [q_wait, q_repair], rtol=0, atol=1e-12)
    assert res.action == 1 and not res.certified
    for b_ok in (0.1, 0.9):
        res = setup.planner.search(np.array([b_ok, 1 - b_ok]), 1, use_bounds=False)
        np.testing.assert_allclose(res.q_values, _hand_depth1_q(b_ok), rtol=0, atol=1e-12)


def test_discount_one_everything_infinite_horizon_refuses_in_one_line():
    m = load_model(COST)
    for call in (lambda: solve_bounds(m), lambda: solve_grid(m, 4), lambda: reference_policy(m, 4),
                 lambda: alpha_vector_value_iteration(m, 3)):
        with pytest.raises(ModelError, match=r"^discount: .* needs discount < 1 \(an infinite horizon\); this "
                                             r"model's discount is 1, valid for a finite horizon only") as err:
            call()
        assert "\n" not in str(err.value)
    assert solve_grid(m, 4, horizon=2).V.shape[0] > 0  # a finite number of backups is a finite horizon
    with pytest.raises(OptionError, match="policy lower: no valid bounds: discount"):
        make_policy("lower", m)
    with pytest.raises(OptionError, match=r"tail: average values the infinite horizon .* use tail=none"):
        make_belief_mcts_policy(m, {})


def test_discount_one_runs_where_the_horizon_is_finite():
    m = load_model(COST)
    trace = simulate(m, make_policy("bnb", m, depth=2), 5, seed=1)
    assert len(trace.actions) == 5 and np.isfinite(trace.discounted_return)
    assert trace.discounted_return == pytest.approx(float(np.sum(trace.rewards)), abs=1e-12)
    trace = simulate(m, make_belief_mcts_policy(m, {"tail": "none", "simulations": 50}), 3, seed=1)
    assert np.isfinite(trace.discounted_return)
    back = parse_pomdp(export_pomdp(m), "back.POMDP")
    assert back.gamma == 1.0 and np.array_equal(back.r, m.r) and np.array_equal(back.P, m.P)


def test_discount_one_from_the_command_line():
    code, out, err = _cli("plan", str(COST), "--depth", "1", "--belief", "0.5,0.5")
    assert code == 0 and "Traceback" not in err
    assert "exhaustive search: discount: the bound LP (Theorem 2) needs discount < 1" in out
    code, out, err = _cli("check", str(COST))
    assert "finite horizon only" in out and "plan and simulate search exhaustively" in out
    code, out, err = _cli("simulate", str(COST), "--policy", "bnb", "--steps", "3", "--option", "depth=2")
    assert code == 0 and "Traceback" not in err


def test_yaml_discount_one_integer_is_a_finite_horizon_model(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("name: m\ndiscount: 1\nstates: 2\nactions: 1\nobservations: 1\n"
                    "transition: [[[1, 0], [0, 1]]]\nobservation: [[[1], [1]]]\nreward: [[1], [0]]\n")
    m = load_model(path)
    assert m.gamma == 1.0 and isinstance(m.gamma, float)
    res = build_planner(m).planner.search(np.array([1.0, 0.0]), 3, use_bounds=False)
    assert res.q_values[0] == pytest.approx(4.0)  # 1 + 1 + 1 + 1: four rewards, none discounted
