"""Session recordings: everything `cell run --record DIR` needs to replay and audit a session.

Layout of a recording directory (format "cell-recording", version 1):

    manifest.json      format, version, created/closed times, software version (and the numeric libraries
                       and BLAS kernels: cell/numerics.py), status
                       ("recording" while open, then "complete" or "incomplete"), files, counts,
                       can_frames_at_close (the CAN frames can.log held at close: a lower bound,
                       a logger on a bus of its own may still hear the drives shut down),
                       sha256: {"cell": ..., "calibration": ...}, the sha256 (64 hex digits) of the
                       cell.json and calibration.json the recording holds (no "calibration" when it
                       holds none; recordings made before 2026-12-04 have no "sha256": not checked)
    cell.json          copy of the cell file used (the embedded default when none was given)
    calibration.json   copy of the calibration file used (absent when none was given)
    frames/000000.png  the camera frames, PNG, each written atomically
    decisions.jsonl    one JSON object per decision (segmented parts, grasp, configuration,
                       commands ...), flushed and fsynced line by line
    can.log            the CAN traffic in candump format (python-can's Logger / LogReader)
    session.rrd        the rerun recording (written by cell.viz to `rrd_path`)

The manifest is written atomically at the start and again at `close`. A crash leaves a
manifest that still says "recording", every finished decision line and every whole frame;
`RecordingReader` reports such a recording as incomplete (with the torn last line, if any,
dropped) instead of refusing it. Anything else that is wrong is a `BadInput` naming the
file and line.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import logging
import math
import os
import platform
import re
import shutil
import threading
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from cell.errors import BadInput
from cell.fileio import (
    DuplicateKey,
    check_folder_writable,
    check_readable,
    file_sha256,
    json_loads,
    json_text,
    read_json,
    refuse_lone_surrogates,
    short_repr,
    to_jsonable,
    write_atomic,
    write_json_atomic,
)

PNG_SIGNATURE, PNG_END = b"\x89PNG\r\n\x1a\n", b"IEND\xaeB`\x82"  # a PNG's first 8 bytes, its IEND chunk's last 8
FORMAT = "cell-recording"
VERSION = 1
MANIFEST = "manifest.json"
DECISIONS = "decisions.jsonl"
FRAMES_DIR = "frames"
CAN_LOG = "can.log"
RRD = "session.rrd"
STATUSES = ("recording", "complete", "incomplete")
_FRAME_RE = re.compile(r"^(\d{6,})\.png$")
_SHA256_RE = re.compile(r"[0-9a-fA-F]{64}")

log = logging.getLogger(__name__)

# What a recording needs on its disk (measured on the default cell, 1280 x 1024 px: rec of 6 parts, 13.8 MB):
# a frame is a PNG of the camera's noisy pixels, ~1.4 bytes a pixel (1.78 MB); each pick adds ~0.25 MB of
# CAN log (67 kB), rerun recording (128 kB) and decision lines (4 kB); a run takes one frame more than picks.
PNG_BYTES_PER_PX = 1.4
OTHER_MB_PER_PICK = 0.25
# Kept free: a recording stops (and the run with it) before a frame would leave less than this, so that the
# manifest (~40 kB), the last decisions and the CAN log of the arm's stop and shutdown still fit.
CLOSE_RESERVE_MB = 1.0
LOW_SPACE_PICKS = 3  # warn when the disk holds fewer picks than this beyond the reserve
_MB = 1 << 20


class RecordingFailed(OSError):
    """A write into the recording failed (a full disk, an I/O error) or would leave less than the close
    reserve: the session cannot be recorded on. An OSError naming the file; not a CellError, so the loop does
    not hold for the operator over it: the session stops (cell.runtime.session). `decision`: the decision it
    could not write (None for other files): a stop's tells the session why the run was stopping."""

    decision: dict | None = None

    @property
    def reason(self) -> str:
        return f"{self.filename}: {self.strerror}" if self.filename else str(self.strerror or self)


def as_recording_failed(e: OSError, path) -> RecordingFailed:
    """`e` (raised writing `path`) as a RecordingFailed naming the file (a full disk's fsync names none)."""
    return RecordingFailed(e.errno, e.strerror or str(e), str(e.filename or path))


