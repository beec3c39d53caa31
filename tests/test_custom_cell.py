"""A cell file other than the default is honoured, and a bad one is refused (exit 2, the key named)."""

import json
import re

import pytest
from conftest import run_cli

from cell.cellconfig import default_cell_path


def cell_dict() -> dict:
    return json.loads(default_cell_path().read_text())


def write_cell(path, mutate):
    d = cell_dict()
    mutate(d)
    path.write_text(json.dumps(d))
    return path


SCENE = {"units": "mm", "target": "bar",
         "parts": [{"id": "bar", "outline": [[290, -30], [310, -30], [310, 30], [290, 30]], "z_top": 12}]}


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "bar.json"
    path.write_text(json.dumps(SCENE))
    return path


@pytest.mark.parametrize("mutate,key", [
    (lambda d: d.__setitem__("configuraton", {"joint_weights": {"j1": 1, "j2": 0, "j3": 0, "j4": 0}}),
     "configuraton"),
    (lambda d: d["gripper"].__setitem__("pad_widht_mm", 20), "gripper.pad_widht_mm"),
    (lambda d: d["scara"]["max_velocity"].__setitem__("j5", 10), "scara.max_velocity.j5"),
    (lambda d: d["can"]["nodes"]["j1"].__setitem__("nodeid", 7), "can.nodes.j1.nodeid"),
])
def test_an_unknown_key_is_bad_input_not_ignored(tmp_path, scene, capsys, mutate, key):
    cell = write_cell(tmp_path / "cell.json", mutate)
    code, out, err = run_cli("grasp", scene, "--json", "--cell", cell, capsys=capsys)
    assert code == 2 and out == ""
    assert f"unknown key {key}" in err and "Traceback" not in err


def test_notes_for_people_are_allowed_in_a_cell_file(tmp_path, scene, capsys):
    def annotate(d):
        d["description"] = "cell 2, line B"
        d["scara"]["_comment"] = "links measured 2026-11-30"
        d["gripper"]["notes"] = "soft pads"

    code, out, err = run_cli("grasp", scene, "--json", "--cell", write_cell(tmp_path / "cell.json", annotate),
                             capsys=capsys)
    assert code == 0, err


@pytest.mark.parametrize("mutate,match", [
    (lambda d: d["scara"].__setitem__("j2_deg", [-60, 60]), r"motion.home_joints.j2_deg = 90 is outside scara.j2_deg"),
    (lambda d: d["motion"].__setitem__("safe_z_mm", 250), r"motion.safe_z_mm = 250 is outside scara.j3_mm"),
    (lambda d: d["motion"]["dropoff_mm"].__setitem__(2, -5), r"motion.dropoff_mm z = -5 is outside scara.j3_mm"),
])
def test_home_and_travel_heights_outside_the_joint_limits_are_bad_input(tmp_path, capsys, mutate, match):
    # the simulated drives started at home 90 deg outside their own limits [-60, 60] and said so nowhere
    cell = write_cell(tmp_path / "cell.json", mutate)
    code, out, err = run_cli("hw", "status", "--json", "--cell", cell, capsys=capsys)
    assert code == 2 and out == ""
    assert re.search(match, err), err


def test_run_of_a_cell_with_another_camera_sees_frames_of_its_size(tmp_path, capsys):
    # the shipped calibration is the default camera's: the run was refused (1280 x 1024 against
    # 640 x 480) unless the caller also made a calibration for the cell's camera
    import cv2

    from cell.runtime.session import default_assembly_path

    cell = write_cell(tmp_path / "cell.json", lambda d: d.__setitem__(
        "camera", {"width_px": 640, "height_px": 480, "height_mm": 700.0}))
    d = json.loads(default_assembly_path().read_text())
    d["parts"], d["sequence"] = [p for p in d["parts"] if p["id"] == "nut"], ["nut"]
    (tmp_path / "nut.json").write_text(json.dumps(d))
    rec = tmp_path / "rec"
    code, out, err = run_cli("run", tmp_path / "nut.json", "--cell", cell, "--record", rec, "--json", capsys=capsys)
    assert code == 0, err
    summary = json.loads(out.splitlines()[-1])
    assert (summary["parts_total"], summary["parts_removed"]) == (1, 1)
    frames = sorted((rec / "frames").glob("*.png"))
    assert frames and cv2.imread(str(frames[0])).shape[:2] == (480, 640)


