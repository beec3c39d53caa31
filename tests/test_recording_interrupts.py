"""More than one Ctrl-C during `cell run --record`: the arm is still stopped, every axis, and the recording
is still consistent (closed as stopped, its counts those of its files, the stop in it) and replays to the
stop. The interrupts are sent at chosen points of the run, in the process, so that the test does not
depend on timing: a real SIGINT (the CLI's handler sees it as Ctrl-C) or a KeyboardInterrupt raised there."""

import json
import os
import signal
import threading

import pytest
from conftest import run_cli

from cell.recording import RecordingReader

AXES = ["j1", "j2", "j3", "j4", "gripper"]


def _two_parts(tmp_path):
    from importlib import resources

    two = json.loads((resources.files("cell") / "data" / "assemblies" / "default.json").read_text())
    two["parts"] = [p for p in two["parts"] if p["id"] in two["sequence"][:2]]
    two["sequence"] = two["sequence"][:2]
    path = tmp_path / "two.json"
    path.write_text(json.dumps(two))
    return path


@pytest.fixture
def ctrl_c():
    """SIGINT as at a terminal (a worker started with it ignored would not see it); the test's own
    handler is back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals reach the main thread only")
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


def _interrupt(how: str) -> None:
    if how == "signal":
        signal.raise_signal(signal.SIGINT)  # the handler runs as this call returns: here
    else:
        raise KeyboardInterrupt


@pytest.mark.parametrize("how", ["signal", "raise"])
def test_more_interrupts_while_the_arm_stops_leave_a_stopped_recording_that_replays(tmp_path, capsys, monkeypatch,
                                                                                     ctrl_c, how):
    """Ctrl-C as the first pick's outcome is made safe on disk (after its fsync, before it was counted), then
    again as j1's quick stop goes out, as the stop decision is made safe, and as the manifest is closed. Before,
    the second one left the stop path before the status was set: a recording closed as "complete" without its
    stop (replay: "divergence ... the recording has no more decisions"); one between a decision's fsync and its
    count made a recording whose decisions.jsonl held one more line than its manifest said (replay: corrupt);
    one in the manifest's write left it saying "recording"."""
    import cell.recording
    from cell import recording
    from drivers.axis import Axis

    fsync, points = os.fsync, []

    def fsync_then_interrupt(fd):
        fsync(fd)
        writing = _writing.get("decision")
        if writing is not None and writing.get("type") in ("executed", "stop"):
            points.append(writing["type"])
            _interrupt(how)

    _writing: dict = {}
    write_decision = recording.RecordingWriter.write_decision

    def spy_write_decision(self, record):
        _writing["decision"] = record
        try:
            write_decision(self, record)
        finally:
            _writing["decision"] = None

    send, sent = Axis.send_quick_stop, []

    def send_quick_stop(ax):
        seq = send(ax)
        sent.append(ax.name)
        if len(sent) == 1:
            points.append("quick stop")
            _interrupt(how)  # as j1's has gone out
        return seq

    write_json_atomic, states = recording.write_json_atomic, []

    def close_manifest(path, data):
        if data.get("status") != "recording":
            import time

            deadline = time.monotonic() + 2.0  # the drives take their quick stop on a thread of their own
            enabled = lambda: any(d.state == "OPERATION_ENABLED" for d in drives[0].drives.values())  # noqa: E731
            while enabled() and time.monotonic() < deadline:
                time.sleep(0.01)
            states.append({n: d.state for n, d in drives[0].drives.items()})
            if how == "signal":  # (a KeyboardInterrupt raised here is the write failing: nothing can hold it)
                points.append("manifest")
                _interrupt(how)  # before the manifest is replaced: it says "recording"
        return write_json_atomic(path, data)

    from cell.runtime import session

    sources, drives = session._simulated_sources, []

    def keep_drives(*a, **kw):
        arm, camera, world = sources(*a, **kw)
        drives.append(world.drives)
        return arm, camera, world

    monkeypatch.setattr(cell.recording.os, "fsync", fsync_then_interrupt)
    monkeypatch.setattr(recording.RecordingWriter, "write_decision", spy_write_decision)
    monkeypatch.setattr(Axis, "send_quick_stop", send_quick_stop)
    monkeypatch.setattr(recording, "write_json_atomic", close_manifest)
    monkeypatch.setattr(session, "_simulated_sources", keep_drives)
    d = tmp_path / "rec"
    code, _, err = run_cli("run", _two_parts(tmp_path), "--record", d, capsys=capsys)
    monkeypatch.undo()
    assert code == 130 and "cell: interrupted" in err and "Traceback" not in err, err
    assert points[:2] == ["executed", "quick stop"], points  # the interrupts came where they were meant to
    # the later ones were each sent (and, as signals, held: the stop and the close went on)
    assert points == ["executed", "quick stop", "stop"] + (["manifest"] if how == "signal" else []), points
    assert sent[:5] == AXES  # every axis got its quick stop, the interrupt in j1's notwithstanding
    assert states and all(s != "OPERATION_ENABLED" for s in states[0].values()), states
    r = RecordingReader(d)  # the counts are those of the files (it raises otherwise)
    m = r.manifest
    assert m["status"] == "incomplete" and m["summary"]["status"] == "stopped", (m["status"], m.get("summary"))
    assert r.decisions[-1] == {"type": "stop", "source": "operator", "reason": "interrupted at the terminal"}
    assert [x["type"] for x in r.decisions].count("executed") == 1
    code, out, err = run_cli("replay", d, capsys=capsys)
    assert code == 0, err


