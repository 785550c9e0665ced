"""Cassandra ``.POMDP`` files (the pomdp-solve format, also read by SARSOP and pomdp-py).

Export (:func:`export_pomdp`, :func:`save_pomdp_file`) writes the *linear* part of the model:
``discount``, ``values: reward``, the ``states``/``actions``/``observations`` headers, ``start``
(when the model has one in ``metadata``), ``T:`` and ``O:`` matrices and the state reward as
``R: a : s : * : * r(s,a)``. The uncertainty term ``-w_a f(b)`` of the paper's Eq. 3 cannot
be expressed in the format: export then warns (``warnings.warn``) and says so in a comment.

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
rows); ``values: cost`` negates it. The model has no uncertainty term (``function: none``).
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
matrix exists; the entries together may write at most :data:`MAX_ENTRY_CELLS` matrix cells (a
short file of ``T: * uniform`` lines cannot keep the parser busy) and the file at most
:data:`MAX_TOKENS` words; rewards that depend on the
end state or the observation need the ``A x S x S x Z`` array ``R(s, a, s', z)``, which must fit
in ``MAX_MODEL_BYTES`` as well.

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
    short_repr,
)
from .file_text import read_model_text

#: Longest token (name, number, keyword) accepted in a ``.POMDP`` file.
MAX_TOKEN_CHARS = 256
#: Most matrix cells that the ``T:``, ``O:`` and ``R:`` entries of one file may write in all
#: (each cell written once for the largest model allowed is about 6e7; later entries may
#: overwrite earlier ones, so there is room for that).
MAX_ENTRY_CELLS = 400_000_000
#: Most words (numbers, names, keywords, ``:``) in a ``.POMDP`` file. Reading costs about 2 us
#: of CPU per word (measured: 1.8 s for a million), so this bounds the time of any file to a
#: few seconds; the export of a model with S = Z = 200 and A = 5 has about 400 000.
MAX_TOKENS = 1_000_000
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
    """The ``.POMDP`` text of ``model`` (linear part of the reward only; warns otherwise)."""
    S, A, Z = model.S, model.A, model.Z
    lines = [
        f"# Cassandra .POMDP file exported by pomdp_planner from model '{model.name}'",
        "# T: a : start : end = P(end | start, a);  O: a : end : obs = P(obs | end, a);  0-based indices.",
        "# Action index a is the tracking priority a + 1 (action 0 = priority 1 = greatest priority).",
    ]
    if model.uncertainty.name != "none" and np.any(model.w != 0.0):
        msg = (f"model '{model.name}': the uncertainty term -w_a f(b) (f = {model.uncertainty.name}, "
               f"w = {model.w.tolist()}) cannot be expressed in a .POMDP file; only the linear "
               "reward r(s, a) is exported")
        warnings.warn(msg, stacklevel=2)
        lines.append(f"# WARNING: {msg}.")
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
    meta = {"name": model.name, **originals}
    if model.epsilon != default_epsilon(S):
        meta["epsilon"] = model.epsilon
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
    for a in range(A):
        lines.append(f"T: {ref('actions', a)}")
        lines += [" ".join(_num(p) for p in row) for row in model.P[a]]
        lines.append("")
    for a in range(A):
        lines.append(f"O: {ref('actions', a)}")
        lines += [" ".join(_num(p) for p in row) for row in model.O[a]]
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


_TOKEN = re.compile(r":|[^\s:]+")


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
        for lineno, raw in enumerate(io.StringIO(text), start=1):
            if "#" in raw:
                if len(raw) <= MAX_META_CHARS and (m := _META.match(raw.strip())):
                    try:
                        parsed = json.loads(m.group(1))
                    except (ValueError, RecursionError):  # not JSON, or nested too deep
                        parsed = None
                    if isinstance(parsed, dict):
                        self.meta = parsed
                raw = raw.split("#", 1)[0]
            for t in _TOKEN.findall(raw):
                count += 1
                if count > MAX_TOKENS:
                    raise ModelError(f"line {lineno}: more than {MAX_TOKENS:,} words (MAX_TOKENS)")
                if len(t) > MAX_TOKEN_CHARS:
                    raise ModelError(f"line {lineno}: a word of {len(t)} characters "
                                     f"(at most {MAX_TOKEN_CHARS}): {short_repr(t, 40)}")
                yield _Tok(t, lineno)

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

    def expected(self, P: np.ndarray, O: np.ndarray) -> np.ndarray:
        """``r(s, a) = sum_{s', z} P(s'|s,a) O(z|s',a) R(s,a,s',z)``, S x A, with the file's ``P`` and
        ``O`` as they are (not renormalised), as pomdp-solve computes it (``computeRewards``): a
        value given for all end states and observations is multiplied by the mass of its row."""
        if self.full is None:
            mass = np.einsum("asj,ajz->as", P, O)
            return (self.whole * mass).T
        return np.einsum("asj,ajz,asjz->as", P, O, self.full).T


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
        """The sizes declared so far (1 for those still missing) against ``MAX_MODEL_BYTES``."""
        S, A, Z = (self.sizes.get(k, 1) for k in ("states", "actions", "observations"))
        with prefixed(f"line {tok.line}"):
            check_model_size(S, A, Z, kind)

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

    def stochastic(self, key: str, tok: _Tok, S: int, n: int, P: np.ndarray, lines: np.ndarray) -> None:
        """``T:`` (key "T", target P of shape A x S x S) or ``O:`` (A x S x Z) in all forms."""
        what = "T" if key == "T" else "O"
        col = "states" if key == "T" else "observations"
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
                P[np.ix_(acts, rows, cols)] = p
            else:  # row form
                if nxt is not None and nxt.text == "uniform":
                    self.lex.advance()
                    row = np.full(n, 1.0 / n)
                else:
                    row = self.probs(self.numbers(n, f"{what}: row"), f"{what}: row", tok)
                self.write(len(acts) * len(rows) * n, tok)
                P[np.ix_(acts, rows)] = row
            lines[np.ix_(acts, rows)] = tok.line
            return
        if nxt is not None and nxt.text in ("uniform", "identity"):
            self.lex.advance()
            if nxt.text == "uniform":
                M = np.full((S, n), 1.0 / n)
            else:
                if n != S:
                    raise self.error(f"{what}: 'identity' needs as many observations as states ({n} != {S})", nxt)
                M = np.eye(S)
        else:
            M = self.probs(self.numbers(S * n, f"{what}: matrix"), f"{what}: matrix", tok).reshape(S, n)
        self.write(len(acts) * S * n, tok)
        P[acts] = M
        lines[acts] = tok.line

    def reward(self, tok: _Tok, S: int, Z: int, R: _Rewards) -> None:
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
        P_lines = O_lines = None
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
                    P, O = np.zeros((A, S, S)), np.zeros((A, S, Z))
                    P_lines, O_lines = np.zeros((A, S), dtype=int), np.zeros((A, S), dtype=int)
                    R = _Rewards(A, S, Z)
                if t == "T":
                    self.stochastic("T", tok, S, S, P, P_lines)
                elif t == "O":
                    self.stochastic("O", tok, S, Z, O, O_lines)
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
        off = [self.check_rows("T", "transition", P, P_lines, "start state", "states"),
               self.check_rows("O", "observation", O, O_lines, "end state", "observations")]
        r = self.sign * R.expected(P, O)  # with the file's probabilities, as pomdp-solve computes it
        self.renormalise(off, P, O)
        return self.build(P, O, r)

    def check_rows(self, key: str, field: str, M: np.ndarray, lines: np.ndarray, row_label: str, over: str
                   ) -> list[tuple[int, int, str]]:
        """Refuse a row of ``M`` whose sum is off 1 by more than :data:`PEER_ROW_TOLERANCE`; return
        ``(action, row, description)`` of the rows off by more than ``STOCHASTIC_ATOL`` (within it),
        which :meth:`renormalise` divides by their sums."""
        sums = M.sum(axis=-1)
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

    def renormalise(self, off: list[list[tuple[int, int, str]]], *matrices: np.ndarray) -> None:
        """Divide the rows ``off`` (of ``P``, then ``O``) by their sums and say so in one warning
        (:class:`~pomdp_planner.core.errors.InputWarning`) that names the first of them."""
        rows = [(M, a, i, text) for M, found in zip(matrices, off, strict=True) for a, i, text in found]
        if not rows:
            return
        for M, a, i, _ in rows:
            M[a, i] /= M[a, i].sum()
        more = len(rows) - 1
        counts = ", ".join(f"{len(found)} {key}" for key, found in zip(("T", "O"), off, strict=True) if found)
        warnings.warn(InputWarning(
            f"{self.source}: {rows[0][3]}, not 1 but within pomdp-solve's tolerance {PEER_ROW_TOLERANCE:g}: "
            "renormalised" + (f" ({more} more row{'s' * (more != 1)} likewise; in all {counts})" if more else "")),
            stacklevel=4)

    def label(self, kind: str, i: int) -> str:
        """The name of state/action ``i`` if the file names them, else the index."""
        names = self.names[kind]
        return names[i] if names else str(i)

    def build(self, P: np.ndarray, O: np.ndarray, r: np.ndarray) -> POMDP:
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
        epsilon = self.epsilon
        if epsilon is None and "epsilon" in self.lex.meta:
            epsilon = as_number(self.lex.meta["epsilon"], "epsilon (# pomdp_planner: comment)")
        return POMDP(P=P, O=O, r=r, gamma=self.gamma, uncertainty="none", name=name,
                     epsilon=default_epsilon(P.shape[1]) if epsilon is None else epsilon,
                     state_names=names["states"], action_names=names["actions"],
                     observation_names=names["observations"], metadata=metadata)


def parse_pomdp(text: str, source: str = "<string>", epsilon: float | None = None) -> POMDP:
    """Parse the text of a ``.POMDP`` file into a :class:`POMDP` (linear reward, no uncertainty);
    errors start with ``source``. ``epsilon``: the model's ``epsilon`` (module docstring, "Epsilon")."""
    with prefixed(source):
        return _Parser(text, source, epsilon).parse()


def load_pomdp_file(path: str | Path, epsilon: float | None = None) -> POMDP:
    """Load a Cassandra ``.POMDP`` file (see :func:`parse_pomdp`)."""
    path = Path(path)
    return parse_pomdp(read_model_text(path, ".POMDP file"), str(path), epsilon)
