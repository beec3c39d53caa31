"""A grasp taught on the station during a recorded run replays: the loop learns it at its next
plan and records it there, and `cell replay` learns it at the same point. (It used to be
learned at once, unrecorded: the replay planned without it and diverged.)"""

import time

import numpy as np
from conftest import run_cli
from station_runs import T, default_parts, post, state, station_run, wait

from cell.examples import default_examples_path, load_examples
from cell.recording import RecordingReader


def test_a_grasp_taught_mid_run_is_recorded_and_replays(tmp_path, capsys):
    rec = tmp_path / "session"
    t, url, result = station_run(default_parts(tmp_path, ["washer", "nut"]), record=rec, require_approval=True)
    post(url, "/api/run", {})
    s = wait(url, lambda s: s["control"]["state"] == "awaiting_approval", "the first proposal")
    proposal = s["control"]["proposal"]
    assert proposal["target"] == "washer"
    # the page names the shipped examples and, until the first new one starts it, the file new ones go to
    shown = s["cell"]["examples"]
    assert shown["path"] == str(default_examples_path()) and shown["new_to"] == str(rec / "examples.jsonl")
    # teach the washer across another diameter than proposed, then reject the proposal: the loop
    # plans again, learning the taught grasp first (the nearest example: its own grasp is chosen)
    washer = next(p for p in s["cell"]["parts"] if p["id"] == "washer")
    ring = np.asarray(washer["outline_px"], float)
    c = ring.mean(axis=0)
    k = int(np.argmax(np.abs((ring - c) @ np.array([1.0, 1.0]))))
    p1 = ring[k]
    p2 = ring[int(np.argmin(np.linalg.norm(ring - (2 * c - p1), axis=1)))]
    taught = post(url, "/api/teach", {"part": "washer", "p1_px": p1.tolist(), "p2_px": p2.tolist()})["result"]
    seq = state(url)["control"]["seq"]
    # (learned at the next plan: the count follows then)
    assert state(url)["cell"]["examples"] == {"path": str(rec / "examples.jsonl"), "count": shown["count"]}
    post(url, "/api/reject", {"reason": "not there"})
    states = set()
    while t.is_alive():  # approve every proposal from here on (the station closes with the run)
        try:
            s = state(url)
            states.add(s["control"]["state"])
            if s["control"]["state"] == "awaiting_approval" and s["control"]["seq"] != seq:
                seq = s["control"]["seq"]
                post(url, "/api/approve", {})
        except OSError:  # refused, or reset mid-answer: the station closed with the run
            break
        time.sleep(0.05)
    t.join(T)
    assert result and result[0]["status"] == "complete", result
    assert "done" in states  # the station answered long enough after the run for the page to show it
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0 and "decisions match" in out, err
    decisions = RecordingReader(rec).decisions
    kinds = [x["type"] for x in decisions]
    at = kinds.index("example")
    assert decisions[at]["example"]["id"] == taught["example_id"]
    # recorded after the rejection and before the plan that learned it
    assert kinds[at - 1] == "decision" and not decisions[at - 1]["approved"] and kinds[at + 1] == "grasp"
    assert taught["example_id"] in {e.id for e in load_examples(rec / "examples.jsonl")}


def test_the_station_answers_after_a_run_that_ends_stopped(tmp_path):
    """`cell run --station` keeps the page answering STATION_LINGER_S after the run, however it ended:
    after a Stop the page shows "stopped", not a cell that does not answer (it closed at once)."""
    t, url, ended = station_run(default_parts(tmp_path, ["washer"]), require_approval=True)
    post(url, "/api/run", {})
    wait(url, lambda s: s["control"]["state"] == "awaiting_approval", "the proposal")
    post(url, "/api/stop", {"reason": "hand in the cell"})
    time.sleep(0.5)  # the loop has ended by now; the station lingers 2 s after it
    assert state(url)["control"]["state"] == "stopped"
    t.join(T)
    assert ended and ended[0]["status"] == "stopped", ended


def test_after_ctrl_c_at_the_terminal_the_page_is_shown_stopped_and_why(tmp_path):
    """Ctrl-C of `cell run --station` closed the station at once: the page, last told "running", said only that
    the cell did not answer. The station now answers a moment more, the run stopped and why."""
    import _thread
    import re
    import threading

    import pytest
    from station_runs import TOKEN

    from cell.runtime.session import RunConfig, run_session

    lines, seen = [], []
    cfg = RunConfig(assembly=default_parts(tmp_path, ["washer"]), seed=1, station=True, station_port=0,
                    station_token=TOKEN, require_approval=True, progress=lines.append)

    def operator_then_ctrl_c():
        deadline = time.monotonic() + T
        while not any("operator station:" in s for s in lines) and time.monotonic() < deadline:
            time.sleep(0.05)
        url = re.search(r"(http://127\.0\.0\.1:\d+)", next(s for s in lines if "operator station:" in s)).group(1)
        post(url, "/api/run", {})
        wait(url, lambda s: s["control"]["state"] == "awaiting_approval", "the proposal")
        _thread.interrupt_main()  # Ctrl-C at the terminal
        while time.monotonic() < deadline:
            try:
                seen.append(state(url)["control"])
            except OSError:  # closed
                return
            time.sleep(0.1)

    watcher = threading.Thread(target=operator_then_ctrl_c, daemon=True)
    watcher.start()
    with pytest.raises(KeyboardInterrupt):
        run_session(cfg)
    watcher.join(T)
    stopped = [c for c in seen if c["state"] == "stopped"]
    assert stopped, [c["state"] for c in seen]
    assert "interrupted" in str(stopped[-1]), stopped[-1]
