"""The run-time safety checks at their boundaries (cell/runtime/loop.py, cell/runtime/motion.py and
the link check they call): the travel height, the links along the drives' path, the drop-off
options, the pick's commands, the grip tolerance (the gripper driver's check the run acts on), the
frame checks, a part that did not leave the tray, and the carry-off after a cut-short pick and how
wide the jaws open at the grasp depth after a missed grip.

Each test pins one side of a comparison (or one term, or one guard) that decides whether the arm
may move; they were written in a mutation pass over those checks, for the mutants the other
tests let through. Real cells (the default cell file, and the same cell with its links lowered to
150 / 120 mm so that parts can reach under them), real kinematics and the simulated drives; the
parts are hand-built boxes where a boundary is pinned.
"""

import dataclasses
import json
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from cell.cellconfig import default_cell, default_cell_path, load_cell
from cell.errors import CellError
from cell.grasp.synthesis import Grasp
from cell.kinematics import Joints, elbow_points, forward, inverse
from cell.runtime.loop import LinksWouldHit, PartReport, StopRun
from cell.runtime.motion import (
    Command,
    above,
    carry_off_commands,
    dropoff_options,
    pick_commands,
)
from cell.scene import parse_part

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))
NUT_XY_MM = (395.89, -18.62)  # the default assembly's nut (13 mm tall)
HOME = Joints(0.0, 90.0, 200.0, 0.0)  # the default cell's home, where the simulated arm starts
NUT_GRASP = Joints(-46.12, 97.77, 8.0, -51.65)  # the default cell's tips at the nut, 8 mm up, right elbow


def box(pid: str, cx_mm: float, cy_mm: float, z_top_mm: float, half_mm: float = 10.0, z_bottom_mm: float = 0.0):
    return parse_part({"id": pid, "z_bottom": z_bottom_mm, "z_top": z_top_mm, "outline": [
        [cx_mm - half_mm, cy_mm - half_mm], [cx_mm + half_mm, cy_mm - half_mm],
        [cx_mm + half_mm, cy_mm + half_mm], [cx_mm - half_mm, cy_mm + half_mm]]})


def grasp_of(part, cell, grasp_z_mm: float, opening_mm: float = 20.0, joints: Joints | None = None) -> Grasp:
    """A grasp across `part`'s centre along x, at the first joint solution reaching it (right elbow)."""
    c = np.asarray(part.polygon.centroid.coords[0])
    options = inverse(c[0], c[1], grasp_z_mm, 0.0, cell.scara)
    contacts = np.array([c - (opening_mm / 2, 0.0), c + (opening_mm / 2, 0.0)])
    return Grasp(part.id, contacts, np.array([[-1.0, 0.0], [1.0, 0.0]]), c, 0.0, opening_mm, grasp_z_mm,
                 options, joints or options[0])


def make_loop(cell, arm, assembly=None, camera=None, interactive: bool = False):
    """The cell loop on `arm` (the default assembly unless told; no camera unless told)."""
    from calibration import load_calibration
    from cell.examples import default_examples_path
    from cell.runtime.control import RunControl
    from cell.runtime.loop import CellLoop, LoopOptions
    from cell.scene import parse_assembly

    assembly = assembly or parse_assembly(json.loads(DEFAULT.read_text()))
    return CellLoop(cell=cell, calibration=load_calibration(), assembly=assembly, camera=camera, arm=arm,
                    control=RunControl(), examples_path=default_examples_path(),
                    options=LoopOptions(interactive=interactive))


def on_tray(loop, *parts, unexplained=()):
    """The loop believes exactly `parts` (and the material no part explains) lie on the tray."""
    loop.poses = {p.id: p for p in parts}
    loop.unexplained = list(unexplained)
    return loop


def arm_at(loop, joints: Joints):
    """Move the simulated arm there (the link check starts its first path where the arm is), by the way the
    drivers take: up, across, down."""
    from cell.runtime.ways import go_to

    go_to(loop.arm, joints)
    assert np.allclose(loop.arm.joints().as_array(), joints.as_array(), atol=1e-3)  # to whole counts


def cell_file(folder: Path, name: str, section: str, **values) -> Path:
    """The default cell file with `values` set in its `section`, written to `folder`."""
    raw = json.loads(default_cell_path().read_text())
    raw[section].update(values)
    path = folder / f"{name}.json"
    path.write_text(json.dumps(raw))
    return path


def low_arm_cell_file(folder: Path) -> Path:
    """The default cell file with its links' undersides at 150 mm (upper arm) and 120 mm (forearm)."""
    return cell_file(folder, "low_arm", "scara", link1_bottom_z_mm=150.0, link2_bottom_z_mm=120.0)


def forearm_mid(cell, j: Joints) -> np.ndarray:
    _, elbow, wrist = elbow_points(j, cell.scara)
    return (elbow + wrist) / 2


def upper_arm_mid(cell, j: Joints) -> np.ndarray:
    base, elbow, _ = elbow_points(j, cell.scara)
    return (base + elbow) / 2


@pytest.fixture(scope="module")
def cell():
    return default_cell()


