"""Record and replay bus traffic with python-can's own loggers and readers (never a home-made
format): `.asc` or candump `.log` for small fixtures, `.blf` for long runs (by file suffix).

The recorder listens on a bus of its own on the same channel, like candump on a socket: it
hears every participant (the host and the drives) without touching their buses.
"""

from __future__ import annotations

import logging
from pathlib import Path

import can

from cell.errors import BadInput
from cell.fileio import check_writable
from drivers.clock import Clock
from drivers.pump import BusPump

SUFFIXES = (".asc", ".log", ".blf")
log = logging.getLogger(__name__)


class BusRecorder:
    """Write every frame heard on `bus` to `path` until `stop()` (a context manager).

    Parameters
    ----------
    bus : can.BusABC
        A bus of the recorder's own on the channel to record (the caller opens and closes it).
    path : str or Path
        `.asc`, `.log` (candump) or `.blf`.
    clock : Clock, optional
        Stamp frames with this clock's time (simulated time in a simulated session) instead of
        the wall time of reception.
    on_failed : callable, optional
        Called once with the RecordingFailed of the first write that failed (from the bus's thread, or
        from `stop`): a session learns of it before it closes its recording, not only when this exits.
    """

    def __init__(self, bus: can.BusABC, path: str | Path, clock: Clock | None = None, on_failed=None):
        self.path = Path(path)
        if self.path.suffix.lower() not in SUFFIXES:
            raise BadInput(f"CAN log {self.path}: use one of {', '.join(SUFFIXES)} (python-can's formats)")
        check_writable(self.path, "CAN log")  # was "[Errno 17] File exists: 'x'" for x.json/log.asc
        if self.path.exists() or self.path.is_symlink():
            # another session's log, a recording's can.log, the command's own cell file: none is written over
            raise BadInput(f"CAN log {self.path} exists: a CAN log is never written over; give a new name or "
                           "remove it first")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.clock = clock
        self.frames = 0
        self.error: OSError | None = None  # the write that failed (a full disk); nothing is written after it
        self._on_failed = on_failed
        self._writer = can.Logger(str(self.path))
        self._pump = BusPump(bus, [self._on_message], name="can-recorder")
        if clock is not None:
            clock.add_settler(self._pump.settle)
        self._stopped = False

    def _on_message(self, msg: can.Message) -> None:
        if self.clock is not None:
            msg.timestamp = self.clock.now()
        if isinstance(msg.channel, str) and any(c.isspace() for c in msg.channel):
            # a candump line is split at spaces: a channel named with one ("--channel 'test bus'") made the
            # recording's can.log unreadable (this bus is the recorder's own: nobody else sees the change)
            msg.channel = "_".join(msg.channel.split())
        if self.error is not None:
            return  # the log stopped at its first failed write: the file keeps whole lines only
        try:
            self._writer.on_message_received(msg)
        except OSError as e:  # a full disk: said once, here, with why (was "listener failed" for every frame)
            self._failed(e)
            return
        self.frames += 1

    def _failed(self, e: OSError) -> None:
        from cell.recording import as_recording_failed

        self.error = as_recording_failed(e, self.path)
        log.warning("CAN log %s: the frames after the first %d are not written: %s", self.path, self.frames,
                    self.error.strerror)
        if self._on_failed is not None:
            self._on_failed(self.error)

    def stop(self) -> int:
        """Write out what was heard so far and close the file; returns the number of frames."""
        if not self._stopped:
            self._stopped = True
            self._pump.settle()
            if self.clock is not None:
                self.clock.remove_settler(self._pump.settle)
            self._pump.stop()
            try:
                self._writer.stop()
            except OSError as e:  # its last lines could not be written out
                if self.error is None:
                    self._failed(e)
        return self.frames

    def __enter__(self) -> BusRecorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """Stops; a log a write failure cut short is then an error (RecordingFailed, naming the file), unless
        another one is already on its way."""
        self.stop()
        if self.error is not None and exc_type is None:
            raise self.error


def read_log(path: str | Path) -> list[can.Message]:
    """Every frame of a python-can log file, in order; `BadInput` for a missing or unreadable log."""
    path = Path(path)
    if not path.is_file():
        raise BadInput(f"CAN log {path} does not exist")
    try:
        with can.LogReader(str(path)) as reader:
            return list(reader)
    except (ValueError, OSError, can.CanError, EOFError, IndexError) as e:
        raise BadInput(f"CAN log {path} cannot be read: {e}") from None


def replay(path: str | Path, bus: can.BusABC, *, realtime: bool = False) -> int:
    """Send the frames of a log on `bus` (with `realtime`, spaced as recorded); returns the count."""
    frames = read_log(path)
    source = can.MessageSync(frames, timestamps=True) if realtime else frames
    n = 0
    for msg in source:
        bus.send(msg)
        n += 1
    return n


def same_frame(a: can.Message, b: can.Message) -> bool:
    """Equal on the wire: id, id length, frame kind and data (timestamps and channels aside).
    Error frames compare by kind only: the log formats keep different parts of the error class."""
    if a.is_error_frame or b.is_error_frame:
        return a.is_error_frame == b.is_error_frame
    return (
        a.arbitration_id == b.arbitration_id
        and a.is_extended_id == b.is_extended_id
        and a.is_error_frame == b.is_error_frame
        and a.is_remote_frame == b.is_remote_frame
        and a.dlc == b.dlc
        and bytes(a.data) == bytes(b.data)
    )
