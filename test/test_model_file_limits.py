"""Hostile model files: every case ends in one clean line, in bounded memory.

One test per crash class found by the mutation fuzzer (tools/fuzz_models.py) and
listed in the issue: binary content, non-regular files, oversized files, alias bombs, deep
nesting, huge numbers, NaN/infinity, strings and bools where numbers are expected, non-integer
counts, absurd declared sizes (YAML generator and .POMDP headers), long tokens, and the
``uncertainty.function`` values that crashed ``pomdp-planner check``. Memory is measured with
``tracemalloc`` (deterministic): a refusal must happen before anything of the refused size exists.
"""

from __future__ import annotations

import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml

from pomdp_planner.cli import main
from pomdp_planner.core.io import cassandra, file_text, model_yaml
from pomdp_planner.core.io.cassandra import export_pomdp, parse_pomdp
from pomdp_planner.core.io.model_yaml import MAX_YAML_DEPTH, load_model, model_from_dict, model_to_dict
from pomdp_planner.core.model import (
    MAX_MODEL_BYTES,
    MAX_NAME_CHARS,
    MESSAGE_VALUE_CHARS,
    POMDP,
    ModelError,
    check_model_size,
    format_bytes,
    model_bytes,
    short_repr,
)

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"
S3 = MODELS / "tracking_s3_info.yaml"
#: A clean message: one line, at most this many characters after the file name.
MAX_MESSAGE = 400


def explicit_text() -> str:
    return yaml.safe_dump(model_to_dict(load_model(S3)), sort_keys=False, default_flow_style=None)


