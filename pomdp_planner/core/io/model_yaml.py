"""YAML model files (schema in docs/models.md).

Field names are fixed so that files written by others load::

    name: tracking_s3_info
    discount: 0.99
    states: 3            # a count or a list of names; same for actions, observations
    actions: 3
    observations: 3
    transition:  [...]   # A x S x S, transition[a][i][j] = P(next j | prev i, action a)
    observation: [...]   # A x S x Z, observation[a][j][z] = P(z | next j, action a)
    reward: [...]        # S x A
    uncertainty: {function: renyi2 | shannon | none, weights: [...], epsilon: 0.001}

``transition`` and ``observation`` may also be text blocks or the sparse form
(:mod:`.matrix_text`). Instead of them, ``generator: {domain: tracking, S, A, q, x, y}`` or
``generator: {domain: grid, rows, cols, A, ...}`` (:mod:`~pomdp_planner.core.domains.grid`);
instead of ``reward``, ``reward_generator: {kind: tracking_comparison, c_a, c_p, c_d, k_r}`` or
``{kind: effort, cost}``. ``grid: {rows, cols, obstacles}`` records the grid of a grid model
(``metadata["grid"]``).
Every error is a :class:`~pomdp_planner.core.model.ModelError` of one line that starts with the
file name and the field.

A model file is untrusted input, so loading is bounded by design:

* the file is read by :func:`~pomdp_planner.core.io.file_text.read_model_text` (a regular UTF-8
  file of at most ``MAX_MODEL_FILE_BYTES``);
* it is parsed by :class:`ModelLoader`, a safe loader that refuses what the schema never needs:
  anchors and aliases (``&a``, ``*a``: an alias bomb expands a few hundred bytes into gigabytes),
  nesting deeper than :data:`MAX_YAML_DEPTH` (the deepest field, ``transition``, needs 4),
  integers longer than :data:`MAX_INT_CHARS` characters, more than :data:`MAX_YAML_NODES` values
  (parsing time grows with them), and the tags PyYAML's safe loader would
  turn into bytes, dates, sets or ordered pairs. It composes without recursion, so no input
  reaches Python's recursion limit. Scalars are YAML 1.2's: ``1e-3`` is a number, while YAML
  1.1's other number forms (``0b11``, ``017``, ``0x1f``, ``1_000``, ``1:00``) and booleans
  (``yes``, ``no``) are strings, which a numeric field refuses naming it; a key given twice in
  one mapping is an error;
* values are typed strictly: a number is an int or a float, never a bool or a string
  (``discount: "0.5"`` is an error); a count (``states``, ``generator.S``) is an integer, never
  a float (``S: 3.9`` and ``S: 3.0`` are errors: counts are written as integers); NaN and
  infinity are refused wherever a number is expected;
* sizes are checked against ``MAX_MODEL_BYTES`` *before* anything is generated (and the sparse
  form's non-zeros before its matrices are built), and the declared
  ``states``/``actions``/``observations`` against the generator's sizes;
* an error message quotes at most ``MESSAGE_VALUE_CHARS`` characters of any value.
"""

from __future__ import annotations

import contextlib
import re
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import yaml
from yaml.composer import ComposerError
from yaml.constructor import ConstructorError, SafeConstructor
from yaml.events import (
    AliasEvent,
    MappingEndEvent,
    MappingStartEvent,
    ScalarEvent,
    SequenceEndEvent,
    SequenceStartEvent,
    StreamEndEvent,
)
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

from ..belief import start_belief
from ..checks import is_integer
from ..domains.grid import GridLayout, check_grid_size, effort_reward, grid_observations, grid_transitions
from ..domains.tracking import comparison_reward, tracking_observations, tracking_transitions
from ..errors import prefixed
from ..model import (
    MAX_REWARD_MAGNITUDE,
    POMDP,
    ModelError,
    as_count,
    as_number,
    check_model_size,
    kind_of,
    short_repr,
)
from ..sparse import SparseStack
from .cassandra import load_pomdp_file
from .file_text import read_model_text
from .matrix_text import dense_block, dense_text, is_block_list, is_sparse_form, sparse_matrices, sparse_text

