"""Recordings: write a session for real, read it back, crash mid-session, corrupt files."""

import json
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import can
import numpy as np
import pytest

from cell.cellconfig import default_cell_path
from cell.errors import BadInput
from cell.fileio import file_sha256
from cell.recording import RecordingReader, RecordingWriter

ROOT = Path(__file__).resolve().parent.parent


def _frame(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(48, 64, 3), dtype=np.uint8)


@pytest.fixture
def inputs(tmp_path):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"kind": "homography", "H": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}))
    ex = tmp_path / "examples.jsonl"
    ex.write_text('{"id": "a"}\n')
    return cal, ex


def test_write_and_read_back_a_whole_session(tmp_path, inputs):
    cal, ex = inputs
    rec_dir = tmp_path / "recordings" / "s1"
    w = RecordingWriter(rec_dir, calibration_file=cal, examples_file=ex, meta={"argv": ["run"]})
    assert json.loads((rec_dir / "manifest.json").read_text())["status"] == "recording"
    rels = [w.write_frame(i, _frame(i)) for i in range(3)]
    assert rels == ["frames/000000.png", "frames/000001.png", "frames/000002.png"]
    decisions = [
        {"kind": "segment", "frame": 0, "parts": [{"centroid_px": np.array([10.5, 20.25])}]},
        {"kind": "grasp", "frame": 1, "target": "cover", "opening_mm": np.float64(31.5),
         "valid": np.bool_(True), "n": np.int64(4)},
    ]
    for d in decisions:
        w.write_decision(d)

    with can.Bus(interface="virtual", channel="rec-test", receive_own_messages=True) as bus:
        stop = w.attach_can_logger(bus)
        sent = [can.Message(arbitration_id=0x600 + k, data=bytes([0x40, k, 0x60, 0, 0, 0, 0, 0]),
                            is_extended_id=False) for k in range(1, 6)]
        for m in sent:
            bus.send(m)
        time.sleep(0.3)  # the notifier thread writes them
        stop()
    w.close("complete", summary={"parts_removed": 2})

    r = RecordingReader(rec_dir)
    assert r.complete and r.problems == []
    assert r.decisions[0]["parts"][0]["centroid_px"] == [10.5, 20.25]
    assert r.decisions[1] == {"kind": "grasp", "frame": 1, "target": "cover", "opening_mm": 31.5,
                              "valid": True, "n": 4}
    assert r.frame_indices == [0, 1, 2]
    for i, img in r.frames():
        assert np.array_equal(img, _frame(i))  # PNG is lossless
    assert r.cell_path.read_bytes() == default_cell_path().read_bytes()
    assert r.calibration_path.read_text() == cal.read_text()
    assert r.examples_sha256 == file_sha256(ex) and r.examples_match(ex)
    ex.write_text('{"id": "b"}\n')
    assert not r.examples_match(ex)
    msgs = r.can_messages()
    assert [m.arbitration_id for m in msgs] == [0x601, 0x602, 0x603, 0x604, 0x605]
    assert bytes(msgs[2].data) == bytes([0x40, 3, 0x60, 0, 0, 0, 0, 0])
    m = r.manifest
    assert m["format"] == "cell-recording" and m["counts"] == {"frames": 3, "decisions": 2}
    assert m["summary"] == {"parts_removed": 2} and m["software"]["version"]


def test_a_recording_is_never_overwritten(tmp_path):
    RecordingWriter(tmp_path / "r").close()
    with pytest.raises(BadInput, match="already holds a recording"):
        RecordingWriter(tmp_path / "r")


def test_bad_inputs_to_the_writer(tmp_path):
    with pytest.raises(BadInput, match="calibration file"):
        RecordingWriter(tmp_path / "a", calibration_file=tmp_path / "missing.json")
    w = RecordingWriter(tmp_path / "b")
    with pytest.raises(ValueError, match="uint8"):
        w.write_frame(0, np.zeros((4, 4, 3), float))
    with pytest.raises(ValueError, match="non-finite"):
        w.write_decision({"x": float("nan")})
    w.close()
    with pytest.raises(RuntimeError, match="closed"):
        w.write_decision({"x": 1})


CRASHING_SESSION = textwrap.dedent("""
    import os, sys
    import numpy as np
    sys.path.insert(0, sys.argv[2])
    from cell.recording import RecordingWriter
    w = RecordingWriter(sys.argv[1])
    for i in range(3):
        w.write_frame(i, np.full((8, 8, 3), i, np.uint8))
        w.write_decision({"frame": i, "kind": "grasp"})
    w._decisions.write(b'{"frame": 3, "kind": "gra')  # the crash comes in the middle of a line (the file is raw)
    w._decisions.flush()
    os._exit(9)                                       # no close, no atexit, no finally
""")


