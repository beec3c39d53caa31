"""A cell file whose parts do not fit together as one machine is refused (exit 2, the key named): when it is read,
jaws with no approach clearance or no room for a grasp, a pad taller than its finger, a camera under the arm, a name
that is not text; where the arm moves (`cell run`, `cell hw`), a home outside the workspace and a tray partly beyond
the arm's reach (planning with such a cell still works: a target out of reach has no grasp). Each of these used to
load and fail later (every grasp missed, `cell hw corner` found no way home, the run stopped part-way)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from cell_files import edited_cell
from conftest import ROOT, run_cli

from cell.cellconfig import default_cell, default_cell_path, load_cell, parse_cell
from cell.cellgeometry import require_cell_can_move
from cell.errors import BadInput

_raw = edited_cell  # the default cell file's JSON with each edit set: `gripper__opening_mm=[0, 8]`


def _cell(**edits):
    return parse_cell(_raw(**edits), "cell.json")


def _refused(message: str, **edits) -> str:
    with pytest.raises(BadInput) as e:
        _cell(**edits)
    assert str(e.value).startswith("cell file cell.json: ") and message in str(e.value), str(e.value)
    return str(e.value)


def _refused_to_move(message: str, **edits) -> str:
    """Read (planning takes it), refused before the arm moves."""
    cell = _cell(**edits)
    with pytest.raises(BadInput) as e:
        require_cell_can_move(cell)
    assert str(e.value).startswith("cell file cell.json: ") and message in str(e.value), str(e.value)
    return str(e.value)


def test_the_default_cell_and_every_cell_file_in_the_repo_load():
    files = sorted((ROOT / "recordings").rglob("cell.json")) + [default_cell_path()]
    assert len(files) >= 2
    for path in files:
        load_cell(path)


# --- the jaws ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("clearance", [0, -1.0])
def test_no_approach_clearance_is_refused(clearance):
    _refused(f"gripper.approach_clearance_mm = {clearance:g}: the jaws must open wider than the part",
             gripper__approach_clearance_mm=clearance)


def test_half_a_millimetre_of_clearance_is_taken_and_the_jaws_then_close_on_the_part():
    """The jaws open to the planned width + 2 x clearance. At 0 a part 0.2 mm wider than seen (the camera's outline
    is never exact) has both fingers come down on its edges, and the jaws close on nothing (every grasp of the
    hunter's run missed); 0.5 mm grips it."""
    from cell.grasp import shapes
    from cell.physics import close_jaws

    cell = _cell(gripper__approach_clearance_mm=0.5)
    assert cell.gripper.approach_clearance_mm == 0.5
    no_clearance = dataclasses.replace(cell, gripper=dataclasses.replace(cell.gripper, approach_clearance_mm=0.0))
    real = shapes.rectangle("bar", 60, 24.2, (350, 0), 0)  # seen 24 mm wide, planned at 24 mm
    assert close_jaws(real, (350, 0), 90.0, 24.0 + 2 * 0.5, cell=cell) == pytest.approx(24.2, abs=0.1)
    assert close_jaws(real, (350, 0), 90.0, 24.0, cell=no_clearance) is None


@pytest.mark.parametrize("opening, clearance, says", [
    ([0, 8], 5, "gripper.opening_mm 8 mm minus 2 x gripper.approach_clearance_mm 5 mm leaves contacts at most -2 mm"),
    ([0, 80], 45, "gripper.opening_mm 80 mm minus 2 x gripper.approach_clearance_mm 45 mm leaves contacts at most -10"),
    ([0, 80], 40, "leaves contacts at most 0 mm apart, not more than the smallest opening 0 mm: no grasp fits"),
    ([30, 80], 25, "leaves contacts at most 30 mm apart, not more than the smallest opening 30 mm"),
])
def test_jaws_no_grasp_fits_are_refused(opening, clearance, says):
    _refused(says, gripper__opening_mm=opening, gripper__approach_clearance_mm=clearance)


def test_jaws_with_a_little_room_are_taken():
    assert _cell(gripper__opening_mm=[0, 8], gripper__approach_clearance_mm=0.5).gripper.opening_mm == (0, 8)
    assert _cell(gripper__opening_mm=[30, 80], gripper__approach_clearance_mm=24.9).gripper.opening_mm == (30, 80)


def test_a_pad_taller_than_its_finger_is_refused():
    _refused("gripper.pad_height_mm = 60 is more than the finger it is on (gripper.finger_length_mm 40",
             gripper__pad_height_mm=60)
    assert _cell(gripper__pad_height_mm=40).gripper.pad_height_mm == 40


# --- heights ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("height", [50, 290, 0.001])
def test_a_camera_not_above_the_arm_is_refused(height):
    _refused(f"camera.height_mm = {height:g} is not above the arm (the links' undersides at 290 and 240 mm)",
             camera__height_mm=height)


def test_a_link_in_the_table_or_over_the_palm_is_refused():
    _refused("scara.link1_bottom_z_mm = 0: link 1 would sweep through the table", scara__link1_bottom_z_mm=0)
    _refused("scara.link2_bottom_z_mm = 30 is below the palm at the bottom of J3's travel (scara.j3_mm 0 + "
             "gripper.palm_offset_mm 40 = 40 mm)", scara__link2_bottom_z_mm=30)
    # the repo's link-collision tests' arm (links at 150 and 120 mm under a 200 mm J3) is taken
    assert _cell(scara__link1_bottom_z_mm=150.0, scara__link2_bottom_z_mm=120.0).scara.link2_bottom_z_mm == 120


# --- home and tray against the arm ------------------------------------------------------------------------------
def test_a_home_outside_the_workspace_is_refused_before_the_arm_moves():
    _refused_to_move("motion.home_joints (j1_deg 0, j2_deg 0) put the tool at (600.0, 0.0) mm, outside the workspace "
             "(x -50 to 560", motion__home_joints={"j1_deg": 0, "j2_deg": 0, "j3_mm": 200, "j4_deg": 0})
    # on the workspace's edge: taken
    cell = _cell(workspace={"x_mm": [-50, 560], "y_mm": [-450, 275]})
    require_cell_can_move(cell)
    assert cell.workspace.y_mm == (-450, 275)


@pytest.mark.parametrize("edits, says", [
    # a tray to x 700 (the workspace widened with it): its far side beyond the 600 mm reach
    ({"tray__x_mm": [200, 700], "workspace__x_mm": [-50, 800]},
     "the arm cannot reach 23.8 % of the tray within scara.j1_deg and scara.j2_deg (unreachable: x 547.5 to 700.0, "
     "y -250.0 to 250.0 mm; e.g. (700.0, -250.0) mm, 743.3 mm from J1's axis, the arm reaching 50 to 600 mm)"),
    # J1 from 60 deg: the whole tray past its limit (home moved where J1 reaches, inside the workspace)
    ({"scara__j1_deg": [60, 132], "motion__home_joints": {"j1_deg": 60, "j2_deg": -60, "j3_mm": 200, "j4_deg": 0}},
     "the arm cannot reach 72.2 % of the tray"),
    # a 400 / 250 arm: the tray's corner near the base needs J2 past 150 deg
    ({"scara__l1_mm": 400, "scara__l2_mm": 250},
     "(unreachable: x 200.0 to 220.0, y -95.0 to 95.0 mm; e.g. (200.0, -95.0) mm, within the arm's 150 to 650 mm "
     "but past J1 or J2's limits)"),
    # a 200 / 200 arm under the default tray (the hunter's run removed 1 of 6 parts)
    ({"scara__l1_mm": 200, "scara__l2_mm": 200, "motion__dropoff_mm": [100, 300, 120]},
     "the arm cannot reach 42.8 % of the tray"),
])
def test_a_tray_partly_beyond_the_arms_reach_is_refused_before_the_arm_moves(edits, says):
    msg = _refused_to_move(says, **edits)
    assert msg.endswith("a part put there could never be picked; make tray.x_mm and tray.y_mm the area the arm "
                        "reaches")


def test_a_tray_the_arm_reaches_whole_is_taken_and_its_corners_are_reached():
    from cell.kinematics import inverse

    cell = _cell(scara__l1_mm=400, scara__l2_mm=250, tray__x_mm=[225, 500])
    require_cell_can_move(cell)
    for x in cell.tray.x_mm:
        for y in cell.tray.y_mm:
            assert inverse(x, y, 5.0, 0.0, cell.scara)
    with pytest.raises(BadInput):  # 5 mm closer to the base: refused
        require_cell_can_move(_cell(scara__l1_mm=400, scara__l2_mm=250, tray__x_mm=[215, 500]))


# --- name -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", [5, None, "", ["a"]])
def test_a_name_that_is_not_text_is_refused(name):
    _refused("'name' must be a non-empty text", name=name)


def test_a_missing_name_is_the_files_name():
    raw = _raw()
    del raw["name"]
    assert parse_cell(raw, "/x/my_cell.json").name == "my_cell"


# --- the command line -------------------------------------------------------------------------------------------
def test_the_cli_refuses_such_a_cell_file_with_one_line_and_exit_2(tmp_path, capsys):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"units": "mm", "target": "bar", "parts": [
        {"id": "bar", "outline": [[290, -30], [310, -30], [310, 30], [290, 30]], "z_top": 12}]}))
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(_raw(gripper__approach_clearance_mm=0)))
    code, out, err = run_cli("grasp", scene, "--json", "--cell", path, capsys=capsys)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith(f"cell: error: cell file {path}: gripper.approach_clearance_mm = 0"), err


