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
