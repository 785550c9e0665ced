"""Every launch file, read as XML (``ros2 launch`` is not installable from PyPI, so it cannot run here).

For each ``launch/*.launch.xml`` of the source tree:

* it is installed to ``share/pomdp_planner/launch/`` (found through the ament index, as
  ``ros2 launch pomdp_planner <file>`` finds it);
* every ``<arg>`` has a default and a description, and is documented in the user docs;
* every substitution is one the file may use (``$(var X)`` of a declared argument,
  ``$(find-pkg-share pomdp_planner)``; an argument's default may use the arguments declared before
  it), and every ``if``/``unless`` names a declared argument;
* every ``<node>`` names an executable of this package that is installed under
  ``lib/pomdp_planner`` and executable, with a unique fully qualified name (its namespace, from
  the ``<push-ros-namespace>`` of its groups, and its name);
* for every value of ``model_set`` (the shipped parameter sets, :data:`PARAMETER_SETS`; the
  argument's description lists exactly them) every ``<param from=...>`` is an installed file
  whose section applies to that node in any namespace, and the models it names are installed;
  the nodes of one namespace run the same model; nodes in several namespaces only under a sensor
  manager, which names each of them in ``targets`` with that namespace's model in ``model_files``.
"""

from __future__ import annotations

import ast
import itertools
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from pomdp_planner.nodes.processes import PARAMETER_SETS, node_parameters

REPO = Path(__file__).resolve().parent.parent
PACKAGE = "pomdp_planner"
LAUNCH_FILES = sorted((REPO / "launch").glob("*.launch.xml"))
SUBSTITUTION = re.compile(r"\$\(([\w-]+)(?:\s+([^)]*))?\)")
#: Tags a launch file of this package may use (launch and launch_ros XML frontends).
KNOWN_TAGS = {"launch", "arg", "group", "push-ros-namespace", "node", "param", "remap", "let", "include"}


