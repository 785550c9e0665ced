"""The matrices of a YAML model file: nested lists, text blocks, and the sparse form.

``transition`` and ``observation`` (one matrix per action) can be written three ways
(docs/models.md):

* nested lists, ``A x rows x cols`` (the form for small models);
* a list of ``A`` *text blocks*, one per action: a YAML string (a literal block ``|``) of ``rows``
  lines, each holding ``cols`` numbers separated by spaces;
* (``reward`` too: nested lists ``S x A``, or one text block of ``S`` lines of ``A`` numbers;)
* the *sparse form*, ``{sparse: [...]}``: per action a text block of lines ``row column value``
  (0-based indices; cells not listed are 0), or a list of ``[row, column, value]`` lists. The
  file then declares ``states`` (and, for ``observation``, ``observations``): the sizes are not
  implied by the entries.

A text block is one YAML value however long, and its numbers are read in bulk (a scan of its
bytes, then ``numpy.fromstring``): tens of nanoseconds per byte, where nested lists cost a YAML
value, about 5 microseconds, per number. Numbers are plain decimals (``0.25``, ``1e-3``, ``-2``;
no ``nan``, ``inf``, ``_`` or other characters); indices are plain non-negative integers. Every
error names the field, the action and the line of the block.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ModelError
from ..model import check_model_size, kind_of, short_repr
from ..sparse import SparseStack

#: Characters a text block may hold: digits, the signs, the decimal point, exponents, white space.
_ALLOWED = np.zeros(256, dtype=bool)
_ALLOWED[np.frombuffer(b"0123456789+-.eE \t\r\n", dtype=np.uint8)] = True
_SPACE = np.zeros(256, dtype=bool)
_SPACE[np.frombuffer(b" \t\r\n", dtype=np.uint8)] = True
_DIGIT = np.zeros(256, dtype=bool)
_DIGIT[np.frombuffer(b"0123456789", dtype=np.uint8)] = True


class _Block:
    """The numbers of one text block and where each line's numbers are."""

    def __init__(self, text: str, field: str):
        self.field = field
        raw = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
        bad = ~_ALLOWED[raw]
        if bad.any():
            k = int(np.argmax(bad))
            line = int(np.count_nonzero(raw[:k] == 10)) + 1
            char = text.encode("utf-8")[k:k + 1].decode("utf-8", "replace")
            raise ModelError(f"{field}, line {line} of the block: {char!r} is not part of a number (a text block holds "
                             "plain decimal numbers separated by spaces)")
        space = _SPACE[raw]
        starts = ~space & np.r_[True, space[:-1]]  # first byte of each number
        line_of_byte = np.cumsum(raw == 10)
        self.lines = line_of_byte[starts]  # 0-based line of each number
        self.raw, self.starts = raw, starts
        self.values = self._parse(text)

    def _parse(self, text: str) -> np.ndarray:
        n = int(self.starts.sum())
        try:
            values = np.fromstring(text, sep=" ") if n else np.zeros(0)
        except ValueError:
            values = None
        if values is None or values.size != n:
            for k, token in enumerate(text.split()):
                try:
                    float(token)
                except ValueError:
                    raise ModelError(f"{self.field}, line {int(self.lines[k]) + 1} of the block: "
                                     f"{short_repr(token, 40)} is not a number") from None
            raise ModelError(f"{self.field}: not a list of numbers")  # pragma: no cover - fromstring agrees
        return values

    def per_line(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lines, counts)``: the lines that hold numbers (0-based, in order) and how many each."""
        lines, counts = np.unique(self.lines, return_counts=True)
        return lines, counts

    def integer_tokens(self, which: np.ndarray) -> None:
        """Refuse a number at positions ``which`` (a boolean mask over the numbers) that is not
        written as a plain non-negative integer."""
        token_of_byte = np.cumsum(self.starts) - 1
        inside = ~_SPACE[self.raw]
        mask = inside & which[np.maximum(token_of_byte, 0)] & (token_of_byte >= 0)
        bad = mask & ~_DIGIT[self.raw]
        if bad.any():
            k = int(token_of_byte[int(np.argmax(bad))])
            raise ModelError(f"{self.field}, line {int(self.lines[k]) + 1} of the block: an index must be a "
                             f"non-negative integer, got {self.values[k]:g}")


def dense_block(text: Any, field: str, cols: int | None = None) -> np.ndarray:
    """A dense text block: ``rows`` lines of ``cols`` numbers each, as a ``rows x cols`` array."""
    block = _Block(text, field)
    lines, counts = block.per_line()
    if lines.size == 0:
        raise ModelError(f"{field}: an empty text block (expected one line of numbers per row)")
    want = int(counts[0]) if cols is None else cols
    off = np.flatnonzero(counts != want)
    if off.size:
        k = int(off[0])
        raise ModelError(f"{field}, line {int(lines[k]) + 1} of the block: {int(counts[k])} numbers, expected {want} "
                         "(one per column)")
    return block.values.reshape(lines.size, want)


def _sparse_entries(value: Any, field: str, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(i, j, v)`` of one action's sparse entries: a text block of ``row column value`` lines, or a
    list of ``[row, column, value]``; indices checked against ``rows`` and ``cols``, duplicates refused."""
    if isinstance(value, str):
        block = _Block(value, field)
        lines, counts = block.per_line()
        off = np.flatnonzero(counts != 3)
        if off.size:
            k = int(off[0])
            raise ModelError(f"{field}, line {int(lines[k]) + 1} of the block: {int(counts[k])} numbers, expected 3 "
                             "(row column value)")
        position = np.arange(block.values.size) % 3
        block.integer_tokens(position < 2)
        flat = block.values.reshape(-1, 3)

        def where(k: int) -> str:
            return f"line {int(lines[k]) + 1} of the block"
    elif isinstance(value, list):
        flat = np.zeros((len(value), 3))
        for k, item in enumerate(value):
            if not isinstance(item, (list, tuple)) or len(item) != 3:
                raise ModelError(f"{field}[{k}]: expected [row, column, value], got {short_repr(item)}")
            r, c, v = item
            for name, x in (("row", r), ("column", c)):
                if isinstance(x, bool) or not isinstance(x, int) or x < 0:
                    raise ModelError(f"{field}[{k}]: {name} must be a non-negative integer, got {short_repr(x)}")
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ModelError(f"{field}[{k}]: value must be a number, got {kind_of(v)}")
            flat[k] = (r, c, v)

        def where(k: int) -> str:
            return f"entry {k}"
    else:
        raise ModelError(f"{field}: expected a text block of 'row column value' lines or a list of "
                         f"[row, column, value], got {kind_of(value)}")
    i, j, v = flat[:, 0], flat[:, 1], flat[:, 2]
    for name, idx, n in (("row", i, rows), ("column", j, cols)):
        bad = np.flatnonzero(idx >= n)
        if bad.size:
            k = int(bad[0])
            raise ModelError(f"{field}, {where(k)}: {name} {idx[k]:g} is out of range 0..{n - 1}")
    ii, jj = i.astype(np.int64), j.astype(np.int64)
    key = ii * cols + jj
    order = np.argsort(key, kind="stable")
    dup = np.flatnonzero(key[order][1:] == key[order][:-1])
    if dup.size:
        k = int(order[dup[0] + 1])
        raise ModelError(f"{field}, {where(k)}: cell ({ii[k]}, {jj[k]}) given twice")
    return ii, jj, v