@pytest.fixture(scope="module")
def low_cell(tmp_path_factory):
    return load_cell(low_arm_cell_file(tmp_path_factory.mktemp("cell")))


@pytest.fixture(scope="module")
def loop(cell):
    from drivers import simulated_cell

    with simulated_cell(cell) as (arm, _):
        yield make_loop(cell, arm)


@pytest.fixture(scope="module")
def low_loop(low_cell):
    from drivers import simulated_cell

    with simulated_cell(low_cell) as (arm, _):
        yield make_loop(low_cell, arm)


# ---------------------------------------------------------------- travel height (_safe_z_mm)
# Default cell: safe height 150 mm, J3 up to 200 mm, TRAVEL_MARGIN_MM 20. The open jaws pass 20 mm
# over every part (the target's own top too); the held part, hanging from the tips (grasp z) down
# to its bottom, passes 20 mm over every other part.
@pytest.mark.parametrize("target_z_bottom_mm,target_z_top_mm,grasp_z_mm,others_z_top_mm,unexplained_z_top_mm,safe_mm", [
    pytest.param(0.0, 13.0, 8.0, [40.0], [], 150.0, id="low_parts_cell_safe_height"),
    pytest.param(0.0, 160.0, 140.0, [10.0], [], 180.0, id="empty_jaws_over_the_target_top"),
    pytest.param(0.0, 13.0, 8.0, [140.0], [], 168.0, id="held_part_8mm_below_tips_over_the_tallest_other"),
    # on a plate: it hangs from the tips at 18 mm down to its bottom at 10 mm, not to the table
    pytest.param(10.0, 25.0, 18.0, [140.0], [], 168.0, id="part_on_a_plate_hangs_to_its_own_bottom"),
    pytest.param(0.0, 13.0, 8.0, [], [140.0], 168.0, id="unexplained_material_like_a_part"),
    pytest.param(0.0, 160.0, 150.0, [], [], 180.0, id="held_part_not_its_own_obstacle"),
])
def test_travel_height_terms(loop, target_z_bottom_mm, target_z_top_mm, grasp_z_mm, others_z_top_mm,
                             unexplained_z_top_mm, safe_mm):
    target = box("target", 400, 0, target_z_top_mm, z_bottom_mm=target_z_bottom_mm)
    others = [box(f"other{i}", 300, -100 + 40 * i, z) for i, z in enumerate(others_z_top_mm)]
    stray = [box(f"stray{i}", 250, 100 + 40 * i, z) for i, z in enumerate(unexplained_z_top_mm)]
    on_tray(loop, target, *others, unexplained=stray)
    assert loop._safe_z_mm("target", grasp_z_mm) == safe_mm


@pytest.mark.parametrize("target_z_top_mm,grasp_z_mm,other_z_top_mm,safe_mm", [
    (13.0, 8.0, 172.0, 200.0),  # loaded term exactly at J3's top: allowed
    (13.0, 8.0, 172.5, None),  # 0.5 mm past it: refused
    (180.0, 170.0, None, 200.0),  # empty term exactly at J3's top: allowed
    (180.5, 170.0, None, None),  # 0.5 mm past it: refused
], ids=["loaded_at_j3_max", "loaded_past_j3_max", "empty_at_j3_max", "empty_past_j3_max"])
def test_travel_height_refused_just_past_j3_max(loop, target_z_top_mm, grasp_z_mm, other_z_top_mm, safe_mm):
    others = [] if other_z_top_mm is None else [box("post", 300, -60, other_z_top_mm)]
    on_tray(loop, box("target", 400, 0, target_z_top_mm), *others)
    if safe_mm is not None:
        assert loop._safe_z_mm("target", grasp_z_mm) == safe_mm
    else:
        with pytest.raises(CellError, match="target cannot be carried over the parts on the tray.*J3 reaches 200 mm"):
            loop._safe_z_mm("target", grasp_z_mm)


def test_the_pick_and_the_carry_off_travel_at_the_raised_height_from_where_the_arm_is(loop, cell):
    nut, post = box("nut", *NUT_XY_MM, 13.0), box("post", 300, -60, 140.0)
    on_tray(loop, nut, post)
    grasp = grasp_of(nut, cell, 8.0)
    arm_at(loop, HOME)
    assert loop._safe_z_mm("nut", 8.0) == 168.0
    pick = loop._clear_pick("nut", grasp)
    assert {c.label: c.joints.j3_mm for c in pick if c.label in ("approach", "lift", "carry", "retreat")} == {
        "approach": 168.0, "lift": 168.0, "carry": 168.0, "retreat": 168.0}
    off = loop._clear_carry_off("nut", grasp)  # from where the arm is (home here), not from the grasp
    assert off[0].label == "lift" and off[0].joints == above(HOME, 168.0)
    assert [c.joints.j3_mm for c in off if c.label in ("carry", "retreat")] == [168.0, 168.0]


