"""Mutation fuzzer for model files: hostile YAML and ``.POMDP`` files for the loader.

Development tooling (``tools/`` of the source tree, not installed). Seeds are the shipped models
(``config/models/*.yaml``, found through ``core/io/paths.py``), the same models in explicit matrix form
(``core.io.model_yaml.model_to_dict``) and their Cassandra exports (``core.io.cassandra.
export_pomdp``). Each case applies one mutation (:data:`MUTATIONS`) to one seed: byte flips,
truncation, binary junk, deleted or repeated spans, other text encodings, huge or non-finite
numbers, size fields blown up, structured type swaps of a YAML value (on the parsed tree, then
re-dumped), YAML alias bombs and deep nesting, ``.POMDP`` header bombs, long tokens, shuffled
lines; and values at the edge of what the bound LP and the search take (huge weights, rewards
and reward-generator parameters, subnormal epsilon, discount 1), YAML 1.1 number forms and
non-ASCII digits, duplicate keys, ``.POMDP`` rows off 1 by less and more than pomdp-solve's 1e-5.

The loader (``core.io.model_yaml.load_model``) must end every case in a clean ``ModelError``
(one line, naming the file, at most :data:`MAX_MESSAGE` characters beyond the path) or a valid
model, and a valid model must be one the entry points handle (:func:`exercise`: the gate, a
search, the bound LP, a simulation end with finite values or a one-line refusal; a warning counts
as a failure). This script writes the corpus (never committed) and runs the loader over it in
this process, each case under a time limit and the whole run under an address-space limit, and
prints the count of each outcome::

    python -m tools.fuzz_models --count 5000 --out /tmp/fuzz        # write, then run
    python -m tools.fuzz_models --run-only /tmp/fuzz                 # run only

``--run-only`` runs whichever ``pomdp_planner`` is importable (e.g. ``PYTHONPATH=<old checkout>``
to measure an old loader on the same corpus). ``test/test_fuzz_models.py`` draws the same
mutations with hypothesis.
"""

from __future__ import annotations

import argparse
import json
import random
import re
import resource
import signal
import sys
import time
import warnings
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

#: A clean error message is one line of at most this many characters after the file path.
MAX_MESSAGE = 400

# ------------------------------------------------------------------------------------ seeds


#: Shipped models with more states seed the fuzzer as shipped only (a generator file).
SEED_MAX_STATES = 200


def seeds(models_dir: Path | None = None) -> list[tuple[str, str, bytes]]:
    """``(name, kind, content)`` of every seed: each shipped YAML model as shipped, in explicit
    matrix form, and as a ``.POMDP`` export (``kind`` is ``"yaml"`` or ``"pomdp"``); a grid model
    stored sparse, so that the YAML sparse form and ``.POMDP`` element lines are fuzzed too; models
    over :data:`SEED_MAX_STATES` states as shipped only. The shipped models are those of the folder
    the path resolver finds them in (installed or a checkout)."""
    from pomdp_planner.core.io.cassandra import export_pomdp
    from pomdp_planner.core.io.model_yaml import load_model, model_to_dict
    from pomdp_planner.core.io.paths import shipped_model_path

    if models_dir is None:
        models_dir = shipped_model_path("tracking_s3_info").parent

    out = []
    for path in sorted(models_dir.glob("*.yaml")):
        model = load_model(path)
        out.append((path.stem, "yaml", path.read_bytes()))
        if model.S > SEED_MAX_STATES:  # its generator file only: every case would parse a large file
            continue
        if "grid" in model.metadata:  # a grid stored sparse: the YAML sparse form, .POMDP element lines
            model = model.replace(storage="sparse")
        explicit = yaml.safe_dump(model_to_dict(model), sort_keys=False, default_flow_style=None)
        out.append((path.stem + "_explicit", "yaml", explicit.encode()))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out.append((path.stem, "pomdp", export_pomdp(model).encode()))
    return out


# -------------------------------------------------------------------------------- mutations
Mutation = Callable[[bytes, str, random.Random], bytes]