def node_executables() -> set[str]:
    tree = ast.parse((REPO / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "NODE_EXECUTABLES" for t in node.targets):
            return set(ast.literal_eval(node.value))
    raise AssertionError("setup.py: no NODE_EXECUTABLES")


def user_docs() -> str:
    """The docs a launch argument must appear in: docs/ros.md where it exists, else the README."""
    ros = REPO / "docs" / "ros.md"
    return (ros if ros.is_file() else REPO / "README.md").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def prefix() -> Path:
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    except ImportError:
        pytest.skip("ament_index_python is not installed (it comes with the ROS wheels)")
    import sys

    paths = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    old = os.environ.get("AMENT_PREFIX_PATH")
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join([sys.prefix, *paths])
    try:
        return Path(get_package_prefix(PACKAGE))
    except PackageNotFoundError:
        if os.environ.get("POMDP_PLANNER_REQUIRE_INSTALLED") == "1":
            pytest.fail(f"{PACKAGE} is not installed (POMDP_PLANNER_REQUIRE_INSTALLED=1)")
        pytest.skip(f"{PACKAGE} is not installed; run `make test`")
    finally:
        if old is None:
            os.environ.pop("AMENT_PREFIX_PATH", None)
        else:
            os.environ["AMENT_PREFIX_PATH"] = old


def arguments(root: ET.Element) -> dict[str, ET.Element]:
    return {a.get("name"): a for a in root.iter("arg")}


def namespaced_nodes(el: ET.Element, namespace: str = "") -> list[tuple[str, ET.Element]]:
    """``(namespace, node)`` of every ``<node>`` under ``el``, in file order: a ``<push-ros-namespace>``
    applies to what follows it in its group, a ``<group>`` scopes it, a node's own ``namespace``
    attribute comes last (namespaces as written, substitutions left as they are)."""
    found = []
    for child in el:
        if child.tag == "push-ros-namespace":
            namespace = f"{namespace}/{child.get('namespace')}"
        elif child.tag == "group":
            found += namespaced_nodes(child, namespace)
        elif child.tag == "node":
            own = child.get("namespace")
            found.append((namespace if own is None else f"{namespace}/{own}", child))
    return found


def substitute(text: str, values: dict[str, str], share: Path) -> str:
    """``text`` with its substitutions done; an argument's value may hold substitutions itself."""
    def one(m: re.Match) -> str:
        kind, arg = m.group(1), (m.group(2) or "").strip()
        if kind == "var":
            return substitute(values[arg], values, share)
        assert kind == "find-pkg-share" and arg == PACKAGE, f"unexpected substitution {m.group(0)}"
        return str(share)
    return SUBSTITUTION.sub(one, text)


def test_there_are_the_closed_loop_tracker_and_multi_target_launch_files():
    assert {p.name for p in LAUNCH_FILES} >= {"closed_loop.launch.xml", "tracker.launch.xml",
                                              "multi_target.launch.xml"}


def test_the_multi_target_launch_runs_three_targets_and_one_manager():
    root = ET.parse(REPO / "launch" / "multi_target.launch.xml").getroot()
    nodes = [(ns, n.get("exec")) for ns, n in namespaced_nodes(root)]
    base = "/$(var namespace)"
    targets = [f"{base}/target{k}" for k in (1, 2, 3)]
    assert sorted(nodes) == sorted([(t, e) for t in targets for e in ("target_simulator", "belief_filter")]
                                   + [(base, "sensor_manager")])


def test_the_tracker_runs_the_adapter_with_the_filter_and_the_planner():
    root = ET.parse(REPO / "launch" / "tracker.launch.xml").getroot()
    nodes = {n.get("exec"): n for n in root.iter("node")}
    assert set(nodes) == {"measurement_adapter", "belief_filter", "planner"}
    (remap,) = nodes["measurement_adapter"].iter("remap")
    assert remap.get("from") == "measurement" and remap.get("to") == "$(var sensor_topic)"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_is_installed(path, prefix):
    installed = prefix / "share" / PACKAGE / "launch" / path.name
    assert installed.is_file(), f"{path.name} is not installed to share/{PACKAGE}/launch"
    assert installed.read_bytes() == path.read_bytes()


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_every_argument_has_a_default_and_is_documented(path):
    root = ET.parse(path).getroot()
    assert root.tag == "launch"
    args = arguments(root)
    assert args, f"{path.name}: no arguments"
    docs = user_docs()
    for name, arg in args.items():
        assert arg.get("default") is not None, f"{path.name}: argument {name} has no default"
        assert (arg.get("description") or "").strip(), f"{path.name}: argument {name} has no description"
        assert f"`{name}" in docs, f"{path.name}: argument {name} is not documented (docs/ros.md or README.md)"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_tags_substitutions_and_conditions_are_known(path):
    root = ET.parse(path).getroot()
    args = arguments(root)
    declared: list[str] = []
    for arg in root.iter("arg"):  # a default may use only the arguments declared before it
        for m in SUBSTITUTION.finditer(arg.get("default") or ""):
            if m.group(1) == "var":
                assert m.group(2).strip() in declared, f"{path.name}: {arg.get('name')}'s default uses {m.group(0)}"
        declared.append(arg.get("name"))
    for el in root.iter():
        assert el.tag in KNOWN_TAGS, f"{path.name}: unexpected tag <{el.tag}>"
        for attr, value in el.attrib.items():
            for m in SUBSTITUTION.finditer(value):
                kind, arg = m.group(1), (m.group(2) or "").strip()
                assert kind in ("var", "find-pkg-share"), f"{path.name}: substitution {m.group(0)}"
                if kind == "var":
                    assert arg in args, f"{path.name}: $(var {arg}) names no declared argument"
                else:
                    assert arg == PACKAGE, f"{path.name}: {m.group(0)}"
            if attr in ("if", "unless"):
                assert SUBSTITUTION.fullmatch(value) and SUBSTITUTION.fullmatch(value).group(1) == "var", \
                    f"{path.name}: condition {value!r} is not an argument"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_nodes_are_installed_executables_of_this_package(path, prefix):
    root = ET.parse(path).getroot()
    nodes = list(root.iter("node"))
    assert nodes, f"{path.name}: no nodes"
    names = [f"{ns}/{n.get('name')}" for ns, n in namespaced_nodes(root)]
    assert len(names) == len(nodes) and len(set(names)) == len(names), f"{path.name}: node names repeat: {names}"
    for node in nodes:
        assert node.get("pkg") == PACKAGE, f"{path.name}: node of another package {node.get('pkg')!r}"
        exe = node.get("exec")
        assert exe in node_executables(), f"{path.name}: {exe!r} is not a node executable of setup.py"
        installed = prefix / "lib" / PACKAGE / exe
        assert installed.is_file() and os.access(installed, os.X_OK), f"{path.name}: {installed} not executable"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_parameter_files_and_models_exist_for_every_model_set(path, prefix):
    root = ET.parse(path).getroot()
    args = arguments(root)
    share = prefix / "share" / PACKAGE
    choices: dict[str, list[str]] = {name: [a.get("default")] for name, a in args.items()}
    if "model_set" in args:
        listed = re.findall(r"\b(?:perimeter_)?s\d+\b", args["model_set"].get("description"))
        assert tuple(listed) == PARAMETER_SETS, f"{path.name}: model_set lists {listed}, not {PARAMETER_SETS}"
        assert args["model_set"].get("default") in PARAMETER_SETS
        choices["model_set"] = list(PARAMETER_SETS)
    checked = 0
    for combo in itertools.product(*choices.values()):
        values = dict(zip(choices, combo, strict=True))
        models: dict[str, set[str]] = {}  # namespace -> the models its nodes run
        managers = []  # (namespace, targets, model_files) of each sensor manager
        for ns, node in namespaced_nodes(root):
            for param in node.iter("param"):
                if param.get("from") is None:
                    continue
                file = Path(substitute(param.get("from"), values, share))
                assert file.is_file(), f"{path.name} ({values}): {file} is not installed"
                section = node_parameters(yaml.safe_load(file.read_text()), node.get("name"))
                assert f"/**/{node.get('name')}" in yaml.safe_load(file.read_text()), \
                    f"{file.name}: its section would not apply to {node.get('name')} in a namespace"
                files = section["model_files"] if "model_files" in section else [section["model_file"]]
                for f in files:
                    assert (share / f).is_file(), f"{file.name}: model {f} is not installed"
                if "targets" in section:
                    assert len(section["targets"]) == len(files), f"{file.name}: one model file per target"
                    managers.append((ns, section["targets"], files))
                else:
                    models.setdefault(ns, set()).update(files)
                checked += 1
        for ns, group in models.items():
            assert len(group) == 1, f"{path.name} ({values}): the nodes of {ns or '/'} run different models {group}"
        targets = {f"{ns}/{t}": f for ns, names, files in managers for t, f in zip(names, files, strict=True)}
        for ns, f in targets.items():
            assert models.get(ns) == {f}, f"{path.name} ({values}): the manager's {ns} runs {f}, " \
                                          f"its nodes {models.get(ns)}"
        managed = set(targets) | {ns for ns, _, _ in managers}
        assert len(models) == 1 or set(models) <= managed, \
            f"{path.name} ({values}): nodes in several namespaces {sorted(models)} without a sensor manager"
    assert checked >= len(PARAMETER_SETS)