# ---------------------------------------------------------------- links along the path (_check_links)
# The low cell: upper arm's underside 150 mm, forearm's 120 mm. The arm stands still at REACH; a box
# under one link's middle. A 160 mm post out of the arm's way makes both links' footprints be built,
# so that the comparison with each link's own underside is what decides.
REACH = Joints(-30.0, 60.0, 100.0, 0.0)  # forearm over the tray (x 281-519 mm), upper arm beside it


@pytest.mark.parametrize("under,z_top_mm,hit", [
    ("forearm", 120.0, False),  # exactly at the forearm's underside: passes under it
    ("forearm", 120.01, True),
    ("forearm", 130.0, True),  # above the forearm, below the upper arm
    ("upper_arm", 140.0, False),  # above the forearm's underside but under the upper arm, whose is 150
    ("upper_arm", 150.0, False),  # exactly at the upper arm's underside
    ("upper_arm", 150.01, True),
    ("elbow", 150.01, True),  # under both links: named once
])
def test_a_part_is_an_obstacle_only_above_the_underside_of_the_link_over_it(low_loop, low_cell, under, z_top_mm, hit):
    at = {"forearm": forearm_mid, "upper_arm": upper_arm_mid,
          "elbow": lambda cell, j: elbow_points(j, cell.scara)[1]}[under](low_cell, REACH)
    arm_at(low_loop, REACH)
    on_tray(low_loop, box("block", *at, z_top_mm), box("post", 0, 450, 160.0))
    commands = [Command("move", "stay", REACH)]
    if hit:
        with pytest.raises(LinksWouldHit) as e:
            low_loop._check_links("held", commands, "")
        assert str(e.value) == "on the way to 'stay' the arm's links would hit block"
    else:
        low_loop._check_links("held", commands, "")


def test_the_part_in_the_jaws_is_no_obstacle_to_the_links_but_unexplained_material_is(low_loop, low_cell):
    wrist = elbow_points(REACH, low_cell.scara)[2]
    arm_at(low_loop, REACH)
    commands = [Command("move", "stay", REACH)]
    on_tray(low_loop, box("held", *wrist, 130.0))  # under the forearm's end: the part being picked
    low_loop._check_links("held", commands, "")
    with pytest.raises(LinksWouldHit, match="would hit held"):
        low_loop._check_links("another", commands, "")
    on_tray(low_loop, unexplained=[box("stray", *forearm_mid(low_cell, REACH), 130.0)])
    with pytest.raises(LinksWouldHit, match="would hit stray"):
        low_loop._check_links("held", commands, "")


# Three configurations and a 130 mm column such that only the sweep between the two stretched ones
# passes over the column: not the arm's start (folded), nor either stretched configuration, nor the
# sweeps from the start to either (found by search).
FOLDED = Joints(60.0, -140.0, 100.0, 0.0)  # the arm's start: folded over the tray's edge
STRETCHED_CW = Joints(-40.0, 0.0, 100.0, 0.0)  # stretched, J1 40 degrees clockwise
STRETCHED_CCW = Joints(40.0, 0.0, 100.0, 0.0)  # stretched, J1 40 degrees counter-clockwise
COLUMN_XY_MM = (462.5, 0.0)  # under the stretched forearm at J1 = 0


def test_the_links_are_checked_along_each_move_from_where_the_last_one_ended(low_loop):
    """Every sample of every move counts (not only where moves end), each move from where the one
    before ended (not from where the arm is), and the moves after a gripper command too."""
    arm_at(low_loop, FOLDED)
    commands = [Command("move", "first", STRETCHED_CW), Command("open", "open", width_mm=80.0),
                Command("move", "second", STRETCHED_CCW)]
    on_tray(low_loop, box("column", *COLUMN_XY_MM, 120.0))  # at the forearm's underside: nothing in the way
    low_loop._check_links("held", commands, "")
    on_tray(low_loop, box("column", *COLUMN_XY_MM, 130.0))
    with pytest.raises(LinksWouldHit, match="on the way to 'second' the arm's links would hit column"):
        low_loop._check_links("held", commands, "")
    for where in (FOLDED, STRETCHED_CW, STRETCHED_CCW):  # under none of the moves' ends
        arm_at(low_loop, where)
        low_loop._check_links("held", [Command("move", "stay", where)], "")


def test_the_first_move_is_checked_from_where_the_arm_is(low_loop, low_cell):
    """From home (elbow bent up) to the stretched arm the forearm sweeps over a column that neither
    configuration is over."""
    column = box("column", *forearm_mid(low_cell, Joints(10.0, 0.0, 100.0, 0.0)), 130.0)
    on_tray(low_loop, column)
    commands = [Command("move", "stretch", STRETCHED_CW)]
    arm_at(low_loop, STRETCHED_CW)
    low_loop._check_links("held", commands, "")
    arm_at(low_loop, HOME)
    with pytest.raises(LinksWouldHit, match="on the way to 'stretch' the arm's links would hit column"):
        low_loop._check_links("held", commands, "")