#: Replacements for a number: huge, non-finite, not numbers at all.
ODD_NUMBERS = [
    "9" * 400, "9" * 5000, "1" + "0" * 30, "1.0e999", "-1.0e999", "1e999", "1e-400", ".nan", ".inf", "-.inf",
    "nan", "inf", "0x" + "f" * 40, "-0", "3.9", '"0.5"', "'7'", "true", "null", "[]", "{}", "~", "1_000",
    "0o17", "1:30", "2024-01-01", "-1", "0", "1e308", "4.9e-324",
]
#: Replacements for a size field (count of states, actions, observations, generator S/A).
ODD_SIZES = ["0", "-1", "1", "2", "3.9", "3.0", "5000", "20000", "100000", "1000000000", "9" * 40, "1e9", '"3"',
             "true", "null", "[3]"]
#: Values swapped into a parsed YAML tree.
ODD_VALUES: list[Any] = [
    None, True, False, 0, -1, 1.5, 3.9, "0.5", "abc", "", [], {}, [1, 2], {"a": 1}, [[1, [2]]], 10**400,
    -(10**30), float("nan"), float("inf"), float("-inf"), "x" * 3000, [None], [True, False], {"function": [1]},
    {"domain": "tracking", "S": 5000, "A": 3, "q": 0.7}, {"1": 2, "3": [4]}, [[["0.5"]]], "uniform",
]
_NUMBER = re.compile(rb"-?\d+(\.\d+)?([eE][+-]?\d+)?")
_SIZE = re.compile(rb"\b(states|actions|observations|S|A)(\s*:\s*)(\d+)")
_FIELDS = ["name", "description", "start", "states", "actions", "observations", "discount", "reward",
           "transition", "uncertainty", "generator"]


def _span(data: bytes, rnd: random.Random) -> tuple[int, int]:
    i = rnd.randrange(len(data) + 1)
    return i, min(len(data), i + rnd.randint(1, 200))


def flip_bytes(data: bytes, kind: str, rnd: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rnd.randint(1, 8)):
        i = rnd.randrange(len(b))
        b[i] ^= 1 << rnd.randrange(8)
    return bytes(b)


def truncate(data: bytes, kind: str, rnd: random.Random) -> bytes:
    return data[:rnd.randrange(len(data))]


def insert_junk(data: bytes, kind: str, rnd: random.Random) -> bytes:
    i = rnd.randrange(len(data) + 1)
    junk = rnd.choice([rnd.randbytes(rnd.randint(1, 64)), b"\x00" * rnd.randint(1, 8), b"\xff\xfe", b"\xc3\x28",
                       b"\xe2\x82", "é€😀".encode(), b"\t:\t-\t[", b"\r\n\r"])
    return data[:i] + junk + data[i:]


def delete_span(data: bytes, kind: str, rnd: random.Random) -> bytes:
    i, j = _span(data, rnd)
    return data[:i] + data[j:]


def repeat_span(data: bytes, kind: str, rnd: random.Random) -> bytes:
    i, j = _span(data, rnd)
    return data[:j] + data[i:j] * rnd.randint(1, 50) + data[j:]


def reencode(data: bytes, kind: str, rnd: random.Random) -> bytes:
    text = data.decode("utf-8", errors="replace")
    choice = rnd.randrange(4)
    if choice == 0:
        return text.encode(rnd.choice(["utf-16", "utf-32", "utf-16-be"]))
    if choice == 1:
        return "\ufeff".encode() + data
    if choice == 2:
        i = rnd.randrange(len(text) + 1)
        return (text[:i] + "ÿé" + text[i:]).encode("latin-1", errors="replace")
    return data.replace(b"\n", b"\r", rnd.randint(1, 50))


def _replace(data: bytes, pattern: re.Pattern, group: int, choices: list[str], rnd: random.Random) -> bytes | None:
    """``data`` with group ``group`` of one match of ``pattern`` replaced by one of ``choices``
    (``None`` if nothing matches)."""
    matches = list(pattern.finditer(data))
    if not matches:
        return None
    m = rnd.choice(matches)
    return data[:m.start(group)] + rnd.choice(choices).encode() + data[m.end(group):]


def odd_number(data: bytes, kind: str, rnd: random.Random) -> bytes:
    return _replace(data, _NUMBER, 0, ODD_NUMBERS, rnd) or data


def blow_size(data: bytes, kind: str, rnd: random.Random) -> bytes:
    return _replace(data, _SIZE, 3, ODD_SIZES, rnd) or odd_number(data, kind, rnd)


def shuffle_lines(data: bytes, kind: str, rnd: random.Random) -> bytes:
    lines = data.split(b"\n")
    i, j = sorted(rnd.randrange(len(lines) + 1) for _ in range(2))
    part = lines[i:j]
    rnd.shuffle(part)
    return b"\n".join(lines[:i] + part + lines[j:])


