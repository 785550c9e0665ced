"""The experiments' cache files: JSON data, never code.

``bench all`` keeps each section's results in ``DIR/.experiments-cache/<section>.json`` and the
peer comparison its finished chunks of episodes in ``.../peers-chunks/*.json``
(:mod:`.runner`, :mod:`.peers`). Anybody who can write into ``DIR`` can write these files, so
reading one must never run code or crash the run: they are plain JSON, decoded by the closed
set of rules below, and nothing else is ever loaded (an old ``*.pickle`` file is ignored
unread).

**File layout** (one JSON object)::

    {"format": "pomdp_planner.experiments-cache", "version": 1, "signature": {...},
     "sha256": "<hex digest of the canonical payload>", "meta": {...}, "payload": <value>}

A file is used only when it parses (strict JSON plus ``NaN``, ``Infinity``, ``-Infinity``;
duplicate keys refused), carries this format and :data:`VERSION`, a ``signature`` the reader
accepts (the plan that made it: :class:`.peers.PeerPlan` chunk signature, or the section's
plan, :func:`.runner.section_signature`), a payload whose SHA-256 matches and that decodes by
the rules below, and passes the reader's own validation. Otherwise it is ignored with one
line on stderr (:func:`read_entry` returns ``None``) and the caller recomputes it or reports
the section missing.

**Values** (:func:`encode`, :func:`decode`):

* ``None``, ``bool``, ``int``, ``str``, ``list``: themselves; numpy scalars become Python ones.
* ``float``: itself; non-finite floats are written ``NaN``, ``Infinity``, ``-Infinity``
  (Python's JSON extension), so every float round-trips bit for bit (``repr`` is exact).
* ``tuple``: ``{"__tuple__": [...]}`` (the report formats tuples and lists differently).
* ``dict`` with string keys none of which starts with ``__``: a JSON object; any other dict
  (e.g. budgets as keys): ``{"__dict__": [[key, value], ...]}``.
* ``numpy.ndarray`` of a numeric or boolean dtype: ``{"__ndarray__": nested lists, "dtype":
  name, "shape": [...]}``.
* a dataclass registered with :func:`register` (a closed list: the result rows of the
  experiments): ``{"__dataclass__": name, "fields": {...}}``, built by calling the class with
  exactly its init fields. Any other type is refused when writing; any other tag when reading.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "pomdp_planner.experiments-cache"
#: The cache file format; files of another version are ignored.
VERSION = 1
#: Largest cache file read (bytes); a larger file is ignored unread.
MAX_FILE_BYTES = 256 * 2**20
#: dtypes an array may have in a cache file.
ARRAY_DTYPES = ("bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
                "float32", "float64")

_FIELDS = {"format", "version", "signature", "sha256", "meta", "payload"}
_DATACLASSES: dict[str, type] = {}
_TAGS = {"__tuple__": {"__tuple__"}, "__dict__": {"__dict__"}, "__ndarray__": {"__ndarray__", "dtype", "shape"},
         "__dataclass__": {"__dataclass__", "fields"}}


class CacheError(ValueError):
    """A cache file or value that cannot be used (the message says why, one line)."""


def register(cls: type) -> type:
    """Allow dataclass ``cls`` in cache files (a class decorator; the name must be unique)."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls.__name__} is not a dataclass")
    if _DATACLASSES.get(cls.__name__, cls) is not cls:
        raise TypeError(f"another dataclass named {cls.__name__} is registered already")
    _DATACLASSES[cls.__name__] = cls
    return cls


