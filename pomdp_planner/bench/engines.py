"""The search engines side by side: the compiled kernel, the numpy reference, and an optimised C yardstick.

Part of ``pomdp-planner bench search`` (:mod:`.search`). For each model and depth, over a few
seeded random beliefs, in interleaved rounds (each variant once per round, so a burst of load
hits all of them), the CPU time of the measuring thread per search (``time.thread_time``; a
search of a few microseconds is timed as a batch of calls, the mean per call):

* **kernel** and **numpy**: :meth:`Planner.search` of the same planner set-up with
  ``kernel="c"`` and ``kernel="numpy"``, exhaustive and branch-and-bound (the gate's bounds),
  the whole call (belief check and result included);
* **C yardstick**: ``expectimax_ref.c`` beside this file, a standalone hand-optimised C
  implementation of the same exhaustive expectimax (level-wise contiguous belief arrays, the leaf
  level fused, the logarithms of 32 parents in one vectorised loop), compiled here with the
  machine's ``cc -O3 -march=native -ffast-math`` into a temporary directory and called through
  ``ctypes`` (it times its own runs with the same thread clock). Never part of the planner. Its
  root values and node count are checked against the kernel's before it is timed.

Reported per depth: nodes/s of each (median over rounds of each belief, tree nodes / time, then the
median over beliefs), kernel / C, and the branch-and-bound efficiency of each engine:
``(exhaustive time / B&B time) / (exhaustive nodes / B&B nodes)`` (1: pruning saves exactly the
time of the nodes it removes).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import statistics
import subprocess
import tempfile
import time
from collections.abc import Callable, Sequence
from importlib import resources
from typing import Any

import numpy as np

from ..core.gate import build_planner
from ..core.model import POMDP
from ..core.search import Planner

#: The models of the engine comparison (the issue's four), and the depths.
ENGINE_MODELS = ("tracking_s8_info.yaml", "tracking_s8_natural.yaml", "perimeter_s8.yaml", "perimeter_s3.yaml")
ENGINE_DEPTHS = (2, 3, 4, 5)
#: The C yardstick's compiler flags.
CFLAGS = ("-O3", "-march=native", "-ffast-math", "-fPIC")
#: A timed batch lasts at least this long (CPU seconds).
MIN_BATCH = 2e-3

_DP = ctypes.POINTER(ctypes.c_double)


class Yardstick:
    """The compiled C yardstick (``expectimax_ref.c``), or why there is none (``reason``)."""

    def __init__(self) -> None:
        self.fn: Any = None
        self.reason = ""
        self.command = ""
        self._dir = tempfile.mkdtemp(prefix="pomdp_planner_cref_")
        cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
        if cc is None:
            self.reason = "no C compiler (cc) on PATH"
            return
        src = resources.files("pomdp_planner.bench").joinpath("expectimax_ref.c")
        obj, lib = os.path.join(self._dir, "expectimax_ref.o"), os.path.join(self._dir, "expectimax_ref.so")
        # compiled with CFLAGS but linked without -ffast-math: linked with it, the library would set the
        # processor's flush-to-zero mode for the whole process when it is loaded
        steps = [[cc, *CFLAGS, "-c", "-o", obj, str(src)], [cc, "-shared", "-o", lib, obj, "-lm"]]
        self.command = " ".join([os.path.basename(cc), *CFLAGS])
        try:
            for cmd in steps:
                subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=120)
        except (OSError, subprocess.SubprocessError) as exc:
            self.reason = f"cannot compile the C yardstick: {getattr(exc, 'stderr', '') or exc}".strip()
            return
        fn = ctypes.CDLL(lib).expectimax
        fn.restype = ctypes.c_int
        self.fn = fn

    def close(self) -> None:
        shutil.rmtree(self._dir, ignore_errors=True)

    def run(self, model: POMDP, b: np.ndarray, depth: int, reps: int) -> tuple[np.ndarray, int, float]:
        """``(root Q values, tree nodes, mean CPU seconds per search over reps)``."""
        kind = {"none": 0, "renyi2": 1, "shannon": 2}[model.uncertainty.name if np.any(model.w) else "none"]
        arrays = [np.ascontiguousarray(x, dtype=float) for x in (model.P, model.O, model.r, model.w, b)]
        Q = np.zeros(model.A)
        nodes, secs = ctypes.c_longlong(), ctypes.c_double()
        rc = self.fn(model.S, model.A, model.Z, ctypes.c_double(model.gamma), kind,
                     *[a.ctypes.data_as(_DP) for a in arrays], depth, reps, Q.ctypes.data_as(_DP),
                     ctypes.byref(nodes), ctypes.byref(secs))
        if rc != 0:
            raise MemoryError("the C yardstick ran out of memory")
        return Q, int(nodes.value), float(secs.value)


def _batch(fn: Callable[[], Any], reps: int) -> float:
    """Mean thread CPU seconds per call over ``reps`` calls."""
    t0 = time.thread_time()
    for _ in range(reps):
        fn()
    return (time.thread_time() - t0) / reps


def _reps(seconds: float) -> int:
    return max(1, int(MIN_BATCH / max(seconds, 1e-7)))


def bench_engines(model: POMDP, depths: Sequence[int], beliefs: int, rounds: int, seed: int,
                  yardstick: Yardstick | None, log: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """The engine comparison for one model (a JSON-ready dict; module docstring)."""
    setup = build_planner(model, prune_without_guarantee=True, override_name="(benchmark)")
    bounds = setup.planner.bounds if setup.pruning else None
    planners = {k: Planner(model, bounds, kernel=k) for k in ("c", "numpy")}
    B = np.random.default_rng(seed).dirichlet(np.ones(model.S), size=beliefs)
    rows = []
    for d in depths:
        samples: dict[str, list[float]] = {}
        nodes: dict[str, list[int]] = {"exh": [], "bnb": []}
        checked = 0.0
        for b in B:
            variants: dict[str, Callable[[], Any]] = {}
            for k, p in planners.items():
                variants[f"{k}_exh"] = lambda p=p, b=b, d=d: p.search(b, d, use_bounds=False)
                if bounds is not None:
                    variants[f"{k}_bnb"] = lambda p=p, b=b, d=d: p.search(b, d, use_bounds=True)
            exh = planners["c"].search(b, d, use_bounds=False)
            nodes["exh"].append(exh.nodes_expanded[-1])
            if bounds is not None:
                nodes["bnb"].append(planners["c"].search(b, d, use_bounds=True).nodes_expanded[-1])
            reps = {name: _reps(_batch(fn, 1)) for name, fn in variants.items()}  # warm-up and calibration
            if yardstick is not None and yardstick.fn is not None:
                Q, n, t = yardstick.run(model, b, d, 1)
                if n != exh.nodes_expanded[-1] or not np.allclose(Q, exh.q_values, rtol=1e-10, atol=1e-10):
                    raise AssertionError(f"the C yardstick disagrees with the kernel on {model.name}, depth {d}")
                checked = max(checked, float(np.max(np.abs(Q - exh.q_values) / np.maximum(1.0, np.abs(exh.q_values)))))
                reps["cref"] = _reps(t)
            per: dict[str, list[float]] = {name: [] for name in reps}
            for _ in range(rounds):
                for name, fn in variants.items():
                    per[name].append(_batch(fn, reps[name]))
                if "cref" in reps:
                    per["cref"].append(yardstick.run(model, b, d, reps["cref"])[2])
            for name, ts in per.items():
                samples.setdefault(name, []).append(statistics.median(ts))
        row: dict[str, Any] = {"depth": d, "exhaustive_nodes": int(np.median(nodes["exh"]))}
        n_exh = float(np.mean(nodes["exh"]))
        for name, ts in samples.items():
            n = n_exh if name.endswith("exh") or name == "cref" else float(np.mean(nodes["bnb"]))
            row[f"{name}_seconds"] = statistics.median(ts)
            row[f"{name}_nodes_per_s"] = n / statistics.median(ts)
        if bounds is not None:
            row["bnb_nodes"] = float(np.mean(nodes["bnb"]))
            for k in ("c", "numpy"):
                speedup = row[f"{k}_exh_seconds"] / row[f"{k}_bnb_seconds"]
                row[f"{k}_bnb_efficiency"] = speedup / (n_exh / row["bnb_nodes"])
        if "cref_seconds" in row:
            row["kernel_over_cref"] = row["cref_seconds"] / row["c_exh_seconds"]
            row["cref_max_rel_diff"] = checked
        rows.append(row)
        log(f"{model.name}: engines at depth {d}: kernel {row['c_exh_nodes_per_s'] / 1e6:.1f} M nodes/s exhaustive")
    return {"model": model.name, "S": model.S, "A": model.A, "Z": model.Z, "pruning": bounds is not None,
            "guaranteed": setup.guaranteed, "rows": rows}


def format_engines(result: dict[str, Any]) -> list[str]:
    """Text tables of the engine comparison (part of :func:`.search.format_report`)."""
    lines = [f"== engines: the compiled kernel, the numpy reference and the C yardstick "
             f"({result['yardstick']}); thread CPU time, median of {result['rounds']} interleaved rounds "
             f"over {result['beliefs']} beliefs; load average {result['load']}"]
    for m in result["models"]:
        lines.append(f"   {m['model']} (S={m['S']}, A={m['A']}, Z={m['Z']})"
                     + ("" if m["pruning"] else ": no bounds (B&B not measured)"))
        lines.append("   depth  exh. nodes  B&B nodes  | M nodes/s: kernel exh  numpy exh  C exh  kernel/C"
                     "  | kernel B&B  numpy B&B  | B&B efficiency: kernel  numpy")
        for r in m["rows"]:
            def f(key: str, spec: str, scale: float = 1.0, r: dict[str, Any] = r) -> str:
                return "-" if key not in r else format(r[key] / scale, spec)
            lines.append(f"   {r['depth']:>5}  {r['exhaustive_nodes']:>10,}  {f('bnb_nodes', '>9,.0f')}  | "
                         f"{f('c_exh_nodes_per_s', '>19.1f', 1e6)}  {f('numpy_exh_nodes_per_s', '>9.1f', 1e6)}  "
                         f"{f('cref_nodes_per_s', '>5.1f', 1e6)}  {f('kernel_over_cref', '>8.2f')}  | "
                         f"{f('c_bnb_nodes_per_s', '>10.1f', 1e6)}  {f('numpy_bnb_nodes_per_s', '>9.1f', 1e6)}  | "
                         f"{f('c_bnb_efficiency', '>22.2f')}  {f('numpy_bnb_efficiency', '>5.2f')}")
    return lines


def run_engines(models: Sequence[POMDP], depths: Sequence[int], beliefs: int, rounds: int, seed: int,
                log: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """The engine comparison over ``models`` (module docstring)."""
    yard = Yardstick()
    try:
        if yard.reason:
            log(f"engines: {yard.reason}: the C yardstick is left out")
        out = [bench_engines(m, depths, beliefs, rounds, seed, yard, log) for m in models]
    finally:
        yard.close()
    return {"models": out, "yardstick": yard.command or yard.reason, "rounds": rounds, "beliefs": beliefs,
            "load": " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "unknown"}
