"""A station session in which the loop stopped to ask and the operator answered replays to its end.
Replay used to run without an operator: it ended at the loop's first stop ("the replay ended after 17 of
48 recorded decisions"), whether the operator then reset and ran on, or stopped the sequence."""

import json
import re
import time
from pathlib import Path

import pytest
from conftest import run_cli
from station_runs import TOKEN, T, default_parts, post, state, station_run, wait

from cell.recording import RecordingReader
from cell.runtime.simworld import WorldFaults


def _control(url):
    return state(url)["control"]


def _wait(url, pred, what):
    return wait(url, lambda s: pred(s["control"]), what)["control"]


def _station_run(tmp_path, faults):
    rec = tmp_path / "session"
    return (*station_run(default_parts(tmp_path, ["washer", "nut"]), record=rec, faults=faults), rec)


@pytest.mark.parametrize("answer", ["reset", "stop"])
def test_a_station_session_replays_past_the_operators_answer_to_a_stop(tmp_path, capsys, answer):
    # the washer's first two grips miss: the loop retries once, then stops to ask
    t, url, ended, rec = _station_run(tmp_path, WorldFaults(miss={"washer": 2}))
    post(url, "/api/run")
    c = _wait(url, lambda c: c["state"] == "fault", "the stop to ask")
    assert c["fault"]["asking"] and "washer: missed 2 times" in c["fault"]["why"], c
    if answer == "reset":
        post(url, "/api/reset")
        post(url, "/api/run")
    else:
        post(url, "/api/stop", {"reason": "the washer is bent"})
    t.join(T)
    summary = ended[0]
    assert isinstance(summary, dict), summary
    if answer == "reset":
        assert (summary["status"], summary["parts_removed"]) == ("complete", 2)
        washer = next(p for p in summary["parts"] if p["part"] == "washer")
        assert washer["attempts"] == 3  # two misses before the stop, the grip after the reset
    else:
        assert summary["status"] == "stopped" and summary["stopped"] == "operator: the washer is bent"
        washer = next(p for p in summary["parts"] if p["part"] == "washer")
        assert washer["reason"] == summary["stopped"]
    recorded = [d for d in RecordingReader(rec).decisions if d["type"] != "summary"]
    code, out, err = run_cli("replay", rec, "--json", capsys=capsys)
    assert code == 0, err
    result = json.loads(out.strip().splitlines()[-1])
    assert result["matched"] == result["decisions"] == len(recorded), result


def test_ctrl_c_while_the_station_shows_the_end_leaves_a_complete_run_complete(tmp_path, capsys, monkeypatch):
    """The station answers 2 s more after the run ends; an operator's Ctrl-C then turned a complete run into
    a stopped one (exit 130), closed the recording incomplete and quick-stopped the arm after its end."""
    from cell.runtime import session

    sleep = time.sleep

    def interrupted_linger(s):
        if s == session.STATION_LINGER_S:
            raise KeyboardInterrupt
        sleep(s)

    monkeypatch.setattr(session.time, "sleep", interrupted_linger)
    t, url, ended, rec = _station_run(tmp_path, WorldFaults())
    post(url, "/api/run")
    t.join(T)
    assert isinstance(ended[0], dict) and ended[0]["status"] == "complete", ended
    assert RecordingReader(rec).manifest["status"] == "complete"
    code, _, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err


def test_the_station_refuses_reset_and_run_once_the_run_has_ended(tmp_path):
    import urllib.error

    t, url, ended, rec = _station_run(tmp_path, WorldFaults())
    post(url, "/api/run")
    c = _wait(url, lambda c: c.get("ended"), "the end of the run")
    assert c["state"] == "done"
    for path, body in (("/api/reset", None), ("/api/run", None),
                       ("/api/teach", {"part": "nut", "p1_px": [600, 500], "p2_px": [640, 500]})):
        with pytest.raises(urllib.error.HTTPError) as e:
            post(url, path, body)
        assert e.value.code == 409 and "the run has ended" in e.value.read().decode()
    assert _control(url)["state"] == "done"
    t.join(T)


