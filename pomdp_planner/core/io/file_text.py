"""Reading a model file that nobody vouches for: a bounded, regular, UTF-8 text file.

Both loaders (YAML and Cassandra ``.POMDP``) read their file with :func:`read_model_text`:

* only a *regular file* is read: a device (``/dev/zero``), a FIFO or a directory is refused
  before it is opened (opening a FIFO would block, reading ``/dev/zero`` would never end);
* at most :data:`MAX_MODEL_FILE_BYTES` are read; a longer file is refused without parsing it
  (parsing time and the memory of the parsed values grow with the file: this bounds both);
* the bytes must be UTF-8 (a leading byte-order mark is dropped); binary content is refused
  with the offset of the first invalid byte. Line ends ``\r\n`` and ``\r`` become ``\n``.

Every refusal is a :class:`~pomdp_planner.core.model.ModelError` of one line that starts with
the file name.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ..model import ModelError, format_bytes, short_repr

#: Largest model file read (bytes): 16 MiB. The loaders bound their work by the number of values
#: as well (``MAX_YAML_NODES``, ``MAX_TOKENS``); this bounds what a file of long strings or
#: comments costs.
MAX_MODEL_FILE_BYTES = 16 * 2**20


def _file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _read_at_most(f, n: int, size_hint: int) -> bytes:
    """At most ``n`` bytes of ``f``; never allocates much more than what the file holds."""
    parts, got = [], 0
    step = max(64 * 2**10, min(size_hint + 1, n))
    while got < n:
        chunk = f.read(min(step, n - got))
        if not chunk:
            break
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


def read_model_text(path: str | Path, what: str = "model file", limit: int | None = None,
                    limit_name: str = "MAX_MODEL_FILE_BYTES") -> str:
    """The text of the model file ``path`` (module docstring); ``ModelError`` otherwise. ``what``
    and ``limit`` (named ``limit_name`` in messages) serve other files a user gives (a beliefs file)."""
    limit = MAX_MODEL_FILE_BYTES if limit is None else limit
    if "\0" in str(path):  # no file has such a name (the OS refuses it with a ValueError)
        raise ModelError(f"{short_repr(str(path))}: cannot read {what}: the name contains a NUL character")
    path = Path(path)
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise ModelError(f"{path}: cannot read {what}: it is {_file_kind(st.st_mode)}, not a regular file")
        if st.st_size > limit:
            raise ModelError(f"{path}: {what} is {format_bytes(st.st_size)}, larger than the limit of "
                             f"{format_bytes(limit)} ({limit_name})")
        with open(path, "rb") as f:
            data = _read_at_most(f, limit + 1, st.st_size)
    except OSError as exc:
        raise ModelError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    if len(data) > limit:  # grew since stat, or a file whose size is not known in advance
        raise ModelError(f"{path}: {what} is larger than the limit of {format_bytes(limit)} ({limit_name})")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ModelError(f"{path}: {what} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}: "
                         f"binary content or another encoding)") from None
    return text.replace("\r\n", "\n").replace("\r", "\n")  # universal newlines, as Path.read_text
