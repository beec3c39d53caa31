"""`cell station --cell F`: the demo cell is that cell (tray, camera frame, jaws, arm, home joints), over real
HTTP on 127.0.0.1; a bad cell file is refused (exit 2, one line) before anything is served or written."""

import json

import cv2
import numpy as np
import pytest
from conftest import run_cli
from test_station_http import TOKEN, call, wait_proposal

from cell.cellconfig import default_cell_path, load_cell
from cell.examples import load_examples
from cell.kinematics import Joints, forward, limit_violations
from cell.runtime.control import PAUSED, RunControl
from cell.station.demo import DemoCell, demo_parts
from cell.station.server import StationServer

TRAY_FILL_GREY, BACKGROUND_GREY = [105, 105, 100], [70, 70, 70]  # (BGR, as the demo draws them)


def custom_cell_dict() -> dict:
    """The default cell with its tray moved 50 mm back and right, a 640 x 480 camera, 42 mm jaws with wider
    pads, other links and another home."""
    d = json.loads(default_cell_path().read_text())
    d["name"] = "test cell B"
    d["tray"] = {"x_mm": [150.0, 450.0], "y_mm": [-300.0, 200.0]}
    d["camera"].update(width_px=640, height_px=480)
    d["gripper"].update(opening_mm=[0.0, 42.0], pad_width_mm=16.0)
    d["scara"].update(l1_mm=300.0, l2_mm=300.0)
    d["motion"]["home_joints"]["j2_deg"] = 60.0
    return d


@pytest.fixture
def cell_file(tmp_path):
    path = tmp_path / "cell_b.json"
    path.write_text(json.dumps(custom_cell_dict()))
    return path


@pytest.fixture
def served(tmp_path, cell_file):
    """The demo cell of cell_b.json behind the station, as `cell station --cell cell_b.json` serves it."""
    control = RunControl()
    cell = DemoCell(control, tmp_path / "examples.jsonl", cell=load_cell(cell_file), motion_s=0.0)
    with StationServer(cell, control, port=0, token=TOKEN) as server:
        cell.start()
        yield server, control, cell
        cell.close()


def across_board(cell: DemoCell) -> tuple[list[float], list[float], np.ndarray]:
    """Two taps (px of `cell`'s frame) on the board's long edges, 45 mm apart, and the contacts (mm)."""
    board = next(p for p in cell._parts if p.id == "board")
    o = board.outline_mm
    c = np.array([(o[0] + o[1]) / 2, (o[2] + o[3]) / 2])
    return cell.view.mm_to_px(c[0]).tolist(), cell.view.mm_to_px(c[1]).tolist(), c


def test_the_state_and_the_frame_are_the_cells(served, cell_file):
    server, _, cell = served
    status, state = call(server, "GET", "/api/state", token=None)
    assert status == 200 and server.base_url.startswith("http://127.0.0.1:")
    snap = state["cell"]
    assert snap["frame"] == {"index": 0, "width_px": 640, "height_px": 480}  # the default's is 1280 x 1024
    assert snap["joints"] == {"j1_deg": 0.0, "j2_deg": 60.0, "j3_mm": 200.0, "j4_deg": 0.0}  # its home
    assert snap["cell_file"] == {"name": "test cell B", "path": str(cell_file), "jaws_mm": [0.0, 42.0],
                                 "tray_mm": {"x_mm": [150.0, 450.0], "y_mm": [-300.0, 200.0]}}
    # the parts lie on this tray (the bracket's corner at y -160 mm is off the default tray's place for it)
    for p in snap["parts"]:
        xy = cell.view.px_to_mm(p["outline_px"])
        assert 150 <= xy[:, 0].min() and xy[:, 0].max() <= 450 and -300 <= xy[:, 1].min() and xy[:, 1].max() <= 200
    default_bracket = next(p for p in demo_parts() if p.id == "bracket").outline_mm
    served_bracket = cell.view.px_to_mm(next(p for p in snap["parts"] if p["id"] == "bracket")["outline_px"])
    assert np.allclose(served_bracket - default_bracket, [-50.0, -50.0], atol=0.1)

    status, png = call(server, "GET", "/api/frame.png", token=None)
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert status == 200 and img.shape == (480, 640, 3)
    u, v = np.round(cell.view.mm_to_px([155.0, -295.0])).astype(int)  # inside this tray's corner
    assert img[v, u].tolist() == TRAY_FILL_GREY
    u, v = np.round(cell.view.mm_to_px([470.0, 0.0])).astype(int)  # on the default tray, off this one
    assert img[v, u].tolist() == BACKGROUND_GREY


def test_proposals_fit_the_cells_jaws_and_arm(served):
    server, control, cell = served
    arm = cell.cell.scara
    call(server, "POST", "/api/approval", {"required": True})
    call(server, "POST", "/api/run")
    prop = wait_proposal(control, "cover")
    assert prop["opening_mm"] <= 42.0
    j = cell.snapshot()["proposal_px"]
    f1 = np.asarray(j["fingers_px"][0])
    assert abs(np.linalg.norm(f1[0] - f1[3]) - 16.0) < 0.2  # this cell's pad width (1 px a mm)
    pose = forward(Joints.from_dict(prop["joints"]), arm)
    assert np.hypot(pose.x_mm - prop["center"][0], pose.y_mm - prop["center"][1]) < 0.1  # its links
    call(server, "POST", "/api/approve")
    # the board is 45 mm across at its narrowest: no proposal for these jaws, the loop waits for a teach
    control.wait_for_state(PAUSED, timeout_s=5.0)
    events = control.snapshot(50)["events"]
    assert any(e["event"] == "teach" and "wider than the jaws' 42 mm" in e["message"] for e in events), events