def _paths(doc: Any) -> list[tuple]:
    """Every path (tuple of keys/indices) into a parsed YAML tree, root excluded."""
    out: list[tuple] = []
    stack: list[tuple[tuple, Any]] = [((), doc)]
    while stack:
        path, node = stack.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for k, v in items:
            out.append((*path, k))
            stack.append(((*path, k), v))
    return out


def _set(doc: Any, path: tuple, value: Any) -> None:
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value


def swap_value(data: bytes, kind: str, rnd: random.Random) -> bytes:
    """Structured: replace one value of the parsed tree with a value of another type, re-dump."""
    doc = yaml.safe_load(data)
    paths = _paths(doc)
    if not paths:
        return data
    path = rnd.choice(paths)
    op = rnd.randrange(10)
    if op == 0 and isinstance(doc, dict):  # delete a field
        node = doc
        for k in path[:-1]:
            node = node[k]
        del node[path[-1]]
    elif op == 1:  # an unknown field, possibly with a non-string name
        doc[rnd.choice(["colour", 7, None, 1.5, "x" * 500, True])] = 1
    else:
        _set(doc, path, rnd.choice(ODD_VALUES))
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=200).encode()


def alias_bomb(data: bytes, kind: str, rnd: random.Random) -> bytes:
    """A billion-laughs value (nested anchors) appended as a field: a later duplicate key wins."""
    levels, width = rnd.randint(3, 9), rnd.randint(2, 10)
    parts = [f"&a0 [{', '.join(['lol'] * width)}]"]
    parts += [f"&a{k} [{', '.join([f'*a{k - 1}'] * width)}]" for k in range(1, levels)]
    value = f"[{', '.join(parts)}]" if rnd.random() < 0.5 else f"&top [{', '.join(parts)}]"
    return data + f"\n{rnd.choice(_FIELDS)}: {value}\n".encode()


def deep_nesting(data: bytes, kind: str, rnd: random.Random) -> bytes:
    n = rnd.choice([20, 100, 500, 5000, 50000])
    value = "[" * n + "1" + "]" * n if rnd.random() < 0.5 else "{a: " * n + "1" + "}" * n
    return data + f"\n{rnd.choice(_FIELDS)}: {value}\n".encode()


def pomdp_bomb(data: bytes, kind: str, rnd: random.Random) -> bytes:
    """``.POMDP``: a blown-up header followed by cheap entries that touch every cell."""
    n = rnd.choice(["200", "2000", "20000", "1000000", "9" * 30])
    head = rnd.choice(["states", "actions", "observations"])
    text = re.sub(rb"^" + head.encode() + rb":.*$", f"{head}: {n}".encode(), data, count=1, flags=re.M)
    return text + rnd.choice([b"\nT: * uniform\n", b"\nO: * uniform\n", b"\nstart: uniform\n",
                              b"\nR: * : * : 0 : 0 1.0\n", b"\nT: * : * : * 0.5\n"])


def long_token(data: bytes, kind: str, rnd: random.Random) -> bytes:
    i = rnd.randrange(len(data) + 1)
    tok = rnd.choice([b"a" * 100000, b"9" * 100000, b"#" + b"x" * 100000,
                      b"\n# pomdp_planner: " + b"[" * 100000 + b"\n",
                      b'\n# pomdp_planner: {"name": "' + b"n" * 100000 + b'"}\n',
                      b'\n# pomdp_planner: {"name": "a\\nb", "states": [[1]]}\n'])
    return data[:i] + tok + data[i:]


#: Values that make the bound LP or the search non-finite unless refused at load time, or that
#: test the edges of what is accepted (weights, epsilon, rewards, reward-generator parameters, discount).
HOSTILE_VALUES: dict[tuple, list[Any]] = {
    ("uncertainty", "weights"): [[1e308, 1, 1], [1e9, 1, 1], [1e10, 0, 0], 1e300, [-1e308, 1, 1]],
    ("uncertainty", "epsilon"): [1e-320, 5e-324, 1e-300, 1e-12, 0.0, -1e-3],
    ("reward_generator", "c_a"): [1e308, -1e308, 1e12, 1e13],
    ("reward_generator", "k_r"): [1e308, 1e-320],
    ("discount",): [1, 1.0, 0, 0.999999, 1.0000001],
}
#: Replacements for a number that only YAML 1.1 (or no YAML) reads as one.
YAML11_NUMBERS = ["0b11", "1:00", "017", "1_000", "0x1f", "0o7", "1:30.5", "1_0.5", "３", "٣", "+0b1", "00"]


