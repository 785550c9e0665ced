"""Cassandra ``.POMDP`` files (the pomdp-solve format, also read by SARSOP and pomdp-py).

Export (:func:`export_pomdp`, :func:`save_pomdp_file`) writes ``discount``, ``values: reward``,
the ``states``/``actions``/``observations`` headers, ``start`` (when the model has one in
``metadata``), ``T:`` and ``O:`` matrices (element lines ``T: a : s : s' p`` for the non-zeros of a
sparse model) and the state reward as ``R: a : s : * : * r(s,a)``. The uncertainty term
``-w_a f(b)`` of the paper's Eq. 3 has no form in the format: it goes into the
``# pomdp_planner: {...}`` comment line, ``"uncertainty": {"function", "weights", "epsilon"}``
(the keys of the YAML ``uncertainty:`` mapping), which this importer reads and other readers ignore
(they see the linear part only; a comment says so). A grid model's ``metadata["grid"]`` goes
there as ``"grid": {"rows", "cols", "obstacles"}``.

Import (:func:`parse_pomdp`, :func:`load_pomdp_file`) reads the format as pomdp-solve
documents it: the header (``discount``, ``values: reward|cost``, ``states``/``actions``/
``observations`` as a count or a list of names), ``start:`` (a probability vector, ``uniform``,
a single state, ``start include: ...``, ``start exclude: ...``), ``T:``/``O:`` entries in
element, row and matrix form (with ``uniform`` and ``identity``), ``R:`` entries in element,
row and matrix form, wildcards ``*``, names or 0-based indices, and ``#`` comments. Later
entries overwrite earlier ones. ``discount: 1`` is accepted (a finite horizon: see
:class:`~pomdp_planner.core.model.POMDP`). A row of ``T:`` or ``O:`` must sum to 1 within
pomdp-solve's tolerance, :data:`PEER_ROW_TOLERANCE`; a row off by more than the model's
``STOCHASTIC_ATOL`` (and within it) is divided by its sum, with one
:class:`~pomdp_planner.core.errors.InputWarning` that names the first such row. The file's
``R(s, a, s', z)`` is reduced to our ``r(s, a)`` by expectation,
``r(s,a) = sum_{s',z} P(s'|s,a) O(z|s',a) R(s,a,s',z)``, as pomdp-solve computes it: with the
rows as written, before renormalising (``R: a : s : * : * v`` gives ``v`` times the mass of its
rows); ``values: cost`` negates it. The uncertainty term comes from the comment line (above;
``function: none`` without it). The ``T:`` and ``O:`` entries are kept as coordinates (later
entries winning) and the model is built from them sparse (:mod:`~pomdp_planner.core.sparse`),
dense only when that is smaller: a large sparse file is never a dense array on the way.
Errors are :class:`~pomdp_planner.core.model.ModelError` with the line number and what is wrong,
after the file name.

Epsilon. The format has no ``epsilon`` (the Shannon bounds' domain, unused without an
uncertainty term but part of every model): it is ``model.default_epsilon(S)`` (``1e-3``, or
``1/(2S)`` when smaller, so a file of any size loads), or the ``"epsilon"`` of a
``# pomdp_planner: {...}`` comment line, or the ``epsilon`` argument of :func:`parse_pomdp` and
:func:`load_pomdp_file`, which wins. Export writes it in that comment when the model's differs
from the default.

Import is bounded, since a model file is untrusted input: the file is read by
:func:`~pomdp_planner.core.io.file_text.read_model_text` (a regular UTF-8 file of at most
``MAX_MODEL_FILE_BYTES``); a token longer than :data:`MAX_TOKEN_CHARS` is refused; the declared
sizes are checked against ``MAX_MODEL_BYTES`` as soon as each header line is read, before any
matrix exists (as the smallest model they allow: one non-zero per row of ``T`` and ``O``); the
entries together may write at most :data:`MAX_ENTRY_CELLS` matrix cells (a short file of
``T: * uniform`` lines cannot keep the parser busy), and the non-zeros they leave must fit in
``MAX_MODEL_BYTES`` (checked as they accumulate, before an entry expands); the file has at most
:data:`MAX_TOKENS` words and :data:`MAX_ELEMENT_LINES` element lines read in bulk; rewards that
depend on the end state or the observation need the ``A x S x S x Z`` array ``R(s, a, s', z)``,
which must fit in ``MAX_MODEL_BYTES`` as well.
A line that is one element entry (``T: a : s : s' p``, ``O: a : s' : z p``) is read as a whole,
several times faster than word by word.

Conventions: ``T: a : start : end p`` is ``P(end | start, a)``, our ``P[a, start, end]``;
``O: a : end : obs p`` is ``P(obs | end, a)``, our ``O[a, end, obs]``. Indices are 0-based in
both. Our action index ``a`` is the tracking priority ``a + 1``.

Names. The format's identifiers start with a letter followed by letters, digits, ``_`` or
``-``; a bare number in a header is a *count* (``states: 5``). Export therefore keeps every
name that is a valid identifier and not a keyword of the format, and renames the others by
this rule (:func:`safe_names`): characters outside ``[A-Za-z0-9_-]`` become ``_``; a name
that then does not start with a letter, or is a keyword, gets the prefix ``s_``/``a_``/``o_``
(states/actions/observations); clashes get ``_2``, ``_3``, ... appended. So ``['5']`` is
written ``states: s_5`` and can never be read as a count. When a name is renamed, the file
records the original names in a comment line ``# pomdp_planner: {...JSON...}`` which this
importer uses to restore them (other readers ignore comments).
"""

from __future__ import annotations

import io
import json
import re
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..belief import start_belief
from ..domains.grid import GridLayout
from ..errors import InputWarning, prefixed
from ..model import (
    MAX_MODEL_BYTES,
    POMDP,
    STOCHASTIC_ATOL,
    ModelError,
    as_number,
    check_model_size,
    check_name,
    default_epsilon,
    format_bytes,
    kind_of,
    short_repr,
)
from ..sparse import SparseStack
from .file_text import read_model_text

