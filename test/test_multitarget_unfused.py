"""The priced search end to end on every leaf-table layout (``Planner.priced`` in ``core/search.py``,
``core/multitarget``, ``simulate --targets``, the sensor manager's loop).

A planner keeps the fused leaf table only up to ``FUSED_TABLE_MAX_BYTES``; above it the leaf
products read the reward table itself, which ``priced()`` must price too. Two checks:

* a real model above the limit (S = Z = 256, A = 16, generated from a small file), two targets, one
  budget, every target searched exhaustively at depth 1: the command line's price, dual bound and
  priorities, its JSON step after step, and the sensor manager's loop, each against an
  independent computation written here (Bayes' rule, Eq. 3 and the depth-1 expectimax by hand,
  the knapsack by enumerating every joint action);
* the limit lowered to nothing (every planner unfused) on the shipped S = 3 models at depth 2: the
  command line's output equals the fused run's, and its dual bounds are never below the exact
  joint planner's value (``core/multitarget/joint_exact.py``) at the beliefs the run reached.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

import pomdp_planner.core.search as search_module
from pomdp_planner.cli import main
from pomdp_planner.core.belief import start_belief
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import JOIN_DELAY, BeliefSample, Liveness, ManagerLoop, StallLimits
from pomdp_planner.core.loop.manager_params import manager_problem
from pomdp_planner.core.multitarget.joint_exact import ExactJointPlanner
from pomdp_planner.core.multitarget.problem import make_problem
from pomdp_planner.core.search import uses_fused_table

S, A = 256, 16
BUDGET = 1
EFFORTS = [1] * 8 + [0] * 8  # priorities 1-8 cost one unit, 9-16 nothing: the budget serves one target


def big_model_file(directory: Path) -> Path:
    """S = Z = 256, A = 16 tracking dynamics (the paper's generator) with a reward that pays for
    high priority, so the budget binds and the price is positive."""
    reward = [[round(0.4 * (A - a) / A + 0.1 * (s / S), 6) for a in range(A)] for s in range(S)]
    text = "\n".join([
        "name: big", "discount: 0.95", f"states: {S}", f"actions: {A}", f"observations: {S}",
        f"generator: {{domain: tracking, S: {S}, A: {A}, q: 0.7}}",
        "reward:", *(f"  - {row}" for row in reward),
        f"uncertainty: {{function: renyi2, weights: {[1.0] * A}}}", ""])
    path = directory / "big.yaml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    path = big_model_file(tmp_path_factory.mktemp("big"))
    model = load_model_file(str(path))
    assert not uses_fused_table(model.S, model.A, model.Z)  # above the real limit
    return path, model


# ----------------------------------------------------------------- the independent computation
def bayes(model, b, a, z):
    unnorm = (b @ model.P[a]) * model.O[a][:, z]
    return unnorm / unnorm.sum()


def rho(model, b):
    """Eq. 3 with the Renyi quadratic entropy, written out: ``b . r_a - w_a (-log sum b^2)``."""
    return b @ model.r - model.w * (-np.log(np.sum(b * b)))


def depth1_q(model, b, price):
    """``Q(b, a) = rho(b, a) - price_a + gamma sum_z eta(z) max_a' [rho(tau, a') - price_a']``, one
    action and one observation at a time."""
    q = np.empty(model.A)
    for a in range(model.A):
        pred = b @ model.P[a]
        eta = pred @ model.O[a]
        future = 0.0
        for z in np.flatnonzero(eta > 1e-300):
            tau = pred * model.O[a][:, z] / eta[z]
            future += eta[z] * np.max(rho(model, tau) - price)
        q[a] = rho(model, b)[a] - price[a] + model.gamma * future
    return q


def dual_bound_at(model, beliefs, lam):
    """``U(lam)`` at depth 1 by enumerating every joint action within the budget, and its maximisers."""
    e = np.array(EFFORTS, dtype=float)
    rows = [depth1_q(model, b, lam * e) + lam * e for b in beliefs]
    best, argmax = -np.inf, []
    for a1 in range(A):
        for a2 in range(A):
            if e[a1] + e[a2] <= BUDGET:
                v = rows[0][a1] + rows[1][a2]
                if v > best + 1e-12:
                    best, argmax = v, [(a1, a2)]
                elif v >= best - 1e-12:
                    argmax.append((a1, a2))
    return best + lam * BUDGET * model.gamma, argmax, rows


# ----------------------------------------------------------------- above the real limit
def test_simulate_targets_above_the_fused_table_limit(big):
    """The command line itself (a process of the installed package), step after step."""
    path, model = big
    efforts = ",".join(str(e) for e in EFFORTS)
    proc = subprocess.run([sys.executable, "-m", "pomdp_planner", "simulate", "--targets", f"{path},{path}",
                           "--budget", str(BUDGET), "--efforts", efforts, "--option", "search=exhaustive",
                           "--option", "depth=1", "--steps", "3", "--json"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    data = json.loads(proc.stdout)
    assert data["planner"]["bound_guaranteed"] is True
    assert start_belief(model) is None  # every target starts uniform
    beliefs = [np.full(S, 1.0 / S), np.full(S, 1.0 / S)]
    for step in data["steps"]:
        assert step["depth"] == 1 and step["lambda"] > 0.0  # the price is used: priced() runs
        want, argmax, _ = dual_bound_at(model, beliefs, step["lambda"])
        assert step["dual_bound"] == pytest.approx(want, rel=1e-9, abs=1e-9)
        actions = tuple(p - 1 for p in step["priorities"])
        assert actions in argmax and step["within_budget"]
        beliefs = [bayes(model, b, a, z) for b, a, z in zip(beliefs, actions, step["observations"], strict=True)]


def test_sensor_manager_loop_above_the_fused_table_limit(big):
    """The sensor manager's rules (``ManagerLoop``) decide on the big model, with a bound."""
    _, model = big
    problem = manager_problem(("t1", "t2"), [model, model], BUDGET, efforts=EFFORTS)
    live = Liveness(epoch_window=50, resend_period=1.0, stall=StallLimits(2.0, 10.0))
    params = {"time_budget": 30.0, "max_depth": 1, "gather_timeout": 0.125, "deadline_slack": 0.02}
    loop = ManagerLoop(problem, params, live, now=100.0, search="exhaustive")
    loop.start(100.0)
    rng = np.random.default_rng(3)
    beliefs = [rng.dirichlet(np.ones(S)), rng.dirichlet(np.ones(S))]
    for k, b in enumerate(beliefs):
        loop.belief(k, BeliefSample(0, b), 100.0)
    job = loop.take(100.0 + JOIN_DELAY)
    searched = loop.search(job)
    assert not searched.error and searched.decision is not None, searched.error
    out = loop.decided(job, searched, 100.0 + JOIN_DELAY)
    decision = searched.decision
    assert decision.bound_guaranteed and decision.depth == 1 and decision.lam > 0.0
    want, argmax, rows = dual_bound_at(model, beliefs, decision.lam)
    assert decision.dual_bound == pytest.approx(want, rel=1e-9, abs=1e-9)
    assert decision.actions in argmax
    for t, row in zip(decision.targets, rows, strict=True):
        np.testing.assert_allclose(t.q_values, row, rtol=1e-9, atol=1e-9)
    assert [a.priority - 1 for _, a in out.actions] == list(decision.actions)
    assert sum(Fraction(EFFORTS[a.priority - 1]) for _, a in out.actions) <= BUDGET


