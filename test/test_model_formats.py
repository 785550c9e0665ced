"""Model files for big models: YAML text blocks and sparse form, .POMDP with the uncertainty term, the
grid generator (docs/models.md).

* YAML: text blocks (dense) and the sparse form read the same model as nested lists; every error
  names the field, the action and the line of the block; the sparse form is bounded by its
  non-zeros (a 100 x 100 grid loads without a dense array: traced memory); ``dump_model`` writes
  the forms back and they round-trip exactly.
* ``.POMDP``: the uncertainty term and the grid travel in the ``# pomdp_planner:`` comment; a sparse
  model is written as element lines and read back into sparse storage (no dense detour, traced
  memory); element lines read in bulk give the same model and the same errors as word by word.
* The grid domain: the generator against a direct construction (loops over cells), obstacles and
  the field of view, ``metadata["grid"]`` and the cell of each state.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import yaml

from pomdp_planner.core.domains.grid import GridLayout, grid_cells, grid_model
from pomdp_planner.core.io.cassandra import export_pomdp, parse_pomdp
from pomdp_planner.core.io.model_yaml import dump_model, model_from_dict, model_to_dict, parse_model_yaml
from pomdp_planner.core.model import POMDP, ModelError


def small_model(seed: int = 0, S: int = 5, A: int = 2, Z: int = 4) -> POMDP:
    rng = np.random.default_rng(seed)
    P = rng.dirichlet(np.ones(S), size=(A, S))
    P[P < 0.15] = 0.0
    P /= P.sum(axis=-1, keepdims=True)
    O = rng.dirichlet(np.ones(Z), size=(A, S))
    return POMDP(P, O, rng.normal(size=(S, A)), 0.9, "renyi2", [0.3, 0.2], name="small")


def same(a: POMDP, b: POMDP, reward_rtol: float = 0.0) -> None:
    assert (a.S, a.A, a.Z, a.name, a.uncertainty.name, a.epsilon) == (b.S, b.A, b.Z, b.name, b.uncertainty.name,
                                                                       b.epsilon)
    for x, y in ((a.P_csr, b.P_csr), (a.O_csr, b.O_csr)):
        for k in range(a.A):
            np.testing.assert_array_equal(x[k].toarray(), y[k].toarray())
    np.testing.assert_allclose(a.r, b.r, rtol=reward_rtol, atol=0)
    np.testing.assert_array_equal(a.w, b.w)


def load_text(text: str) -> POMDP:
    return model_from_dict(parse_model_yaml(text, "m.yaml"), "m.yaml")


# ------------------------------------------------------------------ YAML forms
def test_text_blocks_and_sparse_form_read_the_nested_list_model():
    m = small_model()
    doc = model_to_dict(m)
    blocks = {**doc, "transition": [" ".join(repr(float(x)) for x in row) + "\n" for row in m.P[0:1].reshape(-1, 5)]}
    blocks["transition"] = ["".join(" ".join(repr(float(x)) for x in row) + "\n" for row in m.P[a]) for a in range(2)]
    blocks["reward"] = "".join(" ".join(repr(float(x)) for x in row) + "\n" for row in m.r)
    same(model_from_dict(blocks), m)
    triples = [[[int(i), int(j), float(m.P[a, i, j])] for i, j in zip(*np.nonzero(m.P[a]), strict=True)]
               for a in range(2)]
    same(model_from_dict({**doc, "transition": {"sparse": triples}}), m)
    text_triples = ["".join(f"{i} {j} {p!r}\n" for i, j, p in t) for t in triples]
    same(model_from_dict({**doc, "transition": {"sparse": text_triples}}), m)
    zero = {**doc, "transition": {"sparse": [t + "0 0 0.0\n" if "0 0 " not in t else t for t in text_triples]}}
    same(model_from_dict(zero), m)  # an explicit zero is no entry


@pytest.mark.parametrize("model", [small_model(1), grid_model(6, 7, 3, obstacles=[[2, 3]]),
                                   grid_model(40, 40)], ids=["small", "grid_6x7", "grid_40x40"])
def test_dump_model_round_trips_exactly(model):
    text = dump_model(model)
    back = load_text(text)
    same(back, model)
    assert back.storage == model.storage and back.metadata.get("grid") == model.metadata.get("grid")
    if model.sparse:
        assert "transition:\n  sparse:\n  - |" in text
    doc = yaml.safe_load(text)
    assert isinstance(doc["transition"], dict if model.sparse else list)


@pytest.mark.parametrize("patch, pattern", [
    ({"transition": ["0.5 0.5\n0.5 x\n", "1 0\n0 1\n"]},
     r"transition\[0\], line 2 of the block: 'x' is not part of a number"),
    ({"transition": ["0.5 0.5\n0.5\n", "1 0\n0 1\n"]},
     r"transition\[0\], line 2 of the block: 1 numbers, expected 2 \(one per column\)"),
    ({"transition": ["0.5 0.5\n0.5 0.5e\n", "1 0\n0 1\n"]},
     r"transition\[0\], line 2 of the block: '0.5e' is not a number"),
    ({"transition": {"sparse": ["0 0 1\n1 1 1\n", "0 1 1\n1 0 1\n0 1 0.5\n"]}},
     r"transition.sparse\[1\], line 3 of the block: cell \(0, 1\) given twice"),
    ({"transition": {"sparse": ["0 0 1\n1 2 1\n", "0 1 1\n1 0 1\n"]}},
     r"transition.sparse\[0\], line 2 of the block: column 2 is out of range 0..1"),
    ({"transition": {"sparse": ["0 0 1\n1.5 1 1\n", "0 1 1\n1 0 1\n"]}},
     r"transition.sparse\[0\], line 2 of the block: an index must be a non-negative integer, got 1.5"),
    ({"transition": {"sparse": ["0 0 1 1\n", "0 1 1\n1 0 1\n"]}},
     r"transition.sparse\[0\], line 1 of the block: 4 numbers, expected 3 \(row column value\)"),
    ({"transition": {"sparse": [[[0, 0, 1], [1, -1, 1]], "0 1 1\n1 0 1\n"]}},
     r"transition.sparse\[0\]\[1\]: column must be a non-negative integer, got -1"),
    ({"transition": {"sparse": ["0 0 1\n1 1 1\n"]}}, r"transition.sparse: 1 entry blocks for 2 actions"),
    ({"transition": {"dense": []}}, r"transition: a mapping must be \{sparse: \[...\]\}"),
    ({"transition": {"sparse": ["0 0 1\n1 1 0.5\n", "0 1 1\n1 0 1\n"]}},
     r"transition\[0\]\[1\]: row \(previous state 1, action 0\) sums to 0.5"),
])
def test_text_and_sparse_form_errors_name_field_action_and_line(patch, pattern):
    doc = {"name": "m", "discount": 0.9, "states": 2, "actions": 2, "observations": 2,
           "transition": [[[1, 0], [0, 1]], [[0, 1], [1, 0]]], "observation": [[[1, 0], [0, 1]]] * 2,
           "reward": [[0, 0], [0, 0]], **patch}
    with pytest.raises(ModelError, match=r"^m.yaml: " + pattern):
        model_from_dict(doc, "m.yaml")


def test_sparse_form_needs_the_sizes_declared():
    doc = {"name": "m", "discount": 0.9, "actions": 1, "transition": {"sparse": ["0 0 1\n"]},
           "observation": [[[1.0]]], "reward": [[0.0]]}
    with pytest.raises(ModelError, match=r"transition.sparse: the sparse form needs 'states:' declared"):
        model_from_dict(doc)


def test_a_big_sparse_yaml_loads_without_a_dense_array():
    """A 100 x 100 grid in the sparse form: its dense P alone would be 2.4 GB; loading stays far below."""
    text = dump_model(grid_model(100, 100))
    tracemalloc.start()
    try:
        m = load_text(text)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert m.sparse and m.S == 10_000 and peak < 2**28


# ------------------------------------------------------------------ .POMDP
def test_pomdp_carries_the_uncertainty_term_and_the_grid():
    m = grid_model(5, 4, 3, obstacles=[[1, 1]], uncertainty="shannon", w=[0.5, 0.4, 0.3], epsilon=1e-4,
                   storage="sparse")
    text = export_pomdp(m)
    assert '"uncertainty": {"function": "shannon", "weights": [0.5, 0.4, 0.3], "epsilon": 0.0001}' in text
    assert '"grid": {"rows": 5, "cols": 4, "obstacles": [[1, 1]]}' in text
    assert "\nT: 0 : 0 : 0 " in text and "\nT: 0\n" not in text  # element lines for a sparse model
    back = parse_pomdp(text)
    same(back, m, reward_rtol=1e-12)  # r(s, a) times the mass of its rows (as pomdp-solve computes it)
    assert back.metadata["grid"] == m.metadata["grid"]
    assert parse_pomdp(text, epsilon=2e-4).epsilon == 2e-4  # the argument wins
    bad = text.replace('"function": "shannon"', '"function": "entropy"')
    with pytest.raises(ModelError, match=r"uncertainty.function \(# pomdp_planner: comment\): unknown function "
                       r"'entropy'"):
        parse_pomdp(bad)
    typo = text.replace('"weights"', '"weight"')
    with pytest.raises(ModelError, match=r"uncertainty \(# pomdp_planner: comment\): unknown field\(s\) \['weight'\]"):
        parse_pomdp(typo)


def test_a_big_pomdp_file_loads_into_sparse_storage_without_a_dense_detour():
    text = export_pomdp(grid_model(100, 100))
    tracemalloc.start()
    try:
        m = parse_pomdp(text)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert m.sparse and m.S == 10_000 and m.uncertainty.name == "renyi2" and peak < 2**28


def test_element_lines_in_bulk_read_as_word_by_word():
    """The same entries, written so that the bulk path reads them (one per line) and so that the
    word-by-word path does (two per line), give the same model; overwrites keep the last value."""
    head = "discount: 0.9\nvalues: reward\nstates: 3\nactions: 2\nobservations: 2\n"
    entries = ["T: 0 : 0 : 0 0.5", "T: 0 : 0 : 1 0.5", "T: 0 : 1 : 1 1.0", "T: 0 : 2 : 2 1.0", "T: 1 : * : 0 1.0",
               "O: * : * : 0 0.25", "O: * : * : 1 0.75", "T: 0 : 0 : 0 0.25", "T: 0 : 0 : 2 0.25", "R: * : * : * : * 1"]
    bulk = parse_pomdp(head + "\n".join(entries) + "\n")
    words = parse_pomdp(head + "\n".join(" ".join(entries[k:k + 2]) for k in range(0, len(entries), 2)) + "\n")
    same(bulk, words)
    np.testing.assert_array_equal(bulk.P[0, 0], [0.25, 0.5, 0.25])
    for line, pattern in (("T: 0 : 3 : 0 1.0", r"line 6: state index 3 out of range 0..2"),
                          ("O: 0 : 0 : 2 1.0", r"line 6: observation index 2 out of range 0..1"),
                          ("T: 0 : 0 : 0 1.5", r"line 6: T: entry: probability 1.5 is outside \[0, 1\]"),
                          ("T: 2 : 0 : 0 1.0", r"line 6: action index 2 out of range 0..1")):
        for text in (head + line + "\n", head + line + " " + line + "\n"):
            with pytest.raises(ModelError, match=pattern):
                parse_pomdp(text)


# ------------------------------------------------------------------ the grid domain
def direct_grid(rows: int, cols: int, A: int, move: float, detection, accuracy: float, obstacles=(),
                sensor=None, fov=None) -> tuple[np.ndarray, np.ndarray]:
    """The grid model's P and O written with loops over the cells (docs/models.md)."""
    free = [(r, c) for r in range(rows) for c in range(cols) if [r, c] not in [list(o) for o in obstacles]]
    index = {cell: s for s, cell in enumerate(free)}
    S = len(free)
    P = np.zeros((A, S, S))
    O = np.zeros((A, S, S + 1))
    for s, (r, c) in enumerate(free):
        nbrs = [index.get((r + dr, c + dc)) for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))]
        P[:, s, s] += 1 - move
        for n in nbrs:
            P[:, s, s if n is None else n] += move / 4
        real = [n for n in nbrs if n is not None]
        for a in range(A):
            seen = fov is None or max(abs(r - sensor[0]), abs(c - sensor[1])) <= fov[a]
            p = detection[a] if seen else 0.0
            O[a, s, S] = 1 - p
            O[a, s, s] += p * (accuracy if real else 1.0)
            for n in real:
                O[a, s, n] += p * (1 - accuracy) / len(real)
    return P, O