def test_a_stop_once_the_run_is_done_sends_nothing_and_the_recording_replays(tmp_path, capsys):
    """A Stop a poll late (a second tab) while the station still answers after a complete run: it answered
    "done" but quick-stopped the drives after the summary, onto the recording's bus log, and replay diverged
    ("CAN id 0x201 ... 0600 in the replay, 0200 in the recording")."""
    t, url, ended, rec = _station_run(tmp_path, WorldFaults())
    post(url, "/api/run")
    _wait(url, lambda c: c.get("ended"), "the end of the run")
    assert post(url, "/api/stop", {"reason": "a second tab"})["result"] == "done"
    t.join(T)
    assert ended[0]["status"] == "complete" and RecordingReader(rec).manifest["status"] == "complete"
    code, _, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err


@pytest.mark.parametrize("signals", [("SIGINT",), ("SIGINT", "SIGINT"), ("SIGTERM", "SIGINT")])
def test_signals_while_the_station_shows_the_end_only_end_the_wait(tmp_path, signals):
    """`cell run --station` as a process: Ctrl-C or SIGTERM after its loop has ended ends the station's 2 s
    wait and nothing else: the summary on stdout, the recording complete, exit 0. (A second one was held and
    raised at the end: exit 130, no summary, "stopping the arm" where nothing moved.) A second signal may
    come after the first has ended the wait, while the process exits: it may then end as interrupted, but
    only after the summary and the recording are out."""
    import signal
    import subprocess
    import sys

    assembly = default_parts(tmp_path, ["washer", "nut"])
    rec = tmp_path / "session"
    cell = Path(sys.executable).with_name("cell")
    proc = subprocess.Popen([str(cell), "run", str(assembly), "--station", "--port", "0", "--token", TOKEN,
                             "--record", str(rec), "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        while url is None:
            line = proc.stderr.readline()
            assert line, "cell run ended before its station was up"
            m = re.search(r"(http://127\.0\.0\.1:\d+)", line)
            url = m.group(1) if m else None
        post(url, "/api/run")
        _wait(url, lambda c: c.get("ended"), "the end of the run")
        for name in signals:
            proc.send_signal(getattr(signal, name))
            time.sleep(0.1)
        out, err = proc.communicate(timeout=T)
    finally:
        proc.kill()
    assert json.loads(out.strip().splitlines()[-1])["status"] == "complete", err
    assert "stopping the arm" not in err, err
    assert RecordingReader(rec).manifest["status"] == "complete"
    if len(signals) == 1:
        assert proc.returncode == 0 and "interrupted" not in err, err
    else:
        assert proc.returncode in (0, 130, -signal.SIGINT), err


def test_replay_says_it_cannot_follow_a_session_past_a_drive_fault_the_operator_reset():
    """After a drive fault and the operator's Reset the session went on from where the arm stood when it
    faulted; the replay's arm faults elsewhere. It reset and ran on, and diverged later with a message that
    read like a planning change ("commands: 10 items recorded, 11 replayed")."""
    from cell.runtime.loop import StopRun
    from cell.runtime.replay import Comparison, Divergence, RecordedApprovals

    recorded = [{"type": "perception"}, {"type": "stop", "source": "j2", "reason": "EMCY 0x2310"},
                {"type": "perception"}, {"type": "grasp"}]
    sink = Comparison(recorded, drives=None, position=2)
    control = RecordedApprovals(recorded)
    control.sink = sink
    with pytest.raises(Divergence, match=r"went on after a fault the operator reset \(j2: EMCY 0x2310\).*"
                                         r"compared up to the fault only \(2 of 4 decisions\)"):
        control.report_fault("j2", "EMCY 0x2310")
    lenient = Comparison(recorded, drives=None, strict=False, position=2)
    control = RecordedApprovals(recorded)
    control.sink = lenient
    with pytest.raises(StopRun):
        control.report_fault("j2", "EMCY 0x2310")
    assert len(lenient.found) == 1 and lenient.position == 4
    control = RecordedApprovals(recorded)  # a stop to ask instead: the operator's reset, and on
    control.sink = Comparison(recorded, drives=None, position=2)
    control.report_fault("planner", "no feasible grasp", asking=True)
    assert control.state == "running"
