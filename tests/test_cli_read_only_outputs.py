"""A read-only output file (chmod 444) or folder (chmod 555) is refused with exit 2 before anything is
written: the atomic write renames a temp file over the output, which only the folder's permissions stop,
so a read-only file was replaced without a word (and root writes into a read-only folder too)."""

import json
import os
from pathlib import Path

import pytest
from conftest import ROOT, run_cli

from cell.errors import BadInput
from cell.fileio import write_atomic

ASSEMBLY = ROOT / "cell" / "data" / "assemblies" / "default.json"
OLD = b"keep me\n"


def _read_only_file(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(OLD)
    path.chmod(0o444)
    return path


def test_write_atomic_leaves_a_read_only_file_as_it_is(tmp_path):
    target = _read_only_file(tmp_path / "a.json")
    with pytest.raises(BadInput, match=r"a\.json is read-only: not replaced$"):
        write_atomic(target, b"new")
    assert target.read_bytes() == OLD and os.listdir(tmp_path) == ["a.json"]  # no temp file either


def _plane_points(tmp_path):
    import cv2
    import numpy as np

    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((480, 640, 3), np.uint8))
    grid = [((100 * i + 50, 80 * j + 40), (200 + 10 * i, -50 + 10 * j, 0)) for i in range(3) for j in range(3)]
    (tmp_path / "p.json").write_text(json.dumps({"points": [{"px": list(px), "mm": list(mm)} for px, mm in grid]}))
    return ["calibrate", "plane", tmp_path / "f.png", "--points", tmp_path / "p.json"]


# (argv before the output, the output's option, the output file relative to the option's value)
CASES = {
    "examples-overwrite": (lambda t: ["examples", "generate", "--count", "1", "--overwrite"], "--out", "ex.jsonl", ""),
    "examples-append": (lambda t: ["examples", "generate", "--count", "1", "--append"], "--out", "ex.jsonl", ""),
    "render-out": (lambda t: ["render", ASSEMBLY], "--out", "o.png", ""),
    "render-truth": (lambda t: ["render", ASSEMBLY, "--out", t / "o.png"], "--truth", "t.json", ""),
    "plan-figures": (lambda t: ["plan", ASSEMBLY], "--figures", "fig", "step_02_housing.png"),
    "calibrate-plane": (_plane_points, "--out", "cal.json", ""),
    "study": (lambda t: ["study", "--budget", "tiny"], "--out", "st", "report.md"),
    "run-save": (lambda t: ["run"], "--save", "v.rrd", ""),
}


@pytest.mark.parametrize("case", CASES)
def test_a_read_only_output_is_refused_before_anything_is_written(tmp_path, capsys, case):
    argv, option, value, inside = CASES[case]
    argv = argv(tmp_path)
    ro = _read_only_file(tmp_path / value / inside if inside else tmp_path / value)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    code, out, err = run_cli(*argv, option, tmp_path / value, capsys=capsys)
    assert code == 2 and err == f"cell: error: {option} {ro} is read-only: not replaced\n", err
    assert ro.read_bytes() == OLD and sorted(p.name for p in tmp_path.rglob("*")) == before


def test_an_output_in_a_read_only_folder_is_refused_even_for_root(tmp_path, capsys):
    """Root may write into a chmod 555 folder: the folder's mode says it is not to be written."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    code, out, err = run_cli("examples", "generate", "--count", "1", "--out", ro / "ex.jsonl", capsys=capsys)
    assert code == 2 and err == f"cell: error: --out {ro / 'ex.jsonl'}: the folder {ro} is not writable\n"
    assert os.listdir(ro) == []
    code, out, err = run_cli("run", "--record", ro, capsys=capsys)  # an empty folder is a recording's place
    assert code == 2 and err == f"cell: error: cannot write the recording into {ro}: the folder {ro} is not writable\n"
    assert os.listdir(ro) == []


def test_a_read_only_example_file_the_station_would_append_to_is_refused_before_the_run(tmp_path):
    """The station's rejects and teaching are appended to --examples: the first one stopped the run."""
    import shutil
    import subprocess
    import sys

    ex = tmp_path / "ex.jsonl"
    shutil.copyfile(ROOT / "cell" / "data" / "default_examples.jsonl", ex)
    ex.chmod(0o444)
    p = subprocess.run([sys.executable, "-m", "cell", "run", "--station", "--port", "0", "--examples", str(ex)],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)  # else it serves the station
    assert p.returncode == 2 and p.stderr == f"cell: error: --examples {ex} is read-only: not replaced\n", p.stderr
