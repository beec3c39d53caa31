"""The station over real HTTP (urllib against 127.0.0.1, port 0): tokens, state changes, teach."""

import contextlib
import json
import time
import urllib.error
import urllib.request

import pytest

from cell.errors import BadInput
from cell.examples import load_examples
from cell.runtime.control import AWAITING_APPROVAL, DONE, PAUSED, RunControl
from cell.station.demo import DemoCell, mm_to_px
from cell.station.server import StationServer

T = 5.0
TOKEN = "test-token-0123456789"


@pytest.fixture
def station(tmp_path):
    control = RunControl()
    cell = DemoCell(control, tmp_path / "examples.jsonl", motion_s=0.0)
    with StationServer(cell, control, port=0, token=TOKEN) as server:
        cell.start()
        yield server, control, cell
        cell.close()
        assert cell._thread is None  # the loop thread ended


def wait_proposal(control, target):
    """Block until the loop waits for approval of a grasp on `target` (woken by changes)."""
    deadline = time.monotonic() + T
    while True:
        snap = control.snapshot(0)
        if snap["state"] == AWAITING_APPROVAL and (snap["proposal"] or {}).get("target") == target:
            return snap["proposal"]
        assert time.monotonic() < deadline, f"no proposal on {target}; state {snap['state']}"
        control.wait_change(snap["seq"], timeout_s=0.5)


def call(server, method, path, body=None, token=TOKEN, headers=None):
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(server.base_url + path.lstrip("/"), data=data, method=method)
    if token is not None:
        req.add_header("X-Cell-Token", token)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    for k, v in (headers or {}).items():
        req.add_header(k, v)
    try:
        with urllib.request.urlopen(req, timeout=T) as r:
            raw, status, ctype = r.read(), r.status, r.headers["Content-Type"]
    except urllib.error.HTTPError as e:
        raw, status, ctype = e.read(), e.code, e.headers["Content-Type"]
    return status, (json.loads(raw) if ctype == "application/json" else raw)


def test_page_state_and_frame_need_no_token(station):
    server, _, _ = station
    status, page = call(server, "GET", "/", token=None)
    assert status == 200 and b"<title>Cell station</title>" in page
    for asset in ("/station.js", "/station.css"):
        assert call(server, "GET", asset, token=None)[0] == 200
    status, state = call(server, "GET", "/api/state", token=None)
    assert status == 200 and state["control"]["state"] == "idle"
    assert {p["id"] for p in state["cell"]["parts"]} == {"cover", "board", "bracket", "cap"}
    status, png = call(server, "GET", "/api/frame.png", token=None)
    assert status == 200 and png[:8] == b"\x89PNG\r\n\x1a\n"
    assert call(server, "GET", "/nothing", token=None)[0] == 404


@pytest.mark.parametrize("token", [None, "", "wrong-token-0123456789", TOKEN[:-1]])
def test_every_command_needs_the_token_and_a_wrong_one_changes_nothing(station, token):
    server, control, _ = station
    before = control.snapshot()
    for cmd, body in (("run", None), ("step", None), ("stop", {"reason": "x"}),
                      ("approval", {"required": True}),
                      ("teach", {"part": "cover", "p1_px": [1, 2], "p2_px": [3, 4]})):
        status, reply = call(server, "POST", f"/api/{cmd}", body, token=token)
        assert status == 403 and "token" in reply["error"]
    after = control.snapshot()
    assert after["state"] == before["state"] == "idle"
    assert after["require_approval"] is False and after["seq"] == before["seq"]


def test_a_foreign_host_header_is_refused(station):
    server, control, _ = station
    status, reply = call(server, "POST", "/api/run", headers={"Host": "evil.example:80"})
    assert status == 403 and "127.0.0.1" in reply["error"]
    assert call(server, "GET", "/api/state", headers={"Host": "evil.example"})[0] == 403
    assert control.state == "idle"


