"""`cell examples generate` with values it crashed or never ended on: exit 2, one line, no file written."""

import pytest
from conftest import run_cli


@pytest.mark.parametrize("extra, message", [
    (["--families", ",,,"], "--families ',,,' names no family"),  # was: internal error (IndexError)
    (["--families", " "], "names no family"),
    (["--count", "99999999999999999999999"], "--count must be 1..10000"),  # was: ran without end
    (["--count", "0"], "--count must be 1..10000"),
])
def test_bad_session_options_are_refused_before_the_session(tmp_path, capsys, extra, message):
    out = tmp_path / "e.jsonl"
    code, stdout, err = run_cli("examples", "generate", "--out", out, "--count", "1", *extra, capsys=capsys)
    assert code == 2 and message in err and "internal error" not in err, err
    assert list(tmp_path.iterdir()) == []


def test_an_out_path_under_a_file_is_refused_before_the_session(tmp_path, capsys):
    """It was refused after the session, with '[Errno 17] File exists: ...'."""
    (tmp_path / "f").write_text("x")
    code, stdout, err = run_cli("examples", "generate", "--out", tmp_path / "f" / "e.jsonl", "--count", "1",
                                capsys=capsys)
    assert code == 2 and "is a file, not a folder" in err and "examples:" not in err, err
    assert (tmp_path / "f").read_text() == "x"


def test_append_to_a_broken_example_file_is_refused_before_the_session(tmp_path, capsys):
    """A truncated last line was refused only after the whole teaching session had run (minutes lost)."""
    from pathlib import Path

    out = tmp_path / "e.jsonl"
    text = (Path(__file__).resolve().parents[1] / "cell" / "data" / "default_examples.jsonl").read_bytes()
    out.write_bytes(text[:-40])
    code, stdout, err = run_cli("examples", "generate", "--out", out, "--append", "--count", "1", capsys=capsys)
    assert code == 2 and "line 75: not valid JSON" in err and "examples:" not in err, err  # (no progress line)
    assert out.read_bytes() == text[:-40]


@pytest.mark.parametrize("flag", ["--overwrite", "--append"])
def test_generate_refuses_to_write_over_its_own_cell_file(tmp_path, capsys, flag):
    # --overwrite replaced the cell file with example lines (exit 0); calibrate, render and run refuse it
    from cell.cellconfig import default_cell_path

    cell = tmp_path / "c.json"
    cell.write_bytes(default_cell_path().read_bytes())
    before = cell.read_bytes()
    code, stdout, err = run_cli("examples", "generate", "--count", "2", "--seed", "1", flag, "--out", cell,
                                "--cell", cell, capsys=capsys)
    assert code == 2 and f"--out {cell} is one of the inputs: it would be overwritten" in err
    assert cell.read_bytes() == before