def test_a_cell_whose_tray_the_arm_cannot_reach_whole_plans_but_does_not_run(tmp_path, capsys):
    """A 400 / 250 arm under the default tray (its corners near the base need J2 past 150 deg): `cell grasp` plans
    a part it reaches (exit 0) and says why one it does not has no grasp (exit 3); `cell run` and `cell hw home`
    refuse the cell before anything moves (exit 2, one line)."""
    path = tmp_path / "long_arm.json"
    path.write_text(json.dumps(_raw(scara__l1_mm=400, scara__l2_mm=250)))
    scenes = {}
    for name, x in (("reached", 400), ("near_base", 205)):
        scenes[name] = tmp_path / f"{name}.json"
        scenes[name].write_text(json.dumps({"units": "mm", "target": "bar", "parts": [
            {"id": "bar", "outline": [[x - 10, -20], [x + 10, -20], [x + 10, 20], [x - 10, 20]], "z_top": 12}]}))
    code, out, err = run_cli("grasp", scenes["reached"], "--json", "--cell", path, capsys=capsys)
    assert code == 0 and json.loads(out)["target"] == "bar", err
    code, out, err = run_cli("grasp", scenes["near_base"], "--json", "--cell", path, capsys=capsys)
    assert code == 3 and json.loads(out)["error"] == "no_feasible_grasp", out
    for argv in (("run", "--cell", path), ("hw", "home", "--cell", path, "--yes")):
        code, out, err = run_cli(*argv, capsys=capsys)
        assert code == 2 and err.count("\n") == 1, (argv, err)
        assert "the arm cannot reach" in err and "make tray.x_mm and tray.y_mm the area the arm reaches" in err, err


