"""A grasp taught on the station during a recorded run replays: the loop learns it at its next
plan and records it there, and `cell replay` learns it at the same point. (It used to be
learned at once, unrecorded: the replay planned without it and diverged.)"""

import json
import re
import threading
import time
import urllib.request
from importlib import resources
from pathlib import Path

import numpy as np
from conftest import run_cli

from cell.examples import load_examples
from cell.recording import RecordingReader
from cell.runtime.session import RunConfig, run_session

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))
T = 60.0
TOKEN = "teach-test-token"


def _post(url, token, path, body):
    req = urllib.request.Request(url + path, data=json.dumps(body).encode(), method="POST")
    req.add_header("Content-Type", "application/json")
    req.add_header("X-Cell-Token", token)
    with urllib.request.urlopen(req, timeout=T) as r:
        return json.loads(r.read())


def _state(url):
    with urllib.request.urlopen(url + "/api/state", timeout=T) as r:
        return json.loads(r.read())


def _wait(url, pred, what):
    deadline = time.monotonic() + T
    while time.monotonic() < deadline:
        s = _state(url)
        if pred(s):
            return s
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}: {s['control']['state']}")


def _run_with_station(assembly, record=None):
    """`cell run --station --approve` on a thread: (the thread, the station's URL, [its summary or error])."""
    lines, ended = [], []

    def work():
        try:
            ended.append(run_session(RunConfig(assembly=assembly, record=record, seed=1, station=True,
                                               require_approval=True, station_port=0, station_token=TOKEN,
                                               progress=lines.append)))
        except BaseException as e:  # noqa: BLE001 - the test asserts on it
            ended.append(e)

    t = threading.Thread(target=work, daemon=True)
    t.start()
    deadline = time.monotonic() + T
    while not any("operator station:" in s for s in lines):
        assert time.monotonic() < deadline and t.is_alive(), (lines, ended)
        time.sleep(0.05)
    url = re.search(r"(http://127\.0\.0\.1:\d+)", next(s for s in lines if "operator station:" in s)).group(1)
    return t, url, ended


def test_a_grasp_taught_mid_run_is_recorded_and_replays(tmp_path, capsys):
    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] in ("nut", "washer")]
    d["sequence"] = ["washer", "nut"]
    d.pop("cell", None)
    assembly = tmp_path / "two.json"
    assembly.write_text(json.dumps(d))
    rec = tmp_path / "session"
    t, url, result = _run_with_station(assembly, rec)
    _post(url, TOKEN, "/api/run", {})
    s = _wait(url, lambda s: s["control"]["state"] == "awaiting_approval", "the first proposal")
    proposal = s["control"]["proposal"]
    assert proposal["target"] == "washer"
    # teach the washer across another diameter than proposed, then reject the proposal: the loop
    # plans again, learning the taught grasp first (the nearest example: its own grasp is chosen)
    washer = next(p for p in s["cell"]["parts"] if p["id"] == "washer")
    ring = np.asarray(washer["outline_px"], float)
    c = ring.mean(axis=0)
    k = int(np.argmax(np.abs((ring - c) @ np.array([1.0, 1.0]))))
    p1 = ring[k]
    p2 = ring[int(np.argmin(np.linalg.norm(ring - (2 * c - p1), axis=1)))]
    taught = _post(url, TOKEN, "/api/teach", {"part": "washer", "p1_px": p1.tolist(), "p2_px": p2.tolist()})["result"]
    seq = _state(url)["control"]["seq"]
    _post(url, TOKEN, "/api/reject", {"reason": "not there"})
    states = set()
    while t.is_alive():  # approve every proposal from here on (the station closes with the run)
        try:
            s = _state(url)
            states.add(s["control"]["state"])
            if s["control"]["state"] == "awaiting_approval" and s["control"]["seq"] != seq:
                seq = s["control"]["seq"]
                _post(url, TOKEN, "/api/approve", {})
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
    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] == "washer"]
    d["sequence"] = ["washer"]
    d.pop("cell", None)
    assembly = tmp_path / "one.json"
    assembly.write_text(json.dumps(d))
    t, url, ended = _run_with_station(assembly)
    _post(url, TOKEN, "/api/run", {})
    _wait(url, lambda s: s["control"]["state"] == "awaiting_approval", "the proposal")
    _post(url, TOKEN, "/api/stop", {"reason": "hand in the cell"})
    time.sleep(0.5)  # the loop has ended by now; the station lingers 2 s after it
    assert _state(url)["control"]["state"] == "stopped"
    t.join(T)
    assert ended and ended[0]["status"] == "stopped", ended