def mb_per_pick(width_px: int, height_px: int) -> float:
    """What one pick is likely to add to a recording (MB): its frame and the rest (see PNG_BYTES_PER_PX)."""
    return width_px * height_px * PNG_BYTES_PER_PX / _MB + OTHER_MB_PER_PICK


def free_mb(folder) -> float:
    """Free space (MB) on the disk of `folder`, or of the nearest of its parents that exists."""
    for d in (Path(folder), *Path(os.path.abspath(folder)).parents):
        if d.exists():
            return shutil.disk_usage(d).free / _MB
    return math.inf


def require_space_for(folder, parts: int, width_px: int, height_px: int) -> None:
    """Refuse (BadInput) a recording into `folder` whose disk has less free than the run is likely to need:
    a frame and a pick's other files for each part, one frame more, and the close reserve."""
    per_pick = mb_per_pick(width_px, height_px)
    frame_mb = per_pick - OTHER_MB_PER_PICK
    need = parts * per_pick + frame_mb + CLOSE_RESERVE_MB
    have = free_mb(folder)
    if have < need:
        raise BadInput(f"--record {folder}: its disk has {have:.1f} MB free; a run of {parts} parts is likely to "
                       f"need {need:.1f} MB ({per_pick:.1f} MB a pick: a {width_px} x {height_px} px frame and the "
                       f"CAN log, rerun and decisions; {CLOSE_RESERVE_MB:g} MB kept to close it): free some space "
                       "or record elsewhere")


def _now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _no_constant(name: str):
    """json.loads would read NaN and Infinity, which the writer never writes (allow_nan=False)."""
    raise json.JSONDecodeError(f"{name} is not JSON", name, 0)


def _flushing_logger(writer):
    """Wrap a python-can writer (a `can.Listener`) so that it flushes after every frame."""
    import can

    class FlushingLogger(can.Listener):
        """Writes through a `can.Logger` and flushes after every frame (a crash loses at most
        the frame being written)."""

        def __init__(self):
            self._lock = threading.Lock()

        def on_message_received(self, msg) -> None:
            with self._lock:
                writer.on_message_received(msg)
                f = getattr(writer, "file", None)
                if f is not None:
                    f.flush()

        def stop(self) -> None:
            with self._lock:
                writer.stop()

    return FlushingLogger()


def recording_holding(path) -> Path | None:
    """The recording folder that `path` lies in (its folder, or one above it, whose manifest.json is a cell
    recording's), or None. A manifest that cannot be read as one is not a recording's."""
    for folder in Path(os.path.abspath(path)).resolve().parents:
        manifest = folder / MANIFEST
        try:
            if not manifest.is_file() or manifest.stat().st_size > (1 << 24):
                continue
            m = json.loads(manifest.read_bytes())
        except (OSError, ValueError, RecursionError):
            continue
        if isinstance(m, dict) and m.get("format") == FORMAT:
            return folder
    return None


def nominal_calibration_json(cal, recording_dir=None) -> dict:
    """The simulated camera's nominal calibration (no file of its own) as its file would hold it, refused
    (BadInput) where the calibration file's reader would refuse it: a recording could not be read back, and a
    run without one would see through a camera no calibration file can describe."""
    from calibration.calfile import checked_json

    def refuse(why: str):
        unwritten = (f"; the recording {recording_dir} is not written (`cell replay` could not read it)"
                     if recording_dir is not None else "")
        raise BadInput(f"the simulated camera's calibration ({cal.name}, from the cell file's camera and tray) is "
                       f"one the calibration file's reader refuses: {why}{unwritten}")

    return checked_json(cal, refuse)