def hostile_value(data: bytes, kind: str, rnd: random.Random) -> bytes:
    """Structured: set one field to a value at or beyond what the LP and the search can take."""
    doc = yaml.safe_load(data)
    if not isinstance(doc, dict):
        return data
    path = rnd.choice(list(HOSTILE_VALUES))
    value = rnd.choice(HOSTILE_VALUES[path])
    if path[0] == "reward_generator" and "reward_generator" not in doc:
        doc.pop("reward", None)
        doc["reward_generator"] = {"kind": "tracking_comparison"}
    node = doc
    for key in path[:-1]:
        node = node.setdefault(key, {}) if isinstance(node, dict) else node
    if isinstance(node, dict):
        node[path[-1]] = value
    if rnd.random() < 0.3 and isinstance(doc.get("reward"), list) and doc["reward"]:  # one huge reward
        row = rnd.choice(doc["reward"])
        if isinstance(row, list) and row:
            row[rnd.randrange(len(row))] = rnd.choice([1e308, -1e300, 1e12, -1e13])
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=200).encode()


def yaml11_number(data: bytes, kind: str, rnd: random.Random) -> bytes:
    """A number (or a size) written in a YAML 1.1 form, or with non-ASCII digits."""
    size = _replace(data, _SIZE, 3, YAML11_NUMBERS, rnd) if rnd.random() < 0.5 else None
    return size or _replace(data, _NUMBER, 0, YAML11_NUMBERS, rnd) or data


def duplicate_key(data: bytes, kind: str, rnd: random.Random) -> bytes:
    """A top-level field given twice (the second value differs), or a key repeated in a flow mapping."""
    lines = data.split(b"\n")
    top = [i for i, line in enumerate(lines) if re.match(rb"^[A-Za-z_]+:", line)]
    flow = [m for m in re.finditer(rb"\{([A-Za-z_]+): ", data)]
    if flow and rnd.random() < 0.4:
        m = rnd.choice(flow)
        return data[:m.end()] + b"1, " + m.group(1) + b": " + data[m.end():]
    if not top:
        return data
    i = rnd.choice(top)
    key = lines[i].split(b":", 1)[0]
    return b"\n".join([*lines[:i + 1], key + b": " + rnd.choice([b"0.5", b"3", b"x", b"[1, 2]"]), *lines[i + 1:]])


def row_drift(data: bytes, kind: str, rnd: random.Random) -> bytes:
    """``.POMDP``: scale one probability by ``1 + delta`` (inside and beyond pomdp-solve's 1e-5),
    or set the discount to 1 (a finite-horizon file)."""
    if rnd.random() < 0.2:
        return re.sub(rb"^discount:.*$", rnd.choice([b"discount: 1", b"discount: 1.0"]), data, count=1, flags=re.M)
    matches = [m for m in _NUMBER.finditer(data) if b"." in m.group(0) and 0.0 < float(m.group(0)) <= 1.0]
    if not matches:
        return data
    m = rnd.choice(matches)
    delta = rnd.choice([5e-7, -5e-7, 2e-6, 5e-6, -5e-6, 9e-6, 2e-5, -3e-5])
    return data[:m.start()] + repr(float(m.group(0)) * (1.0 + delta)).encode() + data[m.end():]


