"""`cell render` with bad output paths and impossible parts: exit 2, a clear line, nothing written, no input lost."""

import json
import shutil
import time

import pytest
from conftest import run_cli

from calibration import default_calibration_path
from cell.grasp import shapes
from cell.scene import Scene


@pytest.fixture
def scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    box = shapes.rectangle("box", 50, 30, (300, 100), 30)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(Scene((box,), "box").to_json()))
    shutil.copy(default_calibration_path(), tmp_path / "cal.json")
    (tmp_path / "adir").mkdir()
    return path


def _files(tmp_path):
    return {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}


@pytest.mark.parametrize("extra, message", [
    (["--out", "frame.xyz"], "OpenCV writes no '.xyz' images"),  # was: internal error (cv2.error)
    (["--out", "scene.json"], "OpenCV writes no '.json' images"),
    (["--out", "adir"], "--out adir is a directory, not a file"),  # was: [Errno 21] naming a temp file
    (["--out", "scene.json/frame.png"], "scene.json is a file, not a folder"),  # was: [Errno 17] File exists
    # was: exit 0, the frame replaced by the truth JSON
    (["--out", "frame.png", "--truth", "frame.png"], "--truth frame.png is also --out: the image and its outlines"),
    (["--out", "frame.png", "--truth", "scene.json"], "--truth scene.json is one of the inputs"),  # was: the
    # scene replaced by the truth JSON
    (["--out", "frame.png", "--calibration", "cal.json", "--truth", "cal.json"], "--truth cal.json is one of"),
    (["--out", "frame.png", "--truth", "adir"], "--truth adir is a directory"),  # was: frame.png written first
    (["--out", "frame.png", "--truth", "scene.json/t.json"], "scene.json is a file, not a folder"),
])
def test_bad_outputs_are_refused_before_anything_is_written(scene, tmp_path, capsys, extra, message):
    before = _files(tmp_path)
    code, out, err = run_cli("render", scene, *extra, capsys=capsys)
    assert code == 2 and message in err and "internal error" not in err and out == "", err
    assert _files(tmp_path) == before  # nothing written, nothing replaced
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.parametrize("z_top", [800.0, 5e4, 1e5])
def test_a_part_reaching_the_camera_is_refused_at_once(scene, tmp_path, capsys, z_top):
    """It was drawn for minutes (a shadow blurred over its whole 50 m height) or without end."""
    raw = json.loads(scene.read_text())
    raw["parts"][0]["z_top"] = z_top
    scene.write_text(json.dumps(raw))
    t0 = time.monotonic()
    code, out, err = run_cli("render", scene, "--out", "frame.png", capsys=capsys)
    assert code == 2 and "at or above the camera" in err and "'box'" in err, err
    assert time.monotonic() - t0 < 10 and not (tmp_path / "frame.png").exists()


def test_a_part_just_below_the_camera_is_drawn(scene, tmp_path, capsys):
    raw = json.loads(scene.read_text())
    raw["parts"][0]["z_top"] = 700.0
    scene.write_text(json.dumps(raw))
    code, out, err = run_cli("render", scene, "--out", "frame", "--truth", "t.json", "--no-noise", capsys=capsys)
    assert code == 0, err
    assert (tmp_path / "frame").read_bytes()[:4] == b"\x89PNG" and json.loads((tmp_path / "t.json").read_text())


@pytest.mark.parametrize("which", ["cell", "calibration"])
def test_truth_over_the_shipped_default_it_read_is_refused(scene, tmp_path, monkeypatch, capsys, which):
    """With no --cell or --calibration named, the shipped defaults are inputs too: --truth naming one replaced
    it with the truth JSON (exit 0), and every command then failed on it. Copies stand in for the shipped
    files here, so that a regression cannot damage the real ones."""
    import calibration
    import cell.cellconfig
    from cell.cellconfig import default_cell_path

    copies = {"cell": tmp_path / "default_cell.json", "calibration": tmp_path / "default_cal.json"}
    shutil.copy(default_cell_path(), copies["cell"])
    shutil.copy(default_calibration_path(), copies["calibration"])
    monkeypatch.setattr(cell.cellconfig, "default_cell_path", lambda: copies["cell"])
    monkeypatch.setattr(calibration, "default_calibration_path", lambda: copies["calibration"])
    before = _files(tmp_path)
    code, out, err = run_cli("render", scene, "--out", "frame.png", "--truth", copies[which], capsys=capsys)
    assert code == 2 and out == "" and f"--truth {copies[which]} is one of the inputs" in err
    assert _files(tmp_path) == before
