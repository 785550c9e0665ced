"""Where a command may write: output paths checked before any work starts, write errors as one line.

A user names output files (``export -o FILE``, ``bench search --json FILE``) and folders
(``bench all --output DIR``). They are checked *before* the work that produces the output, so a
long run is not lost to a typo at its end:

* :func:`check_output_file`: ``path`` is not a directory and its folder exists and is a folder;
* :func:`check_output_dir`: ``path`` is a folder, or does not exist yet and the nearest existing
  folder above it is a folder (it will be created);
* :func:`write_text_file`: writes UTF-8 text; any ``OSError`` (no space left, ``/dev/full``, a
  permission denied) becomes a one-line :class:`~pomdp_planner.core.model.ModelError` naming the
  option and the path.

Whether the user may write there is left to the write itself (a process running as root may
write anywhere, and ``os.access`` cannot tell what a network file system will allow).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..model import ModelError, short_repr


def _reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def _as_path(path: str | os.PathLike, field: str, what: str) -> Path:
    text = str(path)
    if not text.strip() or "\0" in text:
        raise ModelError(f"{field}: not a {what} name: {short_repr(text)}")
    return Path(text).expanduser()


def check_output_file(path: str | os.PathLike, field: str) -> Path:
    """``path`` as a :class:`~pathlib.Path` if a file can be created or replaced there (module docstring)."""
    p = _as_path(path, field, "file")
    try:
        if p.is_dir():
            raise ModelError(f"{field}: {p} is a directory, not a file")
        if not p.parent.exists():
            raise ModelError(f"{field}: cannot write {p}: the folder {p.parent} does not exist")
        if not p.parent.is_dir():
            raise ModelError(f"{field}: cannot write {p}: {p.parent} is not a folder")
    except OSError as exc:  # e.g. a folder on the way that may not be searched
        raise ModelError(f"{field}: cannot write {p}: {_reason(exc)}") from None
    return p


def check_output_dir(path: str | os.PathLike, field: str) -> Path:
    """``path`` as a :class:`~pathlib.Path` if it is a folder or can be created (module docstring)."""
    p = _as_path(path, field, "folder")
    try:
        if p.exists():
            if not p.is_dir():
                raise ModelError(f"{field}: {p} exists and is not a folder")
            return p
        above = next((a for a in p.parents if a.exists()), None)
        if above is not None and not above.is_dir():
            raise ModelError(f"{field}: cannot create {p}: {above} is not a folder")
    except OSError as exc:
        raise ModelError(f"{field}: cannot use {p}: {_reason(exc)}") from None
    return p


def write_text_file(path: str | os.PathLike, text: str, field: str) -> None:
    """Write ``text`` (UTF-8) to ``path``; an ``OSError`` becomes a ``ModelError`` naming ``field``."""
    try:
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
    except OSError as exc:
        raise ModelError(f"{field}: cannot write {path}: {_reason(exc)}") from None
