"""The perimeter-defence generator against independent computations (quadrature, brute-force minors)."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from pomdp_planner.core.domains.perimeter import (
    PRESETS,
    band_probabilities,
    inertia_limit,
    perimeter_model,
    preset_model,
)
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import ModelError
from pomdp_planner.core.structure import check_assumptions

ROOT = Path(__file__).resolve().parents[1]
PHYSICS = dict(effort_cost=[0.8, 0.3, 0.0], damage=5.0, damage_from=0.3, interception=[0.8, 0.4, 0.0],
               track_weight=0.05)


def gaussian_band(lo: float, hi: float, mean: float, sd: float) -> float:
    """P(lo < X <= hi) for X ~ N(mean, sd^2), by quadrature of the density (infinite ends allowed)."""
    def pdf(t: float) -> float:
        return math.exp(-0.5 * ((t - mean) / sd) ** 2) / (sd * math.sqrt(2.0 * math.pi))
    total = 0.0
    a = max(lo, mean - 12 * sd)
    b = min(hi, mean + 12 * sd)
    if a < b:
        total = quad(pdf, a, b, epsabs=1e-14, epsrel=1e-12, limit=200)[0]
    return total


def quadrature_bands(n: int, mean: float, sd: float) -> np.ndarray:
    edges = [-math.inf] + [k / n for k in range(1, n)] + [math.inf]
    return np.array([gaussian_band(edges[k], edges[k + 1], mean, sd) for k in range(n)])


def all_minors_nonnegative(M: np.ndarray, rtol: float = 1e-9) -> bool:
    """Every 2x2 minor of M, by loops (relative tolerance as the package's checker uses)."""
    n, m = M.shape
    for i, j in itertools.combinations(range(n), 2):
        for k, l in itertools.combinations(range(m), 2):
            p1, p2 = M[i, k] * M[j, l], M[i, l] * M[j, k]
            if p1 - p2 < -rtol * (abs(p1) + abs(p2)):
                return False
    return True


def mlr_geq(p: np.ndarray, q: np.ndarray, rtol: float = 1e-9) -> bool:
    """p >=_r q: p_i q_j <= q_i p_j for all i < j (Definition 1), by loops."""
    for i, j in itertools.combinations(range(len(p)), 2):
        lhs, rhs = p[i] * q[j], q[i] * p[j]
        if lhs - rhs > rtol * (abs(lhs) + abs(rhs)) + 1e-300:
            return False
    return True


# ------------------------------------------------------------------ matrices
@pytest.mark.parametrize("n,mean,sd", [(3, 0.5, 0.15), (8, 0.05, 0.1), (8, 0.97, 0.3), (5, 1.4, 0.2), (4, -0.3, 0.5)])
def test_band_probabilities_match_quadrature(n, mean, sd):
    np.testing.assert_allclose(band_probabilities(n, mean, sd)[0], quadrature_bands(n, mean, sd), atol=1e-10)


def test_transitions_are_the_ar1_kernel_integrated_over_bands():
    S, lam, sd, c = 5, 0.3, 0.15, [0.1, 0.4, 0.7]
    m = perimeter_model(S, inertia=lam, process_sd=sd, set_points=c, sensor_sd=0.2, **PHYSICS)
    for a in range(3):
        for s in range(S):
            x = (s + 0.5) / S
            np.testing.assert_allclose(m.P[a, s], quadrature_bands(S, lam * x + (1 - lam) * c[a], sd), atol=1e-10)
    for a in range(3):
        for s in range(S):
            np.testing.assert_allclose(m.O[a, s], quadrature_bands(S, (s + 0.5) / S, 0.2), atol=1e-10)


def test_observation_count_can_differ_from_states():
    m = perimeter_model(8, Z=4, inertia=0.2, process_sd=0.15, sensor_sd=0.1, **PHYSICS)
    assert m.O.shape == (3, 8, 4)
    np.testing.assert_allclose(m.O.sum(axis=-1), 1.0, atol=1e-12)


def test_reward_formula_by_hand():
    m = perimeter_model(3, inertia=0.3, process_sd=0.15, sensor_sd=0.15, **PHYSICS)
    # band centres 1/6, 1/2, 5/6; damage 5 * (x - 0.3) / 0.7 beyond x = 0.3
    dmg = [0.0, 5 * (0.5 - 0.3) / 0.7, 5 * (5 / 6 - 0.3) / 0.7]
    for s in range(3):
        for a, (cost, share) in enumerate(zip([0.8, 0.3, 0.0], [0.8, 0.4, 0.0], strict=True)):
            assert m.r[s, a] == pytest.approx(-cost - dmg[s] * (1 - share), abs=1e-12)
    np.testing.assert_array_equal(m.w, [0.05] * 3)
    assert m.uncertainty.name == "renyi2"


def test_generation_is_deterministic():
    a, b = preset_model("perimeter_s8"), preset_model("perimeter_s8")
    for x, y in ((a.P, b.P), (a.O, b.O), (a.r, b.r), (a.w, b.w)):
        np.testing.assert_array_equal(x, y)


@settings(max_examples=25)
@given(S=st.integers(2, 9), lam=st.floats(0.0, 0.95), sd=st.floats(0.05, 0.5), zsd=st.floats(0.05, 0.5),
       c0=st.floats(0.0, 0.5), dc=st.floats(0.0, 0.3))
def test_tp2_and_dominance_hold_for_any_parameters(S, lam, sd, zsd, c0, dc):
    """(A1) and (A3) hold for every inertia and spread (only (A2) constrains the family)."""
    m = perimeter_model(S, inertia=lam, process_sd=sd, sensor_sd=zsd, set_points=[c0, c0 + dc, c0 + 2 * dc],
                        **PHYSICS)
    np.testing.assert_allclose(m.P.sum(axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(m.O.sum(axis=-1), 1.0, atol=1e-12)
    for a in range(3):
        assert all_minors_nonnegative(m.P[a]) and all_minors_nonnegative(m.O[a])
    # (A3) by brute force: from every state, the predicted observation CDF falls with the priority number
    cdf = np.cumsum(m.P @ m.O, axis=-1)  # (A, S, Z)
    assert np.all(cdf[:-1] >= cdf[1:] - 1e-12)


@settings(max_examples=15)
@given(S=st.integers(2, 10), sd=st.floats(0.08, 0.3), frac=st.floats(0.0, 1.0), seed=st.integers(0, 10**6))
def test_inertia_limit_is_sufficient_for_a2(S, sd, frac, seed):
    """Below 2 sigma / (x_max - x_min) every predicted belief moves up in the MLR order with the
    priority number (checked by brute force on random and two-point beliefs), and the package's
    exact (A2) checker agrees."""
    lam = min(0.99, frac * inertia_limit(S, sd))
    m = perimeter_model(S, inertia=lam, process_sd=sd, sensor_sd=0.15, **PHYSICS)
    rng = np.random.default_rng(seed)
    B = np.vstack([rng.dirichlet(np.ones(S) * 0.3, size=20), np.eye(S)])
    two = np.zeros((5, S))
    two[:, 0], two[:, -1] = np.linspace(0.1, 0.9, 5), 1 - np.linspace(0.1, 0.9, 5)
    for b in np.vstack([B, two]):
        pred = b @ m.P
        assert mlr_geq(pred[1], pred[0]) and mlr_geq(pred[2], pred[1])
    assert check_assumptions(m, search=False).holds


@pytest.mark.parametrize("S", [3, 8])
def test_persistent_intruder_violates_a2_with_a_two_point_belief(S):
    """Inertia well above the limit: a belief on the two extreme bands gives predicted beliefs
    that are not MLR ordered, and the checker refutes (A2)."""
    m = perimeter_model(S, inertia=0.9, process_sd=0.1, sensor_sd=0.15, **PHYSICS)
    assert 0.9 > inertia_limit(S, 0.1)
    b = np.zeros(S)
    b[0] = b[-1] = 0.5
    pred = b @ m.P
    assert not mlr_geq(pred[1], pred[0])
    rep = check_assumptions(m)
    assert rep.status["A2"] == "fails" and rep.status["A1"] == "holds" and rep.status["A3"] == "holds"


def test_inertia_limit_value():
    assert inertia_limit(8, 0.15) == pytest.approx(2 * 0.15 / (7 / 8))
    assert inertia_limit(3, 0.15) == pytest.approx(2 * 0.15 / (2 / 3))


# ------------------------------------------------------------------ shipped files and errors
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_shipped_file_is_the_preset(name):
    m, p = load_model(ROOT / "config" / "models" / f"{name}.yaml"), preset_model(name)
    assert (m.S, m.A, m.Z, m.gamma, m.name) == (p.S, p.A, p.Z, p.gamma, name)
    for x, y in ((m.P, p.P), (m.O, p.O), (m.r, p.r), (m.w, p.w)):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-15)
    assert check_assumptions(m).holds


@pytest.mark.parametrize("change,field", [
    (dict(inertia=1.0), "generator.inertia"),
    (dict(inertia=-0.1), "generator.inertia"),
    (dict(set_points=[0.7, 0.4, 0.1]), "generator.set_points"),
    (dict(set_points=[0.1, 0.4]), "generator.set_points"),
    (dict(process_sd=0.0), "generator.process_sd"),
    (dict(sensor_sd=[0.1, -0.1, 0.1]), "generator.sensor_sd"),
    (dict(interception=[1.2, 0.4, 0.0]), "generator.interception"),
    (dict(effort_cost=[0.1, "x", 0.0]), "generator.effort_cost"),
    (dict(damage_from=1.0), "generator.damage_from"),
    (dict(Z=1), "generator.Z"),
])
def test_bad_parameters_name_the_field(change, field):
    p = dict(PRESETS["perimeter_s3"])
    p.update(change)
    with pytest.raises(ModelError, match=field.replace(".", r"\.")):
        perimeter_model(**p)


def test_unknown_preset():
    with pytest.raises(ModelError, match="unknown perimeter preset"):
        preset_model("perimeter_s99")
