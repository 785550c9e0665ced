"""package.xml passes catkin_pkg (what colcon uses) and agrees with setup.py.

A package.xml that catkin_pkg rejects (e.g. a malformed maintainer email) makes colcon build
the package as plain Python, invisible to ``ros2 run`` (ROS_NOTES.md), so this is checked here.
"""

from __future__ import annotations

import ast
import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

if os.environ.get("POMDP_PLANNER_REQUIRE_INSTALLED") == "1":
    import catkin_pkg.package as catkin_package  # a test dependency: make test installs it
else:
    catkin_package = pytest.importorskip("catkin_pkg.package", reason="catkin_pkg (a test dependency) not installed")


@pytest.fixture(scope="module")
def package():
    warnings: list[str] = []
    pkg = catkin_package.parse_package(str(REPO / "package.xml"), warnings=warnings)
    pkg.validate(warnings=warnings)
    assert warnings == []
    return pkg


def test_catkin_pkg_accepts_it_as_ament_python(package):
    assert package.package_format == 3
    assert package.name == "pomdp_planner"
    assert package.get_build_type() == "ament_python"
    assert package.maintainers and all(m.email for m in package.maintainers)


def test_declares_runtime_and_test_dependencies(package):
    exec_deps = {d.name for d in package.exec_depends}
    assert {"rclpy", "std_msgs", "diagnostic_msgs", "python3-numpy", "python3-scipy", "python3-yaml"} <= exec_deps
    assert "python3-pytest" in {d.name for d in package.test_depends}


def test_version_matches_the_python_package(package):
    tree = ast.parse((REPO / "pomdp_planner" / "__init__.py").read_text())
    versions = [ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == "__version__" for t in n.targets)]
    assert versions == [package.version]


def test_catkin_pkg_would_reject_a_bad_email(tmp_path):
    """The check above can fail: the same file with a malformed maintainer email is rejected."""
    bad = tmp_path / "package.xml"
    bad.write_text((REPO / "package.xml").read_text().replace("maintainers@example.com", "maintainers at example"))
    with pytest.raises(catkin_package.InvalidPackage):
        catkin_package.parse_package(str(bad)).validate()