# ------------------------------------------------------------------ values
def encode(x: Any) -> Any:
    """``x`` as a JSON value (module docstring); :class:`CacheError` for a type not listed there."""
    if x is None or isinstance(x, (bool, str)):
        return x
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x)
    if isinstance(x, list):
        return [encode(v) for v in x]
    if isinstance(x, tuple):
        return {"__tuple__": [encode(v) for v in x]}
    if isinstance(x, dict):
        if all(isinstance(k, str) and not k.startswith("__") for k in x):
            return {k: encode(v) for k, v in x.items()}
        return {"__dict__": [[encode(k), encode(v)] for k, v in x.items()]}
    if isinstance(x, np.ndarray):
        if x.dtype.name not in ARRAY_DTYPES:
            raise CacheError(f"array of dtype {x.dtype} cannot be cached")
        return {"__ndarray__": x.tolist(), "dtype": x.dtype.name, "shape": list(x.shape)}
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        name = type(x).__name__
        if _DATACLASSES.get(name) is not type(x):
            raise CacheError(f"dataclass {name} is not registered for the cache")
        return {"__dataclass__": name,
                "fields": {f.name: encode(getattr(x, f.name)) for f in dataclasses.fields(x) if f.init}}
    raise CacheError(f"a {type(x).__name__} cannot be cached")


def decode(x: Any) -> Any:
    """The value :func:`encode` made ``x`` from; :class:`CacheError` for anything it cannot make."""
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    if isinstance(x, list):
        return [decode(v) for v in x]
    if not isinstance(x, dict):
        raise CacheError(f"unexpected {type(x).__name__}")
    tag = next((k for k in x if k.startswith("__")), None)
    if tag is None:
        return {k: decode(v) for k, v in x.items()}
    if tag not in _TAGS or set(x) != _TAGS[tag]:
        raise CacheError(f"unknown tag {tag[:40]!r} with keys {sorted(x)[:5]}")
    body = x[tag]
    if tag == "__tuple__":
        return tuple(decode(_list(body, tag)))
    if tag == "__dict__":
        pairs = _list(body, tag)
        if not all(isinstance(p, list) and len(p) == 2 for p in pairs):
            raise CacheError("__dict__: expected [key, value] pairs")
        out = {}
        for k, v in pairs:
            key = decode(k)
            if isinstance(key, (list, dict)):
                raise CacheError("__dict__: a key must be a number, string, tuple or null")
            out[key] = decode(v)
        return out
    if tag == "__ndarray__":
        return _array(body, x["dtype"], x["shape"])
    return _dataclass(body, x["fields"])


def _list(x: Any, where: str) -> list:
    if not isinstance(x, list):
        raise CacheError(f"{where}: expected a list")
    return x


def _array(data: Any, dtype: Any, shape: Any) -> np.ndarray:
    if dtype not in ARRAY_DTYPES:
        raise CacheError(f"__ndarray__: dtype {str(dtype)[:40]!r} is not allowed")
    if not (isinstance(shape, list) and all(isinstance(n, int) and not isinstance(n, bool) and n >= 0
                                            for n in shape)):
        raise CacheError("__ndarray__: bad shape")
    try:
        arr = np.array(data, dtype=dtype)
    except (TypeError, ValueError, OverflowError) as exc:
        raise CacheError(f"__ndarray__: {str(exc)[:80]}") from None
    if arr.size != math.prod(shape) or (arr.size and list(arr.shape) != shape):
        raise CacheError(f"__ndarray__: data of shape {arr.shape} for shape {tuple(shape)}")
    return arr.reshape(shape)


def _dataclass(name: Any, fields: Any) -> Any:
    cls = _DATACLASSES.get(name) if isinstance(name, str) else None
    if cls is None:
        raise CacheError(f"__dataclass__: {str(name)[:40]!r} is not an allowed class")
    if not isinstance(fields, dict):
        raise CacheError(f"{name}: fields must be an object")
    init = {f.name: f for f in dataclasses.fields(cls) if f.init}
    required = {n for n, f in init.items()
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    if not required <= set(fields) <= set(init):
        raise CacheError(f"{name}: fields {sorted(set(fields) ^ set(init))[:5]} do not match the class")
    try:
        return cls(**{k: decode(v) for k, v in fields.items()})
    except CacheError:
        raise
    except (TypeError, ValueError) as exc:
        raise CacheError(f"{name}: {str(exc)[:80]}") from None


# ------------------------------------------------------------------ files
def _canonical(payload: Any) -> bytes:
    return json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()


def write_entry(path: Path, signature: dict, payload: Any, meta: dict | None = None) -> None:
    """Write ``payload`` (any value :func:`encode` accepts) with ``signature`` to ``path``,
    atomically (a run killed mid-write leaves the old file or none, never half a file)."""
    data = encode(payload)
    doc = {"format": FORMAT, "version": VERSION, "signature": encode(signature),
           "sha256": hashlib.sha256(_canonical(data)).hexdigest(),
           "meta": encode({"written": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), **(meta or {})}),
           "payload": data}
    text = json.dumps(doc, allow_nan=True, separators=(",", ":"))
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)


