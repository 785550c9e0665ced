"""The pure core and the command line never import rclpy; the layers import only
downwards.

``pomdp_planner/core`` and ``pomdp_planner/cli`` must run without ROS. Checked twice: statically
(every import statement, including relative imports of ``pomdp_planner.nodes`` and
``importlib.import_module("rclpy")``-style calls) and dynamically (every module imported in a
fresh interpreter in which importing rclpy raises).

Layering (README, "Repository layout"): the core imports nothing of the package outside itself;
``cli``, ``nodes`` and ``bench`` are adapters on top of it; nothing imports ``nodes`` except
``nodes`` itself and ``bench/ros`` (the ROS benchmarks); nothing imports ``cli`` but the entry
point ``pomdp_planner/__main__.py``; only ``cli`` (its ``bench`` command) and ``bench`` import
``bench``.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PURE = ("pomdp_planner/core", "pomdp_planner/cli")
FORBIDDEN = ("rclpy", "pomdp_planner.nodes")


def pure_files() -> list[Path]:
    return sorted(p for d in PURE for p in (REPO / d).rglob("*.py") if "__pycache__" not in p.parts)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def forbidden(name: str) -> bool:
    return any(name == f or name.startswith(f + ".") for f in FORBIDDEN)


def imported_names(path: Path) -> list[tuple[int, str]]:
    """Absolute names of everything ``path`` imports (relative imports resolved)."""
    return names_in_source(path.read_text(), module_name(path), path.name == "__init__.py")


def names_in_source(source: str, module: str, is_package: bool) -> list[tuple[int, str]]:
    package = module.split(".") if is_package else module.split(".")[:-1]
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join([*base, node.module] if node.module else base)
            else:
                mod = node.module or ""
            out.append((node.lineno, mod))
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            func = node.func
            fname = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if fname in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                out.append((node.lineno, node.args[0].value))
    return out


def test_there_are_pure_modules():
    names = {module_name(p) for p in pure_files()}
    assert {"pomdp_planner.core.model", "pomdp_planner.core.belief", "pomdp_planner.cli"} <= names


def test_static_check_catches_indirect_forms():
    """Relative imports are resolved and import_module/__import__ calls are seen."""
    source = """
from ..nodes import qos
from . import belief
import numpy as np
def f():
    import importlib
    return importlib.import_module("rclpy.node"), __import__("scipy")
"""
    names = [n for _, n in names_in_source(source, "pomdp_planner.core.x", is_package=False)]
    assert "pomdp_planner.nodes.qos" in names and "pomdp_planner.core.belief" in names
    assert [n for n in names if forbidden(n)] == ["pomdp_planner.nodes", "pomdp_planner.nodes.qos", "rclpy.node"]
    sub = [n for _, n in names_in_source("from .. import nodes", "pomdp_planner.core", is_package=True)]
    assert "pomdp_planner.nodes" in sub


@pytest.mark.parametrize("path", pure_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_no_ros_import_statically(path):
    bad = [f"line {line}: {name}" for line, name in imported_names(path) if forbidden(name)]
    assert not bad, f"{path.relative_to(REPO)} imports ROS code: {bad}"


BLOCKER = r"""
import importlib, json, sys
attempts = []

class Blocker:
    def find_spec(self, name, path=None, target=None):
        if name == "rclpy" or name.startswith("rclpy."):
            attempts.append(name)
            raise ImportError(f"blocked by test_core_purity: {name}")
        return None

sys.meta_path.insert(0, Blocker())
failed = {}
for mod in json.loads(sys.argv[1]):
    try:
        importlib.import_module(mod)
    except Exception as exc:
        failed[mod] = f"{type(exc).__name__}: {exc}"
print(json.dumps({"attempts": attempts, "failed": failed,
                  "rclpy_loaded": sorted(m for m in sys.modules if m == "rclpy" or m.startswith("rclpy."))}))
"""


def test_no_ros_import_dynamically():
    modules = sorted(module_name(p) for p in pure_files())
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", BLOCKER, json.dumps(modules)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["attempts"] == [], f"tried to import rclpy: {result}"
    assert result["rclpy_loaded"] == []
    assert result["failed"] == {}, f"pure modules fail to import without ROS: {result['failed']}"


# ------------------------------------------------------------------------------ layering
#: (package, packages it must not import); the most specific package of a module applies.
LAYERS = (
    ("pomdp_planner.core", ("pomdp_planner.cli", "pomdp_planner.nodes", "pomdp_planner.bench", "rclpy")),
    ("pomdp_planner.cli", ("pomdp_planner.nodes", "rclpy")),
    ("pomdp_planner.bench", ("pomdp_planner.cli", "pomdp_planner.nodes", "rclpy")),
    ("pomdp_planner.bench.ros", ("pomdp_planner.cli",)),
    ("pomdp_planner.nodes", ("pomdp_planner.cli", "pomdp_planner.bench")),
    ("pomdp_planner", ("pomdp_planner.nodes", "pomdp_planner.bench", "rclpy")),  # __init__, __main__
)


def _within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def layer_of(module: str) -> tuple[str, tuple[str, ...]]:
    return max((entry for entry in LAYERS if _within(module, entry[0])), key=lambda e: len(e[0]))


def all_files() -> list[Path]:
    return sorted(p for p in (REPO / "pomdp_planner").rglob("*.py") if "__pycache__" not in p.parts)


def test_layer_rules_cover_the_issue_11_statements():
    assert layer_of("pomdp_planner.core.gate")[0] == "pomdp_planner.core"
    assert layer_of("pomdp_planner.bench.ros.latency")[0] == "pomdp_planner.bench.ros"
    assert layer_of("pomdp_planner.bench.experiments.runner")[0] == "pomdp_planner.bench"
    assert layer_of("pomdp_planner.__main__")[0] == "pomdp_planner"
    # nothing outside nodes/ and bench/ros may import nodes
    for package, banned in LAYERS:
        if package not in ("pomdp_planner.nodes", "pomdp_planner.bench.ros"):
            assert "pomdp_planner.nodes" in banned, package


@pytest.mark.parametrize("path", all_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_layers_import_only_downwards(path):
    module = module_name(path)
    package, banned = layer_of(module)
    bad = [f"line {line}: {name}" for line, name in imported_names(path)
           if any(_within(name, b) for b in banned)]
    assert not bad, f"{path.relative_to(REPO)} ({package}) imports {bad}"