#: Every mutation, by name, with the kinds of seed it applies to.
MUTATIONS: dict[str, tuple[Mutation, tuple[str, ...]]] = {
    "flip_bytes": (flip_bytes, ("yaml", "pomdp")),
    "truncate": (truncate, ("yaml", "pomdp")),
    "insert_junk": (insert_junk, ("yaml", "pomdp")),
    "delete_span": (delete_span, ("yaml", "pomdp")),
    "repeat_span": (repeat_span, ("yaml", "pomdp")),
    "reencode": (reencode, ("yaml", "pomdp")),
    "odd_number": (odd_number, ("yaml", "pomdp")),
    "blow_size": (blow_size, ("yaml", "pomdp")),
    "shuffle_lines": (shuffle_lines, ("yaml", "pomdp")),
    "long_token": (long_token, ("yaml", "pomdp")),
    "swap_value": (swap_value, ("yaml",)),
    "alias_bomb": (alias_bomb, ("yaml",)),
    "deep_nesting": (deep_nesting, ("yaml",)),
    "pomdp_bomb": (pomdp_bomb, ("pomdp",)),
    "hostile_value": (hostile_value, ("yaml",)),
    "yaml11_number": (yaml11_number, ("yaml",)),
    "duplicate_key": (duplicate_key, ("yaml",)),
    "row_drift": (row_drift, ("pomdp",)),
}
#: The mutations that change values (rather than break the syntax): a model they leave valid is
#: also run through what the entry points do with it (:func:`exercise`).
VALUE_MUTATIONS = ("odd_number", "hostile_value", "yaml11_number", "duplicate_key", "row_drift", "swap_value")


def mutations_for(kind: str) -> list[str]:
    return [name for name, (_, kinds) in MUTATIONS.items() if kind in kinds]


def mutate(seed: tuple[str, str, bytes], name: str, rnd: random.Random) -> bytes:
    """Apply mutation ``name`` to ``seed`` (``(name, kind, content)``), drawing from ``rnd``."""
    return MUTATIONS[name][0](seed[2], seed[1], rnd)


def write_corpus(out: Path, count: int, seed: int = 0) -> list[Path]:
    """Write ``count`` mutated files into ``out`` (``case_NNNNN_<mutation>.yaml|.POMDP``)."""
    out.mkdir(parents=True, exist_ok=True)
    pool = seeds()
    paths = []
    for i in range(count):
        rnd = random.Random(seed * 1_000_003 + i)
        s = rnd.choice(pool)
        name = rnd.choice(mutations_for(s[1]))
        path = out / f"case_{i:05d}_{name}.{'yaml' if s[1] == 'yaml' else 'POMDP'}"
        path.write_bytes(mutate(s, name, rnd))
        paths.append(path)
    return paths


# ----------------------------------------------------------------------------------- runner
class CaseTimeout(BaseException):
    """A case ran past its time limit (a BaseException, so no ``except Exception`` hides it)."""


def _on_alarm(signum, frame):  # pragma: no cover - signal handler
    raise CaseTimeout


#: Models larger than this (bytes of their matrices) are not exercised: a depth-2 search and the
#: assumption check of a large model take seconds, and they are what the size guards are for.
EXERCISE_MAX_BYTES = 2**20


def exercise(model: Any) -> None:
    """What the entry points do with a model ``check`` accepts: the gate (Assumption 1, the bound LP),
    a depth-2 search, the bound LP itself (discount < 1) and a 3-step simulation of ``bnb``. Raises
    ``FloatingPointError`` on a value that is not finite; the core's one-line refusals
    (``InputError``) pass through as they are."""
    import numpy as np

    from pomdp_planner.core.bounds import solve_bounds
    from pomdp_planner.core.gate import build_planner
    from pomdp_planner.core.model import model_bytes
    from pomdp_planner.core.simulate import simulate

    if model_bytes(model.S, model.A, model.Z) > EXERCISE_MAX_BYTES:
        return
    res = build_planner(model).planner.search(np.full(model.S, 1.0 / model.S), 2)
    if not np.isfinite(res.value) or np.any(np.isinf(res.q_values)):
        raise FloatingPointError(f"search value {res.value}, Q {res.q_values.tolist()}")
    if model.gamma < 1.0:
        sol = solve_bounds(model, samples=50)
        if sol.feasible and not (np.all(np.isfinite(sol.g)) and np.all(np.isfinite(sol.h))):
            raise FloatingPointError("bound vectors not finite")
    ret = simulate(model, "bnb", 3, seed=0).discounted_return
    if not np.isfinite(ret):
        raise FloatingPointError(f"discounted return {ret}")