@pytest.mark.parametrize("kw", [dict(rows=4, cols=5, A=3), dict(rows=6, cols=3, A=2, obstacles=[[1, 1], [2, 1]]),
                                dict(rows=5, cols=5, A=3, sensor=[0, 4], fov=[4, 2, 1], move=0.5, accuracy=0.6,
                                     detection=[0.95, 0.7, 0.2])])
def test_grid_generator_against_loops(kw):
    full = dict(move=0.2, detection=None, accuracy=0.8) | kw
    m = grid_model(**full, storage="dense")
    det = np.linspace(0.9, 0.3, full["A"]) if full["detection"] is None else full["detection"]
    P, O = direct_grid(full["rows"], full["cols"], full["A"], full["move"], det, full["accuracy"],
                       full.get("obstacles", ()), full.get("sensor"), full.get("fov"))
    np.testing.assert_allclose(m.P, P, atol=1e-15)
    np.testing.assert_allclose(m.O, O, atol=1e-15)
    assert m.metadata["grid"] == {"rows": full["rows"], "cols": full["cols"], "obstacles": full.get("obstacles", [])}
    cells = grid_cells(m.metadata)
    layout = GridLayout(full["rows"], full["cols"], full.get("obstacles", []))
    assert all(layout.index[r, c] == s for s, (r, c) in enumerate(cells))
    assert m.P_csr.row_nnz().max() <= 5 and m.O_csr.row_nnz().max() <= 6


