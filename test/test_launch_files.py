"""Every launch file, read as XML (``ros2 launch`` is not installable from PyPI, so CI cannot run it;
docs/ros.md, "Launch", says what was run with the real launch system).

For each ``launch/*.launch.xml`` of the source tree:

* it is installed to ``share/pomdp_planner/launch/`` (found through the ament index, as
  ``ros2 launch pomdp_planner <file>`` finds it);
* it has the arguments every launch file has (:data:`COMMON_ARGUMENTS`: ``params_file``,
  ``model_file``, ``namespace``, ``log_level``, ``autostart``); every ``<arg>`` has a default and a
  description (what ``ros2 launch ... --show-args`` prints), and is documented in the user docs;
* every substitution is one the file may use (``$(var X)`` of a declared argument,
  ``$(find-pkg-share pomdp_planner)``, ``$(eval '...')`` of them; an argument's default may use the
  arguments declared before it), and every ``if``/``unless`` is an argument or such an ``eval``;
* every ``<node>`` names an executable of this package that is installed under
  ``lib/pomdp_planner`` and executable, takes ``--log-level $(var log_level)``, and the managed
  ones (``belief_filter``, ``planner``) get ``autostart`` from the argument;
* :func:`launched` plays the file the way launch_ros does (the arguments' values, the conditions,
  the namespaces, the global parameters of ``<set_parameters_from_file>`` and ``<set_parameter>``
  in order, then each node's own ``<param>``; parameter-file sections matched against the node's
  full name as rcl matches them), and for every value of ``model_set`` (the shipped parameter sets,
  :data:`PARAMETER_SETS`; the argument's description lists exactly them), with and without
  ``model_file``, in the root namespace and in one of its own: every node started has a section in
  the parameter file, the models it runs are installed, the nodes of one namespace run the same
  model (nodes in several namespaces only under a sensor manager, which names each of them in
  ``targets`` with that namespace's model in ``model_files``), a ``model_file`` given is the model
  of every node, ``autostart`` reaches the managed nodes, and fully qualified node names are unique.
"""

from __future__ import annotations

import ast
import itertools
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

from pomdp_planner.nodes.processes import PARAMETER_SETS

REPO = Path(__file__).resolve().parent.parent
PACKAGE = "pomdp_planner"
LAUNCH_FILES = sorted((REPO / "launch").glob("*.launch.xml"))
#: ``$(kind arg)`` with no substitution inside: the innermost ones first.
INNERMOST = re.compile(r"\$\(([\w-]+)(?:\s+([^()$]*))?\)")
EVAL = re.compile(r"\$\(eval '([^']*)'\)")
#: Tags a launch file of this package may use (launch and launch_ros XML frontends).
KNOWN_TAGS = {"launch", "arg", "group", "push-ros-namespace", "node", "param", "remap", "let", "include",
              "set_parameters_from_file", "set_parameter"}
COMMON_ARGUMENTS = ("params_file", "model_file", "namespace", "log_level", "autostart")
MANAGED = {"belief_filter", "planner"}


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


def substitute(text: str, values: dict[str, str], share: Path) -> str:
    """``text`` with its substitutions done as the launch system does them: innermost first
    (``var``, ``find-pkg-share``; an argument's value may hold substitutions itself), then
    ``$(eval '<python>')`` evaluated."""
    def one(m: re.Match) -> str:
        kind, arg = m.group(1), (m.group(2) or "").strip()
        if kind == "var":
            return substitute(values[arg], values, share)
        assert kind == "find-pkg-share" and arg == PACKAGE, f"unexpected substitution {m.group(0)}"
        return str(share)
    while True:
        done = INNERMOST.sub(lambda m: m.group(0) if m.group(1) == "eval" else one(m), text)
        if done == text:
            break
        text = done
    return EVAL.sub(lambda m: str(eval(m.group(1), {})).lower(), text)


def truth(text: str) -> bool:
    assert text.lower() in ("true", "false", "1", "0"), f"condition {text!r} is not a boolean"
    return text.lower() in ("true", "1")


@dataclass
class Launched:
    """A node as the launch system starts it: its full name, executable, the parameter files and
    parameters it gets in order (a file as ``Path``, a parameter as ``(name, value)``), its ROS
    arguments."""

    fqn: str
    name: str
    exe: str
    params: list = field(default_factory=list)
    ros_args: str = ""

    def parameters(self) -> dict:
        """The node's parameters, later ones replacing earlier (rcl), from the sections of each
        file that apply to :attr:`fqn`."""
        out: dict = {}
        for p in self.params:
            if isinstance(p, Path):
                for key, section in yaml.safe_load(p.read_text()).items():
                    if key_matches(key, self.fqn):
                        out.update(section["ros__parameters"])
            else:
                out[p[0]] = p[1]
        return out


