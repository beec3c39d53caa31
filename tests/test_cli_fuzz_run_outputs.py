"""`cell run --save FILE` naming one of the run's own input files: refused, the file left as it was."""

import shutil

import pytest
from conftest import run_cli

from cell.cellconfig import default_cell_path
from cell.examples import default_examples_path
from cell.runtime.session import default_assembly_path


@pytest.mark.parametrize("which", ["assembly", "examples", "cell"])
def test_save_over_an_input_is_refused_and_the_input_kept(tmp_path, capsys, which):
    """--save ASSEMBLY replaced the assembly with the .rrd (exit 0); --save EXAMPLES replaced the examples,
    then the run failed reading them."""
    files = {"assembly": tmp_path / "asm.json", "examples": tmp_path / "ex.jsonl", "cell": tmp_path / "cell.json"}
    shutil.copy(default_assembly_path(), files["assembly"])
    shutil.copy(default_examples_path(), files["examples"])
    shutil.copy(default_cell_path(), files["cell"])
    before = {k: p.read_bytes() for k, p in files.items()}
    code, out, err = run_cli("run", files["assembly"], "--examples", files["examples"], "--cell", files["cell"],
                             "--save", files[which], capsys=capsys)
    assert code == 2 and f"--save {files[which]} is one of the run's input files" in err, err
    assert {k: p.read_bytes() for k, p in files.items()} == before


def test_save_over_the_default_examples_is_refused(tmp_path, monkeypatch, capsys):
    """The examples the run uses when given none (a copy stands in for the shipped file here)."""
    import cell.examples
    import cell.runtime.session

    default = tmp_path / "default_examples.jsonl"
    shutil.copy(default_examples_path(), default)
    for module in (cell.examples, cell.runtime.session):
        monkeypatch.setattr(module, "default_examples_path", lambda: default)
    before = default.read_bytes()
    code, out, err = run_cli("run", "--save", default, capsys=capsys)
    assert code == 2 and "is one of the run's input files" in err, err
    assert default.read_bytes() == before


def test_save_to_a_name_that_is_not_rrd_is_refused_before_the_run(tmp_path, capsys):
    """--save x.txt ran the whole disassembly and wrote a rerun recording under that name."""
    target = tmp_path / "view.txt"
    code, out, err = run_cli("run", "--save", target, capsys=capsys)
    assert code == 2 and "a rerun recording is a .rrd file; name it view.rrd" in err, err
    assert not target.exists() and "parts" not in out


@pytest.mark.parametrize("where", ["session.rrd", "new.rrd", "frames/new.rrd"])
def test_save_into_another_recording_is_refused_and_it_is_kept(tmp_path, capsys, where):
    """--save rs/session.rrd, rs a copy of a recording, run with rs's own cell and calibration files: it replaced
    that session's rerun recording (exit 0). Nothing is written into a recording, not even a new file."""
    from pathlib import Path

    rs = tmp_path / "rs"
    shutil.copytree(Path(__file__).resolve().parent.parent / "recordings" / "shipped", rs)
    before = {p: p.read_bytes() for p in rs.rglob("*") if p.is_file()}
    code, out, err = run_cli("run", "--cell", rs / "cell.json", "--calibration", rs / "calibration.json",
                             "--save", rs / where, capsys=capsys)
    assert code == 2 and f"--save {rs / where} lies in the recording {rs}" in err, err
    assert "Traceback" not in err and "parts" not in out
    assert {p: p.read_bytes() for p in rs.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("where", ["sub", "frames/sub"])
def test_a_recording_inside_another_recording_is_refused_and_it_is_kept(tmp_path, capsys, where):
    """--record rs/sub, rs a recording: a new session was written into it (files it does not name)."""
    from pathlib import Path

    rs = tmp_path / "rs"
    shutil.copytree(Path(__file__).resolve().parent.parent / "recordings" / "shipped", rs)
    before = sorted(p.relative_to(rs) for p in rs.rglob("*"))
    code, out, err = run_cli("run", "--record", rs / where, capsys=capsys)
    assert code == 2 and f"recording directory {rs / where} lies in the recording {rs}" in err, err
    assert sorted(p.relative_to(rs) for p in rs.rglob("*")) == before and "parts" not in out


def test_save_into_the_runs_own_recording_is_still_allowed(tmp_path, capsys):
    """The run's --record folder is made by this run: --save there writes the rerun recording beside it."""
    import json

    one = json.loads(default_assembly_path().read_text())  # one part: the run is what is looked at, not the parts
    one["parts"], one["sequence"] = [p for p in one["parts"] if p["id"] == one["sequence"][0]], one["sequence"][:1]
    (tmp_path / "one.json").write_text(json.dumps(one))
    rec = tmp_path / "rec"
    code, _, err = run_cli("run", tmp_path / "one.json", "--record", rec, "--save", rec / "session.rrd", capsys=capsys)
    assert code == 0, err
    assert (rec / "session.rrd").read_bytes()[:3] == b"RRF"