#: Longest token (name, number, keyword) accepted in a ``.POMDP`` file.
MAX_TOKEN_CHARS = 256
#: Most matrix cells that the ``T:``, ``O:`` and ``R:`` entries of one file may write in all
#: (a dense model of the largest size allowed has about 1.6e7 cells; later entries may
#: overwrite earlier ones, so there is room for that). Writing a cell costs tens of nanoseconds.
MAX_ENTRY_CELLS = 100_000_000
#: Most words (numbers, names, keywords, ``:``) in a ``.POMDP`` file, element lines read in bulk
#: aside. Reading costs about 2 us of CPU per word, so this bounds the time of any file to seconds;
#: the export of a dense model with S = Z = 200 and A = 5 has about 400 000.
MAX_TOKENS = 4_000_000
#: Most element lines with 0-based indices (``T: 0 : 12 : 13 0.05``) in a file, read in bulk at about
#: 1 us each: a 100 x 100 grid model's export has about 330 000, a 200 x 200 one 1.3 million.
MAX_ELEMENT_LINES = 8_000_000
#: Cells held as coordinates before they are compacted (duplicates resolved, zeros dropped).
COMPACT_CELLS = 4_000_000
#: The ``uncertainty`` keys of the ``# pomdp_planner:`` comment (the YAML ``uncertainty:`` mapping).
META_UNCERTAINTY_FIELDS = {"function", "weights", "epsilon"}
#: A row of ``T:`` or ``O:`` may sum to 1 within this (pomdp-solve's ``EPSILON``); a row off by more
#: than ``STOCHASTIC_ATOL`` (and at most this) is renormalised, with a warning.
PEER_ROW_TOLERANCE = 1e-5
#: Longest ``# pomdp_planner: {...}`` comment line that is read (longer ones are ignored).
MAX_META_CHARS = 1 << 20

#: Words with a meaning in the format; a state/action/observation may not be called so.
KEYWORDS = frozenset({
    "discount", "values", "states", "actions", "observations", "start", "include", "exclude",
    "T", "O", "R", "uniform", "identity", "reward", "cost", "reset",
})
#: Words that begin a new section of the file (end a list of names or numbers).
_SECTIONS = frozenset({"discount", "values", "states", "actions", "observations", "start", "T", "O", "R"})
_IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
_INDEX = re.compile(r"^[0-9]+$")
_NUMBER = re.compile(r"^[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?$")
_META = re.compile(r"^#\s*pomdp_planner:\s*(\{.*\})\s*$")
_PREFIX = {"states": "s_", "actions": "a_", "observations": "o_"}


# ---------------------------------------------------------------------------- names
def is_safe_name(name: str) -> bool:
    """True if ``name`` can be written as-is in a ``.POMDP`` header."""
    return bool(_IDENT.match(name)) and name not in KEYWORDS


def safe_names(names: tuple[str, ...] | list[str], kind: str) -> list[str]:
    """Rename ``names`` (of ``kind`` states/actions/observations) to valid, unique identifiers.

    Valid names are kept; see the module docstring for the rule applied to the others.
    """
    prefix = _PREFIX[kind]
    out: list[str] = []
    used: set[str] = {n for n in names if is_safe_name(n)}
    for n in names:
        if is_safe_name(n):
            out.append(n)
            continue
        base = re.sub(r"[^A-Za-z0-9_\-]", "_", n)
        if not base or not base[0].isalpha() or base in KEYWORDS:
            base = prefix + base
        cand, k = base, 2
        while cand in used:
            cand, k = f"{base}_{k}", k + 1
        used.add(cand)
        out.append(cand)
    return out


# ---------------------------------------------------------------------------- export
def _num(x: float) -> str:
    """Shortest round-trip text of a float, always with a decimal point (``1.0e-05``)."""
    s = repr(float(x))
    if "e" in s and "." not in s.split("e")[0]:
        mant, exp = s.split("e")
        s = f"{mant}.0e{exp}"
    elif "." not in s and "e" not in s:
        s += ".0"
    return s


def export_pomdp(model: POMDP) -> str:
    """The ``.POMDP`` text of ``model``; the uncertainty term in the ``# pomdp_planner:`` comment."""
    S, A, Z = model.S, model.A, model.Z
    lines = [
        f"# Cassandra .POMDP file exported by pomdp_planner from model '{model.name}'",
        "# T: a : start : end = P(end | start, a);  O: a : end : obs = P(obs | end, a);  0-based indices.",
        "# Action index a is the tracking priority a + 1 (action 0 = priority 1 = greatest priority).",
    ]
    if model.uncertainty.name != "none":
        lines.append(f"# The uncertainty term -w_a f(b) (f = {model.uncertainty.name}) is in the pomdp_planner "
                     "comment below; other readers see the linear reward r(s, a) only.")
    headers: dict[str, list[str] | int] = {}
    originals: dict[str, list[str]] = {}
    for kind, names, n in (("states", model.state_names, S), ("actions", model.action_names, A),
                           ("observations", model.observation_names, Z)):
        if names is None:
            headers[kind] = n
            continue
        safe = safe_names(names, kind)
        headers[kind] = safe
        if safe != list(names):
            originals[kind] = list(names)
            renamed = ", ".join(f"{o!r} -> {s}" for o, s in zip(names, safe, strict=True) if o != s)
            lines.append(f"# {kind} renamed to valid .POMDP identifiers: {renamed}")
    meta: dict = {"name": model.name, **originals}
    if model.epsilon != default_epsilon(S):
        meta["epsilon"] = model.epsilon
    if model.uncertainty.name != "none":
        meta["uncertainty"] = {"function": model.uncertainty.name, "weights": model.w.tolist(),
                               "epsilon": model.epsilon}
    if "grid" in model.metadata:
        meta["grid"] = model.metadata["grid"]
    lines.append("# pomdp_planner: " + json.dumps(meta))
    lines += ["", f"discount: {_num(model.gamma)}", "values: reward"]
    for kind in ("states", "actions", "observations"):
        h = headers[kind]
        lines.append(f"{kind}: {h}" if isinstance(h, int) else f"{kind}: {' '.join(h)}")

    def ref(kind: str, i: int) -> str:
        h = headers[kind]
        return str(i) if isinstance(h, int) else h[i]

    b0 = start_belief(model)
    if b0 is not None:
        lines.append("start: " + " ".join(_num(p) for p in b0))
    lines.append("")
    for key, row_kind, col_kind, dense, stack in (("T", "states", "states", "P", "P_csr"),
                                                  ("O", "states", "observations", "O", "O_csr")):
        for a in range(A):
            if model.sparse:
                M = getattr(model, stack)[a]
                rows = np.repeat(np.arange(M.shape[0]), np.diff(M.indptr))
                act = ref("actions", a)
                lines += [f"{key}: {act} : {ref(row_kind, i)} : {ref(col_kind, j)} {_num(p)}"
                          for i, j, p in zip(rows.tolist(), M.indices.tolist(), M.data.tolist(), strict=True)]
            else:
                lines.append(f"{key}: {ref('actions', a)}")
                lines += [" ".join(_num(p) for p in row) for row in getattr(model, dense)[a]]
            lines.append("")
    for a in range(A):
        for s in range(S):
            lines.append(f"R: {ref('actions', a)} : {ref('states', s)} : * : * {_num(model.r[s, a])}")
    return "\n".join(lines) + "\n"