def test_bench_grasp_plans_with_the_given_cell(tmp_path, capsys):
    """`cell bench grasp --cell F`: the ring (60 mm across) is planned with the default jaws, not with 40 mm ones."""
    path = tmp_path / "stroke40.json"
    path.write_text(json.dumps(_raw(gripper__opening_mm=[0, 40])))
    rows = {}
    for cell in (None, path):
        code, out, err = run_cli("bench", "grasp", "--repeat", "1", "--json", "--scenes", "ring-with-hole",
                                 *(["--cell", cell] if cell else []), capsys=capsys)
        assert code == 0, err
        rows[cell] = [json.loads(x) for x in out.splitlines()]
    assert rows[None][-1]["cell"] == str(default_cell_path()) and rows[None][0]["error"] is None
    assert rows[path][-1]["cell"] == str(path) and rows[path][-1]["planned"] == 0
    assert "opening 40 mm minus 2 x 5 mm approach clearance" in rows[path][0]["error"]
    code, out, err = run_cli("bench", "grasp", "--cell", tmp_path / "none.json", capsys=capsys)
    assert code == 2 and "none.json" in err and "Traceback" not in err


def test_the_default_cell_is_unchanged():
    assert default_cell().gripper.approach_clearance_mm == 5.0 and np.isclose(default_cell().camera.height_mm, 800)
