"""The one path resolver (core/io/paths.py): order of lookup and errors that name the field."""

from pathlib import Path

import pytest

from pomdp_planner.cli import main
from pomdp_planner.core.io.paths import SOURCE_ROOT, resolve_path, shipped_model_path
from pomdp_planner.core.model import ModelError


def test_relative_path_is_tried_from_the_current_directory_first(tmp_path, monkeypatch):
    (tmp_path / "config" / "models").mkdir(parents=True)
    mine = tmp_path / "config" / "models" / "tracking_s3_info.yaml"
    mine.write_text("not the shipped one")
    monkeypatch.chdir(tmp_path)
    assert resolve_path("config/models/tracking_s3_info.yaml") == mine


def test_relative_path_falls_back_to_the_package(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = resolve_path("config/models/tracking_s3_info.yaml")
    assert p.is_file() and p.name == "tracking_s3_info.yaml"


def test_bare_shipped_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_path("tracking_s8_info").name == "tracking_s8_info.yaml"
    assert shipped_model_path("tracking_s3_info") == resolve_path("tracking_s3_info.yaml")


def test_absolute_path_must_exist(tmp_path):
    with pytest.raises(ModelError, match=r"^params file: file .*nope\.yaml does not exist"):
        resolve_path(str(tmp_path / "nope.yaml"), "params file")


def test_missing_relative_path_names_field_and_places(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ModelError) as err:
        resolve_path("config/models/nope.yaml")
    msg = str(err.value)
    assert msg.startswith("model_file: 'config/models/nope.yaml' not found (looked in ")
    assert str(Path(SOURCE_ROOT) / "config" / "models") in msg


@pytest.mark.parametrize("bad", ["", "   "])
def test_empty_path(bad):
    with pytest.raises(ModelError, match=r"^model_file: empty path$"):
        resolve_path(bad)


LONG = "c" * 300  # longer than a file name may be (NAME_MAX 255)
S3_MODEL = str(Path(__file__).resolve().parents[1] / "config" / "models" / "tracking_s3_info.yaml")


@pytest.mark.parametrize("argv,field", [
    (["check", f"/tmp/{LONG}.yaml"], "MODEL"), (["bounds", f"{LONG}.yaml"], "MODEL"),
    (["export", f"/tmp/{LONG}/m.yaml"], "MODEL"), (["simulate", f"/tmp/{LONG}.yaml"], "MODEL"),
    (["plan", f"/tmp/{LONG}.yaml"], "MODEL"),
    (["simulate", "--targets", f"{S3_MODEL},/tmp/{LONG}.yaml", "--budget", "1"], "--targets[1]"),
    (["simulate", S3_MODEL, "--record", f"/tmp/{LONG}.csv"], "--record"),
    (["export", S3_MODEL, "-o", f"/tmp/{LONG}.pomdp"], "-o/--output"),
    (["plot", "run.csv", "-o", f"/tmp/{LONG}.png"], "--output"),
    (["bench", "all", "--output", f"/tmp/{LONG}"], "--output"),
])
def test_a_path_part_longer_than_a_file_name_is_one_line_in_every_subcommand(argv, field, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err[-2000:]
    assert lines[0].startswith(f"pomdp-planner: error: {field}: a part of the path is ")
    assert "more than a file or folder name may have (255)" in lines[0] and len(lines[0]) < 300


@pytest.mark.parametrize("argv", [["plot", f"/tmp/{LONG}.csv", "-o", "/tmp/x.png"],
                                  ["plot", f"/tmp/{LONG}.mcap", "-o", "/tmp/x.png"], ["replay", f"/tmp/{LONG}.mcap"]])
def test_a_record_or_bag_with_a_long_file_name_is_one_line(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a part of the path is" in err[0] and len(err[0]) < 300, err