def key_matches(key: str, fqn: str) -> bool:
    """Whether a parameter file's key applies to the node ``fqn`` (``/ns/name``): the full name,
    ``name`` or ``/name`` at the root, ``/**`` for every node, ``/**/rest`` for every node whose name
    ends with ``/rest`` (rcl's wildcards)."""
    if key in ("/**", fqn) or (key.lstrip("/") == fqn.lstrip("/") and fqn.count("/") == 1):
        return True
    return key.startswith("/**/") and ("/" + fqn.lstrip("/")).endswith("/" + key[4:])


def launched(root: ET.Element, values: dict[str, str], share: Path) -> list[Launched]:
    """Every node the launch file starts with the arguments ``values`` (module docstring)."""
    out: list[Launched] = []

    def active(el: ET.Element) -> bool:
        if el.get("if") is not None:
            return truth(substitute(el.get("if"), values, share))
        if el.get("unless") is not None:
            return not truth(substitute(el.get("unless"), values, share))
        return True

    def visit(el: ET.Element, namespace: str, global_params: list) -> None:
        global_params = list(global_params)  # a group scopes what is set in it
        for child in el:
            if not active(child):
                continue
            if child.tag == "push-ros-namespace":
                ns = substitute(child.get("namespace"), values, share).strip("/")
                namespace = f"{namespace}/{ns}" if ns else namespace
            elif child.tag == "group":
                visit(child, namespace, global_params)
            elif child.tag == "set_parameters_from_file":
                global_params.append(Path(substitute(child.get("filename"), values, share)))
            elif child.tag == "set_parameter":
                global_params.append((child.get("name"), yaml.safe_load(substitute(child.get("value"), values,
                                                                                    share))))
            elif child.tag == "node":
                name = child.get("name")
                own = [Path(substitute(p.get("from"), values, share)) if p.get("from") is not None
                       else (p.get("name"), yaml.safe_load(substitute(p.get("value"), values, share)))
                       for p in child.iter("param")]
                out.append(Launched(f"{namespace}/{name}", name, child.get("exec"), [*global_params, *own],
                                    substitute(child.get("ros_args") or "", values, share)))

    visit(root, "", [])
    return out


def test_there_are_the_closed_loop_tracker_and_multi_target_launch_files():
    assert {p.name for p in LAUNCH_FILES} >= {"closed_loop.launch.xml", "tracker.launch.xml",
                                              "multi_target.launch.xml"}


def test_the_multi_target_launch_runs_three_targets_and_one_manager(prefix):
    root = ET.parse(REPO / "launch" / "multi_target.launch.xml").getroot()
    values = {name: a.get("default") for name, a in arguments(root).items()}
    nodes = sorted((n.fqn, n.exe) for n in launched(root, values, prefix / "share" / PACKAGE))
    assert nodes == sorted([(f"/target{k}/{e}", e) for k in (1, 2, 3) for e in ("target_simulator", "belief_filter")]
                           + [("/sensor_manager", "sensor_manager")])


def test_the_tracker_runs_the_adapter_with_the_filter_and_the_planner():
    root = ET.parse(REPO / "launch" / "tracker.launch.xml").getroot()
    nodes = {n.get("exec"): n for n in root.iter("node")}
    assert set(nodes) == {"measurement_adapter", "belief_filter", "planner", "belief_visualizer"}
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
    assert set(COMMON_ARGUMENTS) <= set(args), f"{path.name}: lacks {set(COMMON_ARGUMENTS) - set(args)}"
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
        for m in INNERMOST.finditer(arg.get("default") or ""):
            if m.group(1) == "var":
                assert m.group(2).strip() in declared, f"{path.name}: {arg.get('name')}'s default uses {m.group(0)}"
        declared.append(arg.get("name"))
    for el in root.iter():
        assert el.tag in KNOWN_TAGS, f"{path.name}: unexpected tag <{el.tag}>"
        for attr, value in el.attrib.items():
            for m in INNERMOST.finditer(value):
                kind, arg = m.group(1), (m.group(2) or "").strip()
                assert kind in ("var", "find-pkg-share"), f"{path.name}: substitution {m.group(0)}"
                if kind == "var":
                    assert arg in args, f"{path.name}: $(var {arg}) names no declared argument"
                else:
                    assert arg == PACKAGE, f"{path.name}: {m.group(0)}"
            assert INNERMOST.sub("", EVAL.sub("", value)).count("$(") == 0, f"{path.name}: {value!r}"
            if attr in ("if", "unless"):
                assert re.fullmatch(r"\$\(var [\w]+\)", value) or EVAL.fullmatch(value), \
                    f"{path.name}: condition {value!r} is not an argument or an eval"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_nodes_are_installed_executables_with_log_level_and_autostart(path, prefix):
    root = ET.parse(path).getroot()
    nodes = list(root.iter("node"))
    assert nodes, f"{path.name}: no nodes"
    for node in nodes:
        assert node.get("pkg") == PACKAGE, f"{path.name}: node of another package {node.get('pkg')!r}"
        exe = node.get("exec")
        assert exe in node_executables(), f"{path.name}: {exe!r} is not a node executable of setup.py"
        installed = prefix / "lib" / PACKAGE / exe
        assert installed.is_file() and os.access(installed, os.X_OK), f"{path.name}: {installed} not executable"
        assert node.get("ros_args") == "--log-level $(var log_level)", f"{path.name}: {exe} without log_level"
        autostart = [p for p in node.iter("param") if p.get("name") == "autostart"]
        if exe in MANAGED:
            assert [p.get("value") for p in autostart] == ["$(var autostart)"], f"{path.name}: {exe} autostart"
        else:
            assert not autostart, f"{path.name}: {exe} is not a managed node"


