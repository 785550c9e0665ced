"""``bench`` works from an installed copy: models through the one resolver, outputs where the user says.

The experiments write ``RESULTS.md`` and ``img/`` into ``--output DIR`` or the current directory,
never into the package or the repository's docs/; no benchmark or tool finds the shipped models
relative to its own file (that breaks once installed): they go through ``core/io/paths.py``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CLI = Path(sys.executable).with_name("pomdp-planner")


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    exe = [str(CLI)] if CLI.exists() else [sys.executable, "-m", "pomdp_planner"]
    env = {**os.environ, "PYTHONPATH": str(REPO) if not CLI.exists() else os.environ.get("PYTHONPATH", "")}
    return subprocess.run([*exe, *args], cwd=cwd, capture_output=True, text=True, env=env, timeout=600)


def test_bench_all_writes_into_the_current_directory_by_default(tmp_path):
    docs_before = (REPO / "docs" / "RESULTS.md").read_bytes()
    out = _cli(["bench", "all", "--quick", "--only", "fig1", "--no-progress"], tmp_path)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "RESULTS.md").is_file()
    assert (tmp_path / "img" / "fig1_policy_bounds_s3.png").is_file()
    assert not (tmp_path / "docs").exists()
    assert (REPO / "docs" / "RESULTS.md").read_bytes() == docs_before


def test_fuzz_seeds_come_from_the_resolver_from_any_directory(tmp_path, monkeypatch):
    from tools.fuzz_models import seeds

    monkeypatch.chdir(tmp_path)
    names = {name for name, kind, _ in seeds() if kind == "yaml"}
    assert {p.stem for p in (REPO / "config" / "models").glob("*.yaml")} <= names


def test_no_benchmark_or_tool_locates_config_by_its_own_file():
    offenders = []
    for path in [*(REPO / "pomdp_planner" / "bench").rglob("*.py"), *(REPO / "tools").rglob("*.py")]:
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if re.search(r"__file__.*parents\[\d\].*config", line):
                offenders.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert not offenders, "use core/io/paths.py (resolve_path, shipped_model_path):\n" + "\n".join(offenders)