def test_run_step_approve_reject_through_http(station, tmp_path):
    server, control, cell = station
    status, reply = call(server, "POST", "/api/approval", {"required": True})
    assert status == 200 and reply["control"]["require_approval"] is True
    status, reply = call(server, "POST", "/api/step")
    assert status == 200
    control.wait_for_state(PAUSED, timeout_s=T)  # one checkpoint passed, held at the next
    status, reply = call(server, "POST", "/api/run")
    assert status == 200
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    state = call(server, "GET", "/api/state")[1]
    assert state["control"]["proposal"]["target"] == "cover"
    assert len(state["cell"]["proposal_px"]["contacts_px"]) == 2
    status, reply = call(server, "POST", "/api/reject", {"reason": "pad on the hinge"})
    assert status == 200
    # the rejection became an invalid example in the file
    deadline = time.monotonic() + T
    while time.monotonic() < deadline and not (tmp_path / "examples.jsonl").exists():
        time.sleep(0.01)
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)  # the next proposal (other axis)
    ex = load_examples(tmp_path / "examples.jsonl")
    assert len(ex) == 1 and ex[0].valid is False and ex[0].part.id == "cover"
    assert ex[0].source["kind"] == "station-reject" and ex[0].source["note"] == "pad on the hinge"
    # approval off first (a proposal already waiting still needs its decision), then approve
    status, reply = call(server, "POST", "/api/approval", {"required": False})
    assert status == 200 and reply["control"]["state"] == AWAITING_APPROVAL
    status, reply = call(server, "POST", "/api/approve")
    assert status == 200
    control.wait_for_state(DONE, timeout_s=T)
    state = call(server, "GET", "/api/state")[1]
    assert state["cell"]["removed"] == ["cover", "board", "bracket", "cap"]
    assert state["control"]["summary"]["parts_removed"] == 4


def test_commands_the_state_does_not_allow_get_409(station):
    server, control, _ = station
    status, reply = call(server, "POST", "/api/approve")
    assert status == 409 and "no grasp is waiting" in reply["error"]
    assert call(server, "POST", "/api/reset")[0] == 200  # idle: nothing to reset, harmless
    assert call(server, "POST", "/api/fly")[0] == 404
    status, reply = call(server, "POST", "/api/approval", {"required": "yes"})
    assert status == 400 and "true or false" in reply["error"]
    control.report_fault("j2", "following error")
    status, reply = call(server, "POST", "/api/run")
    assert status == 409 and "Reset" in reply["error"]
    status, state = call(server, "GET", "/api/state")
    assert state["control"]["fault"] == {"source": "j2", "why": "following error", "asking": False,
                                         "t": state["control"]["fault"]["t"]}
    assert call(server, "POST", "/api/reset")[1]["control"]["state"] == "idle"


def test_teach_appends_a_valid_example_and_the_next_proposal_uses_it(station, tmp_path):
    server, control, cell = station
    part = next(p for p in cell.snapshot()["parts"] if p["id"] == "board")
    # two points on opposite long edges of the board, given in px as the page would send them
    from cell.station.demo import demo_parts

    board = next(p for p in demo_parts() if p.id == "board")
    o = board.outline_mm
    c1, c2 = (o[0] + o[1]) / 2, (o[2] + o[3]) / 2  # midpoints of two parallel edges
    p1, p2 = mm_to_px(c1).tolist(), mm_to_px(c2).tolist()
    status, reply = call(server, "POST", "/api/teach", {"part": part["id"], "p1_px": p1, "p2_px": p2})
    assert status == 200, reply
    r = reply["result"]
    assert r["part"] == "board" and r["n_examples"] == 1 and r["example_id"].startswith("station-teach")
    ex = load_examples(tmp_path / "examples.jsonl")
    assert ex[0].valid and ex[0].source["kind"] == "station-teach" and ex[0].joints is not None
    assert abs(ex[0].contacts_mm - [c1, c2]).max() < 0.2
    assert {o.id for o in ex[0].obstacles} == {"cover", "bracket", "cap"}
    assert any(e["event"] == "teach" for e in reply["control"]["events"])

    # bad teach input: 400 with a reason, nothing appended
    for body, match in (({"part": "ghost", "p1_px": p1, "p2_px": p2}, "no part 'ghost'"),
                        ({"part": "board", "p1_px": [1], "p2_px": p2}, "p1_px"),
                        ({"part": "board", "p1_px": p1, "p2_px": p1}, "apart"),
                        ({"part": "board", "p1_px": [5, 5], "p2_px": p2}, "from the outline"),
                        # far off the frame: was refused as if the calibration were wrong
                        ({"part": "board", "p1_px": [1e15, 3], "p2_px": p2},
                         "clicked point 1 (1e+15, 3) px is not on the 1280 x 1024 px frame"),
                        ({"part": "board", "p1_px": p1, "p2_px": [-1, 3]}, "clicked point 2 (-1, 3) px is not on"),
                        # two taps on one edge: a pad there would push along it (was taught as valid)
                        ({"part": "board", "p1_px": mm_to_px(o[0] + (o[1] - o[0]) * 0.2).tolist(),
                          "p2_px": mm_to_px(o[0] + (o[1] - o[0]) * 0.8).tolist()}, "faces 90 deg off the jaws' line")):
        status, reply = call(server, "POST", "/api/teach", body)
        assert status == 400 and match in reply["error"], reply
    assert len(load_examples(tmp_path / "examples.jsonl")) == 1

    # the loop's next plan for the board uses the taught contacts
    call(server, "POST", "/api/approval", {"required": True})
    call(server, "POST", "/api/run")
    wait_proposal(control, "cover")
    call(server, "POST", "/api/approve")
    prop = wait_proposal(control, "board")
    assert prop["how"] == "taught by the operator"
    assert abs(abs(prop["opening_mm"]) - float(((c2 - c1) ** 2).sum() ** 0.5)) < 0.2