def test_a_teach_wider_than_the_cells_jaws_is_refused_which_the_default_cell_takes(served, tmp_path):
    server, _, cell = served
    p1, p2, c = across_board(cell)
    assert 44.9 < np.linalg.norm(c[1] - c[0]) < 45.1
    status, reply = call(server, "POST", "/api/teach", {"part": "board", "p1_px": p1, "p2_px": p2})
    assert status == 400 and "45.0 mm apart; the jaws open 0 to 42 mm" in reply["error"], reply
    assert not (tmp_path / "examples.jsonl").exists()

    control = RunControl()
    default = DemoCell(control, tmp_path / "default.jsonl", motion_s=0.0)
    with StationServer(default, control, port=0, token=TOKEN) as server2:
        default.start()
        try:
            p1, p2, _ = across_board(default)
            status, reply = call(server2, "POST", "/api/teach", {"part": "board", "p1_px": p1, "p2_px": p2})
        finally:
            default.close()
    assert status == 200 and reply["result"]["opening_mm"] == pytest.approx(45.0, abs=0.1), reply


def test_a_taught_grasp_carries_the_cells_configuration(served, tmp_path):
    server, _, cell = served
    cap = next(p for p in cell._parts if p.id == "cap")
    o = cap.outline_mm
    c = np.array([(o[0] + o[1]) / 2, (o[2] + o[3]) / 2])  # across its 30 mm
    body = {"part": "cap", "p1_px": cell.view.mm_to_px(c[0]).tolist(), "p2_px": cell.view.mm_to_px(c[1]).tolist()}
    status, reply = call(server, "POST", "/api/teach", body)
    assert status == 200 and reply["result"]["reachable"], reply
    (ex,) = load_examples(tmp_path / "examples.jsonl")
    assert ex.valid and abs(ex.contacts_mm - c).max() < 0.5
    arm, default_arm = cell.cell.scara, load_cell(None).scara
    assert not limit_violations(ex.joints, arm)
    centre = ex.contacts_mm.mean(axis=0)
    pose = forward(ex.joints, arm)
    assert np.hypot(pose.x_mm - centre[0], pose.y_mm - centre[1]) < 0.1 and pose.z_mm == pytest.approx(ex.grasp_z_mm)
    other = forward(ex.joints, default_arm)  # the default arm's links would put the jaws elsewhere
    assert np.hypot(other.x_mm - centre[0], other.y_mm - centre[1]) > 10


def test_cell_station_serves_the_cell_file_given(tmp_path, cell_file, capsys):
    code, out, err = run_cli("station", "--cell", cell_file, "--port", "0", "--for-s", "0.2",
                             "--examples", tmp_path / "e.jsonl", capsys=capsys)
    assert code == 0 and f"cell: test cell B ({cell_file})" in out, err


@pytest.mark.parametrize("make, message", [
    (lambda p: None, "cell file {p} does not exist"),
    (lambda p: p.write_text('{"format":'), "cell file {p} is not valid JSON"),
    (lambda p: p.write_text(json.dumps({**custom_cell_dict(), "trya": {}})), "unknown key trya"),
    (lambda p: p.mkdir(), "cell file {p} is a directory, not a file"),
    # a tray too small for the demo's four parts: said, not served with parts off the tray
    (lambda p: p.write_text(json.dumps({**custom_cell_dict(), "tray": {"x_mm": [300, 400], "y_mm": [-50, 50]}})),
     "does not fit on the tray of cell {p} (x 300..400, y -50..50 mm): give a larger tray"),
])
def test_a_bad_cell_file_exits_2_before_serving_or_writing(tmp_path, monkeypatch, capsys, make, message):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "cell.json"
    make(path)
    code, out, err = run_cli("station", "--cell", path, "--port", "0", "--for-s", "0", capsys=capsys)
    assert code == 2 and out == "" and message.format(p=path) in err and "Traceback" not in err, err
    assert err.count("\n") == 1
    assert not (tmp_path / "station_examples.jsonl").exists()


def test_the_examples_may_not_go_into_the_cell_file(tmp_path, cell_file, capsys):
    before = cell_file.read_text()
    code, out, err = run_cli("station", "--cell", cell_file, "--examples", cell_file, "--port", "0", "--for-s", "0",
                             capsys=capsys)
    assert code == 2 and "is the cell file: taught grasps would be appended to it" in err, err
    assert cell_file.read_text() == before


def test_the_default_cells_demo_is_the_demo_it_was(tmp_path):
    """On the default tray the parts lie where they always did; only the frame is now the camera's size."""
    cell = DemoCell(RunControl(), tmp_path / "e.jsonl")
    assert all(np.array_equal(a.outline_mm, b.outline_mm) for a, b in zip(cell._parts, demo_parts(), strict=True))
    assert (cell.view.width_px, cell.view.height_px, cell.view.px_per_mm) == (1280, 1024, 2.0)
