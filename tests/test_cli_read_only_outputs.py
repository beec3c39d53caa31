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


# (argv before the output, the output's option, the output's name in the read-only folder)
NEW_FOLDER_CASES = {
    "render-out": (["render", ASSEMBLY], "--out", "new/o.png"),
    "plan-figures": (["plan", ASSEMBLY], "--figures", "figs"),
    "study": (["study", "--budget", "tiny"], "--out", "st"),
    "run-save": (["run"], "--save", "new/v.rrd"),
}


@pytest.mark.parametrize("case", NEW_FOLDER_CASES)
def test_an_output_to_be_made_in_a_read_only_folder_is_refused_even_for_root(tmp_path, capsys, case):
    """Was: --figures, study --out and --save made their folder first (root may), then wrote into it."""
    argv, option, name = NEW_FOLDER_CASES[case]
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    code, out, err = run_cli(*argv, option, ro / name, capsys=capsys)
    assert code == 2 and err.startswith(f"cell: error: {option} {ro / name}") and \
        err.endswith(f": the folder {ro} is not writable\n"), err
    assert os.listdir(ro) == []


@pytest.mark.parametrize("case", ["examples-overwrite", "render-out", "render-truth", "plan-figures"])
def test_an_outputs_missing_folders_are_made(tmp_path, capsys, case):
    """The README says so for every output option (the calibrations, study, run --record and --save make theirs
    the same way)."""
    argv, option, value, inside = CASES[case]
    out = tmp_path / "new" / "deeper" / value
    code, _, err = run_cli(*argv(tmp_path), option, out, capsys=capsys)
    assert code == 0, err
    assert (out / inside).is_file() if inside else out.is_file()


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


def test_write_atomic_through_a_link_replaces_the_file_it_leads_to_and_keeps_the_link(tmp_path):
    (tmp_path / "kept").mkdir()
    real = tmp_path / "kept" / "cal-2026-12-04.json"
    real.write_bytes(OLD)
    link = tmp_path / "current.json"
    link.symlink_to(Path("kept") / real.name)  # relative, as `ln -s` is mostly used
    write_atomic(link, b"new")
    assert link.is_symlink() and os.readlink(link) == str(Path("kept") / real.name)
    assert real.read_bytes() == b"new"
    assert sorted(os.listdir(tmp_path / "kept")) == [real.name]  # no temp file left beside it
    real.chmod(0o444)  # a read-only file behind a link is refused as one in place is
    with pytest.raises(BadInput, match=r"cal-2026-12-04\.json is read-only: not replaced$"):
        write_atomic(link, b"newer")
    assert real.read_bytes() == b"new"


def test_a_cli_output_given_as_a_link_is_written_where_it_leads(tmp_path, capsys):
    """Was: the link was replaced by a plain file, and the file it led to kept its old content."""
    from cell.examples import load_examples

    (tmp_path / "kept").mkdir()
    real = tmp_path / "kept" / "examples-v2.jsonl"
    link = tmp_path / "ex.jsonl"
    link.symlink_to(real)  # dangling until the first write
    generate = ("examples", "generate", "--count", "1", "--out", link)
    assert run_cli(*generate, capsys=capsys)[0] == 0
    assert run_cli(*generate, "--seed", "7", "--append", capsys=capsys)[0] == 0
    assert link.is_symlink() and link.resolve() == real
    assert len(load_examples(real)) == 2
    assert sorted(os.listdir(tmp_path / "kept")) == [real.name]  # the lock went with its holder
    assert sorted(os.listdir(tmp_path)) == ["ex.jsonl", "kept"]