def classify(path: Path, load: Callable[[Path], Any], model_error: type,
             use: Callable[[Any], None] | None = None, input_error: type | None = None) -> tuple[str, str]:
    """``(outcome, detail)`` of loading ``path``: ``valid``, ``clean error``, ``bad message`` (a
    ModelError of several lines, too long or not naming the file), ``memory``, ``timeout`` or
    ``uncaught <Type>``. With ``use`` (e.g. :func:`exercise`), a valid model is then used: a
    refusal of one line (``input_error``) is still ``valid``, anything else ``unusable <Type>``."""
    try:
        model = load(path)
    except model_error as exc:
        msg = str(exc)
        if "\n" in msg or not msg.startswith(str(path)) or len(msg) > len(str(path)) + MAX_MESSAGE:
            return "bad message", msg[:200].replace("\n", "\\n")
        return "clean error", msg[len(str(path)):][:200]
    except MemoryError as exc:
        return "memory", str(exc)[:200]
    except RecursionError as exc:
        return "uncaught RecursionError", str(exc)[:200]
    except Exception as exc:
        return f"uncaught {type(exc).__name__}", str(exc)[:200].replace("\n", "\\n")
    if use is not None:
        try:
            use(model)
        except Exception as exc:
            if input_error is not None and isinstance(exc, input_error) and "\n" not in str(exc):
                return "valid", ""
            return f"unusable {type(exc).__name__}", str(exc)[:200].replace("\n", "\\n")
    return "valid", ""


def _vm_size() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


def run_corpus(paths: list[Path], timeout: float = 10.0, memory_limit: int = 2 * 2**30, load_only: bool = False
               ) -> dict:
    """Load every file and (unless ``load_only``) :func:`exercise` every valid model; returns counts
    per outcome, examples and the slowest cases. Warnings count as errors (except ``InputWarning``).

    Each case is stopped after ``timeout`` seconds (``SIGALRM``); the address space of this
    process is limited to its current size plus ``memory_limit`` bytes, so a runaway allocation
    ends in ``MemoryError`` instead of exhausting the machine.
    """
    from pomdp_planner.core.errors import InputError, InputWarning
    from pomdp_planner.core.io.model_yaml import load_model
    from pomdp_planner.core.model import ModelError

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = _vm_size() + memory_limit
    resource.setrlimit(resource.RLIMIT_AS, (limit if hard == resource.RLIM_INFINITY else min(limit, hard), hard))
    old = signal.signal(signal.SIGALRM, _on_alarm)
    counts: Counter = Counter()
    examples: dict[str, list[str]] = {}
    times: list[tuple[float, str, str]] = []
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a numpy warning is a finding, as an exception is
            warnings.simplefilter("ignore", InputWarning)  # a renormalised peer row: said on purpose
            for path in paths:
                t0 = time.perf_counter()
                signal.setitimer(signal.ITIMER_REAL, timeout)
                try:
                    outcome, detail = classify(path, load_model, ModelError, None if load_only else exercise,
                                               InputError)
                except CaseTimeout:
                    outcome, detail = "timeout", ""
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
                dt = time.perf_counter() - t0
                counts[outcome] += 1
                times.append((dt, path.name, outcome))
                if outcome not in ("valid", "clean error"):
                    examples.setdefault(outcome, [])
                    if len(examples[outcome]) < 3:
                        examples[outcome].append(f"{path.name}: {detail}")
    finally:
        signal.signal(signal.SIGALRM, old)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    times.sort(reverse=True)
    return {"counts": dict(counts.most_common()), "examples": examples,
            "slowest": [f"{t:.2f} s {name} ({outcome})" for t, name, outcome in times[:5]],
            "total_time": sum(t for t, _, _ in times)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--out", type=Path, help="write the corpus into this folder, then run the loader over it")
    g.add_argument("--run-only", type=Path, metavar="DIR", help="run the loader over the files of DIR")
    p.add_argument("--count", type=int, default=5000, help="number of files to write (default 5000)")
    p.add_argument("--seed", type=int, default=0, help="corpus seed (default 0)")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds per case (default 10)")
    p.add_argument("--memory-limit", type=float, default=2.0, help="GiB of address space for the run (default 2)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--load-only", action="store_true", help="only load the files (do not exercise valid models)")
    args = p.parse_args(argv)
    if args.out is not None:
        paths = write_corpus(args.out, args.count, args.seed)
    else:
        paths = sorted(q for q in args.run_only.iterdir() if q.is_file())
    report = run_corpus(paths, args.timeout, int(args.memory_limit * 2**30), args.load_only)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{len(paths)} files, {report['total_time']:.1f} s")
    for outcome, n in report["counts"].items():
        print(f"  {n:6d}  {outcome}")
    for outcome, ex in report["examples"].items():
        print(f"{outcome}:")
        for line in ex:
            print(f"    {line}")
    print("slowest:")
    for line in report["slowest"]:
        print(f"    {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