KNOWN_FIELDS = {
    "name", "discount", "states", "actions", "observations", "transition", "observation",
    "reward", "uncertainty", "generator", "reward_generator", "description", "start", "grid",
}
#: The fields of each generator domain.
GENERATOR_FIELDS = {"tracking": {"domain", "S", "A", "q", "x", "y"},
                    "grid": {"domain", "rows", "cols", "A", "move", "detection", "accuracy", "obstacles", "sensor",
                             "fov"}}
#: The fields of each reward generator.
REWARD_GENERATOR_FIELDS = {"tracking_comparison": {"kind", "c_a", "c_p", "c_d", "k_r"}, "effort": {"kind", "cost"}}
GRID_FIELDS = {"rows", "cols", "obstacles"}
#: A model with more matrix entries than this is exported with text blocks instead of nested lists.
EXPORT_LIST_MAX_VALUES = 20_000
UNCERTAINTY_FIELDS = {"function", "weights", "epsilon"}
#: Deepest nesting of collections accepted in a model file (the schema needs 4).
MAX_YAML_DEPTH = 16
#: Longest integer literal accepted (characters); longer ones cannot be a meaningful count or value.
MAX_INT_CHARS = 64
#: Most YAML nodes (scalars and collections) in a model file. Parsing costs about 5 us of CPU
#: per node, so this bounds the time of any file to a few seconds (measured: 4.4 s of CPU for
#: a million); an explicit model with S = Z = 150 and A = 6 has 270 000 numbers.
MAX_YAML_NODES = 300_000

try:  # libyaml's event parser is about 5 times faster than PyYAML's pure-Python one
    from yaml import CSafeLoader as _BaseLoader
except ImportError:  # pragma: no cover - PyYAML built without libyaml
    from yaml import SafeLoader as _BaseLoader  # type: ignore[assignment]

_UNSAFE_TAGS = ("binary", "timestamp", "set", "omap", "pairs")
#: Implicit types that model files read as YAML 1.2 does, not as YAML 1.1 (PyYAML's default):
#: their YAML 1.1 resolvers are replaced below; ``<<`` (merge) and ``=`` (value) keys are plain strings.
_YAML11_RESOLVED = ("bool", "int", "float", "timestamp", "merge", "value")


