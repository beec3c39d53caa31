"""The CLI's last line of defence: whatever goes wrong, one line on stderr and an exit code, never a traceback."""

import pytest
from conftest import run_cli

import cell.commands.rules as rules_command


def _fails_with(exc):
    def run(args):
        raise exc

    return run


def test_an_unexpected_exception_is_one_line_and_exit_1(monkeypatch, capsys):
    monkeypatch.setattr(rules_command, "run", _fails_with(RuntimeError("the tree has no root")))
    code, out, err = run_cli("rules", capsys=capsys)
    assert code == 1 and out == ""
    assert err.strip().splitlines() == [
        "cell: internal error: RuntimeError: the tree has no root (please report it with the command line; "
        "CELL_TRACEBACK=1 shows where it happened)"]


def test_cell_traceback_lets_the_exception_through(monkeypatch):
    monkeypatch.setenv("CELL_TRACEBACK", "1")
    monkeypatch.setattr(rules_command, "run", _fails_with(RuntimeError("the tree has no root")))
    with pytest.raises(RuntimeError, match="no root"):
        run_cli("rules")


def test_an_os_error_is_bad_input(monkeypatch, capsys):
    monkeypatch.setattr(rules_command, "run", _fails_with(PermissionError(13, "Permission denied", "/x/examples")))
    code, out, err = run_cli("rules", capsys=capsys)
    assert code == 2 and err.strip() == "cell: error: [Errno 13] Permission denied: '/x/examples'"

