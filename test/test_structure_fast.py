"""The fast (A2) path of ``check_copositivity`` against the previous path and against brute force.

* ``reduce=True`` (the separable ratio bound, then dominance over the observations of one
  ``(j, a)``) decides every ``D^{j,a,z}`` as ``reduce=False`` does (proven / refuted / unknown
  per matrix, the same ``min_entry`` and counterexamples), on random TP2 models (hypothesis),
  on every shipped and test model and on perimeter models where dominance does the work.
* Both against an independent exact minimum of ``x^T D x`` over the simplex (every face, its
  KKT system solved directly) on small models.
* The separable bound never exceeds the exact ratio ``min F1 / F2`` (written out with loops).
"""

from __future__ import annotations

import glob
import json
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from pomdp_planner.core import structure
from pomdp_planner.core.domains.perimeter import PRESETS, perimeter_model
from pomdp_planner.core.domains.tracking import tracking_transitions
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.structure import (
    PROVEN_DOMINATED,
    REFUTED,
    UNKNOWN,
    check_assumptions,
    check_copositivity,
    copositivity_matrices,
    is_proven,
    separable_ratio_bound,
)

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted(glob.glob(str(ROOT / "config/models/*.yaml")) + glob.glob(str(ROOT / "test/models/*.yaml")))


def verdict_classes(codes: np.ndarray) -> np.ndarray:
    """0 proven, 1 refuted, 2 unknown: what a verdict says, whichever test gave it."""
    return np.where(is_proven(codes), 0, np.where(codes == REFUTED, 1, 2))


def tp2_model(seed: int, S: int, A: int, Z: int, shared_sensor: bool, zeros: bool = False) -> POMDP:
    """Tracking transitions (random increasing x, y: TP2 rows, actions moving the state up) and
    TP2 observation kernels exp(u_j v_z), one for all actions or one per action; ``zeros`` cuts
    small transition entries (zeros make the separable bound weak)."""
    rng = np.random.default_rng(seed)
    P = tracking_transitions(S, A, np.sort(rng.uniform(0, 3, S)), np.sort(rng.uniform(-9, 2, S * A)))
    if zeros:
        P = np.where(P < 0.05, 0.0, P)
        P /= P.sum(axis=-1, keepdims=True)
    kernels = 1 if shared_sensor else A
    u = np.sort(rng.uniform(-2, 2, S))
    O = np.stack([np.exp(np.outer(u, np.sort(rng.uniform(-2, 2, Z)))) for _ in range(kernels)])
    O = np.broadcast_to(O / O.sum(axis=-1, keepdims=True), (A, S, Z)).copy()
    return POMDP(P=P, O=O, r=np.zeros((S, A)), gamma=0.9, name=f"tp2_{seed}")


def assert_same_verdicts(model: POMDP) -> tuple:
    new, old = check_copositivity(model), check_copositivity(model, reduce=False)
    np.testing.assert_array_equal(verdict_classes(new.codes), verdict_classes(old.codes))
    same_test = new.codes != PROVEN_DOMINATED  # where no dominance was used, the very same test decided
    np.testing.assert_array_equal(new.codes[same_test], old.codes[same_test])
    np.testing.assert_array_equal(new.min_entry, old.min_entry)  # the same D's built (NaN: never built)
    assert new.refutations.keys() == old.refutations.keys()
    for key, (x, value) in new.refutations.items():
        np.testing.assert_allclose(x, old.refutations[key][0], atol=1e-15)
        assert value == pytest.approx(old.refutations[key][1], rel=1e-12, abs=1e-300)
    return new, old


# ------------------------------------------------------------------ fast == previous path
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 7), st.integers(2, 4), st.integers(2, 5), st.booleans(), st.booleans())
def test_fast_path_gives_the_verdicts_of_the_previous_path(seed, S, A, Z, shared, zeros):
    assert_same_verdicts(tp2_model(seed, S, A, Z, shared, zeros))


@pytest.mark.parametrize("path", FILES)
def test_every_shipped_and_test_model_keeps_its_verdicts(path):
    model = load_model(path)
    new, old = assert_same_verdicts(model)
    np.testing.assert_array_equal(new.codes, old.codes)  # no dominance needed on these: the same tests
    fast, slow = check_assumptions(model), check_assumptions(model, reduce=False)
    assert fast.status == slow.status and fast.holds == slow.holds
    assert fast.tp2 == slow.tp2


