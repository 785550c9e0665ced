"""Sparse models: every sparse path against the dense computation on the same model.

A random model with zeros is built twice, ``storage="dense"`` and ``storage="sparse"``
(core/sparse.py), and every computation that takes a sparse model is compared with its dense
twin (hypothesis): Bayes filter (prediction, observation probabilities, update, batches, the
observation branches), the epoch filter (several sensors, restarts and drops), sampling
(simulate's and the target simulator's: the same outcomes from the same random numbers),
Assumption 1 ((A1) negative minors and worst relative minor, (A2) verdict per matrix, smallest
entries and counterexamples, (A3) worst margin and violations), the bound LP (g, h) and the
myopic bound matrices. Plus the storage rule, the size limit counting what is stored, the dense
view's limit, digests, pickling and ``replace``.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core import belief as bel
from pomdp_planner.core import model as model_module
from pomdp_planner.core.bounds import _structure, solve_bounds
from pomdp_planner.core.domains.tracking import tracking_transitions
from pomdp_planner.core.filter import EpochFilter
from pomdp_planner.core.gate import model_key
from pomdp_planner.core.model import POMDP, ModelError, check_model_size, model_bytes, model_digest
from pomdp_planner.core.myopic import transform_matrix
from pomdp_planner.core.simulate import simulate
from pomdp_planner.core.sparse import SparseStack, choose_storage, csr_bytes, sample_choice, sample_inverse_cdf
from pomdp_planner.core.structure import (
    check_assumptions,
    is_proven,
    quick_tp2_refutation,
    worst_tp2_minor,
)
from pomdp_planner.core.structure_sparse import candidate_counts, worst_minor_support


def stochastic(rng: np.random.Generator, shape: tuple[int, ...], zero_frac: float) -> np.ndarray:
    M = rng.random(shape)
    M[rng.random(shape) < zero_frac] = 0.0
    empty = M.sum(axis=-1) == 0
    M[empty, rng.integers(shape[-1])] = 1.0
    return M / M.sum(axis=-1, keepdims=True)


def pair(seed: int, S: int, A: int, Z: int, zero_frac: float = 0.5, tp2: bool = False,
         uncertainty: str = "renyi2") -> tuple[POMDP, POMDP]:
    """The same random model stored dense and sparse (``tp2``: tracking transitions and one TP2
    observation kernel with small entries cut, so that (A2)'s expensive tests and dominance run)."""
    rng = np.random.default_rng(seed)
    if tp2:
        P = tracking_transitions(S, A, np.sort(rng.uniform(0, 3, S)), np.sort(rng.uniform(-9, 2, S * A)))
        P = np.where(P < 0.05, 0.0, P)
        P /= P.sum(axis=-1, keepdims=True)
        u = np.sort(rng.uniform(-2, 2, S))
        O = np.exp(np.outer(u, np.sort(rng.uniform(-2, 2, Z))))
        O /= O.sum(axis=-1, keepdims=True)
        O = np.where(O < 0.1, 0.0, O)
        O = np.broadcast_to(O / O.sum(axis=-1, keepdims=True), (A, S, Z))
    else:
        P, O = stochastic(rng, (A, S, S), zero_frac), stochastic(rng, (A, S, Z), zero_frac)
    kw = dict(r=rng.normal(size=(S, A)), gamma=0.9, uncertainty=uncertainty, w=rng.uniform(0.05, 0.3, A))
    return POMDP(P, O, storage="dense", **kw), POMDP(P, O, storage="sparse", **kw)


def random_belief(rng: np.random.Generator, S: int, zeros: bool = True) -> np.ndarray:
    b = rng.dirichlet(np.ones(S))
    if zeros and S > 1:
        b[rng.random(S) < 0.3] = 0.0
        if b.sum() == 0:
            b[0] = 1.0
    return b / b.sum()


sizes = st.tuples(st.integers(1, 9), st.integers(1, 4), st.integers(1, 6), st.integers(0, 2**32 - 1))


# ------------------------------------------------------------------ storage and limits
def test_storage_rule_and_forms():
    d, s = pair(0, 6, 2, 3)
    assert d.storage == "dense" and s.storage == "sparse" and s.sparse and not d.sparse
    np.testing.assert_array_equal(d.P, s.P)  # the dense view of the sparse model
    np.testing.assert_array_equal(d.O_csr[1].toarray(), s.O_csr[1].toarray())
    assert s.P_csr[0].has_canonical_format and not s.P_csr[0].data.flags.writeable
    assert s.P_csr.nnz == np.count_nonzero(d.P) and s.O_csr.nnz == np.count_nonzero(d.O)
    assert s.stored_bytes == s.P_csr.nbytes + s.O_csr.nbytes + 8 * s.S * s.A < d.stored_bytes
    # auto: sparse only when a quarter of the dense bytes at most and the dense form over 1 MiB
    assert choose_storage(3, 1600, 1601, 3 * 5 * 1600, 3 * 6 * 1600) == "sparse"
    assert choose_storage(3, 100, 101, 3 * 5 * 100, 3 * 6 * 100) == "dense"  # dense form under 1 MiB
    assert choose_storage(3, 1600, 1600, 3 * 1600 * 400, 3 * 1600 * 400) == "dense"  # a quarter filled
    assert POMDP(d.P_csr, d.O_csr, d.r, 0.9).storage == "dense"  # sparse input, small model: dense
    with pytest.raises(ModelError, match="storage: must be one of auto, dense, sparse"):
        POMDP(d.P, d.O, d.r, 0.9, storage="csr")


def test_sparse_input_is_validated_like_dense():
    d, _ = pair(1, 4, 2, 3)
    cases = ((lambda M: M.__setitem__((1, 2, 0), -0.1), r"transition\[1\]\[2\]\[0\]: probability is negative"),
             (lambda M: M.__setitem__((0, 3, 1), np.nan), r"transition\[0\]\[3\]\[1\]: value is not finite"),
             (lambda M: M.__setitem__((1, 0, 0), M[1, 0, 0] + 0.5), r"transition\[1\]\[0\]: row .* sums to"))
    for bad, pattern in cases:
        P = d.P.copy()
        if P[1, 2, 0] == 0:
            P[1, 2, 0] = 1e-3
        bad(P)
        for form in (P, [sp.csr_array(x) for x in P]):
            with pytest.raises(ModelError, match=pattern):
                POMDP(form, d.O, d.r, 0.9)


def test_size_limit_counts_what_is_stored():
    # a 100 x 100 grid with three priorities (<= 5 and 6 non-zeros per row) fits sparse, far from dense
    S, A = 10_000, 3
    check_model_size(S, A, S + 1, "grid", nnz=A * 11 * S)
    assert model_bytes(S, A, S + 1, nnz=A * 11 * S) < 2**23 < model_module.MAX_MODEL_BYTES < model_bytes(S, A, S + 1)
    with pytest.raises(ModelError, match=r"^f: S=10000, A=3, Z=10001 with 12,000,000 non-zeros need"):
        check_model_size(S, A, S + 1, "f", nnz=12_000_000)
    assert csr_bytes(10, 2, 3) == 12 * 10 + 4 * 2 * 4


def test_dense_view_of_a_large_sparse_model_is_refused_in_one_line(monkeypatch):
    _, s = pair(2, 8, 2, 5)
    monkeypatch.setattr(model_module, "MAX_DENSE_BYTES", 8 * 2 * 8 * 8 - 1)
    with pytest.raises(ModelError) as info:
        s.P  # noqa: B018 - the access is the test
    msg = str(info.value)
    assert msg.startswith("transition: this computation needs the dense A x S x S array of a sparse model (A=2, S=8")
    assert "MAX_DENSE_BYTES" in msg and "\n" not in msg
    bel.predict(s, np.full(8, 1 / 8), 1)  # the sparse paths need no dense form


def test_digest_pickle_and_replace_keep_the_sparse_form():
    d, s = pair(3, 6, 3, 4)
    assert model_digest(d) != model_digest(s) and model_key(d) != model_key(s)
    s.P  # noqa: B018 - builds the dense view; pickling leaves it out
    back = pickle.loads(pickle.dumps(s))
    assert back.sparse and "P" not in back.__dict__ and model_digest(back) == model_digest(s)
    r = s.replace(gamma=0.5)
    assert r.sparse and r.gamma == 0.5 and r.P_csr.nnz == s.P_csr.nnz
    assert SparseStack.from_dense(d.P).nnz == s.P_csr.nnz


# ------------------------------------------------------------------ Bayes filter
@settings(max_examples=60, deadline=None)
@given(sizes)
def test_filter_functions_match_dense(args):
    S, A, Z, seed = args
    d, s = pair(seed, S, A, Z)
    rng = np.random.default_rng(seed + 1)
    b = random_belief(rng, S)
    for a in range(A):
        np.testing.assert_allclose(bel.predict(s, b, a), bel.predict(d, b, a), rtol=0, atol=1e-15)
        eta = bel.observation_probabilities(d, b, a)
        np.testing.assert_allclose(bel.observation_probabilities(s, b, a), eta, rtol=0, atol=1e-15)
        for z in range(Z):
            if eta[z] > bel.ETA_MIN:
                np.testing.assert_allclose(bel.update(s, b, a, z), bel.update(d, b, a, z), rtol=0, atol=1e-15)
            else:
                with pytest.raises(bel.ImpossibleObservation):
                    bel.update(s, b, a, z)
        zs, es, ts = bel.observation_branches(s, b, a)
        zd, ed, td = bel.observation_branches(d, b, a)
        np.testing.assert_array_equal(zs, zd)
        np.testing.assert_array_equal(zs, np.flatnonzero(eta > bel.ETA_MIN))
        np.testing.assert_allclose(es, ed, atol=1e-15)
        np.testing.assert_allclose(ts.toarray(), td.toarray(), atol=1e-15)
        tau, _ = bel.posteriors_all(d, b)
        np.testing.assert_allclose(ts.toarray(), tau[a][zs], atol=1e-15)
    Bt = np.stack([random_belief(rng, S) for _ in range(5)])
    np.testing.assert_allclose(bel.predict_all(s, Bt), bel.predict_all(d, Bt), atol=1e-15)
    acts, obs = rng.integers(0, A, 5), rng.integers(0, Z, 5)
    (p1, e1), (p2, e2) = bel.update_batch(s, Bt, acts, obs), bel.update_batch(d, Bt, acts, obs)
    np.testing.assert_allclose(p1, p2, atol=1e-15)
    np.testing.assert_allclose(e1, e2, atol=1e-15)
    assert bel.posterior_floor(s) == pytest.approx(bel.posterior_floor(d), abs=1e-15)


def test_observation_branches_touch_only_the_support():
    """On a sparse model the posteriors of a point belief hold only the states reachable from it."""
    _, s = pair(4, 40, 2, 41, zero_frac=0.9)
    b = np.zeros(40)
    b[7] = 1.0
    zs, eta, tau = bel.observation_branches(s, b, 1)
    reach = set(s.P_csr.row(1, 7)[0].tolist())
    assert set(tau.indices.tolist()) <= reach and tau.nnz <= len(reach) * zs.size
    assert eta.sum() == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(sizes, st.integers(1, 3))
def test_epoch_filter_matches_dense(args, sensors):
    S, A, Z, seed = args
    d, s = pair(seed, S, A, Z, zero_frac=0.6)
    rng = np.random.default_rng(seed + 2)
    extra = [stochastic(rng, (A, S, Z), 0.6) for _ in range(sensors - 1)]
    fd = EpochFilter(d, [d.O, *extra])
    fs = EpochFilter(s, [s.O_csr, *[SparseStack.from_dense(O) for O in extra]])
    b = random_belief(rng, S)
    for _ in range(6):
        a = int(rng.integers(A))
        readings = {k: int(rng.integers(Z)) for k in range(sensors) if rng.random() < 0.8}
        ud, us = fd.step(b, a, readings), fs.step(b, a, readings)
        np.testing.assert_allclose(us.belief, ud.belief, atol=1e-14)
        assert (us.restarted, us.dropped) == (ud.restarted, ud.dropped)
        b = ud.belief


@settings(max_examples=30, deadline=None)
@given(sizes)
def test_sampling_gives_the_same_outcomes(args):
    S, A, Z, seed = args
    d, s = pair(seed, S, A, Z, zero_frac=0.6)
    for sampler in (sample_inverse_cdf, sample_choice):
        r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
        for k in range(20):
            a, i = k % A, (3 * k) % S
            assert sampler(r1, d.P, a, i) == sampler(r2, s.P_csr, a, i)
            assert sampler(r1, d.O, a, i) == sampler(r2, s.O_csr, a, i)
        assert r1.random() == r2.random()  # the same random numbers drawn
    t1, t2 = simulate(d, "random", 15, seed=seed), simulate(s, "random", 15, seed=seed)
    np.testing.assert_array_equal(t1.states, t2.states)
    np.testing.assert_array_equal(t1.observations, t2.observations)
    np.testing.assert_allclose(t1.beliefs, t2.beliefs, atol=1e-13)


# ------------------------------------------------------------------ Assumption 1
def test_candidate_counts_against_loops():
    rng = np.random.default_rng(5)
    for n, m in ((7, 5), (12, 12), (30, 8)):
        M = np.where(rng.random((n, m)) < 0.35, rng.random((n, m)), 0.0)
        C = sp.csr_array(M)
        rows = np.repeat(np.arange(n), np.diff(C.indptr))
        want = [sum(1 for i in range(j) for l in range(k + 1, m) if M[i, l] > 0)
                for j, k in zip(rows, C.indices, strict=True)]
        np.testing.assert_array_equal(candidate_counts(C), want)


@settings(max_examples=80, deadline=None)
@given(st.integers(2, 9), st.integers(2, 9), st.floats(0.0, 0.8), st.integers(0, 2**32 - 1))
def test_support_minor_decides_tp2_like_the_dense_tests(n, m, zero_frac, seed):
    rng = np.random.default_rng(seed)
    M = np.where(rng.random((n, m)) < zero_frac, 0.0, rng.uniform(0.05, 1.0, (n, m)))
    value, rows, cols, count, rel = worst_minor_support(sp.csr_array(M))
    full, reduced = worst_tp2_minor(M, method="full"), worst_tp2_minor(M, method="sparse")
    assert count == full[3] == reduced[3]
    # the worst minor when TP2 fails; the worst candidate (method "sparse") when it holds
    assert rel == pytest.approx(full[4] if count else reduced[4], abs=1e-12)
    (i, j), (k, l) = rows, cols
    if count:  # the reported minor is one of the worst, recomputed from the matrix
        minor = M[i, k] * M[j, l] - M[i, l] * M[j, k]
        assert i < j and k < l and minor == pytest.approx(value, abs=1e-15) and minor < 0


@settings(max_examples=40, deadline=None)
@given(sizes, st.booleans())
def test_assumption_check_matches_dense(args, tp2):
    S, A, Z, seed = args
    d, s = pair(seed, S, A, Z, tp2=tp2)
    rd, rs = check_assumptions(d), check_assumptions(s)
    assert rs.status == rd.status and rs.holds == rd.holds
    assert rs.tp2.num_negative == rd.tp2.num_negative
    if rd.tp2.holds:  # the worst *candidate* minor, as the dense check reports it for large matrices
        reduced = min(worst_tp2_minor(M[a], method="sparse")[4] for M in (d.P, d.O) for a in range(A))
        assert rs.tp2.worst_relative == pytest.approx(min(reduced, np.inf), abs=1e-12)
    else:
        assert rs.tp2.worst_relative == pytest.approx(rd.tp2.worst_relative, abs=1e-12)
    cs, cd = rs.copositivity, rd.copositivity
    assert cs.total == cd.codes.size and cs.counts() == cd.counts()
    codes = np.zeros(cs.shape, np.int8)
    mins = np.full(cs.shape, np.nan)
    codes[tuple(cs.index.T)], mins[tuple(cs.index.T)] = cs.codes, cs.min_entry
    np.testing.assert_array_equal(is_proven(codes), is_proven(cd.codes))
    np.testing.assert_array_equal(codes, cd.codes)
    np.testing.assert_allclose(mins, cd.min_entry, rtol=1e-12, atol=1e-300, equal_nan=True)
    assert set(cs.refutations) == set(cd.refutations)
    for key, (x, v) in cs.refutations.items():
        xd, vd = cd.refutations[key]
        np.testing.assert_allclose(np.asarray(x), xd, atol=1e-12)
        assert v == pytest.approx(vd, rel=1e-9, abs=1e-300)
    (md, *wd), (ms, *ws) = rd.dominance.worst, rs.dominance.worst
    assert ms == pytest.approx(md, abs=1e-12) and rs.dominance.num_violations == rd.dominance.num_violations
    if abs(md) > 1e-12:
        assert ws == wd
    assert rs.summary().count("\n") == rd.summary().count("\n")


@settings(max_examples=60, deadline=None)
@given(sizes, st.booleans())
def test_quick_refutation_is_sound(args, tp2):
    """A minor named by the one-pass test is negative (so (A1) fails), on both storages."""
    S, A, Z, seed = args
    for m in pair(seed, S, A, Z, tp2=tp2):
        reason = quick_tp2_refutation(m)
        if reason:
            assert check_assumptions(m).tp2.status == "fails"
            label = "transition" if "transition" in reason else "observation"
            a = int(reason.split("priority ")[1].split(" ")[0]) - 1
            i, j, k, l = (int(x) for x in reason.split("(rows ")[1].rstrip(")").replace("columns ", "")
                          .replace(",", " ").split())
            M = (m.P if label == "transition" else m.O)[a]
            assert M[i, k] * M[j, l] - M[i, l] * M[j, k] < 0


# ------------------------------------------------------------------ bound LP
@settings(max_examples=15, deadline=None)
@given(st.integers(2, 8), st.integers(2, 3), st.integers(2, 5), st.integers(0, 2**32 - 1), st.booleans())
def test_bound_lp_matches_dense(S, A, Z, seed, tp2):
    d, s = pair(seed, S, A, Z, tp2=tp2)
    st_d, st_s = _structure(d), _structure(s)
    assert (st_s.monotone, st_s.ordered) == (st_d.monotone, st_d.ordered)
    assert st_s.kappa1 == pytest.approx(st_d.kappa1, rel=1e-12, abs=1e-12)
    for variant in ("feasible", "tight"):
        bd, bs = solve_bounds(d, variant, samples=40), solve_bounds(s, variant, samples=40)
        assert (bs.g_feasible, bs.h_feasible) == (bd.g_feasible, bd.h_feasible)
        if bd.feasible:
            np.testing.assert_allclose(bs.g, bd.g, atol=1e-7)
            np.testing.assert_allclose(bs.h, bd.h, atol=1e-7)
            np.testing.assert_allclose(transform_matrix(s, bs.g), transform_matrix(d, bd.g), atol=1e-9)


def test_least_element_sparse_solve_matches_dense():
    """A banded model (kappa_1 >= 0.5: policy iteration with sparse solves in G)."""
    S = 40
    P = np.zeros((3, S, S))
    for a in range(3):
        for i in range(S):
            for step, p in ((-1, 0.25 - 0.05 * a), (0, 0.5), (1, 0.25 + 0.05 * a)):
                P[a, i, min(max(i + step, 0), S - 1)] += p
    O = np.zeros((3, S, S))
    for i in range(S):
        for step, p in ((-1, 0.15), (0, 0.7), (1, 0.15)):
            O[:, i, min(max(i + step, 0), S - 1)] += p
    r = np.linspace(-1, 1, S)[:, None] - np.array([0.1, 0.05, 0.0])
    kw = dict(gamma=0.95, uncertainty="renyi2", w=[0.05] * 3)
    d, s = POMDP(P, O, r, storage="dense", **kw), POMDP(P, O, r, storage="sparse", **kw)
    assert _structure(s).kappa1 >= 0.5
    bd, bs = solve_bounds(d, "feasible"), solve_bounds(s, "feasible")
    assert bd.feasible and bs.feasible and "least" in bs.message
    np.testing.assert_allclose(bs.g, bd.g, atol=1e-8)
    np.testing.assert_allclose(bs.h, bd.h, atol=1e-8)