@pytest.mark.parametrize("where", ["decision", "frame"])
def test_an_interrupt_between_a_write_and_its_count_still_closes_a_consistent_recording(tmp_path, monkeypatch,
                                                                                         where):
    """Ctrl-C after a decision's fsync (or a frame's rename) and before the writer counted it: the manifest
    said one fewer than the file held, and the reader refused the recording as corrupt."""
    import numpy as np

    from cell import recording

    w = recording.RecordingWriter(tmp_path / "r")
    w.write_frame(0, np.zeros((8, 8, 3), np.uint8))
    w.write_decision({"type": "frame"})
    if where == "decision":
        fsync = os.fsync

        def fsync_then_interrupt(fd):
            fsync(fd)
            raise KeyboardInterrupt

        monkeypatch.setattr(recording.os, "fsync", fsync_then_interrupt)
        with pytest.raises(KeyboardInterrupt):
            w.write_decision({"type": "stop"})
    else:
        write_atomic = recording.write_atomic

        def write_then_interrupt(path, data):
            write_atomic(path, data)
            raise KeyboardInterrupt

        monkeypatch.setattr(recording, "write_atomic", write_then_interrupt)
        with pytest.raises(KeyboardInterrupt):
            w.write_frame(1, np.zeros((8, 8, 3), np.uint8))
    monkeypatch.undo()
    w.close("incomplete")
    r = RecordingReader(tmp_path / "r")  # raised: "decisions.jsonl holds 2 decisions, the manifest says 1"
    assert len(r.decisions) == (2 if where == "decision" else 1) and r.frame_indices == ([0] if where == "decision"
                                                                                         else [0, 1])
    assert r.manifest["counts"] == {"frames": len(r.frame_indices), "decisions": len(r.decisions)}


def test_a_decision_file_cut_short_during_the_session_is_still_refused(tmp_path):
    """The counts at close are never below what was written: a file that lost a line meanwhile is caught."""
    from cell import recording
    from cell.errors import BadInput

    w = recording.RecordingWriter(tmp_path / "r")
    for i in range(3):
        w.write_decision({"type": "frame", "i": i})
    path = tmp_path / "r" / recording.DECISIONS
    path.write_bytes(b"".join(path.read_bytes().splitlines(keepends=True)[:2]))
    w.close("incomplete")
    with pytest.raises(BadInput, match="holds 2 decisions, the manifest says 3"):
        RecordingReader(tmp_path / "r")


def test_a_session_stopped_before_its_first_frame_replays(tmp_path, capsys):
    """The camera gave no readable frame (or the operator stopped before Run): the recording is whole, with
    one stop and no frames. Replay refused it as "holds no frames" (exit 2)."""
    from cell.runtime.session import RunConfig, run_session
    from cell.runtime.simworld import WorldFaults

    rec = tmp_path / "no-frames"
    s = run_session(RunConfig(assembly=_two_parts(tmp_path), record=rec, seed=1, faults=WorldFaults(bad_frames=5)))
    assert s["status"] == "stopped" and "no readable frame" in s["stopped"]
    assert RecordingReader(rec).frame_indices == []
    code, out, err = run_cli("replay", rec, "--json", capsys=capsys)
    assert code == 0, err
    result = json.loads(out.strip().splitlines()[-1])
    assert result["matched"] == result["decisions"] == 1 and "no readable frame" in result["session"]["stopped"]


def test_a_session_interrupted_before_it_started_replays_as_nothing_to_re_run(tmp_path, monkeypatch, capsys):
    """SIGTERM while the drives and the camera were set up: the recording is closed as 'not started', with no
    decision and no frame. Replay read it as corrupt ("holds no frames", exit 2)."""
    from cell.runtime import session
    from cell.runtime.session import RunConfig, run_session

    def interrupted(*a, **k):
        raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(session, "_simulated_sources", interrupted)
    rec = tmp_path / "not-started"
    with pytest.raises(KeyboardInterrupt):
        run_session(RunConfig(assembly=_two_parts(tmp_path), record=rec, seed=1))
    assert RecordingReader(rec).manifest["summary"]["status"] == "not started"
    code, out, err = run_cli("replay", rec, "--json", capsys=capsys)
    assert code == 0 and "did not start (SIGTERM)" in err + out, err
    result = json.loads(out.strip().splitlines()[-1])
    assert result["decisions"] == result["matched"] == 0 and result["session"]["status"] == "not started"


