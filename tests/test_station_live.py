"""LiveView: the backend a cell loop fills in, served through the real station over HTTP."""

import json
import threading
import urllib.error
import urllib.request

import cv2
import numpy as np
import pytest

from cell.runtime.control import RunControl
from cell.station.live import LiveView
from cell.station.server import StationServer

TOKEN = "live-token-0123456789"


def _get(server, path):
    with urllib.request.urlopen(server.base_url + path.lstrip("/"), timeout=5) as r:
        return r.status, r.read()


def _post(server, path, body):
    req = urllib.request.Request(server.base_url + path.lstrip("/"), data=json.dumps(body).encode(),
                                 method="POST", headers={"X-Cell-Token": TOKEN})
    try:
        with urllib.request.urlopen(req, timeout=5) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def test_loop_updates_are_served_and_teach_reaches_the_loop():
    taught = []

    def teach_fn(part_id, p1, p2):
        taught.append((part_id, p1, p2, threading.current_thread().name))
        return {"example_id": f"ex-{len(taught)}", "n_examples": len(taught)}

    view = LiveView(teach_fn, info={"examples": {"path": "x.jsonl", "count": 0}})
    with StationServer(view, RunControl(), port=0, token=TOKEN) as server:
        with pytest.raises(urllib.error.HTTPError) as e:
            _get(server, "/api/frame.png")
        assert e.value.code == 404
        frame = np.zeros((60, 80, 3), np.uint8)
        frame[10:30, 20:50] = (0, 0, 255)
        view.show_frame(7, frame)
        view.show_parts([{"id": "cover", "outline_px": np.array([[20, 10], [50, 10], [50, 30], [20, 30]])}])
        view.show_proposal("cover", [[20, 20], [50, 20]], [np.zeros((4, 2))], np.ones((4, 2)))
        status, raw = _get(server, "/api/state")
        cell = json.loads(raw)["cell"]
        assert cell["frame"] == {"index": 7, "width_px": 80, "height_px": 60}
        assert cell["parts"][0]["outline_px"][1] == [50.0, 10.0]
        assert cell["proposal_px"]["contacts_px"] == [[20.0, 20.0], [50.0, 20.0]]
        assert cell["examples"]["path"] == "x.jsonl"
        status, png = _get(server, "/api/frame.png")
        assert np.array_equal(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), frame)

        status, reply = _post(server, "/api/teach", {"part": "cover", "p1_px": [20, 15], "p2_px": [50, 25.5]})
        assert status == 200 and reply["result"] == {"example_id": "ex-1", "n_examples": 1}
        assert taught[0][:3] == ("cover", [20.0, 15.0], [50.0, 25.5])
        status, reply = _post(server, "/api/teach", {"part": "ghost", "p1_px": [1, 1], "p2_px": [2, 2]})
        assert status == 400 and "no part 'ghost'" in reply["error"] and len(taught) == 1

        view.show_frame(8, frame)  # a new frame clears the old outlines and proposal
        cell = json.loads(_get(server, "/api/state")[1])["cell"]
        assert cell["parts"] == [] and cell["proposal_px"] is None and cell["frame"]["index"] == 8


def test_without_a_teach_function_teaching_is_refused():
    view = LiveView()
    with StationServer(view, RunControl(), port=0, token=TOKEN) as server:
        status, reply = _post(server, "/api/teach", {"part": "a", "p1_px": [1, 1], "p2_px": [2, 2]})
        assert status == 409 and "does not take taught grasps" in reply["error"]
    with pytest.raises(ValueError, match="uint8"):
        view.show_frame(0, np.zeros((4, 4), float))


def test_numpy_values_in_the_state_are_served_as_json_numbers_and_lists():
    """The loop's state holds numpy values (a count, a score, a flag, joints as an array): the
    server's JSON writer raised on them, so the page got a 500 for every poll, and a command the
    cell took was answered as an error."""
    view = LiveView(info={"examples": {"path": "x.jsonl", "count": np.int64(3)}, "score": np.float64(0.25),
                          "ok": np.bool_(True), "joints_deg": np.array([10.0, -20.5]),
                          "reach_mm": np.float32(1.5), "unknown": float("nan")})
    control = RunControl()
    control.log("note", "numpy in the event data", step=np.int64(2), seen=np.array([1, 2]))
    with StationServer(view, control, port=0, token=TOKEN) as server:
        status, raw = _get(server, "/api/state")
        cell = json.loads(raw, parse_constant=lambda c: pytest.fail(f"{c} is not JSON"))["cell"]
        assert status == 200
        assert cell["examples"]["count"] == 3 and cell["score"] == 0.25 and cell["ok"] is True
        assert cell["joints_deg"] == [10.0, -20.5] and cell["reach_mm"] == 1.5 and cell["unknown"] is None
        status, reply = _post(server, "/api/pause", {})  # a command's answer carries the same state
        assert status == 200 and reply["ok"] is True and reply["cell"]["ok"] is True
        note = next(e for e in reply["control"]["events"] if e["event"] == "note")
        assert note["data"] == {"step": 2, "seen": [1, 2]}


def test_a_teach_on_an_older_frame_does_not_reach_the_loop():
    taught = []
    view = LiveView(lambda *a: taught.append(a) or {"example_id": "ex", "n_examples": 1})
    outline = np.array([[20, 10], [50, 10], [50, 30], [20, 30]])
    with StationServer(view, RunControl(), port=0, token=TOKEN) as server:
        view.show_frame(7, np.zeros((60, 80, 3), np.uint8))
        view.show_parts([{"id": "cover", "outline_px": outline}])
        view.show_frame(8, np.zeros((60, 80, 3), np.uint8))  # the loop moved on; the cover is seen again
        view.show_parts([{"id": "cover", "outline_px": outline + 5}])
        body = {"part": "cover", "p1_px": [20, 15], "p2_px": [50, 25], "frame": 7}
        status, reply = _post(server, "/api/teach", body)
        assert status == 409 and "no longer the current one (now 8)" in reply["error"] and taught == []
        status, reply = _post(server, "/api/teach", {**body, "frame": 8})
        assert status == 200 and len(taught) == 1