def test_non_loopback_bind_needs_explicit_permission(tmp_path):
    control = RunControl()
    cell = DemoCell(control, tmp_path / "e.jsonl")
    with pytest.raises(BadInput, match="exposes the arm"):
        StationServer(cell, control, host="0.0.0.0", port=0)
    with pytest.raises(BadInput, match="at least 8"):
        StationServer(cell, control, port=0, token="short")


def test_cli_serves_and_exits(tmp_path, capsys):
    from cell.cli import main

    code = main(["station", "--port", "0", "--examples", str(tmp_path / "e.jsonl"), "--for-s", "0.2",
                 "--token", TOKEN])
    out = capsys.readouterr().out
    assert code == 0 and f"#token={TOKEN}" in out and "http://127.0.0.1:" in out
    assert main(["station", "--port", "70000"]) == 2


def raw_request(server, head: bytes, body: bytes = b"") -> tuple[int | None, dict | None]:
    """Send bytes as they are (urllib would fix up a bad Content-Length); the status and JSON body
    of the answer, (None, None) when the server hung up without one."""
    import socket

    with socket.create_connection((server.host, server.port), timeout=T) as s:
        s.sendall(head + body)
        out = b""
        try:
            while chunk := s.recv(65536):
                out += chunk
        except ConnectionResetError:
            pass
    if not out:
        return None, None
    status = int(out.split(b" ", 2)[1])
    return status, json.loads(out.split(b"\r\n\r\n", 1)[1] or b"{}")


def post_head(server, path, length, token=TOKEN) -> bytes:
    return (f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\nContent-Type: application/json\r\n"
            + (f"X-Cell-Token: {token}\r\n" if token else "") + f"Content-Length: {length}\r\n\r\n").encode()


@pytest.mark.parametrize("body", [b"[" * 50_000, b'{"reason": ' + b"7" * 5000 + b"}",
                                  b'{"part": "cap", "p1_px": [' + b"1" * 5000 + b', 1], "p2_px": [1, 1]}'],
                         ids=["nested-too-deep", "huge-integer", "huge-integer-in-teach"])
def test_bodies_json_cannot_hold_are_400_not_500(station, tmp_path, body):
    server, control, _ = station
    for cmd in ("reject", "teach"):
        status, r = raw_request(server, post_head(server, f"/api/{cmd}", len(body)), body)
        assert status == 400 and r["ok"] is False and "JSON" in r["error"], r
    assert not (tmp_path / "examples.jsonl").exists()


@pytest.mark.parametrize("length", ["100000000", "abc", "-5"])
def test_a_bad_content_length_gets_an_answer_with_or_without_the_token(station, length, capfd):
    server, control, _ = station
    status, r = raw_request(server, post_head(server, "/api/run", length, token=None), b"{}")
    assert status == 403 and r["ok"] is False  # the token is checked first, and answered
    status, r = raw_request(server, post_head(server, "/api/run", length), b"{}")
    assert status == 400 and ("Content-Length" in r["error"] or "too large" in r["error"]), r
    assert control.state == "idle"
    assert "Traceback" not in capfd.readouterr().err


def test_a_chunked_body_is_refused_not_dropped(station, tmp_path):
    """http.server does not read a chunked body: a chunked Reject with a reason was done with the default
    reason, and the invalid example lost the operator's words. Now 411, and nothing done."""
    server, control, _ = station
    body = b'{"reason": "the pads would crush the clip"}'
    head = (f"POST /api/reject HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\nContent-Type: application/json\r\n"
            f"X-Cell-Token: {TOKEN}\r\nTransfer-Encoding: chunked\r\n\r\n").encode()
    chunked = f"{len(body):x}\r\n".encode() + body + b"\r\n0\r\n\r\n"
    status, r = raw_request(server, head, chunked)
    assert status == 411 and r["ok"] is False and "Content-Length" in r["error"], r
    assert control.state == "idle" and not (tmp_path / "examples.jsonl").exists()


