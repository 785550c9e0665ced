"""The INSTALLED package layout, as ``ros2 run`` and launch files see it.

``ros2 run pomdp_planner <exe>`` finds ``<prefix>/lib/pomdp_planner/<exe>``, with ``<prefix>``
the entry of ``AMENT_PREFIX_PATH`` that holds the marker
``share/ament_index/resource_index/packages/pomdp_planner``; nodes find their parameter files
under ``share/pomdp_planner/config``. We check exactly that through ``ament_index_python``.

The package is installed into the interpreter's prefix (``make`` runs ``pip install .`` into
``.venv``), but nothing sets ``AMENT_PREFIX_PATH`` to a venv (there is no ROS ``setup.bash``
there), so the fixture below puts ``sys.prefix`` in front of it for the test.

A developer running pytest without having installed the package gets a skip with the reason;
``make test`` sets ``POMDP_PLANNER_REQUIRE_INSTALLED=1`` so that CI fails instead.
"""

from __future__ import annotations

import ast
import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = "pomdp_planner"
REQUIRE_INSTALLED = os.environ.get("POMDP_PLANNER_REQUIRE_INSTALLED") == "1"


def setup_literal(name: str) -> dict[str, str]:
    """A module-level ``NAME = {...}`` literal of setup.py, read with ast (setup.py is not importable)."""
    tree = ast.parse((REPO / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError(f"setup.py: no module-level literal {name}")


def declared_executables() -> dict[str, str]:
    return {**setup_literal("CLI_EXECUTABLES"), **setup_literal("NODE_EXECUTABLES")}


def repo_config_files() -> list[Path]:
    return sorted(p.relative_to(REPO / "config") for p in (REPO / "config").rglob("*")
                  if p.is_file() and "__pycache__" not in p.parts)


def _skip_or_fail(reason: str) -> None:
    if REQUIRE_INSTALLED:
        pytest.fail(f"{reason} (POMDP_PLANNER_REQUIRE_INSTALLED=1)")
    pytest.skip(f"{reason}; run `make test` (or `pip install .`) to check the installed layout")


@pytest.fixture
def prefix(monkeypatch) -> Path:
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    except ImportError:
        _skip_or_fail("ament_index_python is not installed (it comes with the ROS wheels)")
    paths = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    # This interpreter's prefix first: that is the installation `make test` has just made.
    monkeypatch.setenv("AMENT_PREFIX_PATH", os.pathsep.join([sys.prefix, *paths]))
    try:
        return Path(get_package_prefix(PACKAGE))
    except PackageNotFoundError:
        _skip_or_fail(f"{PACKAGE} is not installed in AMENT_PREFIX_PATH or {sys.prefix}")


def test_setup_declares_cli_and_nodes():
    exes = declared_executables()
    assert exes["pomdp-planner"] == "pomdp_planner.__main__:main"
    assert set(setup_literal("NODE_EXECUTABLES")) >= {"target_simulator", "belief_filter", "planner", "closed_loop"}
    for name, target in exes.items():
        module, _, func = target.partition(":")
        assert module.startswith(f"{PACKAGE}.") and func.isidentifier(), f"{name}: bad entry point {target!r}"


def test_the_package_knows_its_executables_for_its_start_up_sigint_handler():
    """pomdp_planner/__init__.py guards the start of exactly setup.py's console scripts (and their -m forms)."""
    import pomdp_planner

    assert set(pomdp_planner.EXECUTABLES) == set(declared_executables())
    started = pomdp_planner._started_as_executable
    assert started(["/v/bin/python", "/v/bin/planner", "--ros-args"]) == "planner"
    assert started(["python", "-m", "pomdp_planner.nodes.planner"]) == "pomdp_planner.nodes.planner"
    assert started(["python", "-m", "pomdp_planner", "check", "m.yaml"]) == "pomdp_planner"
    assert started(["python", "-m", "pomdp_planner.nodes.demo"]) == ""  # the demo handles Ctrl-C itself
    assert started(["python", "-c", "import pomdp_planner"]) == "" and started(["python", "-m", "pytest"]) == ""


def test_entry_points_name_existing_functions():
    """Every console script targets a function that the source tree defines."""
    for name, target in declared_executables().items():
        module, _, func = target.partition(":")
        base = REPO / Path(*module.split("."))
        source = base.with_suffix(".py") if base.with_suffix(".py").is_file() else base / "__init__.py"
        assert source.is_file(), f"{name}: module {module} not found ({source.relative_to(REPO)})"
        defined = {n.name for n in ast.parse(source.read_text()).body
                   if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)}
        imported = {a.asname or a.name for n in ast.parse(source.read_text()).body
                    if isinstance(n, ast.ImportFrom) for a in n.names}
        assert func in defined | imported, f"{name}: {module} defines no {func}()"


def test_package_found_through_ament_index(prefix):
    from ament_index_python.packages import get_package_share_directory

    share = Path(get_package_share_directory(PACKAGE))
    assert share == prefix / "share" / PACKAGE
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    assert (share / "package.xml").read_text() == (REPO / "package.xml").read_text()


@pytest.mark.parametrize("exe", sorted(declared_executables()))
def test_executable_installed_for_ros2_run(prefix, exe):
    path = prefix / "lib" / PACKAGE / exe
    assert path.is_file(), f"{path} missing: `ros2 run {PACKAGE} {exe}` would say 'No executable found'"
    assert os.access(path, os.X_OK), f"{path} is not executable"


def test_config_installed(prefix):
    config = repo_config_files()
    assert Path("models/tracking_s3_info.yaml") in config
    share = prefix / "share" / PACKAGE / "config"
    missing = [str(p) for p in config if not (share / p).is_file()]
    assert not missing, f"not installed under {share}: {missing}"
    for p in config:
        assert (share / p).read_bytes() == (REPO / "config" / p).read_bytes(), f"{p}: installed copy is stale"


def installed_package_dir() -> Path:
    """Where a fresh interpreter, outside the source tree, imports ``pomdp_planner`` from."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-I", "-c", f"import {PACKAGE}; print({PACKAGE}.__file__)"],
                             cwd=tmp, capture_output=True, text=True)
    if out.returncode != 0:
        _skip_or_fail(f"{PACKAGE} is not importable outside the source tree: {out.stderr.strip()[-200:]}")
    where = Path(out.stdout.strip()).parent
    if where == REPO / PACKAGE:
        _skip_or_fail(f"{PACKAGE} imports from the source tree, not from an installed copy")
    return where


def test_installed_package_is_typed():
    """PEP 561: the ``py.typed`` marker ships with the package, so type checkers use its annotations."""
    assert (REPO / PACKAGE / "py.typed").is_file()
    assert (installed_package_dir() / "py.typed").is_file(), "py.typed is not installed (setup.py package_data)"


def test_development_tooling_is_not_installed():
    """``tools/`` (model search, fuzz corpus) runs from a checkout; the installed package has no copy."""
    pkg = installed_package_dir()
    assert (REPO / "tools" / "lookahead_models.py").is_file()
    assert not (pkg / "bench" / "lookahead_models.py").exists()
    assert not (pkg / "bench" / "fuzz_models.py").exists()
    assert not (pkg.parent / "tools" / "lookahead_models.py").exists()