# ---------------------------------------------------------------- drop-off options (_clear_way)
def nut_held_with_the_left_elbow(loop, cell, *columns):
    """The nut (and `columns`) on the tray, a grasp of it with the left elbow, the arm waiting above
    it at the travel height. Returns (grasp, travel height)."""
    nut = box("nut", *NUT_XY_MM, 13.0)
    c = nut.polygon.centroid.coords[0]
    grasp = grasp_of(nut, cell, 8.0, joints=next(o for o in inverse(c[0], c[1], 8.0, 0.0, cell.scara)
                                                 if o.elbow == "left"))
    on_tray(loop, nut, *columns)
    safe_z = loop._safe_z_mm("nut", 8.0)
    arm_at(loop, above(grasp.joints, safe_z))
    return grasp, safe_z


# Two 130 mm columns beside the nut's way to the drop-off (found by search): A under the way with the
# left elbow (the nearest options to a left-elbow grasp), B under the way with the right elbow.
COLUMN_A = dict(cx_mm=150.0, cy_mm=230.0, z_top_mm=130.0, half_mm=12.0)
COLUMN_B = dict(cx_mm=270.0, cy_mm=80.0, z_top_mm=130.0, half_mm=12.0)


def test_when_the_nearest_drop_off_way_hits_the_pick_and_the_carry_off_take_the_other_elbow(low_loop, low_cell):
    grasp, safe_z = nut_held_with_the_left_elbow(low_loop, low_cell, box("column_a", **COLUMN_A))
    usual, *others = dropoff_options(low_cell, grasp.joints)
    assert usual.elbow == "left"
    with pytest.raises(LinksWouldHit, match="on the way to 'carry' the arm's links would hit column_a"):
        low_loop._check_links("nut", pick_commands(grasp.joints, 20.0, low_cell, safe_z, usual), "")
    pick = low_loop._clear_pick("nut", grasp)
    lower = next(c for c in pick if c.label == "lower")
    assert lower.joints in others and lower.joints.elbow == "right"
    low_loop._check_links("nut", pick, "")  # its whole way is clear
    off = low_loop._clear_carry_off("nut", grasp)  # the same, for a part in the jaws after a fault
    assert [c.label for c in off[:2]] == ["lift", "check"]  # the jaws grip again once up (the stop ended their push)
    assert [c.label for c in off[2:5]] == ["carry", "check at drop-off", "lower"] and off[4].joints.elbow == "right"
    low_loop._check_links("nut", off, "")


def test_no_clear_way_to_any_drop_off_refuses_with_the_nearest_options_reason(low_loop, low_cell):
    """Both columns: every option is refused, and the refusal given is the nearest option's, not the
    last one tried."""
    grasp, safe_z = nut_held_with_the_left_elbow(low_loop, low_cell, box("column_a", **COLUMN_A),
                                                 box("column_b", **COLUMN_B))
    options = dropoff_options(low_cell, grasp.joints)
    reasons = []
    for drop in options:
        with pytest.raises(LinksWouldHit) as e:
            low_loop._check_links("nut", pick_commands(grasp.joints, 20.0, low_cell, safe_z, drop), "nut: ")
        reasons.append(str(e.value))
    assert (options[0].elbow, options[-1].elbow) == ("left", "right")
    assert reasons[0] == "nut: on the way to 'carry' the arm's links would hit column_a"
    assert reasons[-1] == "nut: on the way to 'carry' the arm's links would hit column_b"
    with pytest.raises(LinksWouldHit) as refused:
        low_loop._clear_pick("nut", grasp)
    assert str(refused.value) == reasons[0]


# ---------------------------------------------------------------- pick_commands
@pytest.mark.parametrize("safe_z_mm,refused", [(8.0, True), (7.0, True), (8.001, False)])
def test_the_travel_height_must_be_above_the_grasp(cell, safe_z_mm, refused):
    if refused:
        with pytest.raises(CellError, match="is not above the grasp z 8 mm"):
            pick_commands(NUT_GRASP, 20.0, cell, safe_z_mm=safe_z_mm)
    else:
        assert pick_commands(NUT_GRASP, 20.0, cell, safe_z_mm=safe_z_mm)[0].joints == above(NUT_GRASP, safe_z_mm)


def test_the_gripper_commands_of_a_pick_pre_open_grip_at_the_opening_and_release_fully(cell):
    # pre-open: the opening + 2 x approach_clearance_mm 5 (its cap at the 80 mm stroke is pinned in
    # tests/test_arm_limit_boundaries.py)
    commands = pick_commands(NUT_GRASP, 28.0, cell)
    assert [(c.label, c.width_mm, c.force_n) for c in commands if c.action != "move"] == [
        ("pre-open", 38.0, None), ("grip", 28.0, cell.gripper.grip_force_n),
        ("check", 28.0, cell.gripper.grip_force_n), ("release", 80.0, None)]
    # the check grips again after the lift, above the tray, before the carry
    labels = [c.label for c in commands]
    assert labels.index("lift") + 1 == labels.index("check") == labels.index("carry") - 1