@pytest.mark.parametrize("method,path,allow", [
    ("PUT", "/api/run", "POST"), ("DELETE", "/api/teach", "POST"), ("PATCH", "/", "GET, HEAD"),
    ("OPTIONS", "/api/stop", "POST"), ("GET", "/api/run", "POST"), ("GET", "/api/teach", "POST"),
    ("POST", "/api/state", "GET, HEAD"), ("POST", "/api/frame.png", "GET, HEAD")])
def test_a_wrong_method_is_405_in_json_and_changes_nothing(station, method, path, allow):
    server, control, _ = station
    req = urllib.request.Request(server.base_url + path.lstrip("/"), method=method,
                                 data=b"{}" if method != "GET" else None, headers={"X-Cell-Token": TOKEN})
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(req, timeout=T)
    assert e.value.code == 405 and e.value.headers["Allow"] == allow
    assert e.value.headers["Content-Type"] == "application/json"
    assert "not allowed" in json.loads(e.value.read())["error"]
    assert control.state == "idle"


def test_cli_ends_cleanly_on_sigterm(tmp_path):
    """`cell station` under a service manager: SIGTERM ends it as Ctrl-C does (loop closed, exit 0)."""
    import signal
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-m", "cell", "station", "--port", "0", "--token", TOKEN,
                          "--examples", str(tmp_path / "e.jsonl")], stdout=subprocess.PIPE, text=True)
    try:
        for line in p.stdout:
            if line.startswith("open:"):
                break
        time.sleep(0.2)
        p.send_signal(signal.SIGTERM)
        out, _ = p.communicate(timeout=10)
    finally:
        p.kill()
    assert p.returncode == 0, p.returncode
    assert "closed" in out


@contextlib.contextmanager
def demo_at_the_cover(tmp_path, motion_s: float = 0.0):
    """The demo cell running with approval on, its first proposal (the cover) waiting."""
    control = RunControl(require_approval=True)
    cell = DemoCell(control, tmp_path / "examples.jsonl", motion_s=motion_s)
    cell.start()
    try:
        control.run()
        wait_proposal(control, "cover")
        yield control, cell
    finally:
        cell.close()


def test_a_stop_during_the_demo_pick_leaves_the_part_on_the_tray(tmp_path):
    """The demo's pick slept its whole motion and then took the part off: the log said "cover removed" a
    second after "stopped by the operator", and the tray lost the part."""
    import time

    with demo_at_the_cover(tmp_path, motion_s=30.0) as (control, cell):
        control.approve()
        deadline = time.monotonic() + 10
        while control.snapshot()["checkpoint"] != "move":
            assert time.monotonic() < deadline
            time.sleep(0.01)
        t0 = time.monotonic()
        control.stop("hand in the cell")
        control.wait_for_state("stopped", timeout_s=5)
        deadline = time.monotonic() + 5
        while "sequence abandoned" not in str(control.snapshot()["events"]):
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert time.monotonic() - t0 < 2.0  # not the 30 s motion
        shown = cell.snapshot()
        assert "cover" in {p["id"] for p in shown["parts"]} and shown["removed"] == []
        assert not any(e["event"] == "removed" for e in control.snapshot()["events"])


def test_the_demo_parts_keep_their_colour_when_another_leaves_the_tray(tmp_path):
    """Coloured by their place in the list, the cap turned from purple to blue and the bracket from
    blue to green when the cover was taken off."""
    import cv2
    import numpy as np

    from cell.station.demo import demo_parts

    with demo_at_the_cover(tmp_path) as (control, cell):
        def colours():
            img = cv2.imdecode(np.frombuffer(cell.frame_png(), np.uint8), cv2.IMREAD_COLOR)
            return {p.id: img[tuple(np.round(mm_to_px(p.polygon.representative_point().coords[0]))[::-1]
                                    .astype(int))].tolist() for p in demo_parts()}

        before = colours()
        control.approve()
        wait_proposal(control, "board")  # the cover is off the tray, the next frame drawn
        after = colours()
        assert after["cover"] != before["cover"]  # the tray shows where it was
        for pid in ("board", "bracket", "cap"):
            assert after[pid] == before[pid], pid