@pytest.mark.parametrize("S", [12, 16])
def test_dominance_decides_shared_sensor_models_from_one_matrix_per_pair(S):
    """One sensor for all priorities: beta = alpha for every z, so each D^{j,a,z} is a positive
    multiple of one matrix; only that one goes through the exact test."""
    model = perimeter_model(**(PRESETS["perimeter_s8"] | {"S": S}))
    new, old = assert_same_verdicts(model)
    counts = new.counts()
    assert new.holds and old.holds
    assert counts["proven_dominated"] > 0
    assert counts["proven_exact"] + counts["proven_elementwise"] + counts["proven_sdp"] + \
        counts["proven_dominated"] == new.codes.size
    dominated_pairs = {(a, j) for a, j, _ in np.argwhere(new.codes == PROVEN_DOMINATED)}
    for a, j in dominated_pairs:  # each such pair has exactly one D decided by a test of its own
        assert np.count_nonzero(new.codes[a, j] != PROVEN_DOMINATED) >= 1
    text = check_assumptions(model).summary()
    assert f"{counts['proven_dominated']} as dominated by a proven D of the same (j,a)" in text
    d = json.loads(json.dumps(check_assumptions(model).to_dict()))
    assert d["A2_copositivity"]["counts"]["proven_dominated"] == counts["proven_dominated"]


def test_dominance_does_not_depend_on_the_block_size(monkeypatch):
    model = perimeter_model(**(PRESETS["perimeter_s8"] | {"S": 16}))
    whole = check_copositivity(model)
    monkeypatch.setattr(structure, "_D_BLOCK", 300)  # one matrix per block
    blocked = check_copositivity(model)
    np.testing.assert_array_equal(whole.codes, blocked.codes)
    np.testing.assert_array_equal(whole.min_entry, blocked.min_entry)


def test_a_refuted_worst_observation_proves_nothing_else():
    """Reversed priorities: (A2) fails; a refuted D^w dominates nothing, every other D of its (j, a)
    is classified on its own (and refutations agree with the previous path)."""
    base = load_model(str(ROOT / "config/models/perimeter_s8.yaml"))
    model = POMDP(P=base.P[::-1].copy(), O=base.O, r=base.r, gamma=base.gamma, name="reversed")
    new, _ = assert_same_verdicts(model)
    assert new.refuted and not np.any(new.codes == PROVEN_DOMINATED)


# ------------------------------------------------------------------ against brute force
def simplex_minimum(D: np.ndarray) -> float:
    """Exact min of x^T D x on the simplex: on every face J with a regular KKT system
    [[2 D_JJ, 1], [1^T, 0]] [x; l] = [0; 1] and x > 0, the critical point; the vertices. (A minimiser
    lies in the relative interior of some face; where that face's system is singular the form is
    constant along a direction in it, so a smaller face attains the minimum too.)"""
    S = D.shape[0]
    best = float(np.min(np.diag(D)))
    for k in range(2, S + 1):
        for J in combinations(range(S), k):
            J = list(J)
            K = np.zeros((k + 1, k + 1))
            K[:k, :k] = 2 * D[np.ix_(J, J)]
            K[:k, k] = K[k, :k] = 1.0
            rhs = np.zeros(k + 1)
            rhs[k] = 1.0
            if abs(np.linalg.det(K)) < 1e-14 * max(1.0, np.abs(K).max()) ** (k + 1):
                continue
            x = np.linalg.solve(K, rhs)[:k]
            if np.all(x > 0):
                best = min(best, float(x @ D[np.ix_(J, J)] @ x))
    return best


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 5), st.integers(2, 3), st.integers(2, 4), st.booleans(), st.booleans())
def test_verdicts_match_the_exact_minimum_over_the_simplex(seed, S, A, Z, shared, zeros):
    model = tp2_model(seed, S, A, Z, shared, zeros)
    rep = check_copositivity(model)
    assert not np.any(rep.codes >= UNKNOWN)  # small S: the exact test decides every matrix
    for a in range(A - 1):
        D = copositivity_matrices(model, a)
        for j in range(S - 1):
            for z in range(Z):
                scale = np.abs(D[j, z]).max()
                m = simplex_minimum(D[j, z])
                margin = m + rep.tol * scale
                if abs(margin) <= 1e-9 * scale:  # on the tolerance's edge: either answer is right
                    continue
                assert bool(is_proven(rep.codes[a, j, z])) == (margin > 0), (a, j, z, m, scale)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 6), st.floats(0.0, 0.7))
