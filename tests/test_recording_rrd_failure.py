"""The rerun file of a recording that rerun stops writing (a full disk, a broken file): handled as the recording's
other files are. The run stops at the next frame, naming session.rrd, the summary and manifest say so, and replay
calls the recording incomplete (its end was not recorded), not corrupt (the .rrd is cut short, as the manifest says).
rerun writes from a thread of its own (Rust): the failure is made real with a FIFO as session.rrd whose reader
goes away after some bytes (rerun's writes then fail with EPIPE)."""

import json
import os
import threading

import pytest
from conftest import run_cli
from test_recording_interrupts import _two_parts  # the default assembly's first two parts

import cell.viz
from cell.recording import RecordingReader
from cell.runtime.session import RunConfig, run_session

RRD_TAKES_BYTES = 150_000  # a two-part run writes ~350 kB: the header, the first frame, not all of the second


def _rrd_that_breaks_after(n_bytes: int, monkeypatch) -> list:
    """session.rrd made a FIFO whose reader takes `n_bytes` and leaves. Returns what it read (a count)."""
    viz_init, taken = cell.viz.Viz.__init__, []

    def reader(path):
        with open(path, "rb") as f:
            while sum(taken) < n_bytes and (chunk := f.read(min(65536, n_bytes - sum(taken)))):
                taken.append(len(chunk))

    def init(self, *a, save_path=None, **kw):
        os.mkfifo(save_path)
        threading.Thread(target=reader, args=(save_path,), daemon=True).start()
        viz_init(self, *a, save_path=save_path, **kw)

    monkeypatch.setattr(cell.viz.Viz, "__init__", init)
    return taken


@pytest.mark.skip(reason="rerun's file writer on a FIFO whose reader left can hold the test process at its exit "
                  "(a CI run and a local run hung there after the test passed); Viz.close no longer waits for it")
def test_a_rerun_file_cut_short_stops_the_run_and_the_recording_says_so(tmp_path, monkeypatch, capsys):
    """Was: the run went on and ended complete (exit 0), the manifest named a session.rrd cut short as whole, and
    the only word was 'the rerun viewer did not take the recording' (there was no viewer)."""
    rec, lines = tmp_path / "rec", []
    taken = _rrd_that_breaks_after(RRD_TAKES_BYTES, monkeypatch)
    s = run_session(RunConfig(assembly=_two_parts(tmp_path), seed=3, record=rec, progress=lines.append))
    monkeypatch.undo()
    assert sum(taken) == RRD_TAKES_BYTES
    rrd = str(rec / "session.rrd")
    assert s["status"] == "stopped" and s["stopped"].startswith(f"recording: {rrd}: rerun stopped writing it ("), s
    if s["parts_removed"] == 2:  # rerun's writer thread noticed the reader gone only at the close (it races the
        # loop): the close is given up after FLUSH_TIMEOUT_S (it had hung a CI run), the rrd counted as failed
        assert s["rrd_failed"] == s["stopped"].removeprefix("recording: ") and "within 5 s" in s["rrd_failed"], s
        return
    assert s["stopped"].startswith(f"recording: {rrd}: rerun stopped writing it (File-writer"), s["stopped"]
    assert s["recording_failed"] == s["rrd_failed"] == s["stopped"].removeprefix("recording: ")
    assert f"stopped: {s['stopped']}" in lines and not any("viewer" in line for line in lines)
    m = json.loads((rec / "manifest.json").read_text())
    assert m["status"] == "incomplete" and m["summary"]["status"] == "failed"
    assert m["summary"]["rrd_failed"] == s["rrd_failed"] and m["files"]["rrd"] == "session.rrd"
    decisions = RecordingReader(rec).decisions
    assert decisions and decisions[-1]["type"] != "summary"
    code, out, err = run_cli("replay", rec, "--json", capsys=capsys)
    verdict = json.loads(out.strip().splitlines()[-1])
    assert code == 2 and "is incomplete" in err and verdict["incomplete"] is True, err
    assert verdict["matched"] == len([d for d in decisions if d["type"] != "interrupted"])


def test_a_rerun_file_cut_short_only_at_the_close_leaves_a_recording_that_replays(tmp_path, monkeypatch, capsys):
    """rerun's last writes (after the loop ended) fail: the decisions and CAN log are whole, replay does not need
    the .rrd: the run is stopped on it (exit 1), the manifest says rrd_failed, and the recording replays (exit 0)."""
    import errno

    from cell.recording import RecordingFailed

    close = cell.viz.Viz.close

    def failing_close(self):
        close(self)
        self.failed = RecordingFailed(errno.ENOSPC, "rerun stopped writing it (File-writer thread shut down "
                                      "prematurely); 0.0 MB free on its disk: the disk is full", str(self.save_path))

    monkeypatch.setattr(cell.viz.Viz, "close", failing_close)
    rec = tmp_path / "rec"
    s = run_session(RunConfig(assembly=_two_parts(tmp_path), seed=3, record=rec))
    monkeypatch.undo()
    assert s["parts_removed"] == 2 and s["status"] == "stopped" and "recording_failed" not in s
    assert s["stopped"] == f"recording: {s['rrd_failed']}" and "session.rrd" in s["rrd_failed"]
    m = json.loads((rec / "manifest.json").read_text())
    assert m["status"] == "incomplete" and m["summary"]["status"] == "stopped" and m["summary"]["rrd_failed"]
    (rec / "session.rrd").write_bytes((rec / "session.rrd").read_bytes()[:100])  # cut short, as rerun left it
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
    assert "the recorded session was stopped" in out and "session.rrd" in out