class RecordingWriter:
    """Write one session into `directory` (created; refused if it already holds a recording).

    Parameters
    ----------
    directory : path of the recording directory.
    cell_file : the cell file used, copied as cell.json (None: the embedded default cell).
    calibration_file : the calibration used, copied as calibration.json (None: none used).
    nominal_calibration : a calibration with no file of its own (the simulated cell's nominal camera for a
        cell file's camera), written as calibration.json instead.
    examples_file : the teaching-example file; its path and sha256 go into the manifest.
    meta : free JSON-able information for the manifest (command line, assembly, ...).
    """

    def __init__(self, directory, *, cell_file=None, calibration_file=None, examples_file=None,
                 meta: dict | None = None, nominal_calibration=None, examples_copy: str | None = None):
        """`examples_copy`: the name the recording holds a copy of `examples_file` under (as it was at the start),
        made with the rest of the set-up, and taken away with it when that is cut short."""
        self.dir = Path(directory)
        if (self.dir / MANIFEST).exists():
            raise BadInput(f"recording directory {self.dir} already holds a recording; choose a new name")
        if self.dir.exists() and not self.dir.is_dir():
            raise BadInput(f"recording directory {self.dir} is a file")
        if self.dir.is_dir() and any(self.dir.iterdir()):
            # its files would be overwritten or, worse, mixed into the recording (decisions appended
            # to a stale decisions.jsonl, stale frames counted): an unreadable recording
            raise BadInput(f"recording directory {self.dir} is not empty; choose a new name")
        held_by = recording_holding(self.dir)
        if held_by is not None:  # (as --save: a recording is kept as it was made)
            raise BadInput(f"recording directory {self.dir} lies in the recording {held_by}; choose a place outside it")
        check_folder_writable(self.dir, f"cannot write the recording into {self.dir}")  # before any file is made

        from cell import __version__
        from cell.cellconfig import default_cell_path
        from cell.numerics import numeric_platform

        cell_src = Path(cell_file) if cell_file is not None else default_cell_path()
        if not cell_src.is_file():
            raise BadInput(f"cell file {cell_src} does not exist")
        cal = Path(calibration_file) if calibration_file is not None else None
        if cal is not None and not cal.is_file():
            raise BadInput(f"calibration file {cal} does not exist")
        ex = Path(examples_file) if examples_file is not None else None
        if ex is not None and not ex.is_file():
            raise BadInput(f"example file {ex} does not exist")
        nominal_json = None
        if nominal_calibration is not None:  # checked as `cell replay` will read it, before any file is made
            nominal_json = nominal_calibration_json(nominal_calibration, self.dir)
        has_cal = cal is not None or nominal_calibration is not None
        files = {"cell": "cell.json", "calibration": "calibration.json" if has_cal else None, "decisions": DECISIONS,
                 "frames": FRAMES_DIR, "can_log": CAN_LOG, "rrd": RRD}
        made = [d for d in (self.dir, *self.dir.parents) if not d.exists()]  # taken away again on failure
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            (self.dir / FRAMES_DIR).mkdir(exist_ok=True)
            shutil.copyfile(cell_src, self.dir / "cell.json")
            if cal is not None:
                shutil.copyfile(cal, self.dir / "calibration.json")
            elif nominal_json is not None:
                write_json_atomic(self.dir / "calibration.json", nominal_json)
            examples = {"path": json_text(str(ex.resolve())), "sha256": file_sha256(ex)} if ex is not None else None
            if ex is not None and examples_copy is not None:
                write_atomic(self.dir / examples_copy, ex.read_bytes())
            held_sha256 = {"cell": file_sha256(self.dir / "cell.json")}  # of the copies: what replay reads
            if has_cal:
                held_sha256["calibration"] = file_sha256(self.dir / "calibration.json")

            self._lock = threading.Lock()
            self._frame_indices: set[int] = set()
            self._n_decisions = 0
            self.last_decision: dict | None = None
            self._closed = False
            self._can_stops: list[Callable[[], None]] = []
            self.manifest = {
                "format": FORMAT, "version": VERSION, "status": "recording",
                "created": _now_iso(), "closed": None,
                "software": {"name": "disassembly-cell", "version": __version__,
                             "python": platform.python_version(), "numeric": numeric_platform()},
                "cell_source": (json_text(str(Path(cell_file).resolve())) if cell_file is not None
                                else "embedded default"),
                "calibration_source": (json_text(str(Path(calibration_file).resolve())) if calibration_file
                                       else nominal_calibration.name if nominal_calibration is not None else None),
                "examples": examples, "files": files, "sha256": held_sha256, "counts": {"frames": 0, "decisions": 0},
                "meta": to_jsonable(meta or {}),
            }
            write_json_atomic(self.dir / MANIFEST, self.manifest)
            # unbuffered: a line a full disk cut short is cut off again (`_append_decision`), none is left buffered
            self._decisions = open(self.dir / DECISIONS, "xb", buffering=0)  # noqa: SIM115 - held open
            self._decisions_bytes = 0
            self._low_space_warned = False
            self.failed: RecordingFailed | None = None  # the first frame or decision the disk did not take
        except BaseException as e:  # a full disk, Ctrl-C, SIGTERM: no half-made folder that blocks the name
            self._take_away(made, examples_copy)
            if isinstance(e, OSError):
                raise BadInput(f"cannot write the recording into {self.dir}: {e.strerror or e}") from None
            raise

    def _take_away(self, made: list[Path], examples_copy: str | None) -> None:
        """Remove what a set-up cut short made: the files it writes in the folder (it was empty or new), then
        the folders it made."""
        with contextlib.suppress(OSError):
            if (d := getattr(self, "_decisions", None)) is not None:
                d.close()
            for name in (MANIFEST, DECISIONS, "cell.json", "calibration.json", *filter(None, [examples_copy])):
                (self.dir / name).unlink(missing_ok=True)
            for tmp in self.dir.glob(".*.tmp*"):
                tmp.unlink()
            (self.dir / FRAMES_DIR).rmdir()
        for d in made:  # deepest first
            with contextlib.suppress(OSError):
                d.rmdir()

    # -- paths the lead's loop attaches other writers to
    @property
    def can_log_path(self) -> Path:
        return self.dir / CAN_LOG

    @property
    def rrd_path(self) -> Path:
        return self.dir / RRD

    def write_frame(self, index: int, frame_bgr: np.ndarray) -> str:
        """Store a frame as frames/NNNNNN.png (atomically); returns that relative path."""
        import cv2

        if self._closed:
            raise RuntimeError("recording is closed")
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
            raise ValueError(f"frame index must be a non-negative integer, got {index!r}")
        a = np.asarray(frame_bgr)
        if a.dtype != np.uint8 or not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (1, 3, 4))):
            raise ValueError(f"frame must be uint8 of shape (h, w) or (h, w, 3), got {a.dtype} {a.shape}")
        ok, png = cv2.imencode(".png", a)
        if not ok:
            raise ValueError("frame could not be encoded as PNG")
        rel = f"{FRAMES_DIR}/{int(index):06d}.png"
        try:
            self._require_room(self.dir / rel, png.nbytes)
            try:
                write_atomic(self.dir / rel, png.tobytes())
            except OSError as e:
                raise as_recording_failed(e, self.dir / rel) from None
        except RecordingFailed as e:
            self._failed(e)
            raise
        with self._lock:
            self._frame_indices.add(int(index))
        return rel

    def write_decision(self, record: dict) -> None:
        """Append one decision as a JSON line, flushed and fsynced before returning."""
        if not isinstance(record, dict):
            raise TypeError("a decision is a dict")
        line = json.dumps(to_jsonable(record), separators=(",", ":"), allow_nan=False)
        with self._lock:
            if self._closed:
                raise RuntimeError("recording is closed")
            try:
                self._append_decision((line + "\n").encode("utf-8"))
            except RecordingFailed as e:
                e.decision = record
                self._failed(e)
                raise
            self._n_decisions += 1
            self.last_decision = record

    def _failed(self, e: RecordingFailed) -> None:
        """Keep the first write that failed: a caller that goes on past one (a fault already ending a pick stays the
        run's cause) leaves the recording a line short all the same; the session says so at the end."""
        if self.failed is None:
            self.failed = e

    def _append_decision(self, data: bytes) -> None:
        """Write `data` at the end of decisions.jsonl and fsync it; on a failure (a full disk) cut the file
        back to its last whole line, so that the recording stays readable, and raise RecordingFailed."""
        fd, start = self._decisions.fileno(), self._decisions_bytes
        try:
            done = 0
            while done < len(data):  # a nearly full disk takes part of a write before it refuses the rest
                done += os.write(fd, data[done:])
            os.fsync(fd)
        except OSError as e:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, start)
                os.lseek(fd, start, os.SEEK_SET)
            raise as_recording_failed(e, self.dir / DECISIONS) from None
        self._decisions_bytes = start + len(data)

    def _require_room(self, path: Path, nbytes: int) -> None:
        """Before a frame: refuse it (RecordingFailed, ENOSPC) when it would leave less than the close reserve
        on the disk; warn once when fewer than LOW_SPACE_PICKS picks' worth are left."""
        left_mb = free_mb(self.dir) - nbytes / _MB
        if left_mb < CLOSE_RESERVE_MB:
            raise RecordingFailed(errno.ENOSPC, f"the disk is full: {left_mb + nbytes / _MB:.1f} MB free, the "
                                  f"frame needs {nbytes / _MB:.1f} MB and {CLOSE_RESERVE_MB:g} MB are kept to close "
                                  "the recording", str(path))
        per_pick = nbytes / _MB + OTHER_MB_PER_PICK
        if not self._low_space_warned and left_mb < CLOSE_RESERVE_MB + LOW_SPACE_PICKS * per_pick:
            self._low_space_warned = True
            log.warning("recording %s: only %.1f MB left on its disk, about %d more picks (%.1f MB each); the run "
                        "stops when it is full", self.dir, left_mb, max(0, int((left_mb - CLOSE_RESERVE_MB)
                                                                                 // per_pick)), per_pick)

    def attach_can_logger(self, bus=None, *, notifier=None) -> Callable[[], None]:
        """Log every frame seen on the bus into can_log_path (candump format).

        The simplest is not to call this at all: `drivers.session.simulated_cell(record=
        rec.can_log_path)` (and `real_cell`) record with a bus of their own on the channel,
        like candump, hearing host and drives alike. Otherwise give either `bus` (best: a bus
        of its own on the channel; a new `can.Notifier` is started on it) or `notifier`, the one that
        already reads the bus (e.g. canopen's `network.notifier`): two notifiers on one bus
        would split its frames between them. Returns a function that detaches the logger
        and closes the log (also called by `close`). The notifier sees received frames; a
        master's own frames appear when the bus echoes them (python-can's virtual bus with
        receive_own_messages=True) or when the caller passes them to the logger itself.
        """
        import can

        if (bus is None) == (notifier is None):
            raise ValueError("give either bus or notifier")
        listener = _flushing_logger(can.Logger(str(self.can_log_path)))
        if notifier is None:
            notifier = can.Notifier(bus, [listener], timeout=0.1)
            own = True
        else:
            notifier.add_listener(listener)
            own = False
        done = threading.Event()

        def stop() -> None:
            if done.is_set():
                return
            done.set()
            if own:
                notifier.stop()
            else:
                notifier.remove_listener(listener)
            listener.stop()

        self._can_stops.append(stop)
        return stop

    @property
    def counts(self) -> dict:
        with self._lock:
            return {"frames": len(self._frame_indices), "decisions": self._n_decisions}

    def close(self, status: str = "complete", summary: dict | None = None) -> None:
        """Stop the CAN logger(s), close the decision file and rewrite the manifest."""
        if status not in ("complete", "incomplete"):
            raise ValueError(f"status must be 'complete' or 'incomplete', not {status!r}")
        for stop in self._can_stops:
            stop()
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._decisions.close()
            self.manifest.update(status=status, closed=_now_iso(), counts=self._counts_at_close())
            if summary is not None:
                self.manifest["summary"] = to_jsonable(summary)
            if not self.can_log_path.exists():
                self.manifest["files"]["can_log"] = None
            else:  # a lower bound: a logger on a bus of its own may still be hearing the drives shut down
                with open(self.can_log_path, "rb") as f:
                    self.manifest["can_frames_at_close"] = sum(b.count(b"\n") for b in iter(
                        lambda: f.read(1 << 20), b""))
            if not self.rrd_path.exists():
                self.manifest["files"]["rrd"] = None
        try:
            write_json_atomic(self.dir / MANIFEST, self.manifest)
        except OSError as e:  # it still says "recording": read back as incomplete, a crash's
            raise as_recording_failed(e, self.dir / MANIFEST) from None

    def restate_end(self, status: str, summary: dict) -> None:
        """Closed already: rewrite the manifest's status and summary (a CAN log, heard until the drives shut
        down, that failed after the close). RecordingFailed when the disk cannot take it (the old one stays)."""
        if status not in ("complete", "incomplete"):
            raise ValueError(f"status must be 'complete' or 'incomplete', not {status!r}")
        with self._lock:
            if not self._closed:
                raise RuntimeError("restate_end: the recording is not closed")
            self.manifest.update(status=status)
            self.manifest["summary"] = to_jsonable(summary)
        try:
            write_json_atomic(self.dir / MANIFEST, self.manifest)
        except OSError as e:
            raise as_recording_failed(e, self.dir / MANIFEST) from None

    def _counts_at_close(self) -> dict:
        """The counts the manifest states: what was written, and what an interrupt kept from being counted.
        Ctrl-C between a decision's fsync and its count (or a frame's rename and its index) left a file
        holding one more than the manifest said, which the reader refuses as corrupt. What the files hold
        now is counted too; never less than was written (a file cut short meanwhile stays a mismatch)."""
        lines = 0
        with contextlib.suppress(OSError), open(self.dir / DECISIONS, "rb") as f:
            lines = sum(1 for line in f if line.strip())  # as the reader counts: whole lines, blank ones skipped
        frames = set(self._frame_indices)
        with contextlib.suppress(OSError):
            frames |= {int(m.group(1)) for p in (self.dir / FRAMES_DIR).iterdir() if (m := _FRAME_RE.match(p.name))}
        return {"frames": len(frames), "decisions": max(self._n_decisions, lines)}

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close("complete" if exc_type is None else "incomplete")


class RecordingReader:
    """Open and validate a recording directory.

    Attributes
    ----------
    manifest : dict, the manifest as read.
    status : "complete", or "incomplete" (closed so, or the writer never closed: a crash).
    complete : bool.
    problems : list of str, what makes it incomplete (never fatal).
    decisions : list of dict, every whole decision line, in order.
    """

    def __init__(self, directory):
        self.dir = Path(directory)
        if not self.dir.exists():
            raise BadInput(f"recording {self.dir} does not exist")
        if not self.dir.is_dir():
            raise BadInput(f"recording {self.dir} is not a directory")
        mpath = self.dir / MANIFEST
        if not mpath.exists():
            raise BadInput(f"recording {self.dir} has no {MANIFEST}: not a recording, or never started")
        m = read_json(mpath, "recording manifest")
        if not isinstance(m, dict) or m.get("format") != FORMAT:
            fmt = m.get("format") if isinstance(m, dict) else None
            raise BadInput(f"{mpath}: not a {FORMAT} manifest (format={short_repr(fmt)})")
        if m.get("version") != VERSION:
            raise BadInput(f"{mpath}: version {short_repr(m.get('version'))} is not supported (reader: {VERSION})")
        if m.get("status") not in STATUSES:
            raise BadInput(f"{mpath}: status must be one of {', '.join(STATUSES)}, not {short_repr(m.get('status'))}")
        files = m.get("files")
        if not isinstance(files, dict) or not isinstance(files.get("cell"), str):
            raise BadInput(f"{mpath}: 'files' must name at least the cell file")
        if not isinstance(files.get("calibration"), (str, type(None))):
            raise BadInput(f"{mpath}: 'files.calibration' must be a file name or null")
        if not isinstance(m.get("counts"), (dict, type(None))):
            raise BadInput(f"{mpath}: 'counts' must be an object")
        held_sha256 = m.get("sha256", {})  # absent in recordings made before the copies' sha256 was kept
        if not isinstance(held_sha256, dict):
            raise BadInput(f"{mpath}: 'sha256' must be an object, not {short_repr(held_sha256)}")
        for key in ("cell", "calibration"):
            if key in held_sha256 and not (isinstance(held_sha256[key], str)
                                           and _SHA256_RE.fullmatch(held_sha256[key])):
                raise BadInput(f"{mpath}: 'sha256.{key}' must be a sha256 (64 hex digits), not "
                               f"{short_repr(held_sha256[key])}")
        if "calibration" in held_sha256 and not files.get("calibration"):
            raise BadInput(f"{mpath}: 'sha256.calibration' is given, but the recording holds no calibration")
        self.manifest = m
        self.problems: list[str] = []
        if m["status"] == "recording":
            self.problems.append("the writer was never closed (the session crashed or was killed)")
        elif m["status"] == "incomplete":
            self.problems.append("the session ended early (closed as incomplete)")

        self.cell_path = self.dir / files["cell"]
        if not self.cell_path.is_file():
            raise BadInput(f"recording {self.dir}: the cell file copy {files['cell']} is missing")
        cal = files.get("calibration")
        self.calibration_path = self.dir / cal if cal else None
        if self.calibration_path is not None and not self.calibration_path.is_file():
            raise BadInput(f"recording {self.dir}: the calibration copy {cal} is missing")

        self.decisions = self._read_decisions()
        self._frames = self._index_frames()
        counts = m.get("counts") or {}
        for key in ("decisions", "frames"):  # "14" for 14 gave "holds 14 decisions, the manifest says 14"
            if key in counts and (isinstance(counts[key], bool) or not isinstance(counts[key], int)):
                raise BadInput(f"{mpath}: 'counts.{key}' must be a whole number, not {short_repr(counts[key])}")
        at_close = m.get("can_frames_at_close", 0)  # absent in recordings made before replay checked it
        if isinstance(at_close, bool) or not isinstance(at_close, int) or at_close < 0:  # else the check is skipped
            raise BadInput(f"{mpath}: 'can_frames_at_close' must be a whole number of CAN frames (0 or more), "
                           f"not {short_repr(at_close)}")
        if m["status"] != "recording":  # a closed manifest states its counts: they must match
            if counts.get("decisions") != len(self.decisions):
                raise BadInput(f"recording {self.dir}: {DECISIONS} holds {len(self.decisions)} decisions, "
                               f"the manifest says {counts.get('decisions')}")
            if counts.get("frames") != len(self._frames):
                raise BadInput(f"recording {self.dir}: {FRAMES_DIR}/ holds {len(self._frames)} frames, "
                               f"the manifest says {counts.get('frames')}")
        gap = next((i for i, k in enumerate(self._frames) if i != k), None)
        if gap is not None:  # the loop numbers its frames 0, 1, 2 ...: replay would shift all that follow
            raise BadInput(f"recording {self.dir}: frame {gap} ({FRAMES_DIR}/{gap:06d}.png) is missing")

    @property
    def status(self) -> str:
        return "complete" if self.manifest["status"] == "complete" and not self.problems else "incomplete"

    @property
    def complete(self) -> bool:
        return self.status == "complete"

    @property
    def examples_sha256(self) -> str | None:
        ex = self.manifest.get("examples")
        return ex.get("sha256") if isinstance(ex, dict) else None

    def held_sha256(self, key: str) -> str | None:
        """The sha256 the manifest holds of the recording's copy of `key` ("cell" or "calibration"), lower
        case; None in recordings made before it was kept."""
        h = self.manifest.get("sha256", {}).get(key)
        return h.lower() if h is not None else None

    @property
    def examples_path(self) -> Path | None:
        ex = self.manifest.get("examples")
        return Path(ex["path"]) if isinstance(ex, dict) and ex.get("path") else None

    def examples_match(self, path) -> bool:
        """True when the example file at `path` is the one the session used (same sha256)."""
        return self.examples_sha256 is not None and file_sha256(path) == self.examples_sha256

    @property
    def can_log_path(self) -> Path | None:
        p = self.dir / CAN_LOG
        return p if p.exists() else None

    @property
    def rrd_path(self) -> Path | None:
        p = self.dir / RRD
        return p if p.exists() else None

    # -- decisions
    def _read_decisions(self) -> list[dict]:
        path = self.dir / DECISIONS
        if not path.exists():
            if self.manifest["status"] == "recording":
                return []
            raise BadInput(f"recording {self.dir}: {DECISIONS} is missing")
        check_readable(path, "recording file", max_bytes=math.inf)  # a long session's log may be large
        try:
            raw = path.read_bytes()
        except OSError as e:
            raise BadInput(f"recording {path} cannot be read: {e.strerror or e}") from None
        lines = raw.split(b"\n")
        torn = lines[-1] if lines and lines[-1] else b""  # bytes after the last newline
        out = []
        for lineno, line in enumerate(lines[:-1], 1):
            if not line.strip():
                continue
            out.append(self._parse_line(path, lineno, line))
        if torn.strip():
            rec = self._parse_line(path, len(lines), torn, last=True)
            if rec is None:
                self.problems.append(f"{DECISIONS} line {len(lines)} is torn (cut off by a crash); dropped")
            else:  # a whole object, only its newline is missing
                out.append(rec)
                self.problems.append(f"{DECISIONS} line {len(lines)} has no final newline")
        return out

    def _parse_line(self, path: Path, lineno: int, line: bytes, last: bool = False) -> dict | None:
        """The decision on `line`; None for a `last` line that is not whole JSON (a crash cut it short)."""
        try:
            text = line.decode("utf-8")
            rec = json_loads(text, parse_constant=_no_constant)
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
            if last:
                return None
            msg = (e.msg if isinstance(e, json.JSONDecodeError) else "not UTF-8" if isinstance(e, UnicodeDecodeError)
                   else "nested too deeply")  # json's decoder recurses per level: [[[[...]]]] 100000 deep
            raise BadInput(f"recording {path} line {lineno}: not valid JSON ({msg})") from None
        except DuplicateKey as e:  # whole, but corrupt: was read with the last value (a divergence, exit 1)
            raise BadInput(f"recording {path} line {lineno}: {e}") from None
        if not isinstance(rec, dict):
            raise BadInput(f"recording {path} line {lineno}: a decision must be a JSON object")
        refuse_lone_surrogates(text, rec, f"recording {path} line {lineno}")  # no writer of ours writes one
        return rec

    # -- frames
    def _index_frames(self) -> dict[int, Path]:
        d = self.dir / FRAMES_DIR
        out = {}
        if d.is_dir():
            try:
                names = [p for p in d.iterdir()]
            except OSError as e:
                raise BadInput(f"recording {self.dir}: {FRAMES_DIR}/ cannot be read: {e.strerror or e}") from None
            for p in names:
                m = _FRAME_RE.match(p.name)
                if m:
                    out[int(m.group(1))] = p
        return dict(sorted(out.items()))

    @property
    def frame_indices(self) -> list[int]:
        return list(self._frames)

    def frame_path(self, index: int) -> Path:
        if index not in self._frames:
            raise BadInput(f"recording {self.dir} has no frame {index}")
        return self._frames[index]

    def read_frame(self, index: int) -> np.ndarray:
        """The frame as stored, BGR uint8 of shape (h, w, 3) (or (h, w) for grey frames)."""
        import cv2

        p = self.frame_path(index)
        check_readable(p, "recording frame")
        try:  # read here, decoded by OpenCV: its imread says only None, and crashed on a name that is not UTF-8
            data = p.read_bytes()
        except OSError as e:
            raise BadInput(f"recording frame {p} cannot be read: {e.strerror or e}") from None
        if data.startswith(PNG_SIGNATURE) and not data.endswith(PNG_END):  # libpng would print its own line first
            raise BadInput(f"recording frame {p} is cut short: its PNG has no end ({len(data)} bytes)")
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
        except cv2.error as e:  # e.g. a header claiming more pixels than OpenCV decodes
            raise BadInput(f"recording frame {p} cannot be decoded as PNG (OpenCV: {getattr(e, 'err', e)})") from None
        if img is None:
            raise BadInput(f"recording frame {p} cannot be decoded as PNG")
        return img

    def frames(self) -> Iterator[tuple[int, np.ndarray]]:
        for i in self._frames:
            yield i, self.read_frame(i)

    # -- CAN traffic
    def can_messages(self) -> list:
        """Every CAN frame of the session as `can.Message`, read by python-can's LogReader.
        A line torn by a crash at the end is dropped (and noted in `problems`)."""
        import can

        path = self.can_log_path
        if path is None:
            return []
        check_readable(path, "recording file", max_bytes=math.inf)
        try:
            text = path.read_text(encoding="ascii", errors="replace")
        except OSError as e:
            raise BadInput(f"recording {path} cannot be read: {e.strerror or e}") from None
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]
            self.problems.append(f"{CAN_LOG}: the last line is torn (cut off by a crash); dropped")
            reader = can.CanutilsLogReader(io.StringIO(text))
        else:
            reader = can.LogReader(str(path))
        try:
            return list(reader)
        except (ValueError, IndexError) as e:
            raise BadInput(f"recording {path}: not a readable candump log ({e})") from None
        finally:
            reader.stop()