def refused(path: Path, pattern: str, max_peak: int | None = None) -> str:
    """Load ``path``; assert a one-line ``ModelError`` naming the file and matching ``pattern``,
    and (``max_peak``) that the traced memory peak stayed below that many bytes."""
    tracemalloc.start()
    try:
        with pytest.raises(ModelError, match=pattern) as info:
            load_model(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    msg = str(info.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg and len(msg) <= len(str(path)) + MAX_MESSAGE, msg
    if max_peak is not None:
        assert peak < max_peak, f"peak {peak} bytes"
    return msg


def write(tmp_path: Path, name: str, content: str | bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    return path


# ------------------------------------------------------------------------ reading the file
@pytest.mark.parametrize("suffix", ["yaml", "POMDP"])
def test_binary_content_is_refused_with_the_offset(tmp_path, suffix):
    data = S3.read_bytes()
    path = write(tmp_path, f"bin.{suffix}", data[:100] + b"\xff\xfe\x00\x93" + data[100:])
    refused(path, r"is not UTF-8 text \(byte 0xff at offset 100")


def test_utf16_and_bom_and_old_mac_line_ends(tmp_path):
    text = explicit_text()
    refused(write(tmp_path, "utf16.yaml", text.encode("utf-16")), "not UTF-8 text")
    assert load_model(write(tmp_path, "bom.yaml", b"\xef\xbb\xbf" + text.encode())).S == 3
    assert load_model(write(tmp_path, "cr.yaml", text.replace("\n", "\r"))).S == 3


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_device_is_refused_before_reading():
    with pytest.raises(ModelError, match=r"^/dev/zero: cannot read model file: it is a character device"):
        load_model("/dev/zero")
    with pytest.raises(ModelError, match=r"cannot read \.POMDP file: it is a character device"):
        cassandra.load_pomdp_file("/dev/zero")


def test_fifo_and_directory_are_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)  # opening it for reading would block until a writer appears
    refused(fifo, "it is a FIFO")
    (tmp_path / "dir.yaml").mkdir()
    refused(tmp_path / "dir.yaml", "it is a directory")


def test_oversized_file_is_refused_before_parsing(tmp_path, monkeypatch):
    path = write(tmp_path, "big.yaml", explicit_text())
    monkeypatch.setattr(file_text, "MAX_MODEL_FILE_BYTES", 1000)
    refused(path, r"model file is .* larger than the limit of 1000 B \(MAX_MODEL_FILE_BYTES\)")


def test_default_file_limit_admits_large_explicit_models():
    assert file_text.MAX_MODEL_FILE_BYTES >= 8 * 2**20
    assert model_yaml.MAX_YAML_NODES >= 2 * 6 * 150 * 150 and cassandra.MAX_TOKENS >= 400_000


def test_value_and_word_counts_bound_the_parsing_time(tmp_path, monkeypatch):
    """A file of many tiny values (``[0,0,0,...]``) is refused once it passes the count, before
    anything else is built; the shipped models are far below it."""
    monkeypatch.setattr(model_yaml, "MAX_YAML_NODES", 1000)
    assert load_model(S3).S == 3
    refused(write(tmp_path, "many.yaml", "discount: 0.9\nreward: [" + "0," * 2000 + "0]\n"),
            r"line 2, column \d+: more than 1,000 values \(MAX_YAML_NODES\)")
    monkeypatch.setattr(cassandra, "MAX_TOKENS", 1000)
    refused(write(tmp_path, "many.POMDP", "discount: 0.9\nstates: 2\nstart: " + "0 " * 2000 + "\n"),
            r"line 3: more than 1,000 words \(MAX_TOKENS\)")


# ------------------------------------------------------------------------ YAML structure
@pytest.mark.parametrize("field", ["description", "name", "start", "states", "reward"])
def test_alias_bomb_is_refused_at_the_first_anchor(tmp_path, field):
    levels = [f"&a0 [{', '.join(['lol'] * 9)}]"] + [f"&a{k} [{', '.join([f'*a{k - 1}'] * 9)}]" for k in range(1, 9)]
    path = write(tmp_path, "bomb.yaml", S3.read_text() + f"\n{field}: [{', '.join(levels)}]\n")  # 9^9 if expanded
    refused(path, r"not valid YAML for a model file: line \d+, column \d+: anchors and aliases", max_peak=2 * 2**20)


def test_even_a_harmless_anchor_is_refused(tmp_path):
    path = write(tmp_path, "anchor.yaml", S3.read_text().replace("name: tracking_s3_info", "name: &n tracking"))
    refused(path, "anchors and aliases .* are not allowed")


@pytest.mark.parametrize("depth", [MAX_YAML_DEPTH + 1, 500, 100_000])
def test_deep_nesting_is_refused_without_recursion_error(tmp_path, depth):
    path = write(tmp_path, "deep.yaml", S3.read_text() + "\nstart: " + "[" * depth + "1" + "]" * depth + "\n")
    refused(path, "not valid YAML for a model file: .*(nested deeper than 16 levels|maximum nesting depth)")


def test_schema_depth_fits_the_limit():
    assert MAX_YAML_DEPTH >= 4  # top level -> transition -> action -> row
    text = explicit_text()
    assert "transition" in text and load_model(S3).S == 3


@pytest.mark.parametrize(("text", "pattern"), [
    ("discount: 0.9\nname: !!binary aGVsbG8=\n", "could not determine a constructor"),
    ("discount: !!python/object/apply:os.system ['echo hi']\n", "could not determine a constructor"),
    ("discount: 0.9\n---\ndiscount: 0.8\n", "expected a single document"),
    ("discount: [0.9\n", r"line 2, column 1: .*expected ',' or ']'"),
    ("discount: 0.9\x00\n", "control characters are not allowed"),
    ("discount: " + "9" * 5000 + "\n", "an integer of 5000 characters"),
])
def test_yaml_errors_are_one_line(tmp_path, text, pattern):
    refused(write(tmp_path, "m.yaml", text), pattern)


# ------------------------------------------------------------------------ values and types
@pytest.mark.parametrize(("old", "new", "pattern"), [
    ("discount: 0.99", 'discount: "0.5"', "discount: must be a number, got a string '0.5'"),
    ("discount: 0.99", "discount: true", r"discount: must be a number, got a boolean \(True\)"),
    ("discount: 0.99", "discount: [0.5]", "discount: must be a number, got a list"),
    ("discount: 0.99", "discount: .nan", "discount: must be a finite number, got nan"),
    ("discount: 0.99", "discount: " + "9" * 400, r"line 6, column 11: an integer of 400 characters \(at most 64\)"),
    ("discount: 0.99", "discount: 2024-01-01", "discount: must be a number, got a string '2024-01-01'"),
    ("S: 3,", "S: 3.9,", r"generator.S: must be an integer count, got the number 3.9"),
    ("S: 3,", "S: 3.0,", r"generator.S: must be an integer count, got the number 3.0"),
    ("S: 3,", "S: '3',", r"generator.S: must be an integer count, got a string '3'"),
    ("states: 3", "states: 3.0", "states: expected a positive count or a non-empty list of names, got the number 3.0"),
    ("q: 0.7", "q: .inf", "generator.q: must be a finite number, got inf"),
    ("x: [1, 2, 3]", "x: [1, " + "9" * 400 + ", 3]", "an integer of 400 characters"),
    ("[2.0, 2.5, 1.0]", "[2.0, '2.5', 1.0]", r"reward\[0\]\[1\]: must be a number, got a string '2.5'"),
    ("[2.0, 2.5, 1.0]", "[2.0, 1.0e999, 1.0]", r"reward\[0\]\[1\]: value is not finite \(inf\)"),
    ("[2.0, 2.5, 1.0]", "[2.0, null, 1.0]", r"reward\[0\]\[1\]: must be a number, got null"),
    ("weights: [1.1, 1.6, 1.0]", "weights: [1.1, true, 1.0]",
     r"uncertainty.weights\[1\]: must be a number, got a bool"),
    ("weights: [1.1, 1.6, 1.0]", "weights: [1.1, yes, 1.0]",
     r"uncertainty.weights\[1\]: must be a number, got a string 'yes'"),
    ("epsilon: 0.001", "epsilon: '1e-3'", "uncertainty.epsilon: must be a number, got a string"),
    ("name: tracking_s3_info", "name: [a, b]", "name: must be a string, got a list"),
    ("name: tracking_s3_info", 'name: "a\\nb"', "name: must be one line of at most 256 printable characters"),
    ("description: Paper Sec. VI-A, information-acquisition tracking with S = 3", "description: {a: 1}",
     "description: must be a string, got a mapping"),
    ("states: 3", "states: [a, [b], c]", r"states\[1\]: must be a string, got a list"),
    ("states: 3", "7: 3", "top level: field names must be strings, got the integer 7"),
])
def test_wrong_types_name_the_field(tmp_path, old, new, pattern):
    text = S3.read_text()
    assert old in text
    refused(write(tmp_path, "m.yaml", text.replace(old, new, 1)), pattern)


def test_integers_too_large_for_a_float_from_code():
    doc = model_to_dict(load_model(S3))
    doc["reward"][0][1] = 10**400
    with pytest.raises(ModelError, match=r"^<dict>: reward\[0\]\[1\]: number too large for a float \(<integer of"):
        model_from_dict(doc)
    with pytest.raises(ModelError, match="discount: number too large for a float"):
        model_from_dict({**model_to_dict(load_model(S3)), "discount": 10**400})


def test_exponent_without_point_is_a_number(tmp_path):
    text = S3.read_text().replace("epsilon: 0.001", "epsilon: 1e-3")
    assert load_model(write(tmp_path, "m.yaml", text)).epsilon == 1e-3


@pytest.mark.parametrize("function", ["[renyi2]", "{name: renyi2}", "1", "null", "true"])
def test_uncertainty_function_of_wrong_type_is_exit_2(tmp_path, capsys, function):
    text = S3.read_text().replace("function: renyi2", f"function: {function}")
    path = write(tmp_path, "m.yaml", text)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "uncertainty.function: must be the name of a function (none, renyi2, shannon)" in err


def test_pomdp_refuses_a_non_string_uncertainty():
    P, O, r = np.full((1, 2, 2), 0.5), np.ones((1, 2, 1)), np.zeros((2, 1))
    for bad in ([1], {"f": 1}, 3, None):
        with pytest.raises(ModelError, match=r"uncertainty.function: must be the name of a function"):
            POMDP(P=P, O=O, r=r, gamma=0.5, uncertainty=bad)


def test_messages_quote_bounded_values(tmp_path):
    huge = "x" * 1_000_000
    for text in (S3.read_text().replace("function: renyi2", f"function: {huge}"),
                 S3.read_text().replace("start", "start") + f"\nstart: {huge}\n",
                 S3.read_text() + f"\n{huge}: 1\n",
                 S3.read_text().replace("name: tracking_s3_info", f"name: {huge}")):
        msg = refused(write(tmp_path, "m.yaml", text), ".")
        assert len(msg) < len(str(tmp_path)) + 300


def test_short_repr_is_bounded_for_anything():
    assert short_repr("abc") == "'abc'"
    for value in ("x" * 10**6, [[list(range(10**5))]] * 1000, {str(i): i for i in range(10**5)}, 10**5000, -(10**400)):
        text = short_repr(value)
        assert len(text) <= MESSAGE_VALUE_CHARS and "\n" not in text
    assert "digits" in short_repr(10**5000)


# ------------------------------------------------------------------------ sizes before allocating
def test_generator_size_is_checked_before_generating(tmp_path):
    text = S3.read_text()
    contradicted = text.replace("S: 3,", "S: 5000,")
    refused(write(tmp_path, "a.yaml", contradicted), "states: declares 3 but generator.S is 5000", max_peak=2**20)
    alone = "\n".join(line for line in contradicted.splitlines()
                      if not line.startswith(("states", "observations", "reward", "  -")))
    alone = alone.replace(", x: [1, 2, 3], y: [-9, -8, -7, -6, -5, -4, -3, -2, -1]", "")
    alone += "\nreward_generator: {kind: tracking_comparison}\n"
    need = format_bytes(model_bytes(5000, 3, 5000))
    refused(write(tmp_path, "b.yaml", alone),
            rf"generator: S=5000, A=3, Z=5000 need {need} .*the limit is 128 MiB \(MAX_MODEL_BYTES\)", max_peak=2**20)


def test_check_model_size_is_the_documented_budget():
    check_model_size(1600, 3, 1600, "f")  # the documented example fits
    with pytest.raises(ModelError, match=r"^f: S=1700, A=3, Z=1700 need"):
        check_model_size(1700, 3, 1700, "f")
    assert model_bytes(1600, 3, 1600) <= MAX_MODEL_BYTES < model_bytes(1700, 3, 1700)


def test_pomdp_header_bomb_is_refused_before_anything_of_its_size_exists(tmp_path):
    # 20 000 states fit (stored sparse), but a uniform transition over them does not: refused at the
    # entry, before it expands (4e8 cells, or 1e8 non-zeros of 12 bytes for 10 000 states)
    path = write(tmp_path, "bomb.POMDP", "discount: 0.9\nstates: 20000\nactions: 1\nobservations: 1\nT: * uniform\n")
    assert len(path.read_bytes()) < 80
    refused(path, r"line 5: the T:, O: and R: entries so far write 400,000,000 matrix cells, more than the limit of "
            r"100,000,000 \(MAX_ENTRY_CELLS\)", max_peak=2**20)
    path = write(tmp_path, "bomb2.POMDP", "discount: 0.9\nstates: 10000\nactions: 1\nobservations: 1\nT: * uniform\n")
    refused(path, r"line 5: the T: and O: entries so far: S=10000, A=1, Z=1 with 100,000,000 non-zeros need "
            r"1.12 GiB .*MAX_MODEL_BYTES", max_peak=2**20)
    # the smallest model the header allows (one non-zero per row of T and O) does not fit: at the header
    late = write(tmp_path, "late.POMDP", "discount: 0.9\nstates: 5\nactions: 10000000\nobservations: 5\n")
    refused(late, r"line 3: actions: S=5, A=10000000, Z=1 with 100,000,000 non-zeros need", max_peak=2**20)


def test_pomdp_end_state_rewards_need_the_4d_array_within_budget(tmp_path, monkeypatch):
    text = "discount: 0.9\nstates: 60\nactions: 2\nobservations: 60\nT: * uniform\nO: * uniform\nR: * : * : 0 : 0 1.0\n"
    m = parse_pomdp(text)  # R(s, a, s', z) = 1 at s' = z = 0 only: r(s, a) = P(0|s,a) O(0|0,a) = 1/3600
    np.testing.assert_allclose(m.r, np.full((60, 2), 1 / 3600), rtol=1e-12)
    monkeypatch.setattr(cassandra, "MAX_MODEL_BYTES", 2**20)  # 2 * 60^3 * 8 bytes = 3.3 MiB do not fit
    with pytest.raises(ModelError, match=r"line 7: R: rewards that depend on the end state .* of 3.3 MiB"):
        parse_pomdp(text)


def test_pomdp_entries_cannot_keep_the_parser_busy(monkeypatch):
    head = "discount: 0.9\nstates: 100\nactions: 3\nobservations: 1\n"
    text = head + "T: * uniform\n" * 30 + "O: * uniform\n"
    assert parse_pomdp(text).S == 100  # 30 * 30000 cells
    monkeypatch.setattr(cassandra, "MAX_ENTRY_CELLS", 500_000)
    with pytest.raises(ModelError, match=r"line 21: the T:, O: and R: entries so far write 510,000 matrix cells"):
        parse_pomdp(text)


def test_pomdp_long_tokens_and_bad_meta(tmp_path):
    model = load_model(MODELS / "tracking_s2_info.yaml")
    text = export_pomdp(model)
    refused(write(tmp_path, "long.POMDP", text.replace("values: reward", "values: " + "r" * 10**5)),
            r"line \d+: a word of 100000 characters \(at most 256\): 'rrrr")
    bomb = text + "# pomdp_planner: " + "[" * 10**5 + "\n"
    assert load_model(write(tmp_path, "meta.POMDP", bomb)).S == 2  # a broken meta comment is ignored
    injected = text.replace('{"name": "tracking_s2_info"', '{"name": "a\\nb"')
    assert load_model(write(tmp_path, "inj.POMDP", injected)).name == "inj"  # invalid name: the file's stem


def test_names_are_single_lines_so_export_cannot_inject_lines():
    base = load_model(S3)
    with pytest.raises(ModelError, match="name: must be one line"):
        model_from_dict({**model_to_dict(base), "name": "x\ndiscount: 0.1"})
    with pytest.raises(ModelError, match=rf"at most {MAX_NAME_CHARS}"):
        model_from_dict({**model_to_dict(base), "name": "x" * (MAX_NAME_CHARS + 1)})


def test_pomdp_element_lines_are_bounded_by_their_own_count(monkeypatch):
    """Element lines read in bulk count against MAX_ELEMENT_LINES (cheap lines), words against
    MAX_TOKENS; both refusals name the line."""
    head = "discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nO: 0 : * : 0 1.0\n"  # 20 words
    text = head + "T: 0 : 0 : 1 0.5\n" * 30 + "T: 0 : 0 : 0 0.5\nT: 0 : 1 : 1 1.0\n"
    assert parse_pomdp(text).P[0, 0, 0] == 0.5
    monkeypatch.setattr(cassandra, "MAX_ELEMENT_LINES", 20)
    with pytest.raises(ModelError, match=r"^<string>: line 26: more than 20 element lines \(MAX_ELEMENT_LINES\)$"):
        parse_pomdp(text)
    monkeypatch.setattr(cassandra, "MAX_ELEMENT_LINES", 10**6)
    monkeypatch.setattr(cassandra, "MAX_TOKENS", 20)
    assert parse_pomdp(text).S == 2  # the lines read in bulk are no words
    with pytest.raises(ModelError, match=r"^<string>: line 6: more than 20 words \(MAX_TOKENS\)$"):
        parse_pomdp(head + "T: 0 : 0 : 0 0.5 T: 0 : 1 : 1 1.0\n")  # two entries on a line: read word by word
