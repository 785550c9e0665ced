"""Build script of the ament_python package ``pomdp_planner``.

Works for both install paths (README.md, "Install"):

* colcon (``colcon build``): the standard ament_python layout; ``setup.cfg`` sends the console
  scripts to ``lib/pomdp_planner`` where ``ros2 run`` looks for them; the command line
  ``pomdp-planner`` also gets a forwarder ``bin/pomdp-planner``, on ``PATH`` once the workspace
  is sourced.
* pip (``pip install .``, used by ``make demo``/``make test``): pip ignores ``setup.cfg``'s
  script directories, so console scripts land in ``<prefix>/bin``. For wheel builds only we
  add tiny forwarders ``lib/pomdp_planner/<exe>`` that exec ``<prefix>/bin/<exe>``; with
  ``AMENT_PREFIX_PATH=<prefix>`` ``ros2 run pomdp_planner <exe>`` then finds every executable.
"""

import os
import re
import sys
from pathlib import Path

from setuptools import Extension, find_packages, setup

PACKAGE = "pomdp_planner"

#: The command line (``pomdp-planner``; ``__main__`` guards Ctrl-C while it imports). Plain literal:
#: test/test_package_layout.py reads it with ast.
CLI_EXECUTABLES = {"pomdp-planner": "pomdp_planner.__main__:main"}

#: The ROS 2 node executables (``ros2 run pomdp_planner <name>``). Plain literal, as above.
NODE_EXECUTABLES = {
    "target_simulator": "pomdp_planner.nodes.target_simulator:main",
    "belief_filter": "pomdp_planner.nodes.belief_filter:main",
    "planner": "pomdp_planner.nodes.planner:main",
    "closed_loop": "pomdp_planner.nodes.closed_loop:main",
    "measurement_adapter": "pomdp_planner.nodes.measurement_adapter:main",
    "sensor_manager": "pomdp_planner.nodes.sensor_manager:main",
    "run_recorder": "pomdp_planner.nodes.run_recorder:main",
    "belief_visualizer": "pomdp_planner.nodes.belief_visualizer:main",
}

HERE = Path(__file__).absolute().parent  # not resolved: colcon --symlink-install builds in a tree of symlinks
FORWARDER_DIR = Path("build") / "ros_forwarders"  # generated, never committed
FORWARDER = """#!/bin/sh
# Forwarder for `ros2 run` after a pip install: runs <prefix>/bin/<this file's name>.
exec "$(dirname "$0")/../../bin/$(basename "$0")" "$@"
"""
BIN_FORWARDER = """#!/bin/sh
# `pomdp-planner` on PATH after a colcon build: runs <prefix>/lib/pomdp_planner/<this file's name>.
exec "$(dirname "$0")/../lib/pomdp_planner/$(basename "$0")" "$@"
"""


def _version() -> str:
    text = (HERE / PACKAGE / "__init__.py").read_text()
    return re.search(r'^__version__ = "([^"]+)"', text, re.M).group(1)


