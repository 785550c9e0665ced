"""Starting and stopping the node executables as processes, as ``ros2 run`` would: used by the
demo (``nodes/demo.py``), the latency benchmark (``bench/ros/latency.py``) and the tests.

Each process gets this machine only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and the ROS
domain it is given, its parameter file ``config/<node>_<model>.yaml`` (found by
``core.io.paths.resolve_path``; ``<model>`` one of :data:`PARAMETER_SETS`) and a log file;
:func:`stop_nodes` ends them the way Ctrl-C in a terminal does (SIGINT), so they exit cleanly.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from ..core.io.paths import resolve_path

NODES = ("target_simulator", "belief_filter", "planner")
#: The shipped parameter sets: ``config/<node>_<key>.yaml`` for every node (and
#: ``config/closed_loop_<key>.yaml``): the paper's tracking models (``s3``, ``s8``) and the
#: perimeter models where lookahead pays (docs/MODEL_SEARCH.md).
PARAMETER_SETS = ("s3", "s8", "perimeter_s3", "perimeter_s8")


def node_parameters(doc: dict, node: str) -> dict:
    """The ``ros__parameters`` of ``node`` in a parameter file's document: under ``/**/<node>`` (the
    shipped files: the node in any namespace), ``<node>`` or ``/<node>``."""
    for key in (f"/**/{node}", node, f"/{node}"):
        if key in doc:
            return doc[key]["ros__parameters"]
    raise KeyError(f"no section for node {node!r} (keys: {', '.join(map(str, doc))})")


def parameter_set_values(key: str, node: str) -> dict:
    """The parameters ``config/<node>_<key>.yaml`` gives node ``node`` (its ``ros__parameters``)."""
    params = resolve_path(f"config/{node}_{key}.yaml", "params file")
    return node_parameters(yaml.safe_load(params.read_text(encoding="utf-8")), node)


def parameter_set_model(key: str) -> Path:
    """The model file of parameter set ``key``: the ``model_file`` of ``config/planner_<key>.yaml``
    (every node of a set names the same model; a test checks it), resolved as the nodes resolve it."""
    return resolve_path(parameter_set_values(key, "planner")["model_file"], "model_file")


def node_command(name: str) -> list[str]:
    """How ``ros2 run pomdp_planner <name>`` would start the node: the installed console script if
    it sits next to this interpreter (a venv's ``bin``), else ``python -m pomdp_planner.nodes.<name>``."""
    script = Path(sys.executable).parent / name
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-m", f"pomdp_planner.nodes.{name}"]


def ros_env(domain_id: int) -> dict[str, str]:
    """This process's environment with ROS on this machine only, in domain ``domain_id``."""
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1")
    return env


def start_nodes(model: str, domain_id: int, log_dir: Path, extra: dict[str, list[str]] | None = None,
                names=NODES, preexec_fn=None) -> dict[str, tuple[subprocess.Popen, Path]]:
    """Start node processes with ``config/<name>_<model>.yaml``; output goes to ``log_dir/<name>.log``;
    ``preexec_fn`` runs in each child before it starts (``subprocess.Popen``'s)."""
    procs = {}
    env = ros_env(domain_id)
    for name in names:
        params = resolve_path(f"config/{name}_{model}.yaml", "params file")
        cmd = [*node_command(name), "--ros-args", "--params-file", str(params), *(extra or {}).get(name, [])]
        log = log_dir / f"{name}.log"
        with open(log, "wb") as fh:
            procs[name] = (subprocess.Popen(cmd, env=env, stdout=fh, stderr=subprocess.STDOUT,
                                              preexec_fn=preexec_fn), log)
    return procs


def stop_nodes(procs: dict[str, tuple[subprocess.Popen, Path]], timeout: float = 10.0) -> dict[str, int]:
    """SIGINT every process (as Ctrl-C would), wait, SIGKILL stragglers; returns the exit codes."""
    for p, _ in procs.values():
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    codes = {}
    deadline = time.monotonic() + timeout
    for name, (p, _) in procs.items():
        try:
            codes[name] = p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            codes[name] = p.wait()
    return codes