def _model_of(params: dict) -> list[str]:
    return list(params["model_files"]) if "model_files" in params else [params["model_file"]]


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_every_node_gets_its_parameters_and_one_model_per_namespace(path, prefix):
    root = ET.parse(path).getroot()
    args = arguments(root)
    share = prefix / "share" / PACKAGE
    choices: dict[str, list[str]] = {name: [a.get("default")] for name, a in args.items()}
    if "model_set" in args:
        listed = re.findall(r"\b(?:perimeter_)?s\d+\b", args["model_set"].get("description"))
        assert tuple(listed) == PARAMETER_SETS, f"{path.name}: model_set lists {listed}, not {PARAMETER_SETS}"
        assert args["model_set"].get("default") in PARAMETER_SETS
        choices["model_set"] = list(PARAMETER_SETS)
    choices["model_file"] = ["", "perimeter_s3", str(share / "config" / "models" / "tracking_s3_info.yaml")]
    choices["namespace"] = ["", "robot1"]
    choices["autostart"] = ["true", "false"]
    checked = 0
    for combo in itertools.product(*choices.values()):
        values = dict(zip(choices, combo, strict=True))
        nodes = launched(root, values, share)
        names = [n.fqn for n in nodes]
        assert len(set(names)) == len(names), f"{path.name} ({values}): node names repeat: {names}"
        ns = "/robot1" if values["namespace"] else ""
        assert all(n.fqn.startswith(ns + "/") for n in nodes), f"{path.name}: {names} not all in {ns}"
        params_file = Path(substitute(args["params_file"].get("default"), values, share))
        assert params_file.is_file(), f"{path.name} ({values}): {params_file} is not installed"
        sections = yaml.safe_load(params_file.read_text())
        models: dict[str, set[str]] = {}  # namespace -> the models its nodes run
        managers = []  # (namespace, targets, model_files) of each sensor manager
        for node in nodes:
            assert any(key_matches(k, node.fqn) for k in sections), \
                f"{params_file.name}: no section applies to {node.fqn}"
            params = node.parameters()
            files = _model_of(params)
            for f in files:
                found = [share / f, share / "config" / "models" / f"{f}.yaml", Path(f)]
                assert any(p.is_file() for p in found), f"{params_file.name}: {node.fqn}: model {f} is not installed"
            if values["model_file"]:
                assert set(files) == {values["model_file"]}, f"{path.name}: model_file not in force at {node.fqn}"
            if node.name in MANAGED:
                assert params["autostart"] is (values["autostart"] == "true")
            else:
                assert "autostart" not in params
            node_ns = node.fqn.rsplit("/", 1)[0]
            if "targets" in params:
                assert len(params["targets"]) == len(files), f"{params_file.name}: one model file per target"
                managers.append((node_ns, params["targets"], files))
            else:
                models.setdefault(node_ns, set()).update(files)
            checked += 1
        for n, group in models.items():
            assert len(group) == 1, f"{path.name} ({values}): the nodes of {n or '/'} run different models {group}"
        targets = {f"{n}/{t}": f for n, names_, files in managers for t, f in zip(names_, files, strict=True)}
        for n, f in targets.items():
            assert models.get(n) == {f}, f"{path.name} ({values}): the manager's {n} runs {f}, " \
                                         f"its nodes {models.get(n)}"
        managed = set(targets) | {n for n, _, _ in managers}
        assert len(models) == 1 or set(models) <= managed, \
            f"{path.name} ({values}): nodes in several namespaces {sorted(models)} without a sensor manager"
    assert checked >= len(PARAMETER_SETS)


def test_the_emulation_matches_parameters_as_rcl_does():
    """:func:`key_matches` (what the test above relies on) on the keys the shipped files use."""
    assert key_matches("/**/planner", "/planner") and key_matches("/**/planner", "/robot1/planner")
    assert key_matches("planner", "/planner") and not key_matches("planner", "/robot1/planner")
    assert key_matches("/**/target1/belief_filter", "/site1/target1/belief_filter")
    assert key_matches("/**/target1/belief_filter", "/target1/belief_filter")
    assert not key_matches("/**/target1/belief_filter", "/target2/belief_filter")
    assert not key_matches("/**/filter", "/belief_filter")
