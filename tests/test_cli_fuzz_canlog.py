"""`cell hw status --record PATH` where PATH cannot be a file: one line naming the path, nothing written."""

import pytest
from conftest import run_cli


@pytest.mark.parametrize("record, message", [
    ("f/bus.asc", "CAN log f/bus.asc: f is a file, not a folder"),  # was: [Errno 17] File exists: 'f'
    ("d.asc", "CAN log d.asc is a directory, not a file"),  # was: [Errno 21] Is a directory: 'd.asc'
])
def test_a_can_log_that_cannot_be_a_file_is_named(tmp_path, monkeypatch, capsys, record, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "f").write_text("x")
    (tmp_path / "d.asc").mkdir()
    code, out, err = run_cli("hw", "status", "--simulated-time", "--record", record, capsys=capsys)
    assert code == 2 and err.strip() == f"cell: error: {message}" and out == "", err
    assert (tmp_path / "f").read_text() == "x" and list((tmp_path / "d.asc").iterdir()) == []