@pytest.mark.parametrize("existing", [False, True], ids=["new-folder", "empty-folder"])
def test_a_recording_set_up_cut_short_leaves_no_half_made_folder(tmp_path, monkeypatch, existing):
    """SIGTERM between the folder's making and its manifest left frames/ alone: replay said "has no
    manifest.json", and the next `cell run --record` with the name refused it as "not empty"."""
    from cell import recording
    from cell.recording import RecordingWriter

    where = tmp_path / "shift" / "session"
    if existing:
        where.mkdir(parents=True)
    copy = recording.shutil.copyfile

    def interrupted(src, dst, *a, **k):
        copy(src, dst, *a, **k)
        raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(recording.shutil, "copyfile", interrupted)
    with pytest.raises(KeyboardInterrupt):
        RecordingWriter(where)
    assert (where.is_dir() and not any(where.iterdir())) if existing else not (tmp_path / "shift").exists()
    monkeypatch.setattr(recording.shutil, "copyfile", copy)
    RecordingWriter(where).close("complete")  # the name can be used again
    assert RecordingReader(where).manifest["status"] == "complete"


def test_sigterm_during_cell_runs_set_up_is_an_interrupt_not_a_kill(monkeypatch, capsys):
    """The imports and the set-up take seconds before the session starts; SIGTERM there killed the process
    (exit 143, no word) where the README promises 130 and "cell: interrupted"."""
    import time

    from cell.commands import run as run_command

    def set_up(args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises in here
        return 0

    monkeypatch.setattr(run_command, "_run", set_up)
    before = signal.getsignal(signal.SIGTERM)
    code, _, err = run_cli("run", capsys=capsys)
    assert code == 130 and "cell: interrupted" in err
    assert signal.getsignal(signal.SIGTERM) is before  # handed back


def test_a_full_disk_while_holding_the_examples_leaves_no_half_made_recording(tmp_path, monkeypatch):
    """The copy of the examples the session starts with was written after the recording's set-up, outside
    its clean-up: a full disk there left a manifest saying "recording" and no CAN log (replay: exit 2; the
    name refused as holding a recording). The copy is now part of the set-up."""
    import errno

    from cell import recording
    from cell.errors import BadInput
    from cell.examples import default_examples_path
    from cell.recording import RecordingWriter

    def full(path, data, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recording, "write_atomic", full)
    where = tmp_path / "session"
    with pytest.raises(BadInput, match="No space left on device"):
        RecordingWriter(where, examples_file=default_examples_path(), examples_copy="examples_at_start.jsonl")
    assert not where.exists()
    monkeypatch.undo()
    RecordingWriter(where, examples_file=default_examples_path(), examples_copy="examples_at_start.jsonl").close()
    assert (where / "examples_at_start.jsonl").read_bytes() == default_examples_path().read_bytes()


def test_ctrl_c_during_a_station_run_waits_for_the_loop_before_the_recording_closes(tmp_path, capsys, ctrl_c,
                                                                                    monkeypatch):
    """`cell run --station --record`, Ctrl-C while the loop's thread is busy (here: reading its second frame, made
    slow) and the main thread waits for it. Python 3.11's Thread.join, interrupted by the signal, marked the loop's
    thread stopped although it ran on: the stop was recorded and the recording closed while the loop went on (4
    of 14 such sessions: replay "ended after 18 of 22 recorded decisions", or frames/ holding one more frame than
    the manifest said), or the process ended under it (SIGABRT). Now the recording closes after the loop has
    ended, the stop its last decision, and it replays."""
    import sys
    import time

    from station_runs import TOKEN, post

    from cell.recording import RecordingWriter
    from cell.runtime.loop import CellLoop

    rec, port, reads, busy = tmp_path / "rec", _free_port(), [], threading.Event()
    read_frame = CellLoop._read_frame

    def slow_second_read(self):
        reads.append(1)
        if len(reads) == 2:
            busy.set()
            time.sleep(1.0)  # the signal comes meanwhile
        return read_frame(self)

    monkeypatch.setattr(CellLoop, "_read_frame", slow_second_read)
    loop_alive_at_close = []
    close = RecordingWriter.close

    def spy_close(self, *a, **kw):
        running = sys._current_frames()  # a thread that still runs has a frame, whatever is_alive() says
        loop_alive_at_close.append(any(t.name == "cell-loop" and t.ident in running for t in threading.enumerate()))
        return close(self, *a, **kw)

    monkeypatch.setattr(RecordingWriter, "close", spy_close)

    def operator():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the station answers once the set-up is done
            try:
                post(f"http://127.0.0.1:{port}", "/api/run")
                break
            except OSError:
                time.sleep(0.1)
        if busy.wait(60):
            time.sleep(0.2)
            os.kill(os.getpid(), signal.SIGINT)

    t = threading.Thread(target=operator, daemon=True)
    t.start()
    code, _, err = run_cli("run", _two_parts(tmp_path), "--station", "--port", port, "--token", TOKEN,
                           "--record", rec, capsys=capsys)
    t.join(5)
    assert code == 130, err
    assert loop_alive_at_close == [False]
    assert RecordingReader(rec).decisions[-1]["type"] == "stop"
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