def save_pomdp_file(model: POMDP, path: str | Path) -> None:
    """Write ``model`` to ``path`` as a ``.POMDP`` file (see :func:`export_pomdp`)."""
    Path(path).write_text(export_pomdp(model))


# ---------------------------------------------------------------------------- import
class _Tok(NamedTuple):
    text: str
    line: int
    #: For a line that is one element entry read whole: its action, row and column references and
    #: its probability (the texts of the words).
    elem: tuple[str, str, str, str] | None = None
    #: Consecutive element lines with 0-based indices, read in bulk: ``(keys, actions, rows, columns,
    #: probabilities, lines)``, lists of the words (``keys``: ``T`` or ``O``).
    bulk: tuple[list, ...] | None = None


_TOKEN = re.compile(r":|[^\s:]+")
#: A line holding exactly one element entry ``T: a : s : s' p`` or ``O: a : s' : z p``.
_ELEMENT_LINE = re.compile(r"\s*([TO])\s*:\s*([^\s:]+)\s*:\s*([^\s:]+)\s*:\s*([^\s:]+)\s+([^\s:]+)\s*")
#: A line holding exactly one reward entry ``R: a : s : * : * v`` with 0-based indices (read whole).
_REWARD_LINE = re.compile(r"\s*R\s*:\s*([0-9]{1,18})\s*:\s*([0-9]{1,18})\s*:\s*\*\s*:\s*\*\s+([^\s:]{1,64})\s*")
#: The same with three 0-based indices (read in bulk, :class:`_Tok` ``bulk``).
_INDEX_ELEMENT_LINE = re.compile(r"\s*([TO])\s*:\s*([0-9]{1,18})\s*:\s*([0-9]{1,18})\s*:\s*([0-9]{1,18})\s+"
                                 r"([0-9.eE+\-]{1,64})\s*")
#: Most element lines in one bulk token.
BULK_LINES = 65536


class _Lexer:
    """Streams tokens (``:`` is a token of its own) with one token of lookahead.

    Tokens are produced lazily, so that a large file is never held as a list of tokens.
    ``meta`` collects the ``# pomdp_planner: {...}`` comment (see the module docstring).
    """

    def __init__(self, text: str):
        self.meta: dict = {}
        self.last: _Tok | None = None  # the last token consumed
        self._it = self._tokens(text)
        self.head: _Tok | None = next(self._it, None)

    def _tokens(self, text: str):
        count = 0
        bulk: tuple[list, ...] = ([], [], [], [], [], [])

        def flush():
            nonlocal bulk
            tok = _Tok(bulk[0][0], bulk[5][0], bulk=bulk)
            bulk = ([], [], [], [], [], [])
            return tok

        elements = 0
        for lineno, raw in enumerate(io.StringIO(text), start=1):
            if (m := _INDEX_ELEMENT_LINE.fullmatch(raw)) is not None:
                elements += 1
                if elements > MAX_ELEMENT_LINES:
                    raise ModelError(f"line {lineno}: more than {MAX_ELEMENT_LINES:,} element lines "
                                     "(MAX_ELEMENT_LINES)")
                for store, word in zip(bulk, m.groups(), strict=False):
                    store.append(word)
                bulk[5].append(lineno)
                if len(bulk[0]) >= BULK_LINES:
                    yield flush()
                continue
            if bulk[0]:
                yield flush()
            if (m := _REWARD_LINE.fullmatch(raw)) is not None:
                count += 10  # R : a : s : * : * v
                if count > MAX_TOKENS:
                    raise ModelError(f"line {lineno}: more than {MAX_TOKENS:,} words (MAX_TOKENS)")
                yield _Tok("R", lineno, (m.group(1), m.group(2), "*", m.group(3)))
                continue
            if "#" in raw:
                if len(raw) <= MAX_META_CHARS and (m := _META.match(raw.strip())):
                    try:
                        parsed = json.loads(m.group(1))
                    except (ValueError, RecursionError):  # not JSON, or nested too deep
                        parsed = None
                    if isinstance(parsed, dict):
                        self.meta = parsed
                raw = raw.split("#", 1)[0]
            if (m := _ELEMENT_LINE.fullmatch(raw)) is not None and all(
                    len(t) <= MAX_TOKEN_CHARS for t in m.groups()):
                count += 8  # T : a : s : s' p
                if count > MAX_TOKENS:
                    raise ModelError(f"line {lineno}: more than {MAX_TOKENS:,} words (MAX_TOKENS)")
                yield _Tok(m.group(1), lineno, m.groups()[1:])
                continue
            for t in _TOKEN.findall(raw):
                count += 1
                if count > MAX_TOKENS:
                    raise ModelError(f"line {lineno}: more than {MAX_TOKENS:,} words (MAX_TOKENS)")
                if len(t) > MAX_TOKEN_CHARS:
                    raise ModelError(f"line {lineno}: a word of {len(t)} characters "
                                     f"(at most {MAX_TOKEN_CHARS}): {short_repr(t, 40)}")
                yield _Tok(t, lineno)
        if bulk[0]:
            yield flush()

    def advance(self) -> _Tok:
        tok = self.head
        assert tok is not None
        self.last = tok
        self.head = next(self._it, None)
        return tok


class _Rewards:
    """The file's ``R(s, a, s', z)``: one value per ``(a, s)`` while every entry covers all end
    states and observations, the full ``A x S x S x Z`` array (checked against
    ``MAX_MODEL_BYTES`` before it is allocated) as soon as one entry does not."""

    def __init__(self, A: int, S: int, Z: int):
        self.shape = (A, S, S, Z)
        self.whole = np.zeros((A, S))
        self.full: np.ndarray | None = None

    def set_whole(self, acts: list[int], starts: list[int], v: float) -> None:
        if self.full is None:
            self.whole[np.ix_(acts, starts)] = v
        else:
            self.full[np.ix_(acts, starts)] = v

    def ensure_full(self, parser: _Parser, tok: _Tok) -> np.ndarray:
        if self.full is None:
            A, S, _, Z = self.shape
            need = 8 * A * S * S * Z
            if need > MAX_MODEL_BYTES:
                raise parser.error(f"R: rewards that depend on the end state or the observation need the "
                                   f"A x S x S x Z array R(s, a, s', z) of {format_bytes(need)}, more than the limit "
                                   f"of {format_bytes(MAX_MODEL_BYTES)} (MAX_MODEL_BYTES); give R: a : s : * : * "
                                   "values instead", tok)
            self.full = np.broadcast_to(self.whole[:, :, None, None], self.shape).copy()
        return self.full

    def expected(self, P: SparseStack, O: SparseStack) -> np.ndarray:
        """``r(s, a) = sum_{s', z} P(s'|s,a) O(z|s',a) R(s,a,s',z)``, S x A, with the file's ``P`` and
        ``O`` as they are (not renormalised), as pomdp-solve computes it (``computeRewards``): a
        value given for all end states and observations is multiplied by the mass of its row."""
        if self.full is None:
            mass = np.stack([P[a] @ np.asarray(O[a].sum(axis=1)).ravel() for a in range(P.shape[0])])
            return (self.whole * mass).T
        return np.einsum("asj,ajz,asjz->as", P.to_dense(), O.to_dense(), self.full).T


