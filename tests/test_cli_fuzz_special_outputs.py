"""An output path that is a pipe (or a device: --out /dev/null, run as root) must not be replaced by a file.

Files are written to a temp file renamed over the target: over a FIFO that put a plain file in its place
(exit 0), and the same would have replaced /dev/null. Such paths are refused (render and examples
before any work), the pipe left as it was. (Tests use FIFOs in a temp folder, never a real device.)"""

import json
import os
import stat

import pytest
from conftest import run_cli

from cell.errors import BadInput
from cell.fileio import write_atomic
from cell.grasp import shapes
from cell.scene import Scene


@pytest.fixture
def pipe(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    os.mkfifo(tmp_path / "pipe")
    box = shapes.rectangle("box", 50, 30, (300, 100), 30)
    (tmp_path / "scene.json").write_text(json.dumps(Scene((box,), "box").to_json()))
    return tmp_path / "pipe"


def _still_a_pipe(path):
    return stat.S_ISFIFO(os.lstat(path).st_mode)


@pytest.mark.parametrize("argv, message", [
    (["render", "scene.json", "--out", "pipe"], "--out pipe: it is not a regular file"),
    (["render", "scene.json", "--out", "f.png", "--truth", "pipe"], "--truth pipe: it is not a regular file"),
    (["examples", "generate", "--out", "pipe", "--overwrite", "--count", "1"], "--out pipe: it is not a regular"),
])
def test_an_output_that_is_a_pipe_is_refused_and_kept(pipe, tmp_path, capsys, argv, message):
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and message in err, err
    assert _still_a_pipe(pipe) and sorted(p.name for p in tmp_path.iterdir()) == ["pipe", "scene.json"]


def test_a_calibration_is_not_written_over_a_pipe(pipe, tmp_path, capsys):
    points = {"points": [{"px": [100 * i + 50, 80 * j + 40], "mm": [200 + 10 * i, -50 + 10 * j, 0]}
                         for i in range(3) for j in range(3)]}
    (tmp_path / "p.json").write_text(json.dumps(points))
    import cv2
    import numpy as np

    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((480, 640, 3), np.uint8))
    code, out, err = run_cli("calibrate", "plane", "f.png", "--points", "p.json", "--out", "pipe", capsys=capsys)
    assert code == 2 and "pipe: it is not a regular file" in err and out == "", err
    assert _still_a_pipe(pipe)


def test_write_atomic_never_renames_over_a_pipe(pipe, tmp_path):
    with pytest.raises(BadInput, match="not a regular file"):
        write_atomic(pipe, "x")
    assert _still_a_pipe(pipe) and not list(tmp_path.glob(".*.tmp"))