class ModelLoader(_BaseLoader):  # type: ignore[misc, valid-type]
    """A safe YAML loader for model files: no anchors or aliases, bounded depth and integers,
    YAML 1.2 scalars, no duplicate keys.

    Composes nodes from the parser's events with an explicit stack (no recursion); refuses any
    anchor or alias at the event that carries it, so nothing is ever expanded. Scalars resolve as
    in YAML 1.2's core schema: a number is plain decimal (``3``, ``-0.5``, ``1e-3``, ``.inf``), a
    boolean is ``true`` or ``false``; YAML 1.1's other forms (``0b11``, ``017``, ``0x1f``,
    ``1_000``, ``1:00`` = 60, ``yes``/``no``, dates) stay strings, which a field expecting a number
    refuses (naming it). A key given twice in one mapping is an error (YAML forbids it; PyYAML
    would keep the last). ``!!binary``, ``!!timestamp``, ``!!set``, ``!!omap`` and ``!!pairs`` are
    refused like any unknown tag.
    """

    yaml_implicit_resolvers: ClassVar[dict] = {
        first: [(tag, regexp) for tag, regexp in resolvers
                if not tag.endswith(tuple(":" + t for t in _YAML11_RESOLVED))]
        for first, resolvers in _BaseLoader.yaml_implicit_resolvers.items()
    }
    yaml_constructors: ClassVar[dict] = {tag: fn for tag, fn in SafeConstructor.yaml_constructors.items()
                         if not (tag or "").endswith(tuple(":" + t for t in _UNSAFE_TAGS))}

    def construct_yaml_int(self, node):
        text = self.construct_scalar(node)
        if len(text) > MAX_INT_CHARS:
            raise ConstructorError(None, None, f"an integer of {len(text)} characters (at most {MAX_INT_CHARS})",
                                   node.start_mark)
        if not _INT_12.fullmatch(text):  # an explicit !!int in another notation
            raise ConstructorError(None, None, f"{short_repr(text)} is not a plain decimal integer", node.start_mark)
        return int(text)

    def construct_yaml_float(self, node):
        text = self.construct_scalar(node)
        if not (_FLOAT_12.fullmatch(text) or _INT_12.fullmatch(text) or _SPECIAL_12.fullmatch(text)):
            raise ConstructorError(None, None, f"{short_repr(text)} is not a plain decimal number", node.start_mark)
        return SafeConstructor.construct_yaml_float(self, node)

    def construct_mapping(self, node, deep=False):
        if isinstance(node, MappingNode):
            first_line: dict = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, ScalarNode):
                    continue  # a collection as a key: PyYAML refuses it as unhashable
                key = self.construct_object(key_node, deep=deep)
                if key in first_line:
                    raise ConstructorError(None, None, f"duplicate key {short_repr(key, 40)} (first given on line "
                                           f"{first_line[key] + 1}): give each field once", key_node.start_mark)
                first_line[key] = key_node.start_mark.line
        return SafeConstructor.construct_mapping(self, node, deep=deep)

    def get_single_node(self):
        self.get_event()  # stream start
        document = None
        if not self.check_event(StreamEndEvent):
            self.get_event()  # document start
            document = self._compose()
            self.get_event()  # document end
        if not self.check_event(StreamEndEvent):
            event = self.get_event()
            raise ComposerError(None, None, "expected a single document, but found another", event.start_mark)
        self.get_event()  # stream end
        return document

    def _compose(self):
        stack: list[list] = []  # [node, pending mapping key]
        root = None
        count = 0
        while True:
            event = self.get_event()
            if isinstance(event, AliasEvent) or getattr(event, "anchor", None) is not None:
                raise ComposerError(None, None, "anchors and aliases (&name, *name) are not allowed in model files",
                                    event.start_mark)
            if isinstance(event, (SequenceEndEvent, MappingEndEvent)):
                node = stack.pop()[0]
                node.end_mark = event.end_mark
                if not stack:
                    return node
                continue
            count += 1
            if count > MAX_YAML_NODES:
                raise ComposerError(None, None, f"more than {MAX_YAML_NODES:,} values (MAX_YAML_NODES)",
                                    event.start_mark)
            tag = event.tag
            if isinstance(event, ScalarEvent):
                if tag is None or tag == "!":
                    tag = self.resolve(ScalarNode, event.value, event.implicit)
                node = ScalarNode(tag, event.value, event.start_mark, event.end_mark, style=event.style)
            elif isinstance(event, (SequenceStartEvent, MappingStartEvent)):
                if len(stack) >= MAX_YAML_DEPTH:
                    raise ComposerError(None, None, f"nested deeper than {MAX_YAML_DEPTH} levels", event.start_mark)
                cls = SequenceNode if isinstance(event, SequenceStartEvent) else MappingNode
                if tag is None or tag == "!":
                    tag = self.resolve(cls, None, event.implicit)
                node = cls(tag, [], event.start_mark, None, flow_style=event.flow_style)
            else:  # pragma: no cover - the parser emits nothing else inside a document
                raise ComposerError(None, None, f"unexpected {type(event).__name__}", event.start_mark)
            if stack:
                parent = stack[-1]
                if isinstance(parent[0], SequenceNode):
                    parent[0].value.append(node)
                elif parent[1] is None:
                    parent[1] = node
                else:
                    parent[0].value.append((parent[1], node))
                    parent[1] = None
            else:
                root = node
            if isinstance(node, ScalarNode):
                if not stack:
                    return root
            else:
                stack.append([node, None])