def test_separable_bound_is_below_the_exact_ratio(seed, S, zero_share):
    rng = np.random.default_rng(seed)
    P = rng.uniform(size=(2, S, S)) * (rng.uniform(size=(2, S, S)) >= zero_share)
    P[:, :, 0] += 1e-3  # rows never all zero
    P /= P.sum(axis=-1, keepdims=True)
    model = POMDP(P=P, O=np.full((2, S, 1), 1.0), r=np.zeros((S, 2)), gamma=0.5)
    bound = separable_ratio_bound(model, 0)
    for j in range(S - 1):
        u, up, v, vp = P[0, :, j], P[0, :, j + 1], P[1, :, j + 1], P[1, :, j]
        ratios = [(u[m] * v[n] + v[m] * u[n]) / (up[m] * vp[n] + vp[m] * up[n])
                  for m in range(S) for n in range(S) if up[m] * vp[n] + vp[m] * up[n] > 0]
        exact = min(ratios) if ratios else np.inf
        assert bound[j] <= exact * (1 + 1e-12) or bound[j] == exact == np.inf


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 5), st.floats(0.1, 0.6))
@example(1127, 3, 0.5)  # products of subnormals computed as 0 hid a negative D: a "proof" of a refuted matrix
def test_subnormal_transitions_give_sound_ratio_bounds_and_no_warning(seed, S, tiny_share):
    """Probabilities as small as the smallest subnormal make ``num / den`` overflow: the bound is
    still below the exact ratio (computed in rationals), the check warns nothing and keeps its
    verdicts, and it proves no ``D`` that ``x = e_m`` refutes in exact arithmetic."""
    import warnings
    from fractions import Fraction

    rng = np.random.default_rng(seed)
    P = rng.uniform(size=(2, S, S))
    P = np.where(rng.uniform(size=P.shape) < tiny_share, 5e-324, P)
    P[:, :, 0] += 1e-3
    P /= P.sum(axis=-1, keepdims=True)
    P = np.where(P < 1e-300, 5e-324, P)  # the division above may flush them; put them back
    O = rng.uniform(size=(2, S, 2))
    model = POMDP(P=P, O=O / O.sum(axis=-1, keepdims=True), r=np.zeros((S, 2)), gamma=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bound = separable_ratio_bound(model, 0)
        new, _ = assert_same_verdicts(model)
    F = [[[Fraction(x) for x in row] for row in Pa] for Pa in P]
    Of = [[[Fraction(x) for x in row] for row in Oa] for Oa in model.O]
    for j in range(S - 1):
        for z in range(2):
            al, be = Of[0][j][z] * Of[1][j + 1][z], Of[0][j + 1][z] * Of[1][j][z]
            diagonal = [al * F[0][m][j] * F[1][m][j + 1] - be * F[0][m][j + 1] * F[1][m][j] for m in range(S)]
            if min(diagonal) < 0:  # x = e_m gives x^T D x = 2 d[m, m] < 0
                assert not structure.is_proven(new.codes[0, j, z]), (j, z, new.codes)
    for j in range(S - 1):
        ratios = [(F[0][m][j] * F[1][n][j + 1] + F[1][m][j + 1] * F[0][n][j])
                  / (F[0][m][j + 1] * F[1][n][j] + F[1][m][j] * F[0][n][j + 1])
                  for m in range(S) for n in range(S) if F[0][m][j + 1] * F[1][n][j] + F[1][m][j] * F[0][n][j + 1] > 0]
        if ratios:
            assert Fraction(bound[j]) <= min(ratios) * Fraction(1 + 1e-12)  # float rounding of the products
        else:
            assert bound[j] == np.inf


@pytest.mark.parametrize("storage", ["dense", "sparse"])
def test_a_negative_minor_whose_products_underflow_fails_tp2(storage):
    """Both products of the minor (rows 0, 1; columns 1, 2) are below the smallest subnormal, so
    both are computed as 0; in exact arithmetic the minor is 1e-331 - 1e-330 < 0, relative
    (1e-331 - 1e-330) / (1e-331 + 1e-330) = -9/11, and (A1) fails."""
    from fractions import Fraction

    r0, r1 = [1 - 1e-170 - 1e-165, 1e-170, 1e-165], [1 - 1e-165 - 1e-161, 1e-165, 1e-161]
    P = np.array([[r0, r1, r1]] * 2)
    O = np.array([[[0.9, 0.1], [0.5, 0.5], [0.1, 0.9]]] * 2)
    model = POMDP(P=P, O=O, r=np.zeros((3, 2)), gamma=0.5, storage=storage)
    assert P[0, 0, 1] * P[0, 1, 2] == 0.0 == P[0, 0, 2] * P[0, 1, 1]
    p1, p2 = Fraction(P[0, 0, 1]) * Fraction(P[0, 1, 2]), Fraction(P[0, 0, 2]) * Fraction(P[0, 1, 1])
    rep = structure.check_tp2(model)
    assert not rep.holds and (rep.rows, rep.cols) == ((0, 1), (1, 2))
    assert rep.worst_relative == pytest.approx(float((p1 - p2) / (p1 + p2)), rel=1e-9)


@pytest.mark.parametrize("storage", ["dense", "sparse"])
def test_no_copositivity_proof_where_products_of_four_probabilities_underflow(storage):
    """A probability of 1e-100 in the frame of ``D^{j,a,z}`` (products of four can be 1e-400): the
    check proves none of those matrices (unknown_underflow), proves the others as before, and
    Assumption 1 is not reported to hold."""
    base = load_model(ROOT / "config" / "models" / "tracking_s8_natural.yaml")
    P = np.array(base.P)
    P[0, 0, 0] += P[0, 0, 3] - 1e-100
    P[0, 0, 3] = 1e-100
    model = POMDP(P=P, O=base.O, r=base.r, gamma=base.gamma, storage=storage)
    frames = structure.underflow_frames(model)
    assert frames.tolist() == [[j in (2, 3) for j in range(7)], [False] * 7]
    rep = check_copositivity(model)
    codes = rep.codes if rep.index is None else None
    if codes is None:  # a compact report: every matrix of the frames is listed
        codes = np.zeros((2, 7, model.Z), dtype=int)
        codes[tuple(rep.index.T)] = rep.codes
    inside = codes[0, 2:4]
    assert not is_proven(inside).any() and set(np.unique(inside)) <= {structure.UNKNOWN_UNDERFLOW, REFUTED}
    assert rep.counts()["unknown_underflow"] == np.count_nonzero(inside == structure.UNKNOWN_UNDERFLOW) > 0
    for (a, j, _z), (_, value) in rep.refutations.items():
        assert not frames[a, j] or value < -(2.0**-900)  # a refutation there stands far beyond the underflow
    assert is_proven(codes[1]).all() and not rep.holds
    clean = check_copositivity(base)
    assert clean.holds and structure.check_assumptions(base).holds
    assert not structure.check_assumptions(model).holds


@pytest.mark.parametrize("shared", [True, False], ids=["one O for all actions", "one O per action"])
def test_dominance_margins_equal_the_cumulative_sums_written_out(shared):
    """(A3)'s margins, whichever way the products are formed: ``sum_{z' <= z} sum_j P[a][i, j] O[a][j, z']``
    for priority a minus the same for a + 1, by explicit loops."""
    rng = np.random.default_rng(7)
    A, S, Z = 4, 5, 3
    O = rng.dirichlet(np.ones(Z), size=S)
    O = np.stack([O] * A) if shared else rng.dirichlet(np.ones(Z), size=(A, S))
    model = POMDP(P=rng.dirichlet(np.ones(S), size=(A, S)), O=O, r=np.zeros((S, A)), gamma=0.9)
    want = np.zeros((A - 1, S, Z - 1))
    for a in range(A - 1):
        for i in range(S):
            for z in range(Z - 1):
                cdf = [sum(model.P[b, i, j] * model.O[b, j, y] for j in range(S) for y in range(z + 1))
                       for b in (a, a + 1)]
                want[a, i, z] = cdf[0] - cdf[1]
    np.testing.assert_allclose(structure.observation_cdf_margins(model), want, rtol=1e-12, atol=1e-14)