def test_approve_and_reject_decide_only_the_grasp_the_page_showed(station):
    """The page sends the proposal it shows; once another grasp waits (the loop re-proposed after a
    rejection, a double tap), the decision is refused and the waiting grasp stays undecided."""
    server, control, _ = station
    control.set_require_approval(True)
    assert call(server, "POST", "/api/run")[0] == 200
    first = wait_proposal(control, "cover")
    assert call(server, "POST", "/api/reject", {"reason": "too close to the rim", "proposal": first})[0] == 200
    deadline = time.monotonic() + T
    while (second := wait_proposal(control, "cover")) == first:  # until the loop proposes again
        assert time.monotonic() < deadline
        control.wait_change(control.snapshot(0)["seq"], timeout_s=0.5)
    assert second["contacts"] != first["contacts"]  # the long side this time
    for cmd in ("approve", "reject"):
        status, answer = call(server, "POST", f"/api/{cmd}", {"proposal": first})
        assert status == 409 and "no longer the one waiting" in answer["error"], answer
    assert control.state == AWAITING_APPROVAL and control.snapshot(0)["proposal"] == second
    assert [e["event"] for e in control.snapshot(200)["events"]].count("reject") == 1
    assert call(server, "POST", "/api/approve", {"proposal": "cover"})[0] == 400
    status, answer = call(server, "POST", "/api/approve", {"proposal": second})
    assert status == 200, answer
    assert call(server, "POST", "/api/approve")[0] in (200, 409)  # without it: as before (scripts)


def test_the_demo_tray_keeps_its_colours_of_before(tmp_path):
    """The first frame as it always was: cover orange, board green, bracket blue, cap purple (BGR)."""
    import cv2
    import numpy as np

    from cell.station.demo import PART_COLORS_BGR, demo_parts

    cell = DemoCell(RunControl(), tmp_path / "examples.jsonl")
    img = cv2.imdecode(np.frombuffer(cell.frame_png(), np.uint8), cv2.IMREAD_COLOR)
    for k, p in enumerate(demo_parts()):
        u, v = np.round(mm_to_px(p.polygon.representative_point().coords[0])).astype(int)
        assert tuple(img[v, u]) == PART_COLORS_BGR[k], p.id


@pytest.mark.parametrize("body, match", [
    # json keeps the last of a key given twice: the rejection was recorded with a note nobody read
    (b'{"reason": "pad on the hinge", "reason": "ok"}', "key 'reason' appears twice in one object"),
    # half a UTF-16 pair became the example's note, and the example file was then refused whole when read
    (b'{"reason": "pad on the \\udc80 hinge"}', "lone UTF-16 surrogate"),
], ids=["key-twice", "lone-surrogate"])
def test_a_rejection_json_cannot_say_clearly_is_400_and_the_example_file_stays_readable(station, tmp_path, body,
                                                                                        match):
    server, control, _ = station
    call(server, "POST", "/api/approval", {"required": True})
    call(server, "POST", "/api/run")
    wait_proposal(control, "cover")
    status, r = raw_request(server, post_head(server, "/api/reject", len(body)), body)
    assert status == 400 and match in r["error"], r
    assert not (tmp_path / "examples.jsonl").exists()
    assert control.snapshot(0)["state"] == AWAITING_APPROVAL  # the proposal still waits for its decision
    status, _ = call(server, "POST", "/api/reject", {"reason": "pad on the hinge"})
    assert status == 200
    deadline = time.monotonic() + T  # (the loop writes the example)
    while time.monotonic() < deadline and not (tmp_path / "examples.jsonl").exists():
        time.sleep(0.01)
    ex = load_examples(tmp_path / "examples.jsonl")
    assert [e.source["note"] for e in ex] == ["pad on the hinge"]


def test_a_command_is_answered_even_when_the_state_to_show_with_it_fails(station, monkeypatch):
    """A Stop the cell took got no answer when the state after it could not be made (a dropped connection: the
    page said the cell does not answer, and the operator could not tell whether it stopped)."""
    server, control, cell = station
    call(server, "POST", "/api/approval", {"required": True})
    call(server, "POST", "/api/run")
    wait_proposal(control, "cover")

    def broken():
        raise RuntimeError("camera buffer gone")

    monkeypatch.setattr(cell, "snapshot", broken)
    status, reply = call(server, "POST", "/api/stop")
    assert status == 200 and reply["ok"] is True, reply
    assert "the cell cannot report its state (RuntimeError: camera buffer gone)" in reply["state_error"]
    assert control.snapshot(0)["state"] == "stopped"


