"""The lock (constraints.txt): every package requirements.txt asks for is pinned to one exact
version (``name==version``, one line each, no ranges); ``make test`` and ``make demo`` install with
it, and ``make lock`` refreshes it (Makefile); the environment the suite runs in has the locked
versions (under ``make test``; ``make lock`` runs the suite unlocked, before it writes the lock)."""

from __future__ import annotations

import os
import re
from importlib import metadata
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def requirements() -> list[str]:
    names = []
    for line in (REPO / "requirements.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            names.append(canonical(re.split(r"[\[<>=!~ ;]", line, maxsplit=1)[0]))
    return names


def pins() -> dict[str, str]:
    out = {}
    for k, line in enumerate((REPO / "constraints.txt").read_text().splitlines(), 1):
        m = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([A-Za-z0-9.+!_-]+)", line)
        assert m, f"constraints.txt:{k}: not name==version: {line!r}"
        name = canonical(m.group(1))
        assert name not in out, f"constraints.txt:{k}: {name} pinned twice"
        out[name] = m.group(2)
    return out


def test_every_requirement_is_pinned_once():
    locked = pins()
    missing = [r for r in requirements() if r not in locked]
    assert not missing, f"constraints.txt does not pin {missing}: run `make lock`"
    assert "pomdp-planner" not in locked and "pip" not in locked


def test_the_makefile_installs_with_the_lock_and_can_refresh_it():
    text = (REPO / "Makefile").read_text()
    assert "$(PIP) install -r requirements.txt $(if $(UNLOCKED),,-c $(CONSTRAINTS))" in text
    assert re.search(r"^\$\(DEPS_STAMP\): requirements\.txt \$\(CONSTRAINTS\)", text, re.M)
    assert re.search(r"^lock:\n(\t.*\n)+", text, re.M)
    assert "freeze --all --exclude pomdp-planner --exclude pip" in text


def test_the_suite_runs_with_the_locked_versions():
    if os.environ.get("POMDP_PLANNER_REQUIRE_INSTALLED") != "1" or os.environ.get("POMDP_PLANNER_UNLOCKED") == "1":
        pytest.skip("not under `make test` (or under `make lock`, which runs the suite before it writes the lock)")
    locked = pins()
    wrong = {}
    for name in requirements():
        installed = metadata.version(name)
        if installed != locked[name]:
            wrong[name] = (installed, locked[name])
    assert not wrong, f"installed versions differ from constraints.txt (installed, locked): {wrong}"
