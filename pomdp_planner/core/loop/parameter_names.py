"""Which parameters given to a node it reports as unknown, with the closest declared name
("did you mean time_budget?"): the rule the nodes apply at start-up, without ROS. The node side
(``nodes/params.py``) collects what rclpy was given and declares; this module reads the ROS
command-line arguments and parameter files as rcl does (node patterns ``*`` and ``**``, nested
namespaces) and decides.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterator, Sequence
from pathlib import Path

import yaml

#: Parameters rclpy reads only on request (``qos_overriding_options``); a parameter file written for
#: many nodes may carry them, so they are not reported as unknown.
RCLPY_PARAMETER_PREFIXES = ("qos_overrides.",)
#: ``difflib`` similarity of the "did you mean" suggestion, and that of a near miss (a typo) for a
#: parameter given to every node (a wildcard section), which is reported only then.
SUGGEST_CUTOFF = 0.6
NEAR_MISS_CUTOFF = 0.85


# Where a parameter given to a node came from, as far as it matters for reporting it: by the
# node's name (its own section of a parameter file, also ``/**/<name>``, ``-p node:name:=value``,
# the node's own arguments or ``parameter_overrides``), to every node of the process
# (``-p name:=value`` on the command line), or to every node of the system (a wildcard section
# such as ``/**:``).
BY_NAME, TO_PROCESS, TO_ALL = 0, 1, 2


def _matches(pattern: str, fqn: str) -> bool:
    """rcl's node-name match: ``*`` is one name token, ``**`` any number of them."""
    tokens = [t for t in pattern.strip("/").split("/") if t]
    regex = "".join("(?:/[^/]+)*" if t == "**" else "/" + re.escape(t).replace(r"\*", "[^/]*") for t in tokens)
    return re.fullmatch(regex, fqn) is not None


def _pattern_scope(pattern: str) -> int:
    """A node pattern that ends in the node's name (``planner``, ``/ns/planner``, ``/**/planner``:
    that node in any namespace, as the shipped files write it) gives by name; one that ends in a
    wildcard (``/**``, ``/*``) gives to every node."""
    return TO_ALL if "*" in pattern.rstrip("/").rsplit("/", 1)[-1] else BY_NAME


def _flat(params: dict, prefix: str = "") -> Iterator[str]:
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _flat(value, name + ".")
        else:
            yield name


def _file_sections(doc, path: str = "") -> Iterator[tuple[str, dict]]:
    """``(node pattern, parameters)`` of each section of a parameter file (namespaces may nest)."""
    if not isinstance(doc, dict):
        return
    for key, value in doc.items():
        if not isinstance(value, dict):
            continue
        here = f"{path}/{str(key).strip('/')}"
        if isinstance(value.get("ros__parameters"), dict):
            yield here, value["ros__parameters"]
        yield from _file_sections({k: v for k, v in value.items() if k != "ros__parameters"}, here)


def _ros_options(args: Sequence[str]) -> Iterator[tuple[str, str]]:
    """``(option, value)`` for each ``-p``/``--param`` and ``--params-file`` of the ROS arguments."""
    inside = False
    it = iter(args)
    for arg in it:
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif inside and arg in ("-p", "--param", "--params-file"):
            value = next(it, None)
            if value is not None:
                yield ("--params-file" if arg == "--params-file" else "-p"), value


def given_scopes(args: Sequence[str], fqn: str, own: bool) -> dict[str, int]:
    """How each parameter in ``args`` (command-line style) reaches the node named ``fqn``:
    :data:`BY_NAME`, :data:`TO_PROCESS` or :data:`TO_ALL` (the narrowest if several);
    ``own``: the node's own arguments (a plain ``-p`` there is by name)."""
    scopes: dict[str, int] = {}

    def given(name: str, scope: int) -> None:
        scopes[name] = min(scope, scopes.get(name, scope))

    for option, value in _ros_options(args):
        if option == "-p":
            target, _, name = value.split(":=", 1)[0].rpartition(":")
            if not target:
                given(name, BY_NAME if own else TO_PROCESS)
            elif _matches(target, fqn):
                given(name, _pattern_scope(target))
            continue
        try:
            doc = yaml.safe_load(Path(value).read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError, UnicodeDecodeError):
            continue  # rcl read it (the node exists); what it gave the node is then reported by name
        for pattern, params in _file_sections(doc):
            if _matches(pattern, fqn):
                for name in _flat(params):
                    given(name, _pattern_scope(pattern))
    return scopes


def _closest(name: str, names: Sequence[str], cutoff: float) -> str:
    match = difflib.get_close_matches(name, names, n=1, cutoff=cutoff)
    return match[0] if match else ""


def unknown_text(unknown: dict[str, str]) -> str:
    """``unknown_parameters`` in words: ``time_budgett (did you mean time_budget?), ...`` or ``none``."""
    return ", ".join(f"{n} (did you mean {s}?)" if s else n for n, s in unknown.items()) or "none"


def find_unknown(given: Sequence[dict[str, int]], declared: Sequence[Sequence[str]]) -> list[dict[str, str]]:
    """The reporting rule, for the nodes of one process: ``given[i]`` maps each parameter node
    ``i`` was given to how it reached it (:data:`BY_NAME`, :data:`TO_PROCESS`, :data:`TO_ALL`),
    ``declared[i]`` are its parameters; returns, per node, the undeclared parameters it reports,
    each with the closest declared name (``''`` if none is close).

    Reported: a parameter given to a node by name (also ``-p name:=value`` to a single-node
    process); one given to every node of the process that no node of it declares, once (by the
    node with the closest name, the first one if none is close); one from a wildcard section
    (meant for every node of the system, also nodes of other packages) only when no node of the
    process declares it and it is a near miss (:data:`NEAR_MISS_CUTOFF`) of a name the node
    declares. Names under :data:`RCLPY_PARAMETER_PREFIXES` are never reported."""
    everyone = {name for names in declared for name in names}
    found: list[dict[str, str]] = [{} for _ in given]
    to_process: dict[str, list[int]] = {}
    for i, scopes in enumerate(given):
        for name, scope in scopes.items():
            if name in declared[i] or name.startswith(RCLPY_PARAMETER_PREFIXES):
                continue
            if scope == BY_NAME or (scope == TO_PROCESS and len(given) == 1):
                found[i][name] = _closest(name, declared[i], SUGGEST_CUTOFF)
            elif name in everyone:
                continue
            elif scope == TO_PROCESS:
                to_process.setdefault(name, []).append(i)
            elif near := _closest(name, declared[i], NEAR_MISS_CUTOFF):
                found[i][name] = near
    for name, nodes in to_process.items():
        def similarity(i: int, name: str = name) -> float:
            return max((difflib.SequenceMatcher(None, name, d).ratio() for d in declared[i]), default=0.0)
        best = max(nodes, key=similarity)  # the first of equals
        found[best][name] = _closest(name, declared[best], SUGGEST_CUTOFF)
    return found
