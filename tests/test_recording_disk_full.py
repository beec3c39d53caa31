"""A full disk while recording: the run stops (exit 1) with its summary, the recording closes whole and names
the file; a disk too small for the run is refused before anything moves; the writer keeps a reserve to close."""

import errno
import json
import logging
import os
import shutil
from collections import namedtuple

import numpy as np
import pytest
from conftest import run_cli
from test_recording_interrupts import _two_parts  # the default assembly's first two parts

from cell.recording import CLOSE_RESERVE_MB, RecordingFailed, RecordingReader, RecordingWriter

MB = 1 << 20
_Usage = namedtuple("_Usage", "total used free")


def _fail_writes_to(name: str, after_bytes: int, monkeypatch):
    """os.write into the file called `name` takes `after_bytes` in all, then part of one write, then refuses
    (ENOSPC), as a disk that fills does."""
    real_write, taken = os.write, [0]

    def write(fd, data):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            target = ""
        if not target.endswith(name):
            return real_write(fd, data)
        room = after_bytes - taken[0]
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = real_write(fd, bytes(data[:room]))
        taken[0] += n
        return n

    monkeypatch.setattr(os, "write", write)


def _disk_of(budget_mb: float, folder, monkeypatch):
    """shutil.disk_usage of a disk holding `budget_mb`, of which `folder`'s files take their real size."""
    def usage(path):
        used = sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) if folder.exists() else 0
        return _Usage(int(budget_mb * MB), used, max(0, int(budget_mb * MB) - used))

    monkeypatch.setattr(shutil, "disk_usage", usage)


def test_a_full_disk_stops_the_run_with_its_summary_and_closes_the_recording(tmp_path, capsys, monkeypatch):
    # the hunter's 11600 kB tmpfs: exit 2 "[Errno 28] No space left on device", no summary, no file named,
    # a torn last decision and a manifest left saying "recording"
    d = tmp_path / "rec"
    _fail_writes_to("decisions.jsonl", 5000, monkeypatch)  # in the second part (7.8 kB for both)
    code, out, err = run_cli("run", _two_parts(tmp_path), "--record", d, "--json", capsys=capsys)
    monkeypatch.undo()
    summary = json.loads(out.strip().splitlines()[-1])
    assert code == 1, err
    assert summary["status"] == "stopped" and summary["parts_total"] == 2
    assert f"{d / 'decisions.jsonl'}: No space left on device" in summary["stopped"]
    assert "No space left on device" in summary["recording_failed"]
    assert f"stopped: recording: {d / 'decisions.jsonl'}" in err
    m = json.loads((d / "manifest.json").read_text())
    assert m["status"] == "incomplete" and m["summary"]["status"] == "failed"
    assert "No space left on device" in m["summary"]["error"]
    assert (d / "decisions.jsonl").read_bytes().endswith(b"\n")  # the line the disk cut short is cut off
    rec = RecordingReader(d)
    assert not any("torn" in p for p in rec.problems)
    assert m["counts"]["decisions"] == len(rec.decisions)


def test_a_disk_too_small_for_the_run_is_refused_before_anything_moves(tmp_path, capsys, monkeypatch):
    d = tmp_path / "rec"
    _disk_of(6.0, d, monkeypatch)  # two parts need 6.8 MB: 3 frames of 1.75 MB, 0.25 MB a pick, 1 MB reserve
    code, _, err = run_cli("run", _two_parts(tmp_path), "--record", d, capsys=capsys)
    assert code == 2 and "its disk has 6.0 MB free; a run of 2 parts is likely to need 6.8 MB" in err, err
    assert not d.exists()


def _frame(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (600, 600, 3), np.uint8)  # ~1 MB as PNG (noise)


def test_the_writer_warns_when_space_runs_low_and_stops_before_the_reserve(tmp_path, monkeypatch, caplog):
    d = tmp_path / "rec"
    _disk_of(7.0, d, monkeypatch)
    w = RecordingWriter(d)
    written = []
    with caplog.at_level(logging.WARNING, "cell.recording"), pytest.raises(RecordingFailed) as failed:
        for i in range(20):
            written.append(w.write_frame(i, _frame(i)))
            w.write_decision({"type": "frame", "index": i})
    e = failed.value
    assert e.errno == errno.ENOSPC and e.filename == str(d / f"frames/{len(written):06d}.png")
    assert f"{CLOSE_RESERVE_MB:g} MB are kept to close the recording" in e.strerror
    assert "more picks" in caplog.text and "the run stops when it is full" in caplog.text
    assert caplog.text.count("only") == 1  # warned once
    assert shutil.disk_usage(d).free >= CLOSE_RESERVE_MB * MB  # the reserve is still there to close it
    w.close("incomplete", {"status": "failed"})
    rec = RecordingReader(d)
    assert rec.frame_indices == list(range(len(written))) and len(rec.decisions) == len(written)
    assert not list((d / "frames").glob(".*"))  # no half-written frame left behind


def test_a_manifest_the_disk_cannot_take_names_its_file(tmp_path, monkeypatch):
    w = RecordingWriter(tmp_path / "rec")
    w.write_decision({"type": "x"})
    real_fsync = os.fsync

    def fsync(fd):
        if ".manifest.json." in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, "No space left on device")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(RecordingFailed) as failed:
        w.close("incomplete")
    assert failed.value.reason == f"{tmp_path / 'rec' / 'manifest.json'}: No space left on device"