_INT_12 = re.compile(r"[-+]?(?:0|[1-9][0-9]*)")
_FLOAT_12 = re.compile(r"[-+]?(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|[-+]?[0-9]+[eE][-+]?[0-9]+")
_SPECIAL_12 = re.compile(r"[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)")
ModelLoader.add_constructor("tag:yaml.org,2002:int", ModelLoader.construct_yaml_int)
ModelLoader.add_constructor("tag:yaml.org,2002:float", ModelLoader.construct_yaml_float)
# YAML 1.2 core schema scalars (the class docstring); an exponent without a decimal point
# (``1e-3``) is a number, as users expect (YAML 1.1 reads it as a string).
ModelLoader.add_implicit_resolver("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                                  list("tTfF"))
ModelLoader.add_implicit_resolver("tag:yaml.org,2002:int", re.compile(f"^(?:{_INT_12.pattern})$"),
                                  list("-+0123456789"))
ModelLoader.add_implicit_resolver("tag:yaml.org,2002:float",
                                  re.compile(f"^(?:{_FLOAT_12.pattern}|{_SPECIAL_12.pattern})$"),
                                  list("-+0123456789."))


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """One line: where (line, column) and what, from any PyYAML error."""
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    problem = getattr(exc, "problem", None) or getattr(exc, "reason", None)
    if not problem:
        problem = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    where = ""
    if mark is not None:
        where = f"line {mark.line + 1}, column {mark.column + 1}: "
    elif getattr(exc, "position", None) is not None:
        where = f"character {exc.position}: "
    context = getattr(exc, "context", None)
    text = f"{problem} ({context})" if context and getattr(exc, "problem", None) else problem
    return where + " ".join(str(text).split())[:200]


def parse_model_yaml(text: str, source: str = "<string>") -> Any:
    """Parse model-file YAML with :class:`ModelLoader`; errors are one-line ``ModelError``."""
    try:
        return yaml.load(text, Loader=ModelLoader)
    except yaml.YAMLError as exc:
        raise ModelError(f"{source}: not valid YAML for a model file: {_yaml_problem(exc)}") from None
    except (ValueError, RecursionError) as exc:  # e.g. int('9' * 5000) beyond Python's digit limit
        raise ModelError(f"{source}: not valid YAML for a model file ({type(exc).__name__}: "
                         f"{short_repr(str(exc), 120)})") from None


# ------------------------------------------------------------------------ typed fields
def _check_fields(mapping: dict, allowed: set[str], where: str) -> None:
    """Field names are strings from ``allowed`` (``where`` prefixes the message, e.g. ``generator: ``)."""
    for key in mapping:
        if not isinstance(key, str):
            raise ModelError(f"{where or 'top level: '}field names must be strings, got {kind_of(key)}")
    unknown = sorted(set(mapping) - allowed)
    if unknown:
        shown = ", ".join(short_repr(k, 40) for k in unknown[:5]) + (f", ... ({len(unknown)} in all)"
                                                                     if len(unknown) > 5 else "")
        raise ModelError(f"{where}unknown field(s) [{shown}]; known: {sorted(allowed)}")


def _mapping(value: Any, key: str, fields: str) -> dict:
    if not isinstance(value, dict):
        raise ModelError(f"{key}: expected a mapping {{{fields}}}, got {kind_of(value)}")
    return value


def _size(doc: dict, key: str) -> tuple[int | None, list[str] | None]:
    """A declared size: a count or a non-empty list of names (``None`` when absent)."""
    v = doc.get(key)
    if v is None:
        return None, None
    if isinstance(v, list):
        if not v:
            raise ModelError(f"{key}: expected a positive count or a non-empty list of names, got an empty list")
        return len(v), v  # the names are checked by POMDP
    if is_integer(v):
        return as_count(v, key), None
    raise ModelError(f"{key}: expected a positive count or a non-empty list of names, got {kind_of(v)}")


def _numbers(value: Any, field: str, ndim: int) -> np.ndarray:
    """A rectangular ``ndim``-dimensional nested list of numbers (strict types) as a float array."""
    if isinstance(value, np.ndarray):  # from code (model_from_dict of a built dict)
        if value.dtype.kind not in "iuf":
            raise ModelError(f"{field}: must be numbers, got an array of {value.dtype}")
        if value.ndim != ndim:
            raise ModelError(f"{field}: expected a {ndim}-dimensional nested list, got {value.ndim} dimensions "
                             f"(shape {value.shape})")
        return value.astype(float)
    level, shape = [value], []
    for depth in range(ndim):
        width = None
        for item in level:
            if not isinstance(item, (list, tuple)):
                got = f"{depth} dimension{'s' * (depth != 1)} ({kind_of(item)} inside)" if depth else kind_of(item)
                raise ModelError(f"{field}: expected a {ndim}-dimensional nested list, got {got}")
            if width is None:
                width = len(item)
            elif len(item) != width:
                raise ModelError(f"{field}: not a rectangular array (lists of {width} and of {len(item)} items "
                                 f"at depth {depth + 1})")
        shape.append(width or 0)
        if depth < ndim - 1:
            level = [x for item in level for x in item]
    flat = [x for item in level for x in item]
    for i, x in enumerate(flat):
        if type(x) not in (int, float):
            if isinstance(x, (list, tuple)):
                raise ModelError(f"{field}: expected a {ndim}-dimensional nested list, got more dimensions")
            idx = "".join(f"[{k}]" for k in np.unravel_index(i, shape))
            as_number(x, f"{field}{idx}")  # raises, naming the entry and what it is
    try:
        return np.array(flat, dtype=float).reshape(shape)
    except OverflowError:
        i = next(i for i, x in enumerate(flat) if type(x) is int and abs(x) > 1e308)
        idx = "".join(f"[{k}]" for k in np.unravel_index(i, shape))
        raise ModelError(f"{field}{idx}: number too large for a float ({short_repr(flat[i])})") from None


def _vector(value: Any, field: str) -> np.ndarray:
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise ModelError(f"{field}: must be a list of numbers, got {kind_of(value)}")
    return _numbers(value, field, 1)


def _reward_parameter(value: Any, field: str) -> float:
    """A parameter of ``reward_generator``: a finite number of magnitude at most ``MAX_REWARD_MAGNITUDE``
    (checked before the rewards are computed, so that none can overflow)."""
    x = as_number(value, field)
    if abs(x) > MAX_REWARD_MAGNITUDE:
        raise ModelError(f"{field}: magnitude must be at most {MAX_REWARD_MAGNITUDE:g} (MAX_REWARD_MAGNITUDE: "
                         f"searches and the bound LP must stay finite), got {x:g}")
    return x


def _text(value: Any, field: str) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise ModelError(f"{field}: must be a string, got {kind_of(value)}")
    return value if isinstance(value, str) else short_repr(value)


def _start(value: Any, S: int) -> str | list[float]:
    """``start``: a state name, ``uniform``, or ``S`` probabilities (checked by ``start_belief``)."""
    if isinstance(value, str):
        return value
    if isinstance(value, list):
        return _vector(value, "start").tolist()
    raise ModelError(f"start: expected a list of {S} probabilities, 'uniform' or a state name, got {kind_of(value)}")


# ------------------------------------------------------------------------ the schema
def model_from_dict(doc: Any, source: str = "<dict>") -> POMDP:
    """Build a :class:`POMDP` from a parsed YAML document; errors start with ``source``.

    The schema is checked here (fields, shapes, types of the matrices, generators); what every
    model needs (names, discount, weights, epsilon, probabilities, magnitudes) is checked once,
    by :class:`POMDP`, whose messages name the same fields."""
    with prefixed(source):
        return _model_from_dict(doc)


def _generated(doc: dict, S: int | None, A: int | None, Z: int | None) -> tuple[Any, Any, dict]:
    """``P``, ``O`` and metadata from ``generator``, after checking its fields and sizes (before allocating)."""
    if "transition" in doc or "observation" in doc:
        raise ModelError("generator: give either generator or transition/observation, not both")
    gen = _mapping(doc["generator"], "generator", "domain, ...")
    domain = gen.get("domain")
    if not isinstance(domain, str) or domain not in GENERATOR_FIELDS:
        raise ModelError(f"generator.domain: one of {', '.join(sorted(GENERATOR_FIELDS))}, got {kind_of(domain)}")
    _check_fields(gen, GENERATOR_FIELDS[domain], "generator: ")
    if domain == "grid":
        return _grid_generated(gen, S, A, Z)
    for key in ("S", "A", "q"):
        if key not in gen:
            raise ModelError(f"generator.{key}: missing")
    gS, gA = as_count(gen["S"], "generator.S"), as_count(gen["A"], "generator.A")
    q = as_number(gen["q"], "generator.q")
    for key, n, got, src in (("states", S, gS, "S"), ("actions", A, gA, "A"), ("observations", Z, gS, "S")):
        if n is not None and n != got:
            raise ModelError(f"{key}: declares {n} but generator.{src} is {got}")
    check_model_size(gS, gA, gS, "generator")
    gx = None if gen.get("x") is None else _vector(gen["x"], "generator.x")
    gy = None if gen.get("y") is None else _vector(gen["y"], "generator.y")
    return tracking_transitions(gS, gA, gx, gy), tracking_observations(gS, gA, q), {}


def _grid_generated(gen: dict, S: int | None, A: int | None, Z: int | None) -> tuple[Any, Any, dict]:
    """The grid domain's ``P`` and ``O`` (:mod:`~pomdp_planner.core.domains.grid`)."""
    for key in ("rows", "cols", "A"):
        if key not in gen:
            raise ModelError(f"generator.{key}: missing")
    layout = GridLayout(gen["rows"], gen["cols"], gen.get("obstacles") or [])
    gA = as_count(gen["A"], "generator.A")
    for key, n, got in (("states", S, layout.S), ("actions", A, gA), ("observations", Z, layout.S + 1)):
        if n is not None and n != got:
            raise ModelError(f"{key}: declares {n} but the grid generator gives {got}")
    check_grid_size(layout, gA)
    kw = {k: gen[k] for k in ("detection", "accuracy", "sensor", "fov") if gen.get(k) is not None}
    P = grid_transitions(layout, gA, gen.get("move", 0.2))
    O = grid_observations(layout, gA, **kw)
    return P, O, {"grid": layout.metadata()}


def _matrix(doc: dict, key: str, A: int | None, rows: int | None, cols: int | None, rows_key: str,
            cols_key: str) -> np.ndarray | SparseStack:
    """``transition`` or ``observation`` in any of its forms (:mod:`.matrix_text`)."""
    value = doc[key]
    if is_sparse_form(value):
        return sparse_matrices(value, key, A, rows, cols, rows_key, cols_key)
    if is_block_list(value):
        mats = [dense_block(x, f"{key}[{a}]", cols) if isinstance(x, str) else _numbers(x, f"{key}[{a}]", 2)
                for a, x in enumerate(value)]
        shapes = {m.shape for m in mats}
        if len(shapes) != 1:
            raise ModelError(f"{key}: the matrices of the actions have different shapes {sorted(shapes)}")
        return np.stack(mats)
    return _numbers(value, key, 3)


def _grid_field(value: Any, S: int) -> dict:
    """``grid: {rows, cols, obstacles}``: the grid of a grid model, whose free cells are its ``S`` states."""
    grid = _mapping(value, "grid", "rows, cols, obstacles")
    _check_fields(grid, GRID_FIELDS, "grid: ")
    for key in ("rows", "cols"):
        if key not in grid:
            raise ModelError(f"grid.{key}: missing")
    layout = GridLayout(grid["rows"], grid["cols"], grid.get("obstacles") or [])
    if layout.S != S:
        raise ModelError(f"grid: a {layout.rows} x {layout.cols} grid with {len(layout.obstacles())} obstacles has "
                         f"{layout.S} free cells, but the model has {S} states")
    return layout.metadata()


def _reward(doc: dict, S: int, A: int, metadata: dict) -> np.ndarray:
    if "reward_generator" in doc:
        if "reward" in doc:
            raise ModelError("reward_generator: give either reward or reward_generator, not both")
        rg = _mapping(doc["reward_generator"], "reward_generator", "kind, ...")
        kind = rg.get("kind")
        if not isinstance(kind, str) or kind not in REWARD_GENERATOR_FIELDS:
            raise ModelError(f"reward_generator.kind: one of {', '.join(sorted(REWARD_GENERATOR_FIELDS))}, "
                             f"got {kind_of(kind)}")
        _check_fields(rg, REWARD_GENERATOR_FIELDS[kind], "reward_generator: ")
        metadata["reward_generator"] = dict(rg)
        if kind == "effort":
            cost = rg.get("cost")
            if cost is not None:
                cost = [_reward_parameter(c, f"reward_generator.cost[{k}]") for k, c in enumerate(cost)] \
                    if isinstance(cost, list) else _reward_parameter(cost, "reward_generator.cost")
            return effort_reward(S, A, cost)
        kw = {k: _reward_parameter(v, f"reward_generator.{k}") for k, v in rg.items() if k != "kind"}
        return comparison_reward(S, A, **kw)
    if "reward" in doc:
        if isinstance(doc["reward"], str):
            return dense_block(doc["reward"], "reward", A)
        return _numbers(doc["reward"], "reward", 2)
    raise ModelError("reward: missing (give reward or reward_generator)")


def _model_from_dict(doc: Any) -> POMDP:
    if not isinstance(doc, dict):
        raise ModelError(f"top level: expected a mapping of fields, got {kind_of(doc)}")
    _check_fields(doc, KNOWN_FIELDS, "")
    if "discount" not in doc:
        raise ModelError("discount: missing")
    S, state_names = _size(doc, "states")
    A, action_names = _size(doc, "actions")
    Z, obs_names = _size(doc, "observations")
    metadata: dict = {}
    if "generator" in doc:
        P, O, extra = _generated(doc, S, A, Z)
        metadata["generator"] = dict(doc["generator"])
        metadata.update(extra)
    else:
        for key in ("transition", "observation"):
            if key not in doc:
                raise ModelError(f"{key}: missing (give transition and observation, or generator)")
        P = _matrix(doc, "transition", A, S, S, "states", "states")
        A_P, S_P = P.shape[0], P.shape[1]
        O = _matrix(doc, "observation", A_P, S_P, Z, "states", "observations")
        sparse_nnz = sum(M.nnz for M in (P, O) if isinstance(M, SparseStack))
        if sparse_nnz:
            check_model_size(S_P, A_P, O.shape[2], "model", nnz=sparse_nnz + sum(
                int(np.prod(M.shape)) for M in (P, O) if not isinstance(M, SparseStack)))
    for key, n, got in (("states", S, P.shape[1]), ("actions", A, P.shape[0]), ("observations", Z, O.shape[2])):
        if n is not None and n != got:
            raise ModelError(f"{key}: declares {n} but the matrices have {got}")
    r = _reward(doc, P.shape[1], P.shape[0], metadata)
    unc = doc.get("uncertainty")
    unc = {"function": "none"} if unc is None else _mapping(unc, "uncertainty", "function, weights, epsilon")
    _check_fields(unc, UNCERTAINTY_FIELDS, "uncertainty: ")
    func = unc.get("function", "none")
    weights = unc.get("weights")
    if func != "none" and weights is None:
        raise ModelError("uncertainty.weights: missing (one weight per action)")
    if "start" in doc:
        metadata["start"] = _start(doc["start"], P.shape[1])
    if "description" in doc:
        metadata["description"] = _text(doc["description"], "description")
    if "grid" in doc:
        if "grid" in metadata:
            raise ModelError("grid: the grid generator gives the grid; give grid only with explicit matrices")
        metadata["grid"] = _grid_field(doc["grid"], P.shape[1])
    model = POMDP(
        P=P, O=O, r=r, gamma=doc["discount"], uncertainty=func, w=weights, epsilon=unc.get("epsilon"),
        name=doc.get("name", "pomdp"), state_names=state_names, action_names=action_names,
        observation_names=obs_names, metadata=metadata,
    )
    start_belief(model)  # validates 'start' now (ModelError naming the field), not at first use
    return model


def load_model(path: str | Path, field: str | None = None) -> POMDP:
    """Load a YAML model file (or a Cassandra ``.POMDP`` file, by extension). Every error is one
    :class:`ModelError` that starts with the file name (after ``field``, the parameter or option
    that named the file, if given); nothing re-wraps it."""
    path = Path(path)
    with prefixed(field) if field else contextlib.nullcontext():
        if path.suffix.lower() == ".pomdp":
            return load_pomdp_file(path)
        text = read_model_text(path, "model file")
        return model_from_dict(parse_model_yaml(text, str(path)), source=str(path))


class TextBlock(str):
    """A string that :func:`dump_model` writes as a YAML literal block (``|``)."""


def _matrices_out(model: POMDP, which: str) -> Any:
    """``transition`` or ``observation`` as written by :func:`model_to_dict`: the sparse form for a
    sparse model, text blocks for a large dense one, nested lists otherwise."""
    if model.sparse:
        stack = model.P_csr if which == "P" else model.O_csr
        return {"sparse": [sparse_text(stack, a) for a in range(model.A)]}
    M = model.P if which == "P" else model.O
    if model.A * model.S * (model.S + model.Z) > EXPORT_LIST_MAX_VALUES:
        return [dense_text(M[a]) for a in range(model.A)]
    return M.tolist()


def model_to_dict(model: POMDP) -> dict:
    """The explicit (matrix) form of a model (:func:`dump_model` writes it; ``yaml.safe_dump`` too,
    the text blocks then as quoted strings)."""
    def names_or_count(names, n):
        return list(names) if names is not None else n

    doc: dict = {
        "name": model.name,
        "discount": model.gamma,
        "states": names_or_count(model.state_names, model.S),
        "actions": names_or_count(model.action_names, model.A),
        "observations": names_or_count(model.observation_names, model.Z),
        "transition": _matrices_out(model, "P"),
        "observation": _matrices_out(model, "O"),
        "reward": dense_text(model.r) if model.r.size > EXPORT_LIST_MAX_VALUES else model.r.tolist(),
        "uncertainty": {"function": model.uncertainty.name, "weights": model.w.tolist(),
                        "epsilon": model.epsilon},
    }
    if "start" in model.metadata:
        doc["start"] = model.metadata["start"]
    if "grid" in model.metadata:
        doc["grid"] = dict(model.metadata["grid"])
    return doc


class _Dumper(getattr(yaml, "CSafeDumper", yaml.SafeDumper)):  # type: ignore[misc]
    """``yaml.safe_dump`` with :class:`TextBlock` strings as literal blocks."""


_Dumper.add_representer(TextBlock, lambda dumper, data: dumper.represent_scalar("tag:yaml.org,2002:str", str(data),
                                                                                style="|"))


def dump_model(model: POMDP) -> str:
    """The YAML text of ``model`` in explicit form (:func:`model_to_dict`), text blocks as literal blocks."""
    doc = model_to_dict(model)
    if isinstance(doc["reward"], str):
        doc["reward"] = TextBlock(doc["reward"])
    for key in ("transition", "observation"):
        value = doc[key]
        if isinstance(value, dict):
            value["sparse"] = [TextBlock(x) for x in value["sparse"]]
        elif value and isinstance(value[0], str):
            doc[key] = [TextBlock(x) for x in value]
    return yaml.dump(doc, Dumper=_Dumper, sort_keys=False, default_flow_style=None)


def save_model(model: POMDP, path: str | Path) -> None:
    """Write ``model`` as a YAML model file in explicit form."""
    Path(path).write_text(dump_model(model))