def test_a_pick_opens_at_the_travel_height_before_anything_descends_and_lets_go_at_the_given_drop_off(cell):
    usual, *others = dropoff_options(cell, NUT_GRASP)
    drop = next(o for o in others if o.elbow != usual.elbow)
    commands = pick_commands(NUT_GRASP, 20.0, cell, safe_z_mm=160.0, drop=drop)
    assert [c.label for c in commands] == ["approach", "pre-open", "descend", "grip", "lift", "check", "carry",
                                           "lower", "release", "retreat"]
    first_low = next(i for i, c in enumerate(commands) if c.joints is not None and c.joints.j3_mm < 160.0)
    assert commands[first_low].label == "descend" and first_low > [c.label for c in commands].index("pre-open")
    moves = {c.label: c.joints for c in commands if c.joints is not None}
    assert moves == {"approach": above(NUT_GRASP, 160.0), "descend": NUT_GRASP, "lift": above(NUT_GRASP, 160.0),
                     "carry": above(drop, 160.0), "lower": drop, "retreat": above(drop, 160.0)}
    assert pick_commands(NUT_GRASP, 20.0, cell)[7].joints == usual  # by default: the nearest drop-off


def test_the_drop_off_options_all_reach_it_nearest_to_the_grasp_first(cell):
    options = dropoff_options(cell, NUT_GRASP)
    assert len({o.elbow for o in options}) == 2
    for o in options:
        tool = forward(o, cell.scara)
        assert (tool.x_mm, tool.y_mm, tool.z_mm) == pytest.approx(cell.motion.dropoff_mm)
    distance = [float(np.abs((o.as_array() - NUT_GRASP.as_array())[[0, 1, 3]]).sum()) for o in options]
    assert distance == sorted(distance)


@pytest.mark.parametrize("dropoff_mm", [(650.0, 0.0, 120.0), (-400.0, 10.0, 120.0)],
                         ids=["past_the_reach", "behind_the_base_past_j1_limits"])
def test_a_drop_off_the_arm_cannot_reach_has_no_option(cell, dropoff_mm):
    unreachable = dataclasses.replace(cell, motion=dataclasses.replace(cell.motion, dropoff_mm=dropoff_mm))
    with pytest.raises(CellError, match="is not reachable with the cell's joint limits"):
        dropoff_options(unreachable, NUT_GRASP)


def test_a_carry_off_lifts_straight_up_from_where_the_arm_is(cell):
    stopped = Joints(-20.0, 80.0, 60.0, 10.0)  # where a fault stopped the arm, the part in the jaws
    commands = carry_off_commands(stopped, NUT_GRASP, cell, 150.0)
    assert commands[0].label == "lift" and commands[0].joints == above(stopped, 150.0)
    assert commands[2].label == "lower" and commands[2].joints == dropoff_options(cell, NUT_GRASP)[0]


# ---------------------------------------------------------------- the grip check
@pytest.fixture(scope="module")
def gripper_drives(cell):
    from drivers import simulated_cell

    with simulated_cell(cell) as (arm, drives):
        yield arm, drives


@pytest.mark.parametrize("part_mm,expected_mm,held", [
    (30.0, 30.0, True),
    (28.0, 30.0, True),  # stopped exactly 2 mm short of the expected width: held
    (27.99, 30.0, False),  # 0.01 mm past the tolerance: the jaws slid off
    (27.5, 30.0, False),
    (32.0, 30.0, True),  # stopped exactly 2 mm wide of it: held (the part measured larger)
    (32.01, 30.0, False),  # wider: blocked (a neighbour or a jammed finger), not holding
])
def test_the_drives_grip_check_at_the_2_mm_tolerance(gripper_drives, part_mm, expected_mm, held):
    """What the run acts on: the gripper driver's verdict on the width where the
    simulated jaws stop on a part."""
    arm, drives = gripper_drives
    drives.gripper_object_width_mm = part_mm
    arm.gripper.open()
    result = arm.gripper.grip(expected_mm)
    assert result.width_mm == pytest.approx(part_mm, abs=1e-3) and result.holding is held


# ---------------------------------------------------------------- frames
class Frames:
    """A camera that returns `frame` on every read."""

    def __init__(self, frame):
        self.frame, self.reads = frame, 0

    def read(self):
        self.reads += 1
        return self.frame


@pytest.mark.parametrize("width_px,height_px,refused", [
    pytest.param(1280, 1024, None, id="calibration_size"),
    pytest.param(640, 480, "frame is 640 x 480 px but calibration", id="another_camera_mode"),
    pytest.param(1280, 1023, "frame is 1280 x 1023 px but calibration", id="one_row_short"),
    pytest.param(None, None, "the camera returned no frame", id="no_frame"),
])
def test_a_frame_of_another_size_or_none_is_retried_then_stops_and_asks(loop, width_px, height_px, refused):
    # (a picture, not a black frame: that is refused for showing nothing, test_cell_run_real.py)
    camera = Frames(None if width_px is None else np.random.default_rng(0).integers(40, 220, (height_px, width_px, 3),
                                                                                     dtype=np.uint8))
    loop.camera = camera
    try:
        if refused is None:
            frame, _ = loop._read_frame()
            assert frame is camera.frame and camera.reads == 1
        else:
            with pytest.raises(StopRun, match=f"camera: no readable frame after 3 tries: {refused}"):
                loop._read_frame()
            assert camera.reads == 3
    finally:
        loop.camera = None


