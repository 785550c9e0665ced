"""The installed ``pomdp-planner`` as a user runs it, in real processes: model names from any
directory, outputs that would block, Ctrl-C while the command is still starting.

* Model names resolve as the nodes resolve theirs (``core.io.paths.resolve_path``): from a
  temporary working directory, a bare shipped name, a path relative to the package
  (``config/models/...``) and a file in the working directory all work, for every command
  taking a model; a name found nowhere is one line that lists where it looked.
* An output that is not a regular file (a FIFO) is refused at once: opening a FIFO for writing
  blocks until a reader comes, so each run has a timeout; ``-`` is standard output; an output
  check changes nothing when the work then fails.
* SIGINT during start-up (the command imports numpy, scipy and the solvers for most of a
  second) ends with exit code 130 and the one line ``pomdp-planner: interrupted``, no traceback.
  The signal is sent at offsets after the process has begun importing numpy (seen through
  ``python -X importtime``), so each case is inside the start-up on a loaded machine too.

The executable is the one ``make setup`` installed next to this interpreter; without it the
tests are skipped, unless ``POMDP_PLANNER_REQUIRE_INSTALLED=1`` (set by ``make test``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).with_name("pomdp-planner")
S2, S3 = (str(REPO / "config" / "models" / f"tracking_s{n}_info.yaml") for n in (2, 3))
#: Seconds a command may take here before it counts as blocked (a blocked one never ends).
TIMEOUT = 120

if not EXE.is_file():
    if os.environ.get("POMDP_PLANNER_REQUIRE_INSTALLED") == "1":
        raise RuntimeError(f"{EXE} is not installed (POMDP_PLANNER_REQUIRE_INSTALLED=1): run `make setup`")
    pytest.skip(f"{EXE} is not installed; run `make setup`", allow_module_level=True)


def run(cwd: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    """``pomdp-planner ARGV`` in ``cwd`` (TimeoutExpired if it blocks)."""
    return subprocess.run([str(EXE), *argv], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT)


def one_error_line(proc: subprocess.CompletedProcess[str]) -> str:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    return lines[0]


# ------------------------------------------------------------------ model names
# (command with the model inserted after its first word, what its output then contains)
MODEL_COMMANDS = [
    (["check"], "model: tracking_s2_info"), (["bounds", "--samples", "2"], "tracking_s2_info: S=2"),
    (["plan", "--depth", "1"], "action: priority"), (["simulate", "--steps", "1"], "# tracking_s2_info: S=2"),
    (["export", "--format", "yaml"], "name: tracking_s2_info"),
]


@pytest.mark.parametrize("name", ["tracking_s2_info", "tracking_s2_info.yaml", "config/models/tracking_s2_info.yaml"])
@pytest.mark.parametrize(("command", "expected"), MODEL_COMMANDS, ids=[c[0][0] for c in MODEL_COMMANDS])
def test_shipped_model_names_resolve_from_any_directory(tmp_path: Path, command: list[str], expected: str,
                                                        name: str) -> None:
    proc = run(tmp_path, command[0], name, *command[1:])
    assert proc.returncode == 0, proc.stderr
    assert expected in proc.stdout


def test_a_file_in_the_working_directory_comes_first(tmp_path: Path) -> None:
    """As for the nodes: relative to the current directory before the package."""
    text = (REPO / "config" / "models" / "tracking_s2_info.yaml").read_text()
    (tmp_path / "config" / "models").mkdir(parents=True)
    (tmp_path / "config" / "models" / "tracking_s2_info.yaml").write_text(text.replace("name: tracking_s2_info",
                                                                                       "name: my_copy"))
    (tmp_path / "mine.yaml").write_text(text.replace("name: tracking_s2_info", "name: mine"))
    proc = run(tmp_path, "check", "config/models/tracking_s2_info.yaml")
    assert proc.returncode == 0 and proc.stdout.startswith("model: my_copy\n"), proc.stderr
    proc = run(tmp_path, "check", "mine.yaml")
    assert proc.returncode == 0 and proc.stdout.startswith("model: mine\n"), proc.stderr
    proc = run(tmp_path, "check", str(tmp_path / "mine.yaml"))
    assert proc.returncode == 0 and proc.stdout.startswith("model: mine\n"), proc.stderr


NODE_RESOLVER = """
import sys
from pomdp_planner.core.io.sensors import load_model_file
try:
    load_model_file(sys.argv[1])
except ValueError as exc:
    print(exc)
