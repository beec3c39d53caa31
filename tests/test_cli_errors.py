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
    assert code == 2 and err.strip() == "cell: error: /x/examples: Permission denied"
    # a full disk is no bad input (exit 1); one that names no file still says what is wrong, not "[Errno 28] ..."
    monkeypatch.setattr(rules_command, "run", _fails_with(OSError(28, "No space left on device")))
    code, out, err = run_cli("rules", capsys=capsys)
    assert code == 1 and err.strip() == "cell: error: No space left on device"
    monkeypatch.setattr(rules_command, "run", _fails_with(OSError(18, "Invalid cross-device link", "/a", None, "/b")))
    code, out, err = run_cli("rules", capsys=capsys)
    assert code == 2 and err.strip() == "cell: error: /a -> /b: Invalid cross-device link"



def test_library_warnings_reach_the_user_as_cell_warnings(capsys):
    """A warning the drivers log (a drive keeping its own quick stop) is one `cell: warning:` line on
    stderr, like the CLI's errors; info stays quiet; a second set-up adds no second handler."""
    import logging

    from cell.cli import warnings_to_stderr

    logger = logging.getLogger("tests.cell_warnings")
    logger.propagate = False
    try:
        warnings_to_stderr(logger)
        warnings_to_stderr(logger)
        logger.warning("j1 (node 1): quick stop 0x605A = %d kept", 2)
        logger.info("not shown")
        assert capsys.readouterr().err == "cell: warning: j1 (node 1): quick stop 0x605A = 2 kept\n"
    finally:
        logger.handlers.clear()


def test_the_cli_leaves_an_existing_logging_set_up_alone():
    import logging

    from cell.cli import warnings_to_stderr

    logger = logging.getLogger("tests.cell_warnings_set_up")
    mine = logging.NullHandler()
    logger.addHandler(mine)
    try:
        warnings_to_stderr(logger)
        assert logger.handlers == [mine]
    finally:
        logger.handlers.clear()