def _config_files() -> list[tuple[str, list[str]]]:
    """Every file under ``config/``, keeping sub-folders, into ``share/<pkg>/config/...``."""
    groups: dict[str, list[str]] = {}
    for path in sorted((HERE / "config").rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            rel = path.relative_to(HERE)
            groups.setdefault(str(Path("share", PACKAGE, rel.parent)), []).append(str(rel))
    return sorted(groups.items())


WHEEL_BUILD = bool({"bdist_wheel", "editable_wheel"} & set(sys.argv))


def _launch_files() -> list[tuple[str, list[str]]]:
    """Every ``launch/*.launch.xml`` into ``share/<pkg>/launch`` (``ros2 launch <pkg> <file>``)."""
    files = sorted(str(p.relative_to(HERE)) for p in (HERE / "launch").glob("*.launch.xml"))
    return [(str(Path("share", PACKAGE, "launch")), files)] if files else []


def _forwarders(text: str, folder: Path, install_dir: str, executables) -> list[tuple[str, list[str]]]:
    """Executable scripts ``text``, one per executable, written into ``build/ros_forwarders/<folder>``
    at build time (never committed, so the lists above are the only place an executable is named)
    and installed as data into ``install_dir``."""
    out = HERE / FORWARDER_DIR / folder
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for exe in sorted(executables):
        path = out / exe
        path.write_text(text)
        path.chmod(0o755)  # the executable bit survives the wheel
        files.append(str(FORWARDER_DIR / folder / exe))
    return [(install_dir, files)]


def _wheel_forwarders(executables) -> list[tuple[str, list[str]]]:
    """``lib/<pkg>/<exe>`` forwarders, for wheel builds only (see the module docstring).

    Only for ``bdist_wheel`` and ``editable_wheel``: colcon runs ``setup.py develop``/``install``,
    which already put the real scripts into ``lib/<pkg>`` (setup.cfg), and a forwarder installed
    as data would overwrite them. (``pip install -e .`` installs no data files at all: use
    ``pip install .``.)
    """
    return _forwarders(FORWARDER, Path(), f"lib/{PACKAGE}", executables) if WHEEL_BUILD else []


def _colcon_bin_forwarders(executables) -> list[tuple[str, list[str]]]:
    """``bin/<exe>`` forwarders to ``lib/<pkg>/<exe>``, for every build but a wheel's.

    colcon (``setup.py develop``/``install``) puts the console scripts into ``lib/<pkg>``
    (setup.cfg), where ``ros2 run`` finds them but a shell does not; sourcing the workspace puts
    ``<prefix>/bin`` on ``PATH`` when it exists, so the command line is then ``pomdp-planner`` as
    after a pip install (where the real scripts are already in ``bin``: no forwarder).
    """
    return [] if WHEEL_BUILD else _forwarders(BIN_FORWARDER, Path("bin"), "bin", executables)


EXECUTABLES = {**CLI_EXECUTABLES, **NODE_EXECUTABLES}

#: The compiled search kernel (README.md, "Dependencies"): plain C against the CPython API, built
#: here with the machine's C compiler. A top-level module, so that a source checkout first on
#: sys.path (the tests' ``pythonpath = .``) never hides the installed build. Optional: without a
#: compiler the package still installs, and its planners use the numpy reference (with a warning).
KERNEL = Extension("_pomdp_planner_kernel", sources=["pomdp_planner/core/search_kernel.c"], optional=True,
                   extra_compile_args=[] if os.name == "nt" else ["-O3", "-fno-trapping-math"])

os.chdir(HERE)  # data_files are relative to this directory
setup(
    name=PACKAGE,
    version=_version(),
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"], exclude=["test", "test.*"]),
    # PEP 561: the package is typed; the C yardstick of `bench search` (compiled when it runs)
    package_data={PACKAGE: ["py.typed", "bench/*.c"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        *_config_files(),
        *_launch_files(),
        *_wheel_forwarders(EXECUTABLES),
        *_colcon_bin_forwarders(CLI_EXECUTABLES),
    ],
    ext_modules=[KERNEL],
    python_requires=">=3.11",
    install_requires=["numpy", "scipy", "clarabel", "PyYAML"],
    extras_require={
        "test": ["pytest", "hypothesis", "ruff"],
        # docs/benchmarks.md, "Optional extras": plots of `pomdp-planner bench all`, and its POUCT peer
        "experiments": ["matplotlib"],
        "plot": ["matplotlib"],  # pomdp-planner plot
        "bag": ["rosbags>=0.10"],  # run records as rosbag2 MCAP bags (--record x.mcap, plot and replay of bags)
        "bench": ["pomdp-py"],
    },
    zip_safe=False,  # PEP 561: a typed package is not zip-safe
    maintainer="pomdp_planner maintainers",
    maintainer_email="maintainers@example.com",
    description="Information-acquisition POMDPs with myopic policy bounds (Lauri et al.), with ROS 2 nodes",
    license="Apache-2.0",
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in sorted(EXECUTABLES.items())]},
)
