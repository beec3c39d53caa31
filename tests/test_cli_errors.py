"""The CLI's last line of defence: whatever goes wrong, one line on stderr and an exit code, never a traceback."""

import pytest
from conftest import ROOT, run_cli

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
    # one that names no file still says what is wrong, not "[Errno 28] ..." (a full disk outside a recording is
    # an output that cannot be written: exit 2, as CONTRACT says)
    monkeypatch.setattr(rules_command, "run", _fails_with(OSError(28, "No space left on device")))
    code, out, err = run_cli("rules", capsys=capsys)
    assert code == 2 and err.strip() == "cell: error: No space left on device"
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


def test_only_a_failed_recording_is_exit_1_other_disk_errors_are_bad_input(monkeypatch, capsys):
    """CONTRACT keeps 1 for a run that stopped, a replay's divergence: a full or failing disk is exit 1 only where
    it stops a recording (RecordingFailed: cell run, cell hw --record); elsewhere it is what CONTRACT says of an
    unusable file (2)."""
    import errno

    from cell.recording import RecordingFailed

    monkeypatch.setattr(rules_command, "run", _fails_with(RecordingFailed(errno.ENOSPC, "No space left on device",
                                                                          "/r/decisions.jsonl")))
    code, out, err = run_cli("rules", capsys=capsys)
    assert code == 1 and err.strip() == "cell: error: /r/decisions.jsonl: No space left on device"
    for e in (OSError(errno.ENOSPC, "No space left on device"), OSError(errno.EIO, "Input/output error", "/x")):
        monkeypatch.setattr(rules_command, "run", _fails_with(e))
        code, out, err = run_cli("rules", capsys=capsys)
        assert code == 2, (e, err)


def test_a_segment_image_that_fails_to_read_is_exit_2(monkeypatch, capsys, tmp_path):
    import errno

    import cell.vision.sources as sources

    img = tmp_path / "frame.png"
    img.write_bytes(b"\x89PNG")

    def eio(path, what):
        raise OSError(errno.EIO, "Input/output error", str(path))

    monkeypatch.setattr(sources, "check_readable", eio)
    code, out, err = run_cli("segment", img, "--json", capsys=capsys)
    assert code == 2 and f"{img}: Input/output error" in err, err


def test_a_replay_whose_recording_cannot_be_read_is_exit_2_not_a_divergence(monkeypatch, capsys):
    import errno
    import json

    from cell.recording import RecordingReader

    def eio(self, directory):
        raise OSError(errno.EIO, "Input/output error", f"{directory}/decisions.jsonl")

    monkeypatch.setattr(RecordingReader, "__init__", eio)
    code, out, err = run_cli("replay", ROOT / "recordings" / "shipped", "--json", capsys=capsys)
    assert code == 2 and "decisions.jsonl: Input/output error" in err, err
    assert "divergence" not in err
    verdict = json.loads(out.strip().splitlines()[-1])
    assert verdict["match"] is None and "Input/output error" in verdict["error"]


def test_a_replay_whose_own_can_log_cannot_be_written_is_exit_2_not_a_divergence(monkeypatch, capsys):
    """The replay's own CAN log (in the temporary folder) on a full disk: RecordingFailed, but no recording of
    the user's was stopped, and nothing diverged: exit 2 (was 1)."""
    import errno

    from drivers.record import BusRecorder

    def full(self, msg):
        if self.error is None:
            self._failed(OSError(errno.ENOSPC, "No space left on device"))

    monkeypatch.setattr(BusRecorder, "_on_message", full)
    code, out, err = run_cli("replay", ROOT / "recordings" / "shipped", capsys=capsys)
    assert code == 2 and "No space left on device" in err and "divergence" not in err, err