def sparse_matrices(value: Any, field: str, A: int | None, rows: int | None, cols: int | None,
                    rows_key: str, cols_key: str) -> SparseStack:
    """The sparse form ``{sparse: [per action]}`` of ``field`` as a :class:`SparseStack`."""
    if set(value) != {"sparse"}:
        raise ModelError(f"{field}: a mapping must be {{sparse: [...]}} (one list of entries per action), got the "
                         f"fields {sorted(map(str, value))}")
    per_action = value["sparse"]
    if not isinstance(per_action, list) or not per_action:
        raise ModelError(f"{field}.sparse: expected a list with one entry block per action, got {kind_of(per_action)}")
    for key, n in ((rows_key, rows), (cols_key, cols)):
        if n is None:
            raise ModelError(f"{field}.sparse: the sparse form needs '{key}:' declared (the sizes are not implied "
                             "by the entries)")
    if A is not None and len(per_action) != A:
        raise ModelError(f"{field}.sparse: {len(per_action)} entry blocks for {A} actions")
    # the declared sizes before any entry: the smallest model they allow (its row pointers, r)
    check_model_size(rows, len(per_action), cols, f"{field}.sparse", nnz=0)
    parts = [_sparse_entries(item, f"{field}.sparse[{a}]", rows, cols) for a, item in enumerate(per_action)]
    a = np.concatenate([np.full(p[0].size, k) for k, p in enumerate(parts)])
    i, j, v = (np.concatenate([p[t] for p in parts]) for t in range(3))
    return SparseStack.from_coo(len(per_action), rows, cols, a, i, j, v)


def is_sparse_form(value: Any) -> bool:
    return isinstance(value, dict)


def is_block_list(value: Any) -> bool:
    """A list with at least one text block (one matrix per action, some written as text)."""
    return isinstance(value, list) and any(isinstance(x, str) for x in value)


# ------------------------------------------------------------------------ writing
def _num(x: float) -> str:
    """Shortest round-trip text of a float (``0.1``, ``1e-05``, ``1``)."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def dense_text(M: np.ndarray) -> str:
    """A dense text block of the matrix ``M`` (one line per row)."""
    return "".join(" ".join(_num(x) for x in row) + "\n" for row in M)


def sparse_text(stack: SparseStack, a: int) -> str:
    """A sparse text block of matrix ``a`` of ``stack`` (``row column value`` per stored entry)."""
    M = stack[a]
    rows = np.repeat(np.arange(M.shape[0]), np.diff(M.indptr))
    return "".join(f"{r} {c} {_num(v)}\n" for r, c, v in zip(rows.tolist(), M.indices.tolist(), M.data.tolist(),
                                                             strict=True))