def _constant(name: str) -> float:
    return {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}[name]


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise CacheError("duplicate key in an object")
    return out


def parse(text: str) -> Any:
    """Strict JSON (plus ``NaN``, ``Infinity``, ``-Infinity``; no duplicate keys)."""
    return json.loads(text, parse_constant=_constant, object_pairs_hook=_no_duplicates)


def load_entry(path: Path, accept: Iterable[dict], validate: Callable[[Any], None] | None = None) -> Any:
    """The payload of cache file ``path`` if it passes every check of the module docstring, with
    a signature in ``accept`` and ``validate(payload)`` not raising; :class:`CacheError` otherwise."""
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise CacheError(f"{size} bytes, more than a cache file can be ({MAX_FILE_BYTES})")
        doc = parse(path.read_text(encoding="utf-8"))
    except CacheError:
        raise
    except UnicodeDecodeError:
        raise CacheError("not JSON (not UTF-8 text)") from None
    except OSError as exc:
        raise CacheError(f"cannot be read ({type(exc).__name__})") from None
    except (ValueError, RecursionError) as exc:
        raise CacheError(f"not valid JSON ({str(exc)[:80]})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise CacheError("not an experiments cache file")
    if doc.get("version") != VERSION:
        raise CacheError(f"format version {str(doc.get('version'))[:20]}, this program reads version {VERSION}")
    if set(doc) != _FIELDS:
        raise CacheError(f"fields {sorted(set(doc) ^ _FIELDS)[:5]} missing or unexpected")
    try:
        signature = decode(doc["signature"])
    except (CacheError, RecursionError) as exc:
        raise CacheError(f"bad signature ({str(exc)[:80]})") from None
    if not any(signature == encode_free(s) for s in accept):
        raise CacheError("made by another plan (its signature differs from this run's)")
    try:
        ok = hashlib.sha256(_canonical(doc["payload"])).hexdigest() == doc["sha256"]
    except (ValueError, RecursionError):
        ok = False
    if not ok:
        raise CacheError("checksum mismatch (the file was changed or damaged)")
    try:
        payload = decode(doc["payload"])
        if validate is not None:
            validate(payload)
    except CacheError:
        raise
    except RecursionError:
        raise CacheError("invalid data (nested too deeply)") from None
    except Exception as exc:  # a validator's own failure on malformed data: the file is unusable, not a crash
        raise CacheError(f"invalid data ({type(exc).__name__}: {str(exc)[:80]})") from None
    return payload


def encode_free(signature: dict) -> Any:
    """``signature`` as it reads back from a file (tuples stay tuples, numpy scalars become Python)."""
    return decode(encode(signature))


def read_entry(path: Path, accept: Iterable[dict], validate: Callable[[Any], None] | None = None,
               then: str = "recomputed") -> Any:
    """:func:`load_entry`, or ``None`` after one line on stderr saying why the file is ignored
    and what happens instead (``then``). A missing file is ``None`` silently."""
    if not path.is_file():
        return None
    try:
        return load_entry(path, accept, validate)
    except CacheError as exc:
        warn_ignored(path, str(exc), then)
        return None


def warn_ignored(path: Path, why: str, then: str) -> None:
    """The one stderr line for an ignored cache file."""
    print(f"pomdp-planner: ignoring cache file {path}: {why}; {then}", file=sys.stderr, flush=True)


__all__ = ["FORMAT", "VERSION", "CacheError", "decode", "encode", "load_entry", "parse", "read_entry", "register",
           "warn_ignored", "write_entry"]