# ----------------------------------------------------------------- every planner unfused
def run_cli(*argv: str) -> str:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(list(argv))
    assert code == 0, err.getvalue()
    return out.getvalue()


def test_simulate_targets_unfused_equals_fused(monkeypatch):
    argv = ("simulate", "--targets", "perimeter_s3,perimeter_s3", "--budget", "2", "--option", "search=exhaustive",
            "--option", "depth=2", "--steps", "8", "--seed", "4", "--json")
    fused = json.loads(run_cli(*argv))
    monkeypatch.setattr(search_module, "FUSED_TABLE_MAX_BYTES", 0)
    assert not uses_fused_table(3, 3, 3)
    unfused = json.loads(run_cli(*argv))
    model = load_model_file("perimeter_s3")
    joint = ExactJointPlanner(make_problem([model, model], budget=2), 2)
    beliefs = [start_belief(model) if start_belief(model) is not None else np.full(3, 1 / 3)] * 2
    for a, b in zip(fused["steps"], unfused["steps"], strict=True):
        assert a["priorities"] == b["priorities"] and a["lambda"] == pytest.approx(b["lambda"], abs=1e-12)
        assert a["dual_bound"] == pytest.approx(b["dual_bound"], abs=1e-10)
        assert a["gap"] == pytest.approx(b["gap"], abs=1e-10)
        assert b["dual_bound"] >= joint.value(beliefs) - 1e-9  # Theorem D at the run's own beliefs
        beliefs = [bayes(model, x, p - 1, z) for x, p, z in zip(beliefs, b["priorities"], b["observations"],
                                                                strict=True)]
