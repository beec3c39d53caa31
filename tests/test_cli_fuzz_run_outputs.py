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
