"""A CAN log on a full disk says why, once, and names its file; a failing bus listener says why it failed."""

import errno
import logging

import can
import pytest

from cell.recording import RecordingFailed
from drivers.pump import BusPump
from drivers.record import BusRecorder


class _DiskFillsAfter:
    """The log's file, on a disk that takes `room` characters and then refuses (ENOSPC)."""

    def __init__(self, file, room: int):
        self._file, self._room = file, room

    def write(self, text: str) -> int:
        if len(text) > self._room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self._room -= len(text)
        return self._file.write(text)

    def __getattr__(self, name):
        return getattr(self._file, name)


def _send(channel: str, n: int) -> None:
    with can.Bus(interface="virtual", channel=channel) as bus:
        for i in range(n):
            bus.send(can.Message(arbitration_id=0x181, data=[i], is_extended_id=False))


def test_a_can_log_on_a_full_disk_says_why_once_and_names_its_file(tmp_path, caplog):
    path = tmp_path / "can.log"
    with can.Bus(interface="virtual", channel="fullcan") as tap, caplog.at_level(logging.WARNING):
        with pytest.raises(RecordingFailed) as failed, BusRecorder(tap, path) as rec:
            rec._writer.file = _DiskFillsAfter(rec._writer.file, 200)  # room for a few candump lines
            _send("fullcan", 10)
            rec._pump.settle()
    assert failed.value.filename == str(path) and failed.value.errno == errno.ENOSPC
    assert 0 < rec.frames < 10
    assert caplog.text.count("No space left on device") == 1, caplog.text
    assert f"CAN log {path}: the frames after the first {rec.frames} are not written" in caplog.text
    assert "listener failed" not in caplog.text
    assert path.read_text().endswith("\n")  # whole lines only


def test_a_failing_listener_says_why_once(caplog):
    def broken(msg):
        raise ValueError("the frame has no data")

    with can.Bus(interface="virtual", channel="pumpfail") as bus, caplog.at_level(logging.ERROR):
        pump = BusPump(bus, [broken], name="can-recorder")
        _send("pumpfail", 3)
        pump.settle()
        pump.stop()
    assert len(pump.errors) == 3
    assert caplog.text.count("failed on can-recorder: ValueError: the frame has no data") == 1, caplog.text


def _can_log_fails(monkeypatch, *, after_frames: int | None = None, at_stop: bool = False):
    """The recording's CAN log refuses its frames after the first `after_frames` (ENOSPC), or its last lines
    when it is stopped (as the drives shut down, after the recording's manifest is written)."""
    real_on_message, real_stop = BusRecorder._on_message, BusRecorder.stop

    def on_message(self, msg):
        if after_frames is not None and self.frames >= after_frames and self.error is None:
            self._failed(OSError(errno.ENOSPC, "No space left on device"))
            return
        real_on_message(self, msg)

    def stop(self):
        if at_stop and not self._stopped and self.error is None:
            self._failed(OSError(errno.ENOSPC, "No space left on device"))
        return real_stop(self)

    monkeypatch.setattr(BusRecorder, "_on_message", on_message)
    monkeypatch.setattr(BusRecorder, "stop", stop)


@pytest.mark.parametrize("when", ["during the run", "as the drives shut down"])
def test_a_run_whose_can_log_is_cut_short_stops_and_its_recording_is_incomplete(when, tmp_path, capsys,
                                                                                monkeypatch):
    """Was: exit 0, the manifest "complete" without can_log_failed (the CAN log's failure surfaced as the drives
    shut down, after the manifest), and `cell replay` called the missing frames a divergence (exit 1)."""
    import json

    from conftest import run_cli
    from test_recording_interrupts import _two_parts

    d = tmp_path / "rec"
    if when == "during the run":
        _can_log_fails(monkeypatch, after_frames=300)
    else:
        _can_log_fails(monkeypatch, at_stop=True)
    code, out, err = run_cli("run", _two_parts(tmp_path), "--record", d, "--json", capsys=capsys)
    monkeypatch.undo()
    summary = json.loads(out.strip().splitlines()[-1])
    can_log = d / "can.log"
    assert code == 1, err
    assert summary["status"] == "stopped" and summary["can_log_failed"] == f"{can_log}: No space left on device"
    assert summary["stopped"] == f"recording: {can_log}: No space left on device"
    m = json.loads((d / "manifest.json").read_text())
    assert m["status"] == "incomplete" and m["summary"]["status"] == "failed", m["summary"]
    assert m["summary"]["can_log_failed"] == f"{can_log}: No space left on device"
    assert "No space left on device" in m["summary"]["error"]
    code, out, err = run_cli("replay", d, "--json", capsys=capsys)
    assert code == 2 and "is incomplete" in err and "divergence" not in err, err
    assert json.loads(out.strip().splitlines()[-1])["incomplete"] is True