def test_a_calibration_of_another_size_than_the_cells_camera_is_refused_before_the_run(tmp_path):
    from calibration import default_calibration_path
    from cell.errors import BadInput
    from cell.runtime.session import RunConfig, run_session

    # the shipped calibration is for 1280 x 1024 px
    cell_path = cell_file(tmp_path, "other_camera", "camera", width_px=1280, height_px=1023)
    with pytest.raises(BadInput, match="is for 1280 x 1024 px, the cell's camera has 1280 x 1023 px"):
        run_session(RunConfig(cell=cell_path, calibration=default_calibration_path()))


# ---------------------------------------------------------------- the part picked last must be gone
def test_a_part_still_on_the_tray_after_its_pick_goes_back_first_at_its_new_place(cell):
    from drivers import simulated_cell

    with simulated_cell(cell) as (arm, _):
        loop = make_loop(cell, arm, interactive=True)  # the operator answers: the loop goes on
        nut, washer = box("nut", *NUT_XY_MM, 13.0), box("washer", 306.5, -8.0, 4.0)
        on_tray(loop, washer)
        loop.remaining, loop.reports = ["washer"], [PartReport("nut", "removed"), PartReport("pcb", "removed")]
        loop._last_picked = ("nut", nut)
        assert loop._last_pick_left({"washer": washer})  # gone: nothing changes
        assert loop.remaining == ["washer"] and len(loop.reports) == 2 and loop._last_picked is None
        slipped = nut.moved(3.0, -2.0)
        loop._last_picked = ("nut", nut)
        assert not loop._last_pick_left({"washer": washer, "nut": slipped})
        assert loop.remaining == ["nut", "washer"] and loop.poses["nut"] is slipped
        assert [r.part for r in loop.reports] == ["pcb"]
        assert loop.control.snapshot()["fault"]["why"] == "nut did not leave the tray"
        assert loop.control.snapshot()["fault"]["asking"]  # nothing failed: the page says it stopped to ask


# ---------------------------------------------------------------- after a pick was cut short
def test_a_pick_cut_short_before_the_grip_carries_nothing_off(loop, cell):
    """A fault before the jaws held anything (stage 'sent'): no carry-off is sent, the nut stays a
    part on the tray, and the loop opens and goes up as usual."""
    nut = box("nut", *NUT_XY_MM, 13.0)
    on_tray(loop, nut)
    grasp = grasp_of(nut, cell, 8.0)
    arm_at(loop, grasp.joints)
    if loop.control.state in ("fault", "stopped", "done"):
        loop.control.reset(by="test")
    loop.control.run(by="test")  # a carry-off, were one sent, would pass its checkpoint
    loop._pick = {"part": "nut", "grasp": grasp, "report": PartReport("nut", "removed"), "attempt": 0,
                  "stage": "sent"}
    here = loop.arm.joints()
    assert loop._recover_pick() is False
    assert loop.arm.joints() == here and loop._pick is None and "nut" in loop.poses and loop.reports == []


def test_a_part_held_where_a_fault_stopped_the_arm_outside_the_workspace_is_not_carried_off(cell):
    """Stretched, J1 from -40 to +40 degrees: both ends lie in the workspace box, the middle of the
    sweep does not (x 600 > 560 mm). J1 faults half way with the part in the jaws: the carry-off
    would start with a lift outside the box, so none of it is sent; the operator takes the part. (The
    drivers refuse that sweep now: here they were given a box beyond the arm's reach, the loop the cell's.)"""
    import dataclasses

    from cell.cellconfig import Box2D
    from drivers import simulated_cell

    wide = dataclasses.replace(cell, workspace=Box2D((-700.0, 700.0), (-700.0, 700.0)))
    with simulated_cell(wide) as (arm, drives):
        loop = make_loop(cell, arm)
        arm_at(loop, STRETCHED_CW)
        drives.inject_fault("emcy", "j1", after_s=arm.move_time_s(STRETCHED_CW, STRETCHED_CCW) / 2)
        with pytest.raises(CellError, match="j1"):
            arm.move_joints(STRETCHED_CCW)
        arm.reset_faults()
        here = arm.joints()
        assert forward(here, cell.scara).x_mm > cell.workspace.x_mm[1]
        nut = box("nut", *NUT_XY_MM, 13.0)
        on_tray(loop, nut)
        loop.control.run(by="test")  # a carry-off, were one sent, would pass its checkpoint
        pick = {"part": "nut", "grasp": grasp_of(nut, cell, 8.0), "report": PartReport("nut", "removed"),
                "attempt": 0, "stage": "gripped"}
        loop._pick = pick
        with pytest.raises(CellError, match=r"nut is still in the jaws and cannot be carried off \(tool at x = "
                                            r"\d+\.\d, y = .* outside the workspace .*\): take it out by hand"):
            loop._recover_pick()
        assert arm.joints() == here and loop._taken_by_hand is pick and loop._pick is None


