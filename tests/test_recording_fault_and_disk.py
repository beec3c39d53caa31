"""A disk that fails while a fault or a stop is cutting a pick short: the fault (or stop) stays the run's cause, its
message and exit code, and the recording's failure is said beside it; the recording is closed as cut short."""

import errno
import json
import os

import pytest
from conftest import run_cli
from test_recording_interrupts import _two_parts  # the default assembly's first two parts

from cell.recording import RecordingReader
from cell.runtime.session import RunConfig, run_session

INTERRUPTED = b'"type":"interrupted"'


def _disk_fails_at_the_interrupted_line(monkeypatch, *, for_good: bool) -> list:
    """os.write into decisions.jsonl refuses (ENOSPC) the `interrupted` line, and with `for_good` every line after
    it too (a full disk); else only that one (a passing I/O error). Returns the lines refused."""
    real_write, refused = os.write, []

    def write(fd, data):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            target = ""
        if target.endswith("decisions.jsonl") and (INTERRUPTED in bytes(data) or (for_good and refused)):
            refused.append(json.loads(bytes(data))["type"])
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", write)
    return refused


@pytest.mark.parametrize("for_good", [True, False], ids=["full disk", "one write fails"])
def test_a_drive_fault_stays_the_cause_when_the_disk_fails_at_its_interrupted_line(tmp_path, monkeypatch, capsys,
                                                                                   for_good):
    """Was: 'stopped: recording: .../decisions.jsonl: No space left on device', the drive fault nowhere."""
    rec = tmp_path / "rec"
    refused = _disk_fails_at_the_interrupted_line(monkeypatch, for_good=for_good)
    lines = []
    s = run_session(RunConfig(assembly=_two_parts(tmp_path), seed=3, record=rec,
                              drive_fault=("j2", "emcy", {"after_s": 0.3}), progress=lines.append))
    monkeypatch.undo()
    assert refused == (["interrupted", "stop"] if for_good else ["interrupted"])
    assert s["status"] == "stopped" and s["parts_removed"] == 0  # exit 1, as for the fault alone
    assert s["stopped"].startswith("j2: j2 (node") and "EMCY" in s["stopped"], s["stopped"]
    assert s["parts"][0]["reason"] == s["stopped"]
    assert s["recording_failed"] == f"{rec / 'decisions.jsonl'}: No space left on device"
    assert f"stopped: {s['stopped']}" in lines
    assert any(line.endswith(s["recording_failed"]) and "recording" in line for line in lines), lines
    m = json.loads((rec / "manifest.json").read_text())
    assert m["status"] == "incomplete" and m["summary"]["status"] == "failed"
    assert m["summary"]["stopped"] == s["stopped"] and m["summary"]["recording_failed"] == s["recording_failed"]
    kinds = [d["type"] for d in RecordingReader(rec).decisions]
    assert "interrupted" not in kinds and kinds[-1] == ("commands" if for_good else "stop")
    code, out, err = run_cli("replay", rec, "--json", capsys=capsys)  # a line short: not the session as it ran
    assert code == 2 and "is incomplete" in err, err


def test_ctrl_c_stays_the_cause_when_the_disk_is_full_at_its_interrupted_line(tmp_path, monkeypatch):
    """Ctrl-C mid-pick on a full disk: the run ends as Ctrl-C ends it (KeyboardInterrupt: exit 130, the summary
    printed), not as a disk error (exit 1, no summary)."""
    from cell.runtime import session

    sources = session._simulated_sources

    def ctrl_c_at_the_third_move(*a, **kw):
        arm, camera, world = sources(*a, **kw)
        move, calls = arm.move_joints, []

        def moving(*ma, **mk):
            calls.append(1)
            if len(calls) == 3:  # (the first is the way home) into the first pick
                raise KeyboardInterrupt
            return move(*ma, **mk)

        arm.move_joints = moving
        return arm, camera, world

    monkeypatch.setattr(session, "_simulated_sources", ctrl_c_at_the_third_move)
    rec = tmp_path / "rec"
    refused = _disk_fails_at_the_interrupted_line(monkeypatch, for_good=True)
    with pytest.raises(KeyboardInterrupt) as stopped:
        run_session(RunConfig(assembly=_two_parts(tmp_path), seed=3, record=rec))
    monkeypatch.undo()
    s = stopped.value.summary
    assert refused == ["interrupted", "stop"]
    assert s["status"] == "stopped" and s["stopped"] == "operator: interrupted at the terminal"
    assert s["recording_failed"] == f"{rec / 'decisions.jsonl'}: No space left on device"
    m = json.loads((rec / "manifest.json").read_text())
    assert m["status"] == "incomplete" and m["summary"]["status"] == "failed"