def test_a_crash_mid_session_leaves_a_readable_incomplete_recording(tmp_path):
    rec_dir = tmp_path / "crashed"
    p = subprocess.run([sys.executable, "-c", CRASHING_SESSION, str(rec_dir), str(ROOT)],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 9, p.stderr
    r = RecordingReader(rec_dir)
    assert r.status == "incomplete" and not r.complete
    assert [d["frame"] for d in r.decisions] == [0, 1, 2]
    assert r.frame_indices == [0, 1, 2]
    assert any("never closed" in s for s in r.problems)
    assert any("line 4 is torn" in s for s in r.problems)


def test_torn_can_log_is_dropped_not_fatal(tmp_path):
    w = RecordingWriter(tmp_path / "r")
    w.can_log_path.write_text("(1.000000) vcan0 601#4000100000000000 R\n(1.100000) vcan0 58")
    r = RecordingReader(tmp_path / "r")
    msgs = r.can_messages()
    assert len(msgs) == 1 and msgs[0].arbitration_id == 0x601
    assert any("can.log" in s for s in r.problems)


def _closed_recording(path, n=3):
    w = RecordingWriter(path)
    for i in range(n):
        w.write_frame(i, np.zeros((4, 4, 3), np.uint8))
        w.write_decision({"frame": i})
    w.close()
    return path


def test_corrupt_decision_line_names_file_and_line(tmp_path):
    d = _closed_recording(tmp_path / "r")
    lines = (d / "decisions.jsonl").read_text().splitlines()
    lines[1] = '{"frame": 1,,}'
    (d / "decisions.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInput, match=r"decisions.jsonl line 2: not valid JSON"):
        RecordingReader(d)
    lines[1] = "[1, 2]"
    (d / "decisions.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInput, match="line 2: a decision must be a JSON object"):
        RecordingReader(d)


@pytest.mark.parametrize("damage, match", [
    (lambda d: __import__("shutil").rmtree(d), "does not exist"),
    (lambda d: (d / "manifest.json").unlink(), "has no manifest.json"),
    (lambda d: (d / "manifest.json").write_text("{ not json"), "manifest .* is not valid JSON"),
    (lambda d: (d / "manifest.json").write_text('{"format": "other"}'), "not a cell-recording manifest"),
    (lambda d: (d / "cell.json").unlink(), "cell file copy cell.json is missing"),
    (lambda d: (d / "frames" / "000001.png").unlink(), "holds 2 frames, the manifest says 3"),
    (lambda d: (d / "decisions.jsonl").write_text('{"frame": 0}\n'), "holds 1 decisions, the manifest says"),
])
def test_damaged_recordings_are_bad_input(tmp_path, damage, match):
    d = _closed_recording(tmp_path / "r")
    damage(d)
    with pytest.raises(BadInput, match=match):
        RecordingReader(d)


def test_undecodable_frame_is_bad_input(tmp_path):
    d = _closed_recording(tmp_path / "r", n=1)
    (d / "frames" / "000000.png").write_bytes(b"not a png")
    r = RecordingReader(d)
    with pytest.raises(BadInput, match="cannot be decoded"):
        r.read_frame(0)
    with pytest.raises(BadInput, match="no frame 7"):
        r.read_frame(7)


def test_can_logger_joins_an_existing_notifier(tmp_path):
    # A CANopen network already reads the bus with its own notifier: the logger joins it.
    w = RecordingWriter(tmp_path / "r")
    with can.Bus(interface="virtual", channel="rec-test-2") as master, \
            can.Bus(interface="virtual", channel="rec-test-2") as node:
        seen = []
        notifier = can.Notifier(master, [seen.append], timeout=0.1)
        stop = w.attach_can_logger(notifier=notifier)
        for _ in range(4):
            node.send(can.Message(arbitration_id=0x701, data=[5], is_extended_id=False))
        time.sleep(0.3)
        stop()
        node.send(can.Message(arbitration_id=0x702, data=[5], is_extended_id=False))
        time.sleep(0.2)
        notifier.stop()
    w.close()
    msgs = RecordingReader(tmp_path / "r").can_messages()
    assert [m.arbitration_id for m in msgs] == [0x701] * 4  # logged while attached, not after
    assert len(seen) == 5  # the network's own listener saw everything
    with pytest.raises(ValueError, match="either"):
        RecordingWriter(tmp_path / "q").attach_can_logger()
