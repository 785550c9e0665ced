"""Output files (core/io/outputs.py): regular files or '-', checked before any work without changing anything."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.outputs import STDOUT, check_output_file, write_text_file


def test_checking_an_existing_file_changes_nothing(tmp_path: Path) -> None:
    f = tmp_path / "out.txt"
    f.write_text("old\n")
    os.utime(f, (1_000_000, 1_000_000))
    assert check_output_file(f, "-o") == f
    assert f.read_text() == "old\n" and f.stat().st_mtime == 1_000_000
    assert sorted(tmp_path.iterdir()) == [f]


def test_checking_a_new_file_creates_nothing(tmp_path: Path) -> None:
    assert check_output_file(tmp_path / "new.txt", "-o") == tmp_path / "new.txt"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("make", ["fifo", "dir", "socket"])
def test_what_is_not_a_regular_file_is_refused_by_name(tmp_path: Path, make: str) -> None:
    import socket

    p = tmp_path / make
    if make == "fifo":
        os.mkfifo(p)
    elif make == "dir":
        p.mkdir()
    else:
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(p))
    kind = {"fifo": "a FIFO (named pipe)", "dir": "a directory", "socket": "a socket"}[make]
    with pytest.raises(OptionError, match=rf"^--json: cannot write {re.escape(str(p))}: it is {re.escape(kind)}, not a "
                                         "regular file"):
        check_output_file(p, "--json")
    if make != "dir":  # the write itself never blocks either (a FIFO without a reader)
        with pytest.raises(OptionError, match=rf"^--json: cannot write {re.escape(str(p))}"):
            write_text_file(p, "x", "--json")


@pytest.mark.skipif(not Path("/proc/version").is_file(), reason="needs /proc")
def test_a_pseudo_file_that_cannot_be_written_is_refused_before_the_work() -> None:
    with pytest.raises(OptionError, match=r"^-o: cannot write /proc/version: "):
        check_output_file("/proc/version", "-o")


def test_dash_is_standard_output(capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert str(check_output_file(STDOUT, "-o")) == STDOUT
    write_text_file(STDOUT, "to stdout\n", "-o")
    assert capsys.readouterr().out == "to stdout\n" and list(tmp_path.iterdir()) == []


def test_write_replaces_the_content(tmp_path: Path) -> None:
    f = tmp_path / "out.txt"
    f.write_text("a much longer old content\n")
    write_text_file(f, "new\n", "-o")
    assert f.read_text() == "new\n"