class _Cells:
    """The cells the ``T:`` (or ``O:``) entries write, in file order, later writes winning: blocks of
    coordinates (``key = (a rows + i) cols + j``, value), compacted when they grow (the last write of
    each cell kept, zeros dropped); never a dense array. A write of more than
    :data:`COMPACT_CELLS` cells clears its box and keeps only its non-zeros. ``lines[a, i]``: the
    last line that wrote row ``i`` of matrix ``a`` (0: none)."""

    def __init__(self, A: int, rows: int, cols: int, parser: _Parser):
        self.shape = (A, rows, cols)
        self.parser = parser
        self.blocks: list[tuple[np.ndarray, np.ndarray]] = []
        self.held = 0
        self.one: tuple[list[int], list[float], list[int]] = ([], [], [])  # single cells not yet in a block
        self.lines = np.zeros((A, rows), dtype=np.int64)

    def _keys(self, a: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        _, R, C = self.shape
        return (a * R + i) * C + j

    def write(self, acts, rows, cols, values, tok: _Tok) -> None:
        """Cells ``acts x rows x cols`` (lists or arrays of indices) get ``values`` (broadcast to
        that box)."""
        self._flush()
        acts, rows, cols = (np.atleast_1d(np.asarray(x, dtype=np.int64)) for x in (acts, rows, cols))
        vals = np.broadcast_to(np.asarray(values, dtype=float), (acts.size, rows.size, cols.size))
        np.maximum.at(self.lines, np.ix_(acts, rows), tok.line)
        if vals.size > COMPACT_CELLS:
            self.parser.check_nonzeros(tok, extra=int(np.count_nonzero(vals)))
            self.clear_box(acts, rows, cols)
            ka, ki, kj = np.nonzero(vals)
            self._append(self._keys(acts[ka], rows[ki], cols[kj]), vals[ka, ki, kj].copy())
        else:
            keys = self._keys(acts[:, None, None], rows[None, :, None], cols[None, None, :])
            self._append(keys.ravel(), vals.ravel().copy())

    def write_identity(self, acts, tok: _Tok) -> None:
        """Matrices ``acts`` become the identity (``T: a identity``)."""
        acts = np.atleast_1d(np.asarray(acts, dtype=np.int64))
        S = self.shape[1]
        self.parser.check_nonzeros(tok, extra=acts.size * S)
        self._flush()
        self.lines[acts] = tok.line
        self.clear_box(acts, np.arange(S), np.arange(self.shape[2]))
        d = np.arange(S)
        self._append(self._keys(np.repeat(acts, S), np.tile(d, acts.size), np.tile(d, acts.size)),
                     np.ones(acts.size * S))

    def write_many(self, a: np.ndarray, i: np.ndarray, j: np.ndarray, values: np.ndarray, lines: np.ndarray) -> None:
        """Single cells ``(a[k], i[k], j[k])``, in order (element lines read in bulk)."""
        self._flush()
        np.maximum.at(self.lines, (a, i), lines)
        self._append(self._keys(a, i, j), values)

    def write_one(self, a: int, i: int, j: int, value: float, line: int) -> None:
        """One cell (an element entry read whole)."""
        keys, vals, lines = self.one
        keys.append((a * self.shape[1] + i) * self.shape[2] + j)
        vals.append(value)
        lines.append(line)
        if len(keys) >= 65536:
            self._flush()

    def _flush(self) -> None:
        keys, vals, lines = self.one
        if keys:
            k = np.array(keys, dtype=np.int64)
            np.maximum.at(self.lines.reshape(-1), k // self.shape[2], np.array(lines, dtype=np.int64))
            self.one = ([], [], [])
            self._append(k, np.array(vals, dtype=float))

    def _append(self, keys: np.ndarray, vals: np.ndarray) -> None:
        self.blocks.append((keys, vals))
        self.held += keys.size
        if self.held > COMPACT_CELLS:
            self.compact()

    def clear_box(self, acts: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> None:
        """Drop every cell written so far inside ``acts x rows x cols``."""
        keys, vals = self.compact(check=False)
        _, R, C = self.shape
        a, rest = np.divmod(keys, R * C)
        i, j = np.divmod(rest, C)
        inside = np.isin(a, acts) & np.isin(i, rows) & np.isin(j, cols)
        self.blocks, self.held = [(keys[~inside], vals[~inside])], int(np.count_nonzero(~inside))

    def compact(self, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The last value of every cell written, zeros dropped, sorted by key; refused (one line)
        when the non-zeros cannot be stored within ``MAX_MODEL_BYTES``."""
        self._flush()
        if not self.blocks:
            return np.zeros(0, np.int64), np.zeros(0)
        if len(self.blocks) > 1 or check:
            keys = np.concatenate([b[0] for b in self.blocks])
            vals = np.concatenate([b[1] for b in self.blocks])
            order = np.argsort(keys, kind="stable")
            keys, vals = keys[order], vals[order]
            last = np.r_[keys[1:] != keys[:-1], True]
            keys, vals = keys[last], vals[last]
            nz = vals != 0.0
            self.blocks, self.held = [(keys[nz], vals[nz])], int(np.count_nonzero(nz))
        if check:
            self.parser.check_nonzeros(None)
        return self.blocks[0]

    def stack(self) -> SparseStack:
        keys, vals = self.compact()
        A, R, C = self.shape
        a, rest = np.divmod(keys, R * C)
        i, j = np.divmod(rest, C)
        return SparseStack.from_coo(A, R, C, a, i, j, vals)


class _Parser:
    def __init__(self, text: str, source: str, epsilon: float | None = None):
        self.source = source
        self.epsilon = epsilon
        self.lex = _Lexer(text)
        self.cells = 0  # matrix cells written by the entries so far (MAX_ENTRY_CELLS)
        self.gamma: float | None = None
        self.sign = 1.0
        self.sizes: dict[str, int] = {}
        self.names: dict[str, list[str] | None] = {}
        self.lookup: dict[str, dict[str, int]] = {}  # name -> index, per kind
        self.start: np.ndarray | None = None
        self.entry = _Tok("", 0)  # the keyword token of the entry being parsed
        self.stores: tuple[_Cells, ...] = ()  # T: and O: cells, once the first entry comes

    # -- token helpers
    def error(self, msg: str, tok: _Tok | None = None) -> ModelError:
        if tok is None:
            tok = self.lex.head if self.lex.head is not None else self.lex.last
        where = f"line {tok.line}" if tok is not None else "end of file"
        return ModelError(f"{where}: {msg}")

    def peek(self) -> _Tok | None:
        return self.lex.head

    def next(self, what: str) -> _Tok:
        tok = self.peek()
        if tok is None:
            raise self.error(f"unexpected end of file, expected {what}", self.lex.last)
        return self.lex.advance()

    def colon(self, after: str) -> None:
        tok = self.next(f"':' after {after}")
        if tok.text != ":":
            raise self.error(f"expected ':' after {after}, got {tok.text!r}", tok)

    def number(self, what: str) -> float:
        tok = self.next(what)
        if not _NUMBER.match(tok.text):
            raise self.error(f"expected {what} (a number), got {tok.text!r}", tok)
        x = float(tok.text)
        if not np.isfinite(x):
            raise self.error(f"{what}: {tok.text!r} is too large for a float", tok)
        return x

    def numbers(self, n: int, what: str) -> np.ndarray:
        if n > MAX_TOKENS:  # more numbers than a file may hold words: refused before allocating them
            raise self.error(f"{what}: expects {n:,} numbers, more than the {MAX_TOKENS:,} words a file may hold "
                             "(MAX_TOKENS)", self.entry)
        out = np.empty(n)
        for k in range(n):
            tok = self.peek()
            if tok is None or not _NUMBER.match(tok.text):
                got = "end of file" if tok is None else repr(tok.text)
                where = self.lex.last if tok is None else tok
                since = f" (entry starting on line {self.entry.line})" if self.entry.line != where.line else ""
                raise self.error(f"{what}: expected {n} numbers, got {k} before {got}{since}", where)
            out[k] = float(tok.text)
            if not np.isfinite(out[k]):
                raise self.error(f"{what}: {tok.text!r} is too large for a float", tok)
            self.lex.advance()
        tok = self.peek()
        if tok is not None and _NUMBER.match(tok.text):
            raise self.error(f"{what}: more than the expected {n} numbers", tok)
        return out

    def until_section(self) -> list[_Tok]:
        out = []
        while (tok := self.peek()) is not None and tok.text not in _SECTIONS:
            out.append(tok)
            self.lex.advance()
        return out

    # -- header
    def need(self, kind: str, tok: _Tok) -> int:
        if kind not in self.sizes:
            raise self.error(f"'{kind}:' must be declared before this line", tok)
        return self.sizes[kind]

    def index(self, kind: str, tok: _Tok) -> list[int] | np.ndarray:
        """A reference to a state/action/observation: ``*``, a 0-based index or a name."""
        n = self.need(kind, tok)
        t = tok.text
        if t == "*":
            return np.arange(n)
        if _INDEX.match(t):
            i = int(t)
            if i >= n:
                raise self.error(f"{kind[:-1]} index {i} out of range 0..{n - 1}", tok)
            return [i]
        i = self.lookup.get(kind, {}).get(t)
        if i is not None:
            return [i]
        names = self.names.get(kind)
        known = f"; known names: {' '.join(names)}" if names else " (declared as a count: use 0-based indices)"
        raise self.error(f"unknown {kind[:-1]} {t!r}{known}", tok)

    def ref(self, kind: str) -> list[int] | np.ndarray:
        return self.index(kind, self.next(f"a {kind[:-1]} (name, index or *)"))

    def header_list(self, kind: str, tok: _Tok) -> None:
        if kind in self.sizes:
            raise self.error(f"'{kind}:' declared twice", tok)
        self.colon(kind)
        items = self.until_section()
        if not items:
            raise self.error(f"{kind}: expected a count or a list of names", tok)
        if len(items) == 1 and _INDEX.match(items[0].text):
            n = int(items[0].text)
            if n < 1:
                raise self.error(f"{kind}: count must be at least 1, got {n}", items[0])
            self.sizes[kind], self.names[kind] = n, None
            self.check_size(kind, items[0])
            return
        names: list[str] = []
        lookup: dict[str, int] = {}
        for it in items:
            if _NUMBER.match(it.text) or it.text in ("*", ":") or it.text in KEYWORDS:
                what = "a bare number" if _NUMBER.match(it.text) else "reserved"
                raise self.error(f"{kind}: name {it.text!r} is {what}; give one count or names that start "
                                 "with a letter", it)
            if it.text in lookup:
                raise self.error(f"{kind}: name {it.text!r} appears twice", it)
            lookup[it.text] = len(names)
            names.append(it.text)
        self.sizes[kind], self.names[kind], self.lookup[kind] = len(names), names, lookup
        self.check_size(kind, tok)

    def check_size(self, kind: str, tok: _Tok) -> None:
        """The sizes declared so far (1 for those still missing) against ``MAX_MODEL_BYTES``, as the
        smallest model they allow: stored sparse, one non-zero per row of ``T`` and of ``O``."""
        S, A, Z = (self.sizes.get(k, 1) for k in ("states", "actions", "observations"))
        with prefixed(f"line {tok.line}"):
            check_model_size(S, A, Z, kind, nnz=2 * A * S)

    def write(self, cells: int, tok: _Tok) -> None:
        """Account for an entry writing ``cells`` matrix cells (refused past ``MAX_ENTRY_CELLS``)."""
        self.cells += cells
        if self.cells > MAX_ENTRY_CELLS:
            raise self.error(f"the T:, O: and R: entries so far write {self.cells:,} matrix cells, more than the "
                             f"limit of {MAX_ENTRY_CELLS:,} (MAX_ENTRY_CELLS)", tok)

    def start_line(self, tok: _Tok) -> None:
        S = self.need("states", tok)
        mode = self.peek()
        if mode is not None and mode.text in ("include", "exclude"):
            self.lex.advance()
            self.colon(f"start {mode.text}")
            items = self.until_section()
            if not items:
                raise self.error(f"start {mode.text}: expected a list of states", mode)
            chosen = np.zeros(S, dtype=bool)
            for it in items:
                chosen[self.index("states", it)] = True
            if mode.text == "exclude":
                chosen = ~chosen
            if not chosen.any():
                raise self.error("start exclude: excludes every state", mode)
            self.start = chosen / chosen.sum()
            return
        self.colon("start")
        items = self.until_section()
        if len(items) == 1 and items[0].text == "uniform":
            self.start = np.full(S, 1.0 / S)
        elif len(items) == S and all(_NUMBER.match(it.text) for it in items):
            b = np.array([float(it.text) for it in items])
            if np.any(b < 0) or abs(b.sum() - 1.0) > STOCHASTIC_ATOL:
                raise self.error(f"start: probabilities must be non-negative and sum to 1 (sum {b.sum():.9g})", tok)
            self.start = b
        elif len(items) == 1:
            b = np.zeros(S)
            b[self.index("states", items[0])] = 1.0
            self.start = b
        else:
            raise self.error(f"start: expected {S} probabilities, 'uniform' or one state, got {len(items)} items",
                             tok)

    # -- parameters
    def probs(self, values: np.ndarray, what: str, tok: _Tok) -> np.ndarray:
        if np.any(values < 0.0) or np.any(values > 1.0 + STOCHASTIC_ATOL):
            bad = values[(values < 0.0) | (values > 1.0 + STOCHASTIC_ATOL)].flat[0]
            raise self.error(f"{what}: probability {bad:g} is outside [0, 1]", tok)
        return values

    def bulk_entries(self, tok: _Tok) -> None:
        """Consecutive element lines with 0-based indices (:class:`_Tok` ``bulk``): checked and written
        as arrays, with the checks and messages of the word-by-word path."""
        keys, a_t, i_t, j_t, p_t, lines = tok.bulk
        S, A, Z = (self.need(k, tok) for k in ("states", "actions", "observations"))
        lines = np.array(lines, dtype=np.int64)
        try:
            p = np.array(p_t, dtype=float)
        except ValueError:
            p = None
        if p is None or not np.all(np.isfinite(p)):
            for k, text in enumerate(p_t):
                if not _NUMBER.match(text) or not np.isfinite(float(text)):
                    raise self.error(f"expected {keys[k]}: probability (a number), got {text!r}",
                                     _Tok(keys[k], lines[k]))
        bad = np.flatnonzero((p < 0.0) | (p > 1.0 + STOCHASTIC_ATOL))
        if bad.size:
            k = int(bad[0])
            raise self.error(f"{keys[k]}: entry: probability {p[k]:g} is outside [0, 1]", _Tok(keys[k], lines[k]))
        is_t = np.array(keys) == "T"
        idx = [np.array(x, dtype=np.int64) for x in (a_t, i_t, j_t)]
        for kind, values, n in (("action", idx[0], np.full(is_t.size, A)), ("state", idx[1], np.full(is_t.size, S)),
                                ("state", idx[2], np.where(is_t, S, Z))):
            out = np.flatnonzero(values >= n)
            if out.size:
                k = int(out[0])
                what = "observation" if (kind == "state" and values is idx[2] and not is_t[k]) else kind
                raise self.error(f"{what} index {values[k]} out of range 0..{n[k] - 1}", _Tok(keys[k], lines[k]))
        self.write(len(keys), tok)
        for key, store in (("T", self.stores[0]), ("O", self.stores[1])):
            sel = is_t if key == "T" else ~is_t
            if sel.any():
                store.write_many(idx[0][sel], idx[1][sel], idx[2][sel], p[sel], lines[sel])

    def element_line(self, tok: _Tok, cells: _Cells) -> None:
        """An element entry read whole (:class:`_Tok` ``elem``): the same checks as word by word."""
        what = tok.text
        col = "states" if what == "T" else "observations"
        a_t, i_t, j_t, p_t = tok.elem
        acts = self.index("actions", _Tok(a_t, tok.line))
        rows = self.index("states", _Tok(i_t, tok.line))
        cols = self.index(col, _Tok(j_t, tok.line))
        if not _NUMBER.match(p_t):
            raise self.error(f"expected {what}: probability (a number), got {p_t!r}", tok)
        p = float(p_t)
        if not np.isfinite(p):
            raise self.error(f"{what}: probability: {p_t!r} is too large for a float", tok)
        if p < 0.0 or p > 1.0 + STOCHASTIC_ATOL:
            raise self.error(f"{what}: entry: probability {p:g} is outside [0, 1]", tok)
        n = len(acts) * len(rows) * len(cols)
        self.write(n, tok)
        if n == 1:
            cells.write_one(int(acts[0]), int(rows[0]), int(cols[0]), p, tok.line)
        else:
            cells.write(acts, rows, cols, p, tok)

    def stochastic(self, key: str, tok: _Tok, S: int, n: int, cells: _Cells) -> None:
        """``T:`` (key "T", cells of A x S x S) or ``O:`` (A x S x Z) in all forms."""
        what = "T" if key == "T" else "O"
        col = "states" if key == "T" else "observations"
        if tok.elem is not None:
            self.element_line(tok, cells)
            return
        self.colon(what)
        acts = self.ref("actions")
        nxt = self.peek()
        if nxt is not None and nxt.text == ":":
            self.lex.advance()
            rows = self.ref("states")
            nxt = self.peek()
            if nxt is not None and nxt.text == ":":  # element form
                self.lex.advance()
                cols = self.ref(col)
                p = self.probs(np.array([self.number(f"{what}: probability")]), f"{what}: entry", tok)[0]
                self.write(len(acts) * len(rows) * len(cols), tok)
                cells.write(acts, rows, cols, p, tok)
            else:  # row form
                if nxt is not None and nxt.text == "uniform":
                    self.lex.advance()
                    row = np.full(n, 1.0 / n)
                else:
                    row = self.probs(self.numbers(n, f"{what}: row"), f"{what}: row", tok)
                self.write(len(acts) * len(rows) * n, tok)
                cells.write(acts, rows, np.arange(n), row[None, None, :], tok)
            return
        if nxt is not None and nxt.text in ("uniform", "identity"):
            self.lex.advance()
            self.write(len(acts) * S * n, tok)
            if nxt.text == "uniform":
                cells.write(acts, np.arange(S), np.arange(n), 1.0 / n, tok)
            else:
                if n != S:
                    raise self.error(f"{what}: 'identity' needs as many observations as states ({n} != {S})", nxt)
                cells.write_identity(acts, tok)
            return
        M = self.probs(self.numbers(S * n, f"{what}: matrix"), f"{what}: matrix", tok).reshape(S, n)
        self.write(len(acts) * S * n, tok)
        cells.write(acts, np.arange(S), np.arange(n), M[None, :, :], tok)

    def reward(self, tok: _Tok, S: int, Z: int, R: _Rewards) -> None:
        if tok.elem is not None:  # R: a : s : * : * v, read whole
            a_t, s_t, _, v_t = tok.elem
            acts = self.index("actions", _Tok(a_t, tok.line))
            starts = self.index("states", _Tok(s_t, tok.line))
            if not _NUMBER.match(v_t):
                raise self.error(f"expected R: value (a number), got {v_t!r}", tok)
            v = float(v_t)
            if not np.isfinite(v):
                raise self.error(f"R: value: {v_t!r} is too large for a float", tok)
            self.write(len(acts) * len(starts) * (1 if R.full is None else S * Z), tok)
            R.set_whole(acts, starts, v)
            return
        self.colon("R")
        acts = self.ref("actions")
        self.colon("R: action")
        starts = self.ref("states")
        nxt = self.peek()
        if nxt is not None and nxt.text == ":":
            self.lex.advance()
            ends = self.ref("states")
            nxt = self.peek()
            if nxt is not None and nxt.text == ":":  # element form
                self.lex.advance()
                obs = self.ref("observations")
                v = self.number("R: value")
                if len(ends) == S and len(obs) == Z:
                    self.write(len(acts) * len(starts) * (1 if R.full is None else S * Z), tok)
                    R.set_whole(acts, starts, v)
                else:
                    self.write(len(acts) * len(starts) * len(ends) * len(obs), tok)
                    R.ensure_full(self, tok)[np.ix_(acts, starts, ends, obs)] = v
                return
            row = self.numbers(Z, "R: row (one value per observation)")
            self.write(len(acts) * len(starts) * len(ends) * Z, tok)
            R.ensure_full(self, tok)[np.ix_(acts, starts, ends)] = row
            return
        M = self.numbers(S * Z, "R: matrix (end states x observations)").reshape(S, Z)
        self.write(len(acts) * len(starts) * S * Z, tok)
        R.ensure_full(self, tok)[np.ix_(acts, starts)] = M

    # -- driver
    def parse(self) -> POMDP:
        P = O = None
        R: _Rewards | None = None
        while (tok := self.peek()) is not None:
            self.lex.advance()
            self.entry = tok
            t = tok.text
            if t == "discount":
                self.colon("discount")
                g = self.number("discount")
                if not 0.0 <= g <= 1.0:
                    raise self.error(f"discount: must satisfy 0 <= discount <= 1 (1: a finite horizon only), got {g}",
                                     tok)
                self.gamma = g
            elif t == "values":
                self.colon("values")
                v = self.next("'reward' or 'cost'")
                if v.text not in ("reward", "cost"):
                    raise self.error(f"values: expected 'reward' or 'cost', got {v.text!r}", v)
                self.sign = 1.0 if v.text == "reward" else -1.0
            elif t in ("states", "actions", "observations"):
                if P is not None:
                    raise self.error(f"'{t}:' must come before the T:, O: and R: entries", tok)
                self.header_list(t, tok)
            elif t == "start":
                self.start_line(tok)
            elif t in ("T", "O", "R"):
                S = self.need("states", tok)
                A = self.need("actions", tok)
                Z = self.need("observations", tok)
                if P is None:
                    P, O = _Cells(A, S, S, self), _Cells(A, S, Z, self)
                    self.stores = (P, O)
                    R = _Rewards(A, S, Z)
                if tok.bulk is not None:
                    self.bulk_entries(tok)
                elif t == "T":
                    self.stochastic("T", tok, S, S, P)
                elif t == "O":
                    self.stochastic("O", tok, S, Z, O)
                else:
                    self.reward(tok, S, Z, R)
            else:
                expected = "discount, values, states, actions, observations, start, T, O or R"
                raise self.error(f"unexpected {t!r} (expected one of {expected})", tok)
        if self.gamma is None:
            raise ModelError("'discount:' is missing")
        for kind in ("states", "actions", "observations"):
            if kind not in self.sizes:
                raise ModelError(f"'{kind}:' is missing")
        if P is None:
            raise ModelError("no T: or O: entries")
        Ps, Os = P.stack(), O.stack()
        off = [self.check_rows("T", "transition", Ps, P.lines, "start state", "states"),
               self.check_rows("O", "observation", Os, O.lines, "end state", "observations")]
        r = self.sign * R.expected(Ps, Os)  # with the file's probabilities, as pomdp-solve computes it
        Ps, Os = self.renormalise(off, Ps, Os)
        return self.build(Ps, Os, r)

    def check_nonzeros(self, tok: _Tok | None, extra: int = 0) -> None:
        """The non-zeros kept so far (plus ``extra`` about to be written) within ``MAX_MODEL_BYTES``
        (stored sparse); else one line at ``tok`` (the entry being read)."""
        S, A, Z = (self.sizes[k] for k in ("states", "actions", "observations"))
        nnz = sum(c.held for c in self.stores) + extra
        try:
            check_model_size(S, A, Z, "the T: and O: entries so far", nnz=nnz)
        except ModelError as exc:
            raise self.error(str(exc), tok if tok is not None else self.entry) from None

    def check_rows(self, key: str, field: str, M: SparseStack, lines: np.ndarray, row_label: str, over: str
                   ) -> list[tuple[int, int, str]]:
        """Refuse a row of ``M`` whose sum is off 1 by more than :data:`PEER_ROW_TOLERANCE`; return
        ``(action, row, description)`` of the rows off by more than ``STOCHASTIC_ATOL`` (within it),
        which :meth:`renormalise` divides by their sums."""
        sums = np.stack([np.asarray(M[a].sum(axis=1)).ravel() for a in range(M.shape[0])])
        dev = np.abs(sums - 1.0)
        bad = np.argwhere(dev > PEER_ROW_TOLERANCE)
        if bad.size:
            a, s = bad[0]
            an, sn = self.label("actions", a), self.label("states", s)
            if lines[a, s] == 0:
                raise ModelError(f"{key}: no probabilities given for action {an}, {row_label} {sn} "
                                 f"({field} row sums to {sums[a, s]:.9g})")
            raise ModelError(f"line {lines[a, s]}: {key}: {field} row for action {an}, {row_label} {sn} sums to "
                             f"{sums[a, s]:.9g} over {over}, not 1 (tolerance {PEER_ROW_TOLERANCE:g}; after the "
                             f"last {key}: entry touching it, on this line)")
        return [(int(a), int(s), f"line {lines[a, s]}: {key}: {field} row for action {self.label('actions', a)}, "
                 f"{row_label} {self.label('states', s)} sums to {sums[a, s]:.9g}")
                for a, s in np.argwhere(dev > STOCHASTIC_ATOL)]

    def renormalise(self, off: list[list[tuple[int, int, str]]], *matrices: SparseStack) -> list[SparseStack]:
        """The matrices (``P``, then ``O``) with the rows ``off`` divided by their sums, said in one
        warning (:class:`~pomdp_planner.core.errors.InputWarning`) that names the first of them."""
        rows = [(k, a, i, text) for k, found in enumerate(off) for a, i, text in found]
        if not rows:
            return list(matrices)
        out = []
        for k, M in enumerate(matrices):
            mats = [M[a].copy() for a in range(M.shape[0])]
            for kk, a, i, _ in rows:
                if kk == k:
                    lo, hi = mats[a].indptr[i], mats[a].indptr[i + 1]
                    mats[a].data[lo:hi] /= mats[a].data[lo:hi].sum()
            out.append(SparseStack.from_matrices(mats, M.shape[1], M.shape[2]))
        more = len(rows) - 1
        counts = ", ".join(f"{len(found)} {key}" for key, found in zip(("T", "O"), off, strict=True) if found)
        warnings.warn(InputWarning(
            f"{self.source}: {rows[0][3]}, not 1 but within pomdp-solve's tolerance {PEER_ROW_TOLERANCE:g}: "
            "renormalised" + (f" ({more} more row{'s' * (more != 1)} likewise; in all {counts})" if more else "")),
            stacklevel=4)
        return out

    def label(self, kind: str, i: int) -> str:
        """The name of state/action ``i`` if the file names them, else the index."""
        names = self.names[kind]
        return names[i] if names else str(i)

    def uncertainty(self, S: int) -> dict:
        """The uncertainty term of the ``# pomdp_planner:`` comment (``function``, ``weights``,
        ``epsilon``, as the YAML ``uncertainty:`` mapping), checked; ``{}`` without one."""
        unc = self.lex.meta.get("uncertainty")
        if unc is None:
            return {}
        where = " (# pomdp_planner: comment)"
        if not isinstance(unc, dict):
            raise ModelError(f"uncertainty{where}: expected a mapping {{function, weights, epsilon}}, "
                             f"got {kind_of(unc)}")
        unknown = sorted(set(map(str, unc)) - META_UNCERTAINTY_FIELDS)
        if unknown:
            shown = ", ".join(short_repr(k, 40) for k in unknown[:5]) + (f", ... ({len(unknown)} in all)"
                                                                         if len(unknown) > 5 else "")
            raise ModelError(f"uncertainty{where}: unknown field(s) [{shown}]; "
                             f"known: {sorted(META_UNCERTAINTY_FIELDS)}")
        out: dict = {"uncertainty": unc.get("function", "none"), "w": unc.get("weights")}
        if not isinstance(out["uncertainty"], str):
            raise ModelError(f"uncertainty.function{where}: must be the name of a function, got "
                             f"{kind_of(out['uncertainty'])}")
        if out["uncertainty"] != "none" and out["w"] is None:
            raise ModelError(f"uncertainty.weights{where}: missing (one weight per action)")
        if unc.get("epsilon") is not None:
            out["epsilon"] = as_number(unc["epsilon"], f"uncertainty.epsilon{where}")
        return out

    def build(self, P: SparseStack, O: SparseStack, r: np.ndarray) -> POMDP:
        names = dict(self.names)
        for kind in ("states", "actions", "observations"):
            orig = self.lex.meta.get(kind)
            if (isinstance(orig, list) and names[kind] is not None and len(orig) == len(names[kind])
                    and all(isinstance(x, str) for x in orig) and safe_names(orig, kind) == names[kind]):
                names[kind] = orig
        name = None
        stem = Path(self.source).stem if self.source not in ("", "<string>") else None
        for cand in (self.lex.meta.get("name"), stem):
            try:  # a recorded name or the file's stem, if it is a valid name
                name = check_name(cand) if isinstance(cand, str) else None
            except ModelError:
                continue
            if name is not None:
                break
        name = name or "pomdp"
        metadata: dict = {"source_format": "cassandra"}
        if self.start is not None:
            metadata["start"] = self.start.tolist()
        S = P.shape[1]
        grid = self.lex.meta.get("grid")
        if grid is not None:
            if not isinstance(grid, dict) or not {"rows", "cols"} <= set(grid) or set(grid) - {"rows", "cols",
                                                                                                "obstacles"}:
                raise ModelError("grid (# pomdp_planner: comment): expected a mapping {rows, cols, obstacles}")
            layout = GridLayout(grid["rows"], grid["cols"], grid.get("obstacles") or [])
            if layout.S != S:
                raise ModelError(f"grid (# pomdp_planner: comment): {layout.S} free cells for {S} states")
            metadata["grid"] = layout.metadata()
        unc = self.uncertainty(S)
        epsilon = self.epsilon
        if epsilon is None:
            epsilon = unc.pop("epsilon", None)
        unc.pop("epsilon", None)
        if epsilon is None and "epsilon" in self.lex.meta:
            epsilon = as_number(self.lex.meta["epsilon"], "epsilon (# pomdp_planner: comment)")
        try:
            return POMDP(P=P, O=O, r=r, gamma=self.gamma, name=name,
                         epsilon=default_epsilon(S) if epsilon is None else epsilon,
                         state_names=names["states"], action_names=names["actions"],
                         observation_names=names["observations"], metadata=metadata, **unc)
        except ModelError as exc:  # a field of the comment's uncertainty term: say where it came from
            field, _, rest = str(exc).partition(": ")
            if unc and field.startswith("uncertainty."):
                raise ModelError(f"{field} (# pomdp_planner: comment): {rest}") from None
            raise


def parse_pomdp(text: str, source: str = "<string>", epsilon: float | None = None) -> POMDP:
    """Parse the text of a ``.POMDP`` file into a :class:`POMDP` (the uncertainty term from the
    ``# pomdp_planner:`` comment, if any); errors start with ``source``. ``epsilon``: the model's
    ``epsilon`` (module docstring, "Epsilon")."""
    with prefixed(source):
        return _Parser(text, source, epsilon).parse()


def load_pomdp_file(path: str | Path, epsilon: float | None = None) -> POMDP:
    """Load a Cassandra ``.POMDP`` file (see :func:`parse_pomdp`)."""
    path = Path(path)
    return parse_pomdp(read_model_text(path, ".POMDP file"), str(path), epsilon)