def board_contacts_px():
    """Two points on opposite long edges of the demo's board, in px as the page sends them."""
    from cell.station.demo import demo_parts

    o = next(p for p in demo_parts() if p.id == "board").outline_mm
    return mm_to_px((o[0] + o[1]) / 2).tolist(), mm_to_px((o[2] + o[3]) / 2).tolist()


def test_a_teach_on_a_frame_that_is_no_longer_current_is_refused(station, tmp_path):
    """The clicks are points on the picture the operator saw: a teach was applied to whatever frame
    the cell held by then (the part may have moved or gone). The page sends the frame it showed."""
    server, control, cell = station
    p1, p2 = board_contacts_px()
    shown = cell.snapshot()["frame"]["index"]
    cell._render()  # the camera's next frame comes in between the clicks and the request
    status, reply = call(server, "POST", "/api/teach", {"part": "board", "p1_px": p1, "p2_px": p2, "frame": shown})
    assert status == 409 and f"frame taught on ({shown}) is no longer the current one (now {shown + 1})" \
        in reply["error"], reply
    assert not (tmp_path / "examples.jsonl").exists()
    assert not any(e["event"] == "teach" for e in control.snapshot(200)["events"])
    for bad in ("1", True, 1.0, None):
        status, reply = call(server, "POST", "/api/teach", {"part": "board", "p1_px": p1, "p2_px": p2, "frame": bad})
        assert status == 400 and "'frame'" in reply["error"], (bad, reply)
    status, reply = call(server, "POST", "/api/teach", {"part": "board", "p1_px": p1, "p2_px": p2, "frame": shown + 1})
    assert status == 200 and reply["result"]["n_examples"] == 1, reply


def test_a_second_approve_of_the_grasp_already_approved_is_harmless(station):
    """A double tap on Approve: the second request came after the first had decided, and the page
    showed its 409 ('no longer the one waiting') as an error for a tap that did what was meant."""
    server, control, _ = station
    control.set_require_approval(True)
    assert call(server, "POST", "/api/run")[0] == 200
    wait_proposal(control, "cover")
    shown = call(server, "GET", "/api/state")[1]["control"]
    body = {"proposal": shown["proposal"], "proposal_no": shown.get("proposal_no")}
    assert call(server, "POST", "/api/approve", body)[0] == 200
    board = wait_proposal(control, "board")  # the loop took the decision and proposes the next grasp
    status, answer = call(server, "POST", "/api/approve", body)
    assert status == 200 and answer["ok"] is True, answer
    assert control.state == AWAITING_APPROVAL and control.snapshot(0)["proposal"] == board  # undecided
    assert [e["event"] for e in control.snapshot(200)["events"]].count("approve") == 1
    status, answer = call(server, "POST", "/api/reject", body)  # the other decision on it is refused
    assert status == 409 and "already approved" in answer["error"], answer
    assert call(server, "POST", "/api/approve", {"proposal_no": "1"})[0] == 400


def test_each_start_of_the_station_is_a_session_of_its_own(tmp_path):
    """A page left open across a restart could not tell: with a fixed --token its commands went to the
    new session as if it were the old one. The state names the session; a command that names an older
    one is refused (409) and nothing is done, but Stop (a stop is always meant)."""
    control = RunControl()
    cell = DemoCell(control, tmp_path / "examples.jsonl", motion_s=0.0)
    with StationServer(cell, control, port=0, token=TOKEN) as first:
        old = call(first, "GET", "/api/state")[1]["session"]
    with StationServer(cell, control, port=0, token=TOKEN) as second:
        new = call(second, "GET", "/api/state")[1]["session"]
        assert isinstance(old, str) and isinstance(new, str) and old and old != new
        status, reply = call(second, "POST", "/api/run", headers={"X-Cell-Session": old})
        assert status == 409 and "the station was restarted" in reply["error"] and reply["session"] == new, reply
        assert control.state == "idle"
        status, reply = call(second, "POST", "/api/run", headers={"X-Cell-Session": new})
        assert status == 200 and reply["session"] == new and control.state == "running"
        status, reply = call(second, "POST", "/api/stop", headers={"X-Cell-Session": old})
        assert status == 200 and control.state == "stopped"
        assert call(second, "POST", "/api/reset")[0] == 200  # scripts send no session: as before
        status, reply = call(second, "POST", "/api/run", token="the-token-of-yesterday")
        assert status == 403 and reply["session"] == new  # the page can tell the station restarted