def test_grid_generator_in_yaml_and_its_errors():
    doc = {"name": "g", "discount": 0.95, "generator": {"domain": "grid", "rows": 3, "cols": 4, "A": 2},
           "reward_generator": {"kind": "effort", "cost": [0.2, 0.0]},
           "uncertainty": {"function": "renyi2", "weights": [1, 1]}, "start": "uniform"}
    m = model_from_dict(doc)
    np.testing.assert_array_equal(m.r, np.tile([-0.2, 0.0], (12, 1)))
    assert (m.S, m.A, m.Z) == (12, 2, 13) and m.metadata["grid"] == {"rows": 3, "cols": 4, "obstacles": []}
    for patch, pattern in (({"generator": {**doc["generator"], "obstacles": [[3, 0]]}},
                            r"generator.obstacles\[0\]: cell \[3, 0\] is outside the 3 x 4 grid"),
                           ({"generator": {**doc["generator"], "fov": [1, 1]}}, r"generator.sensor: missing"),
                           ({"generator": {**doc["generator"], "colums": 4}},
                            r"generator: unknown field\(s\) \['colums'\]"),
                           ({"generator": {**doc["generator"], "detection": [0.9, 1.2]}},
                            r"generator.detection\[1\]: must be a probability in \[0, 1\], got 1.2"),
                           ({"states": 13}, r"states: declares 13 but the grid generator gives 12"),
                           ({"generator": {**doc["generator"], "rows": 2000, "cols": 2000}},
                            r"generator: a 2000 x 2000 grid has 4,000,000 cells, more than 1,000,000"),
                           ({"reward_generator": {"kind": "effort", "cost": [0.1]}},
                            r"reward_generator.cost: expected 2 costs \(one per action\)")):
        with pytest.raises(ModelError, match=pattern):
            model_from_dict({**doc, **patch})