# ---------------------------------------------------------------- whole runs
def test_a_grasp_with_no_clear_way_is_skipped_for_the_next_one(tmp_path):
    """The low cell and a 130 mm column under the forearm's way to the usual drop-off from the nut:
    a refused grasp is not a stop of its own (the next one is tried); the run stops when the planner
    has none left, with the last refusal as the reason."""
    from cell.runtime.motion import dropoff_joints
    from cell.runtime.session import RunConfig, run_session

    low_arm = low_arm_cell_file(tmp_path)
    cx, cy = forearm_mid(load_cell(low_arm), dropoff_joints(load_cell(low_arm), HOME))
    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] == "nut"] + [
        {"id": "column", "z_top": 130.0, "outline": [[cx - 15, cy - 15], [cx + 15, cy - 15], [cx + 15, cy + 15],
                                                     [cx - 15, cy + 15]]}]
    d["sequence"] = ["nut", "column"]
    asm = tmp_path / "column.json"
    asm.write_text(json.dumps(d))
    s = run_session(RunConfig(assembly=asm, cell=low_arm, seed=3))
    assert s["status"] == "stopped" and s["parts_removed"] == 0 and s["grasps"] == 0
    # the last refusal: the way to a grasp of the other elbow, which the drivers refuse directly (the elbow flip
    # sweeps the tool out of the workspace) and which goes round only over the column
    assert s["stopped"].startswith("planner: nut: no further grasp to try (nut: "), s["stopped"]
    assert "the arm's links would hit column" in s["stopped"]


def test_a_missed_grip_opens_the_jaws_at_depth_no_wider_than_the_fingers_clear_the_other_parts(cell):
    """The clip of the drive unit slips out of the jaws once (simulated world); the jaws are opened
    again before the arm goes up: every opening while the tips are below the travel height must keep
    the fingers (pads outside the opening) off every other part taller than the tips. (They opened
    to the full 80 mm at z 0 mm, over the 20 mm pulley beside the clip, until c2139a2.)"""
    from calibration import load_calibration
    from cell.grasp.footprints import finger_footprints
    from cell.runtime.session import SimCameraSource, home_joints
    from cell.runtime.simworld import SimWorld, WorldFaults
    from cell.scene import parse_assembly
    from drivers import simulated_cell

    d = json.loads((DEFAULT.parent / "drive_unit.json").read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] != "washer"]
    d["sequence"] = [p for p in d["sequence"] if p != "washer"]
    assembly, cal = parse_assembly(d), load_calibration()
    opened = []  # (width reached, joints) of every gripper opening
    with simulated_cell(cell) as (arm, drives):
        world = SimWorld(list(assembly.parts), cell, drives, faults=WorldFaults(miss={"clip": 1}))
        loop = make_loop(cell, arm, assembly, camera=SimCameraSource(world, cal, 0))
        open_jaws = arm.gripper.open

        def noted_open(width_mm=None):
            reached = open_jaws(width_mm)
            opened.append((reached, arm.joints()))
            return reached

        arm.gripper.open = noted_open
        arm.move_joints(home_joints(cell))
        loop.control.run(by="test")
        try:
            loop._one_part("clip")
        finally:
            world.close()
    assert "the jaws slid off clip" in world.events and "dropped clip off the tray" in world.events
    others = [p for p in assembly.parts if p.id != "clip"]
    for width_mm, j in opened:
        tool = forward(j, cell.scara)
        if j.j3_mm >= cell.motion.safe_z_mm:
            continue  # at the travel height, over everything
        jaws = Grasp("clip", np.zeros((2, 2)), np.zeros((2, 2)), np.array([tool.x_mm, tool.y_mm]), tool.axis_deg,
                     width_mm, tool.z_mm, [])
        fingers = finger_footprints(jaws, cell)
        hit = [p.id for p in others if p.z_top_mm > tool.z_mm and any(f.intersects(p.polygon) for f in fingers)]
        assert not hit, f"the jaws opened to {width_mm:.1f} mm at z {tool.z_mm:.1f} mm: the fingers overlap {hit}"


