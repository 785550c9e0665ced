"""Where a command may write: output paths checked before any work starts, write errors as one line.

A user names output files (``export -o FILE``, ``bench search --json FILE``) and folders
(``bench all --output DIR``). They are checked *before* the work that produces the output, so a
long run is not lost to a typo at its end, and a command never blocks on its output:

* :func:`check_output_file`: ``path`` is :data:`STDOUT` (``-``, standard output) or a *regular
  file*, existing or to be created: an existing FIFO, device, socket or directory is refused
  (opening a FIFO for writing would block until a reader comes; use ``-`` and a shell pipe).
  Writing is tried without changing anything: an existing file is opened for appending and
  zero bytes are written (this fails on ``/proc/version``, a read-only file system, a file
  without write permission); for a new file, a probe file is created in its folder and removed;
* :func:`check_output_dir`: ``path`` is a folder, or does not exist yet and the nearest existing
  folder above it is a folder (it will be created);
* :func:`write_text_file`: writes UTF-8 text to the file or to standard output; the file is
  opened without blocking and must still be a regular file; any ``OSError`` (no space left, a
  permission denied) becomes a one-line :class:`~pomdp_planner.core.errors.OptionError` naming the
  option and the path.
"""

from __future__ import annotations

import os
import stat
import sys
import tempfile
from pathlib import Path

from ..errors import OptionError, short_repr
from .file_text import _file_kind
from .paths import long_part

#: The output name that means standard output.
STDOUT = "-"


def _reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def _as_path(path: str | os.PathLike, field: str, what: str) -> Path:
    text = str(path)
    if not text.strip() or "\0" in text:
        raise OptionError(f"{field}: not a {what} name: {short_repr(text)}")
    problem = long_part(text)
    if problem:
        raise OptionError(f"{field}: {problem}")
    return Path(text).expanduser()


def is_stdout(path: str | os.PathLike) -> bool:
    """Whether the output name ``path`` means standard output (:data:`STDOUT`)."""
    return str(path) == STDOUT


def check_output_file(path: str | os.PathLike, field: str, *, stdout: bool = True) -> Path:
    """``path`` as a :class:`~pathlib.Path` if a regular file can be written there, or ``Path("-")``
    for standard output (module docstring; refused if ``stdout`` is false: an output that cannot
    share standard output); ``OptionError`` naming ``field`` otherwise."""
    if is_stdout(path):
        if not stdout:
            raise OptionError(f"{field}: '{STDOUT}' (standard output) is not possible here: give a file")
        return Path(STDOUT)
    p = _as_path(path, field, "file")
    try:
        if p.exists():
            mode = p.stat().st_mode
            if not stat.S_ISREG(mode):
                raise OptionError(f"{field}: cannot write {p}: it is {_file_kind(mode)}, not a regular file "
                                 f"(write to a file, or '{STDOUT}' for standard output)")
            fd = os.open(p, os.O_WRONLY | os.O_APPEND | os.O_NONBLOCK)
            try:
                os.write(fd, b"")  # changes nothing; fails where the file cannot be written (/proc)
            finally:
                os.close(fd)
            return p
        if not p.parent.exists():
            raise OptionError(f"{field}: cannot write {p}: the folder {p.parent} does not exist")
        if not p.parent.is_dir():
            raise OptionError(f"{field}: cannot write {p}: {p.parent} is not a folder")
        fd, probe = tempfile.mkstemp(dir=p.parent, prefix=".pomdp_planner-write-probe-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:  # a permission denied, a read-only file system, a folder that may not be searched
        raise OptionError(f"{field}: cannot write {p}: {_reason(exc)}") from None
    return p


def check_output_dir(path: str | os.PathLike, field: str) -> Path:
    """``path`` as a :class:`~pathlib.Path` if it is a folder or can be created (module docstring)."""
    p = _as_path(path, field, "folder")
    try:
        if p.exists():
            if not p.is_dir():
                raise OptionError(f"{field}: {p} exists and is not a folder")
            return p
        above = next((a for a in p.parents if a.exists()), None)
        if above is not None and not above.is_dir():
            raise OptionError(f"{field}: cannot create {p}: {above} is not a folder")
    except OSError as exc:
        raise OptionError(f"{field}: cannot use {p}: {_reason(exc)}") from None
    return p


def write_text_file(path: str | os.PathLike, text: str, field: str) -> None:
    """Write ``text`` (UTF-8) to ``path``, or to standard output if it is :data:`STDOUT`; the file
    is opened without blocking and must be a regular file; an ``OSError`` becomes a ``OptionError``
    naming ``field``."""
    if is_stdout(path):
        sys.stdout.write(text)
        return
    try:
        fd = os.open(Path(str(path)).expanduser(), os.O_WRONLY | os.O_CREAT | os.O_NONBLOCK, 0o666)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            mode = os.fstat(fd).st_mode
            if not stat.S_ISREG(mode):
                raise OptionError(f"{field}: cannot write {path}: it is {_file_kind(mode)}, not a regular file")
            fh.truncate(0)
            fh.write(text)
    except OSError as exc:
        raise OptionError(f"{field}: cannot write {path}: {_reason(exc)}") from None
