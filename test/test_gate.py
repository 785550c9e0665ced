"""The assumption gate (core/gate.py): prune only with valid bounds, fall back with a reason,
refuse on request, the explicit override says that no guarantee holds; Assumption 1 checked
once per model.

``test/models/fails_assumption1_s3.yaml`` fails (A1), (A2) and (A3)
but has a feasible LP: its "bounds" agree at (0.3, 0.4, 0.3) on priority 2, which exhaustive
search to depth 6 does not choose, and cross at (0.1, 0.8, 0.1).
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core import gate
from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.gate import assumption_report, build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.search import Planner

from model_factory import ModelSpec, posterior_floor, random_candidate  # isort: skip

REPO = Path(__file__).resolve().parents[1]
FAILING = REPO / "test" / "models" / "fails_assumption1_s3.yaml"
S3 = REPO / "config" / "models" / "tracking_s3_info.yaml"
AGREE = np.array([0.3, 0.4, 0.3])  # the failing model's bounds agree here (priority 2)
CROSS = np.array([0.1, 0.8, 0.1])  # and cross here


@pytest.fixture(scope="module")
def failing() -> POMDP:
    return load_model(FAILING)


@pytest.fixture(scope="module")
def s3() -> POMDP:
    return load_model(S3)


def test_the_fixture_is_what_the_issue_describes(failing: POMDP) -> None:
    """Checked independently of the gate: the report fails, the raw LP bounds agree at AGREE on a
    priority exhaustive search does not choose, and cross at CROSS."""
    from pomdp_planner.core.bounds import solve_bounds
    from pomdp_planner.core.structure import check_assumptions

    status = check_assumptions(failing).status
    assert status["A1"] == "fails" and status["A2"] == "fails"
    mb = solve_bounds(failing).myopic
    assert mb is not None
    lo, up = (int(x[0]) for x in mb.actions(AGREE[None, :]))
    assert lo == up == 1
    assert Planner(failing).search(AGREE, 6, use_bounds=False).action == 0
    lo, up = (int(x[0]) for x in mb.actions(CROSS[None, :]))
    assert lo > up


def test_valid_model_prunes_with_the_guarantee(s3: POMDP) -> None:
    setup = build_planner(s3)
    assert setup.mode == "prune" and setup.pruning and setup.guaranteed and not setup.forced
    assert setup.planner.guaranteed and setup.planner.has_bounds and setup.myopic is not None
    assert setup.report.holds and setup.bounds.feasible
    assert "Assumption 1 holds" in setup.reason
    certified = [setup.planner.plan(b, 3).certified for b in np.random.default_rng(3).dirichlet(np.ones(3), 30)]
    assert any(certified)  # the shipped model's bounds do certify


def test_failing_model_falls_back_to_exhaustive_with_the_reason(failing: POMDP) -> None:
    setup = build_planner(failing)
    assert setup.mode == "exhaustive" and not setup.guaranteed and not setup.planner.has_bounds
    assert "Assumption 1 fails" in setup.reason and "A1 fails" in setup.reason
    assert setup.bounds is None  # no LP solved for nothing
    res = setup.planner.search(AGREE, 6)
    assert not res.certified and res.root_bounds is None
    assert res.action == Planner(failing).search(AGREE, 6, use_bounds=False).action == 0


def test_failing_model_refused_on_request(failing: POMDP) -> None:
    setup = build_planner(failing, on_assumption_failure="refuse")
    assert setup.mode == "refuse" and setup.planner is None and not setup.guaranteed
    assert "Assumption 1 fails" in setup.reason and setup.describe().startswith("refused")


def test_override_prunes_without_guarantee_and_certifies_nothing(failing: POMDP) -> None:
    setup = build_planner(failing, prune_without_guarantee=True, override_name="--prune-without-guarantee")
    assert setup.mode == "prune" and setup.forced and not setup.guaranteed and not setup.planner.guaranteed
    assert "no guarantee holds" in setup.reason and "--prune-without-guarantee" in setup.reason
    assert "WITHOUT GUARANTEE" in setup.describe()
    planner = setup.planner
    # the bounds agree at AGREE and prune, but certify nothing, and the anytime search does not stop early
    fixed = planner.search(AGREE, 4)
    assert fixed.root_bounds == (1, 1) and not fixed.certified and not fixed.guaranteed
    anytime = planner.plan(AGREE, max_depth=4)
    assert anytime.depth == 4 and not anytime.certified
    crossed = planner.search(CROSS, 3)
    assert crossed.crossed and not crossed.certified
    for b in np.random.default_rng(0).dirichlet(np.ones(3), 20):
        assert not planner.plan(b, 2).certified


def test_override_cannot_conjure_bounds_from_an_infeasible_lp() -> None:
    """f = none, deterministic transitions, (A3) fails and the g-LP is infeasible by hand
    (test_bounds.py): even the override falls back, naming the LP."""
    P = np.zeros((2, 3, 3))
    P[0, 0, 0] = P[0, 1, 2] = P[0, 2, 2] = 1.0
    P[1, 0, 0] = P[1, 1, 0] = P[1, 2, 2] = 1.0
    model = POMDP(P=P, O=np.broadcast_to(np.eye(3), (2, 3, 3)).copy(),
                  r=np.array([[2.0, 2.0], [1.0, 1.0], [0.0, 0.0]]), gamma=0.9)
    assert build_planner(model).mode == "exhaustive"
    setup = build_planner(model, prune_without_guarantee=True)
    assert setup.mode == "exhaustive" and "infeasible" in setup.reason and not setup.bounds.feasible


def test_shannon_bounds_covering_no_domain_are_not_used() -> None:
    """Assumption 1 holds and the LP is feasible, but epsilon exceeds the posterior floor."""
    rng = np.random.default_rng(1)
    for _ in range(40):
        model = random_candidate(rng, ModelSpec(2, 3, 2, "shannon", 0.9), epsilon=0.2, sharpness=1.0)
        if model.epsilon > posterior_floor(model) and assumption_report(model).holds:
            break
    else:
        pytest.fail("no Shannon model with an uncovered B_epsilon found")
    setup = build_planner(model)
    if not setup.bounds.feasible:
        pytest.skip("LP infeasible for this draw")
    assert setup.mode == "exhaustive" and "posterior floor" in setup.reason and setup.bounds.covers.startswith("none")
    forced = build_planner(model, prune_without_guarantee=True)
    assert forced.mode == "prune" and not forced.guaranteed and "posterior floor" in forced.reason


def test_bounds_disabled_checks_nothing(monkeypatch: pytest.MonkeyPatch, s3: POMDP) -> None:
    monkeypatch.setattr(gate, "check_assumptions", lambda model: pytest.fail("checked although disabled"))
    setup = build_planner(s3, use_bounds=False)
    assert setup.mode == "exhaustive" and setup.report is None and "disabled" in setup.reason


def test_assumption_report_is_computed_once_per_model(monkeypatch: pytest.MonkeyPatch, s3: POMDP) -> None:
    calls = []
    real = gate.check_assumptions

    def counting(model):
        calls.append(model.name)
        return real(model)

    monkeypatch.setattr(gate, "check_assumptions", counting)
    monkeypatch.setattr(gate, "_reports", type(gate._reports)())
    build_planner(s3)
    build_planner(s3, variant="feasible")
    copy = pickle.loads(pickle.dumps(s3))  # e.g. a worker process's copy: same content, same report
    assert build_planner(copy).report.holds
    assert calls == [s3.name]
    renamed = POMDP(P=s3.P, O=s3.O, r=s3.r, gamma=s3.gamma, name="renamed")
    assert assumption_report(renamed).model_name == "renamed" and calls == [s3.name]
    other = POMDP(P=s3.P[::-1], O=s3.O, r=s3.r, gamma=s3.gamma, name="other")
    assumption_report(other)
    assert calls == [s3.name, "other"]
    report = assumption_report(s3)
    monkeypatch.setattr(gate, "_reports", type(gate._reports)())
    assert build_planner(s3, report=report).report is report and calls == [s3.name, "other"]


def test_to_dict_is_json(failing: POMDP, s3: POMDP) -> None:
    for setup in (build_planner(s3), build_planner(failing), build_planner(failing, prune_without_guarantee=True),
                  build_planner(failing, on_assumption_failure="refuse"), build_planner(s3, use_bounds=False)):
        d = json.loads(json.dumps(setup.to_dict(), allow_nan=False))
        assert d["mode"] == setup.mode and d["guaranteed"] == setup.guaranteed and d["reason"] == setup.reason


def test_bad_arguments_name_the_field(s3: POMDP) -> None:
    with pytest.raises(OptionError, match="variant"):
        build_planner(s3, variant="loose")
    with pytest.raises(OptionError, match="on_assumption_failure"):
        build_planner(s3, on_assumption_failure="ignore")


S8_NATURAL = REPO / "config" / "models" / "tracking_s8_natural.yaml"


def _worst_step_margin(model: POMDP, g: np.ndarray, C: float) -> float:
    """min over actions and state pairs of ``Delta_i (r_a + (I - gamma P[a]) g) - 2 C |w_a|``: the
    lower-bound constraint of the Renyi LP with constant ``C`` (docs/THEORY.md), from its formula."""
    worst = np.inf
    for a in range(model.A):
        phi = model.r[:, a] + g - model.gamma * model.P[a] @ g
        worst = min(worst, float(np.min(np.diff(phi) - 2.0 * C * abs(model.w[a]))))
    return worst


@pytest.mark.parametrize("constant", ["mlr", "fosd"])
def test_the_gate_records_the_constant_its_bounds_satisfy(constant: str) -> None:
    """The constant is recorded (setup, to_dict, reason) and is the one the vectors satisfy: on the
    natural S = 8 model the MLR-exact vector (C = 1) breaks the FOSD constraints (C_S = 1.82)."""
    model = load_model(S8_NATURAL)
    setup = build_planner(model, constant=constant)
    assert setup.mode == "prune" and setup.guaranteed
    assert setup.constant == constant and setup.bounds.constant == constant
    d = json.loads(json.dumps(setup.to_dict()))
    assert d["constant"] == constant and d["bounds"]["constant"] == constant
    assert d["bounds"]["why"].startswith(constant + ":")
    assert f"constant {constant}" in setup.describe()
    c_s = (1 + np.sqrt(model.S - 1)) / 2
    tol = 1e-7 * (1 + float(np.abs(setup.bounds.g).sum()))
    assert _worst_step_margin(model, setup.bounds.g, 1.0) >= -tol
    fosd_margin = _worst_step_margin(model, setup.bounds.g, c_s)
    assert fosd_margin >= -tol if constant == "fosd" else fosd_margin < -0.1


def test_the_default_constant_is_mlr_and_no_lp_records_none(s3: POMDP, failing: POMDP) -> None:
    assert build_planner(s3).constant == "mlr" and build_planner(s3).to_dict()["constant"] == "mlr"
    assert build_planner(s3, use_bounds=False, constant="fosd").constant is None  # nothing solved
    assert build_planner(failing, constant="fosd").constant is None  # exhaustive: the LP is not solved
    forced = build_planner(failing, constant="fosd", prune_without_guarantee=True)
    assert forced.constant == "fosd" and "constant fosd" in forced.reason


@pytest.mark.parametrize("bad", ["paper", "MLR", "", None, 1])
def test_a_bad_constant_is_refused_naming_the_field_and_the_choices(s3: POMDP, bad: object) -> None:
    for use_bounds in (True, False):
        with pytest.raises(OptionError, match=r"constant: expected one of mlr, fosd"):
            build_planner(s3, constant=bad, use_bounds=use_bounds)