@pytest.mark.parametrize("post_top_mm", [60.0, 140.0, 195.0, 230.0])
@pytest.mark.parametrize("with_grasp", [True, False])
def test_after_a_miss_the_empty_jaws_go_up_above_the_tallest_part_before_they_open_fully(loop, cell, post_top_mm,
                                                                                         with_grasp):
    """A post next to the nut: after a missed grip (or a fault) the arm goes straight up to the safe
    height or, when the post is taller, to 20 mm above it (J3's 200 mm at most), and only there opens
    fully. It went up to the cell's 150 mm only, and the next move across the tray started below a
    140 mm post's top."""
    nut = box("nut", *NUT_XY_MM, 13.0)
    post = box("post", NUT_XY_MM[0] + 40.0, NUT_XY_MM[1], post_top_mm)
    on_tray(loop, nut, post)
    arm_at(loop, NUT_GRASP)
    moves, opens, seen = [], [], max((e["n"] for e in loop.control.snapshot()["events"]), default=0)
    move, open_jaws = loop.arm.move_joints, loop.arm.gripper.open
    loop.arm.move_joints = lambda j, **kw: (moves.append(j), move(j, **kw))[1]
    loop.arm.gripper.open = lambda w=None: (opens.append((w, loop.arm.joints().j3_mm)), open_jaws(w))[1]
    try:
        loop._retreat(grasp_of(nut, cell, NUT_GRASP.j3_mm, joints=NUT_GRASP) if with_grasp else None)
    finally:
        loop.arm.move_joints, loop.arm.gripper.open = move, open_jaws
    expected_z = min(max(cell.motion.safe_z_mm, post_top_mm + 20.0), cell.scara.j3_mm[1])
    assert len(moves) == 1 and moves[0].j3_mm == pytest.approx(expected_z)
    assert np.allclose(moves[0].as_array()[[0, 1, 3]], NUT_GRASP.as_array()[[0, 1, 3]], atol=1e-3)  # straight up
    full = [z for w, z in opens if w is None]
    assert len(full) == 1 and full[0] == pytest.approx(expected_z, abs=1e-3)  # fully open only up there
    assert len(opens) == (2 if with_grasp else 1)
    said = [e for e in loop.control.snapshot()["events"] if e["event"] == "retreat" and e["n"] > seen]
    if post_top_mm + 20.0 > cell.scara.j3_mm[1]:  # J3's top caps it: said, not hidden
        where = (f"{200 - post_top_mm:.0f} mm over" if post_top_mm <= 200
                 else f"{post_top_mm - 200:.0f} mm below the top of")
        assert said and said[-1]["message"].startswith(
            f"the empty jaws go up to J3's top, 200 mm, {where} the tallest part")
    else:
        assert not said


def _retreat_seen(loop, grasp):
    """`loop._retreat(grasp)`: the moves sent, the jaws' openings (width, J3 there) and the retreat lines said."""
    moves, opens, seen = [], [], max((e["n"] for e in loop.control.snapshot()["events"]), default=0)
    move, open_jaws = loop.arm.move_joints, loop.arm.gripper.open
    loop.arm.move_joints = lambda j, **kw: (moves.append(j), move(j, **kw))[1]
    loop.arm.gripper.open = lambda w=None: (opens.append((w, loop.arm.joints().j3_mm)), open_jaws(w))[1]
    try:
        loop._retreat(grasp)
    finally:
        loop.arm.move_joints, loop.arm.gripper.open = move, open_jaws
    said = [e for e in loop.control.snapshot()["events"] if e["event"] == "retreat" and e["n"] > seen]
    return moves, opens, said


@pytest.mark.parametrize(("start_z_mm", "post_top_mm", "unexplained_top_mm", "up_to_mm"), [
    (8.0, None, None, 150.0),  # nothing on the tray but the nut: the safe height (no made-up tallest part)
    (8.0, None, 160.0, 180.0),  # material no part explains counts as a part: 20 mm above it
    (8.0, 180.0, None, 200.0),  # 20 mm above the post is J3's top exactly: the margin is had, nothing said
    (150.0, None, None, None),  # already at the safe height: no move
    (190.0, None, None, None),  # above it: no move down (the jaws open fully where they are)
])
def test_the_retreat_goes_only_up_to_its_height(loop, cell, start_z_mm, post_top_mm, unexplained_top_mm, up_to_mm):
    nut = box("nut", *NUT_XY_MM, 13.0)
    parts = [nut] + ([box("post", NUT_XY_MM[0] + 40.0, NUT_XY_MM[1], post_top_mm)] if post_top_mm else [])
    unexplained = [box("blob", NUT_XY_MM[0], NUT_XY_MM[1] - 40.0, unexplained_top_mm)] if unexplained_top_mm else []
    on_tray(loop, *parts, unexplained=unexplained)
    arm_at(loop, Joints(NUT_GRASP.j1_deg, NUT_GRASP.j2_deg, start_z_mm, NUT_GRASP.j4_deg))
    assert not loop.arm.gripper.grip(20.0).holding  # the jaws closed past the nut, as after a miss
    moves, opens, said = _retreat_seen(loop, grasp_of(nut, cell, NUT_GRASP.j3_mm, joints=NUT_GRASP))
    assert not said
    if up_to_mm is None:
        assert moves == [] and opens == [(None, pytest.approx(start_z_mm, abs=1e-3))]
    else:
        assert len(moves) == 1 and moves[0].j3_mm == pytest.approx(up_to_mm)
        # below it, the jaws open to the grasp's approach opening (its 20 mm + 2 x the clearance), not more
        assert opens == [(pytest.approx(20.0 + 2 * cell.gripper.approach_clearance_mm), pytest.approx(start_z_mm,
                                                                                                       abs=1e-3)),
                         (None, pytest.approx(up_to_mm, abs=1e-3))]


def test_with_nothing_left_on_the_tray_the_retreat_goes_to_the_safe_height(loop, cell):
    on_tray(loop)
    arm_at(loop, NUT_GRASP)
    moves, opens, said = _retreat_seen(loop, None)
    assert len(moves) == 1 and moves[0].j3_mm == pytest.approx(cell.motion.safe_z_mm) and not said
    assert opens == [(None, pytest.approx(cell.motion.safe_z_mm, abs=1e-3))]