def test_a_nan_inside_a_range_names_its_place(tmp_path, scene, capsys):
    # the message said "gripper.opening_mm._ must be a finite number"
    cell = tmp_path / "cell.json"
    cell.write_text(default_cell_path().read_text().replace('"opening_mm": [0.0, 80.0]', '"opening_mm": [0.0, NaN]'))
    code, out, err = run_cli("grasp", scene, "--json", "--cell", cell, capsys=capsys)
    assert code == 2 and "gripper.opening_mm[1] must be a finite number, got NaN" in err


@pytest.mark.parametrize("l1_l2,dropoff,says", [
    ((250, 200), None, "outside the arm's reach"),  # the default drop-off, shorter links
    ((325, 275), [650.0, 0.0, 100.0], "outside the arm's reach"),
    # within reach but past the workspace box (y max 450): every carry would have been refused with
    # the part in the jaws; on the box's edge every configuration lands past it, by float noise or once
    # its joints are rounded to whole drive counts
    ((325, 275), [300.0, 460.0, 120.0], "cannot be sent to the arm: tool at x = 300.0, y = 460.0 mm outside"),
    ((325, 275), [330.0, 450.0, 120.0], "cannot be sent to the arm: tool at x = 330.0, y = 450.00000000000006 mm"),
])
def test_a_dropoff_out_of_reach_is_bad_input_before_anything_moves(tmp_path, capsys, l1_l2, dropoff, says):
    def mutate(d):
        d["scara"]["l1_mm"], d["scara"]["l2_mm"] = l1_l2
        if sum(l1_l2) < 600:  # a tray the shorter arm reaches whole (the default's corners lie 559 mm out)
            d["tray"] = {"x_mm": [200.0, 380.0], "y_mm": [-200.0, 200.0]}
        if dropoff is not None:
            d["motion"]["dropoff_mm"] = dropoff

    cell = write_cell(tmp_path / "cell.json", mutate)
    code, out, err = run_cli("run", "--json", "--cell", cell, capsys=capsys)
    assert code == 2 and "motion.dropoff_mm" in err and says in err and "Traceback" not in err, err


def test_an_assembly_out_of_the_cameras_view_is_bad_input_before_anything_moves(tmp_path, capsys):
    # the default camera sees x from about 94 to 606 mm on the table: a pulley at x 620-660 is out
    # of its view (the run used to stop at it with "pulley is not found", exit 1)
    from importlib import resources

    d = json.loads((resources.files("cell") / "data" / "assemblies" / "default.json").read_text())
    d.pop("cell", None)
    pulley = next(p for p in d["parts"] if p["id"] == "pulley")
    pulley["outline"] = [[x + 219.0, y] for x, y in pulley["outline"]]
    pulley["holes"] = [[[x + 219.0, y] for x, y in h] for h in pulley.get("holes", [])]
    path = tmp_path / "far.json"
    path.write_text(json.dumps(d))
    code, out, err = run_cli("run", path, "--json", capsys=capsys)
    assert code == 2 and "'pulley'" in err and "not all in the camera's view" in err and "Traceback" not in err, err


def test_render_follows_the_cells_camera(tmp_path, scene, capsys):
    # a cell with a 640 x 480 camera: the frame has its size (it was always the default 1280 x 1024)
    cell = write_cell(tmp_path / "cell.json", lambda d: d["camera"].update(width_px=640, height_px=480))
    out = tmp_path / "frame.png"
    code, text, err = run_cli("render", scene, "--out", out, "--cell", cell, "--no-noise", capsys=capsys)
    assert code == 0, err
    assert (json.loads(text)["width_px"], json.loads(text)["height_px"]) == (640, 480)
    # and the scene's own cell file, relative to the scene
    d = json.loads(scene.read_text())
    d["cell"] = "cell.json"
    own = tmp_path / "own.json"
    own.write_text(json.dumps(d))
    code, text, err = run_cli("render", own, "--out", out, capsys=capsys)
    assert code == 0 and json.loads(text)["width_px"] == 640, err
    code, text, err = run_cli("render", scene, "--out", out, capsys=capsys)
    assert code == 0 and json.loads(text)["width_px"] == 1280