"""


def test_a_missing_name_lists_where_it_looked_as_the_nodes_do(tmp_path: Path) -> None:
    line = one_error_line(run(tmp_path, "check", "no_such_model"))
    node = subprocess.run([sys.executable, "-c", NODE_RESOLVER, "no_such_model"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=TIMEOUT)  # what an installed node says of its model_file parameter
    assert node.stdout.startswith("model_file: 'no_such_model' not found (looked in "), node.stderr
    assert line == "pomdp-planner: error: " + node.stdout.strip().replace("model_file:", "MODEL:", 1)
    assert f"(looked in {tmp_path}, " in line and str(Path(sys.prefix) / "share" / "pomdp_planner") in line


def test_a_directory_named_like_a_model_is_refused_by_what_it_is(tmp_path: Path) -> None:
    (tmp_path / "adir.yaml").mkdir()
    assert one_error_line(run(tmp_path, "check", "adir.yaml")).endswith("adir.yaml is a directory, not a regular file")


# ------------------------------------------------------------------ outputs
@pytest.mark.parametrize("argv", [["export", "tracking_s2_info", "-o", "{fifo}"],
                                  ["bench", "search", "--model", "tracking_s2_info", "--quick", "--json", "{fifo}"]],
                         ids=["export -o", "bench search --json"])
def test_a_fifo_output_is_refused_without_blocking(tmp_path: Path, argv: list[str]) -> None:
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    line = one_error_line(run(tmp_path, *[a.replace("{fifo}", str(fifo)) for a in argv]))
    assert f"cannot write {fifo}: it is a FIFO (named pipe), not a regular file" in line


def test_dash_is_standard_output(tmp_path: Path) -> None:
    plain = run(tmp_path, "export", "tracking_s2_info", "--format", "yaml")
    dash = run(tmp_path, "export", "tracking_s2_info", "--format", "yaml", "-o", "-")
    assert plain.returncode == dash.returncode == 0 and dash.stdout == plain.stdout and "transition:" in dash.stdout
    proc = run(tmp_path, "bench", "search", "--model", "tracking_s2_info", "--beliefs", "2", "--timed", "1",
               "--quick", "--json", "-")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)  # the JSON alone on stdout; the text report went to stderr
    assert data["models"][0]["model"] == "tracking_s2_info" and "Table II" in proc.stderr
    assert not (tmp_path / "-").exists()


def test_checking_an_output_changes_nothing_when_the_work_fails(tmp_path: Path) -> None:
    existing = tmp_path / "existing.yaml"
    existing.write_text("keep me\n")
    one_error_line(run(tmp_path, "export", "no_such_model", "-o", str(existing)))
    assert existing.read_text() == "keep me\n"
    one_error_line(run(tmp_path, "export", "no_such_model", "-o", str(tmp_path / "new.yaml")))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.yaml"]  # no file, no probe left behind


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write a read-only file")
def test_a_file_without_write_permission_is_refused_before_the_work(tmp_path: Path) -> None:
    locked = tmp_path / "locked.json"
    locked.write_text("")
    locked.chmod(0o444)
    line = one_error_line(run(tmp_path, "bench", "search", "--model", "tracking_s2_info", "--json", str(locked)))
    assert "--json: cannot write" in line


# ------------------------------------------------------------------ Ctrl-C during start-up
def _interrupt_during_start_up(tmp_path: Path, offset: float) -> subprocess.CompletedProcess[str]:
    """Start ``pomdp-planner check``, wait until it imports numpy, wait ``offset`` s, send SIGINT."""
    proc = subprocess.Popen([sys.executable, "-X", "importtime", str(EXE), "check", S3], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    seen: list[str] = []
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        if line.startswith("import time:") and "numpy" in line:  # the command line's own imports have begun
            time.sleep(offset)
            proc.send_signal(signal.SIGINT)
            break
    else:
        proc.kill()
    out, err = proc.communicate(timeout=TIMEOUT)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, "".join(seen) + err)


@pytest.mark.parametrize("offset", [0.0, 0.05, 0.1, 0.2, 0.3])
def test_sigint_during_start_up_is_exit_130_and_one_line(tmp_path: Path, offset: float) -> None:
    proc = _interrupt_during_start_up(tmp_path, offset)
    lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("import time:")]
    assert proc.returncode == 130 and lines == ["pomdp-planner: interrupted"], proc.stderr[-3000:]
    assert proc.stdout == ""  # interrupted before it printed anything: still starting


def test_sigint_while_working_is_exit_130_and_one_line(tmp_path: Path) -> None:
    proc = subprocess.Popen([str(EXE), "simulate", S3, "--steps", "100000000", "--policy", "bnb",
                             "--option", "depth=2"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None
    for _ in range(6):  # the header lines and a few steps: the work has begun
        proc.stdout.readline()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=TIMEOUT)
    assert proc.returncode == 130 and err.strip().splitlines() == ["pomdp-planner: interrupted"], err[-3000:]


def test_an_ignored_sigint_stays_ignored_during_start_up(tmp_path: Path) -> None:
    """A background job of a non-interactive shell ignores SIGINT: the start-up guard keeps it so."""
    proc = subprocess.Popen([str(EXE), "check", S2], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=TIMEOUT)
    assert proc.returncode == 0 and out.startswith("model: tracking_s2_info"), err


def test_python_m_is_the_same_command(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "pomdp_planner", "check", "tracking_s2_info"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 0 and proc.stdout == run(tmp_path, "check", "tracking_s2_info").stdout
