"""Where package files are found: the one resolver for model and parameter file paths.

Every entry point (CLI, nodes, benchmarks, experiments) resolves a path given by a user with
:func:`resolve_path`, in this order:

1. an absolute path is used as it is (it must exist);
2. a relative path is tried as given, i.e. relative to the current directory (what a user at a
   shell expects);
3. then relative to each *package root*: the installed share directory
   ``<prefix>/share/pomdp_planner`` for the running interpreter's prefix and every prefix on
   ``AMENT_PREFIX_PATH`` (a pip install or a colcon workspace), then the source tree (a checkout),
   so ``config/models/tracking_s8_info.yaml`` works installed and from a checkout;
4. a bare shipped-model name (``tracking_s3_info`` or ``tracking_s3_info.yaml``) is also looked
   up under ``config/models/`` of each package root.

The share directory is derived from the prefixes, not from ``ament_index_python``, so this core
module needs nothing from ROS; a colcon workspace sets ``AMENT_PREFIX_PATH`` when sourced.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ..errors import short_repr
from ..model import ModelError
from .file_text import _file_kind

PACKAGE = "pomdp_planner"
#: The repository root when running from a checkout (``pomdp_planner/core/io/`` is 3 levels down).
SOURCE_ROOT = Path(__file__).resolve().parents[3]
#: Folder of the shipped models, relative to a package root.
MODELS_DIR = Path("config") / "models"
#: The longest name of one file or folder (one part of a path), in bytes: NAME_MAX of Linux's file systems.
NAME_MAX = 255


def long_part(path: str | os.PathLike) -> str:
    """The problem of a path with a part longer than :data:`NAME_MAX` bytes (the system refuses it
    with "File name too long"), as the end of a one-line message; ``""`` if there is none."""
    for part in Path(path).parts:
        n = len(os.fsencode(part))
        if n > NAME_MAX:
            return (f"a part of the path is {n} bytes long, more than a file or folder name may have ({NAME_MAX}): "
                    f"{short_repr(part)}")
    return ""


def package_roots() -> list[Path]:
    """Installed share directories (interpreter prefix, then ``AMENT_PREFIX_PATH``), then the source tree
    when running from a checkout."""
    prefixes = [sys.prefix, *os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)]
    roots = [Path(p) / "share" / PACKAGE for p in prefixes if p]
    if (SOURCE_ROOT / "package.xml").is_file():  # a checkout (an installed copy sits in site-packages)
        roots.append(SOURCE_ROOT)
    return list(dict.fromkeys(roots))


def _candidates(path: str) -> list[Path]:
    p = Path(path).expanduser()
    if p.is_absolute():
        return [p]
    out = [Path.cwd() / p]
    roots = package_roots()
    out += [root / p for root in roots]
    if len(p.parts) == 1:  # a bare name: a shipped model
        names = [p.name] if p.suffix else [p.name + ".yaml", p.name]
        out += [root / MODELS_DIR / n for root in roots for n in names]
    return list(dict.fromkeys(out))


def resolve_path(path: str, field: str = "model_file") -> Path:
    """The existing file that ``path`` names (module docstring); ``ModelError`` naming ``field`` if none."""
    if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise ModelError(f"{field}: empty path")
    problem = long_part(path)
    if problem:
        raise ModelError(f"{field}: {problem}")
    cands = _candidates(str(path))
    for c in cands:
        try:
            if c.is_file():
                return c
        except OSError as exc:  # e.g. a folder on the way that may not be searched
            raise ModelError(f"{field}: cannot read {c}: {exc.strerror or type(exc).__name__}") from None
    for c in cands:  # no regular file, but something of that name (a directory, a FIFO, a device)
        try:
            mode = c.stat().st_mode
        except OSError:
            continue
        raise ModelError(f"{field}: {c} is {_file_kind(mode)}, not a regular file")
    if len(cands) == 1:
        raise ModelError(f"{field}: file {cands[0]} does not exist")
    places = list(dict.fromkeys(str(c.parent) for c in cands))
    raise ModelError(f"{field}: {str(path)!r} not found (looked in {', '.join(places)})")


def shipped_model_path(name: str) -> Path:
    """Path of a shipped model (``config/models/<name>[.yaml]``), installed or in the source tree."""
    return resolve_path(str(MODELS_DIR / (name if name.endswith((".yaml", ".POMDP")) else name + ".yaml")),
                        "model")
