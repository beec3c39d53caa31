"""`cell hw pick SCENE`: a grasp planned on a scene file and carried out on the (simulated) arm over CAN."""

from __future__ import annotations

import json

import pytest
from conftest import ROOT, run_cli

from drivers.record import read_log

SCENE = ROOT / "cell" / "data" / "scenes" / "default_step0.json"  # the nut among the default assembly


def _pick(capsys, *argv):
    code, out, err = run_cli("hw", "pick", *argv, "--simulated-time", "--json", capsys=capsys)
    return code, (json.loads(out.strip().splitlines()[-1]) if out.strip() else None), err


def test_the_nut_is_picked_checked_and_carried_to_the_drop_off_over_can(capsys, tmp_path):
    log = tmp_path / "pick.log"
    code, out, err = _pick(capsys, SCENE, "--record", log)
    assert code == 0, err
    assert out["target"] == "nut" and out["outcome"] == "held" and not out["place_back"]
    g = out["grasp"]
    assert 0.0 <= g["grasp_z_mm"] <= 8.0 - 2.0 + 1e-9 and g["opening_mm"] > 0
    records = {r["label"]: r for r in out["records"]}
    assert records["grip"]["holding"] and records["check"]["holding"] and records["check"]["action"] == "check"
    assert records["grip"]["width_mm"] == pytest.approx(g["opening_mm"], abs=0.05)  # the jaws closed on the part
    labels = [r["label"] for r in out["records"]]
    assert labels.index("lift") < labels.index("check") < labels.index("carry") < labels.index("release")
    # the simulated world had the nut between the jaws, and it left the tray at the drop-off
    assert out["sim_events"][0].startswith("gripped nut at") and "dropped nut off the tray" in out["sim_events"]
    ids = {m.arbitration_id for m in read_log(log)}
    assert {0x301, 0x302, 0x303, 0x304, 0x305} <= ids  # the host's target positions to every axis and the gripper


def test_place_back_puts_the_part_down_where_it_lay_and_opens_only_to_the_approach_opening(capsys):
    """... there; fully only once up at the travel height, so that the next trial starts with the jaws open (it
    refused jaws standing at the approach opening: "something may be between them")."""
    code, out, err = _pick(capsys, SCENE, "--place-back")
    assert code == 0, err
    labels = [r["label"] for r in out["records"]]
    assert labels[-6:] == ["lift", "check", "put back", "release", "retreat", "open"] and "carry" not in labels
    by = {r["label"]: r for r in out["records"]}
    assert by["put back"]["joints"] == by["descend"]["joints"]
    assert by["release"]["width_mm"] == pytest.approx(out["grasp"]["opening_mm"] + 10.0, abs=0.01)
    assert by["retreat"]["joints"]["j3_mm"] == by["approach"]["joints"]["j3_mm"]
    assert by["open"]["width_mm"] == pytest.approx(80.0, abs=0.01)
    assert out["sim_events"][-1] == "released nut on the tray"


def test_a_part_that_slips_out_on_the_lift_opens_the_jaws_and_goes_up(cell_cfg):
    """The check after the lift finds the jaws empty: the pick ends there, the jaws open to the approach
    opening (no wider) where they stand, and fully once the arm stands at the travel height."""
    from cell.commands.hw_pick import _carry_out, _outcome
    from drivers import simulated_cell

    _, _, home, first_clear = _planned(cell_cfg)
    with simulated_cell(cell_cfg) as (arm, drives):
        grasp, commands = first_clear(arm)
        grip_z = grasp.joints.j3_mm
        drives.drives["gripper"].object_width_fn = (
            lambda: grasp.opening_mm if drives.positions()["j3"] <= grip_z + 1.0 else None)
        opened = _watch_opening(arm)
        records = _carry_out(arm, cell_cfg, grasp, commands, home, False)
        assert _outcome(records) == "slipped" and records[-1]["label"] == "check"
        travel = next(c.joints.j3_mm for c in commands if c.label == "approach")
        assert drives.positions()["j3"] == pytest.approx(travel, abs=0.01)
        # checked up at the travel height: the approach opening there, then fully
        assert opened[-2:] == [(pytest.approx(grasp.opening_mm + 10.0, abs=0.01), pytest.approx(travel, abs=0.01)),
                               (80.0, pytest.approx(travel, abs=0.01))]
        assert drives.positions()["gripper"] == pytest.approx(80.0, abs=0.01)
        arm.gripper.require_open()  # what the next `hw pick` asks first: it refused jaws at the approach opening
        assert "carry" not in [r["label"] for r in records]


def test_a_part_lost_on_the_way_to_the_drop_off_is_lost_not_let_go_there(cell_cfg):
    """The part falls out of the jaws during the carry: the check above the drop-off finds the jaws empty, so
    nothing is lowered or let go there; the outcome is "lost" (it said held: the pick ran to its release)."""
    from cell.commands.hw_pick import _carry_out, _outcome, _text
    from cell.runtime.motion import TRANSIT_CHECK
    from drivers import simulated_cell

    _, _, home, first_clear = _planned(cell_cfg)
    with simulated_cell(cell_cfg) as (arm, drives):
        grasp, commands = first_clear(arm)
        assert TRANSIT_CHECK in [c.label for c in commands]
        carry = next(c.joints for c in commands if c.label == "carry")
        held = [True]

        def in_jaws():
            at = drives.positions()
            if abs(at["j1"] - carry.j1_deg) < 1.0 and abs(at["j2"] - carry.j2_deg) < 1.0:
                held[0] = False  # it fell out on the way
            return grasp.opening_mm if held[0] else None

        drives.drives["gripper"].object_width_fn = in_jaws
        records = _carry_out(arm, cell_cfg, grasp, commands, home, False)
        labels = [r["label"] for r in records]
        assert _outcome(records) == "lost" and labels[-1] == TRANSIT_CHECK, labels
        assert "lower" not in labels and "release" not in labels
        assert drives.positions()["gripper"] == pytest.approx(80.0, abs=0.01)  # opened once up, as after a slip
        assert "LOST on the way to the drop-off" in _text("nut", grasp, "lost", records, 1.0)


def _watch_opening(arm) -> list[tuple[float, float]]:
    """Every width the jaws are opened to after this (fully: the stroke's top), with the height (J3 mm) they
    stand at then."""
    opened, own_open = [], arm.gripper.open

    def open_and_note(width_mm=None):
        width = own_open(width_mm)
        opened.append((width_mm if width_mm is not None else arm.cell.gripper.opening_mm[1], arm.joints().j3_mm))
        return width

    arm.gripper.open = open_and_note
    return opened


def test_no_feasible_grasp_exits_3_and_moves_nothing(capsys, tmp_path):
    plate = [[300, -60], [420, -60], [420, 60], [300, 60]]  # 120 mm across every way: wider than the stroke
    scene = tmp_path / "plate.json"
    scene.write_text(json.dumps({"units": "mm", "target": "plate",
                                 "parts": [{"id": "plate", "outline": plate, "z_bottom": 0, "z_top": 5}]}))
    log = tmp_path / "none.log"
    code, out, err = _pick(capsys, scene, "--record", log)
    assert code == 3 and out["error"] == "no_feasible_grasp" and out["target"] == "plate", err
    assert not log.exists()  # the bus was never opened


def test_no_grasp_with_a_way_clear_of_the_other_parts_exits_3_and_moves_nothing(capsys, tmp_path):
    """A forearm whose underside is 120 mm up, and a 140 mm column under it where it stands at home (j2 90 deg:
    along +y from the elbow at x 325): the grasp itself is clear (the planner's step 5 checks the links there),
    but the way from home to it sweeps the forearm over the column. Nothing is sent to the axes."""
    from test_runtime_safety_boundaries import low_arm_cell_file

    cell = low_arm_cell_file(tmp_path)
    scene = tmp_path / "column.json"
    scene.write_text(json.dumps({"units": "mm", "target": "nut", "parts": [
        {"id": "nut", "outline": _square(400, -100, 8), "z_bottom": 0, "z_top": 8},
        {"id": "column", "outline": _square(325, 140, 10), "z_bottom": 0, "z_top": 140}]}))
    for extra in ([], ["--place-back"]):
        log = tmp_path / f"column{len(extra)}.log"
        code, out, err = _pick(capsys, scene, "--cell", cell, "--record", log, *extra)
        assert code == 3 and out["error"] == "no_feasible_grasp", err
        assert "links would hit column" in out["reason"]
        assert _targets_sent(log) == {}  # the drives were never enabled: not even the targets enabling sends


def _square(x: float, y: float, h: float) -> list[list[float]]:
    """A square of half-side h (mm) centred at (x, y)."""
    return [[x - h, y - h], [x + h, y - h], [x + h, y + h], [x - h, y + h]]


def _targets_sent(log) -> dict[str, set[float]]:
    """The target positions (RPDO2: int32 counts, 1000 a unit) the host sent each node: enabling sends where
    each axis stands (home, the jaws open), so any other is a move."""
    names = {0x301: "j1", 0x302: "j2", 0x303: "j3", 0x304: "j4", 0x305: "gripper"}
    out: dict[str, set[float]] = {}
    for m in read_log(log):
        if m.arbitration_id in names:
            out.setdefault(names[m.arbitration_id], set()).add(int.from_bytes(m.data[:4], "little", signed=True) / 1000)
    return out


@pytest.mark.parametrize("content, says", [
    ("{not json", "plate.json"),
    (json.dumps({"units": "mm", "target": "gone", "parts": [
        {"id": "plate", "outline": [[300, 0], [320, 0], [320, 20], [300, 20]], "z_bottom": 0, "z_top": 5}]}),
     "gone"),
])
def test_a_bad_scene_is_bad_input(capsys, tmp_path, content, says):
    scene = tmp_path / "plate.json"
    scene.write_text(content)
    code, out, err = _pick(capsys, scene)
    assert code == 2 and says in err and "Traceback" not in err and out is None


def test_a_real_bus_asks_before_moving_and_nothing_moves_without_a_yes(cell_cfg, monkeypatch):
    """On a real interface (here the simulated drives standing in for it, with no world: a real bus has none)
    the pick is confirmed after it is planned and its way checked; refused (no terminal to ask on), nothing
    has moved."""
    import contextlib
    import os
    import sys
    import types

    from cell.commands import hw
    from cell.commands.hw_pick import run_pick
    from cell.errors import BadInput
    from drivers import simulated_cell

    seen = {}

    @contextlib.contextmanager
    def bus(args, cell):
        with simulated_cell(cell) as (arm, drives):
            seen["drives"], seen["start"] = drives, drives.positions()
            yield arm, None

    args = types.SimpleNamespace(scene=str(SCENE), examples=None, place_back=False, interface="socketcan",
                                 channel="can0", yes=False, json=True)
    monkeypatch.setattr(sys, "stdin", open(os.devnull))
    with pytest.raises(BadInput, match=r"refusing to home the arm, pick 'nut' at .* without confirmation"):
        run_pick(args, cell_cfg, bus, hw.confirm_and_enable, hw._stop_on_interrupt, hw._emit)
    assert seen["drives"].positions() == pytest.approx(seen["start"])


def _planned(cell_cfg, scene_path=SCENE, place_back=False):
    from cell.commands.grasp import load_planner_inputs
    from cell.commands.hw_pick import _first_clear
    from cell.grasp.synthesis import GraspPlanner
    from cell.kinematics import Joints
    from cell.runtime.loop import loop_planner_params
    from cell.scene import load_scene

    scene = load_scene(scene_path)
    planner = GraspPlanner(cell_cfg, load_planner_inputs(None), loop_planner_params())
    home = Joints.from_dict(cell_cfg.motion.home_joints)
    return scene, planner, home, lambda arm: _first_clear(arm, cell_cfg, scene, planner.plan(scene).ranked,
                                                          place_back, home, planner)


@pytest.mark.parametrize("at_grasp, above, place_back, outcome", [
    (+5.0, None, False, "blocked"),  # the jaws stop 5 mm wider than the part: something else between them
    (0.0, -8.0, True, "moved"),  # put back: the part turned in the jaws at the check, 8 mm narrower
    (0.0, -8.0, False, "held"),  # carried off: still held, it goes to the drop-off
])
def test_a_blocked_grip_and_a_part_that_moved_in_the_jaws(cell_cfg, at_grasp, above, place_back, outcome):
    """Blocked: said so (not 'missed'), the jaws open no narrower than they stand, the arm goes up. A part that
    moved in the jaws is not set down where it lay (it would hang lower, pushed into the tray by J3): it stays
    held at the travel height."""
    from cell.commands.hw_pick import _carry_out, _outcome
    from drivers import simulated_cell

    _, _, home, first_clear = _planned(cell_cfg, place_back=place_back)
    with simulated_cell(cell_cfg) as (arm, drives):
        grasp, commands = first_clear(arm)
        w, grip_z = grasp.opening_mm, grasp.joints.j3_mm
        drives.drives["gripper"].object_width_fn = (
            lambda: w + at_grasp if drives.positions()["j3"] <= grip_z + 1.0 else (w + above if above else w))
        opened = _watch_opening(arm)
        records = _carry_out(arm, cell_cfg, grasp, commands, home, place_back)
        assert _outcome(records, place_back) == outcome
        labels = [r["label"] for r in records]
        travel = next(c.joints.j3_mm for c in commands if c.label == "approach")
        if outcome == "blocked":
            assert labels[-1] == "grip" and records[-1]["blocked"]
            assert drives.positions()["j3"] == pytest.approx(travel, abs=0.01)
            # the approach opening (> w + 5) at the grasp, fully open at the travel height
            assert opened[-2:] == [(pytest.approx(w + 10.0, abs=0.01), pytest.approx(grip_z, abs=0.01)),
                              (80.0, pytest.approx(travel, abs=0.01))]
            assert drives.positions()["gripper"] == pytest.approx(80.0, abs=0.01)
        elif outcome == "moved":
            assert labels[-1] == "check" and records[-1]["moved_mm"] == pytest.approx(8.0, abs=0.01)
            assert "put back" not in labels and drives.positions()["j3"] == pytest.approx(travel, abs=0.01)
            assert drives.positions()["gripper"] == pytest.approx(w - 8.0, abs=0.01)  # still closed on it
        else:
            assert labels[-1] == "retreat" and "carry" in labels


def test_no_travel_height_over_a_tall_neighbour_exits_3(capsys, tmp_path):
    scene = tmp_path / "tall.json"
    scene.write_text(json.dumps({"units": "mm", "target": "nut", "parts": [
        {"id": "nut", "outline": _square(400, -100, 8), "z_bottom": 0, "z_top": 8},
        {"id": "column", "outline": _square(300, 150, 10), "z_bottom": 0, "z_top": 185}]}))
    code, out, err = _pick(capsys, scene)
    assert code == 3 and out["error"] == "no_feasible_grasp" and "travel height" in out["reason"], err


def test_a_target_off_the_tray_is_bad_input_and_nothing_connects(capsys, tmp_path):
    square = [[-40, 290], [-20, 290], [-20, 310], [-40, 310]]
    scene = tmp_path / "off.json"
    scene.write_text(json.dumps({"units": "mm", "target": "nut", "parts": [
        {"id": "nut", "outline": square, "z_bottom": 0, "z_top": 8}]}))
    log = tmp_path / "off.log"
    code, out, err = _pick(capsys, scene, "--record", log)
    assert code == 2 and "outside the cell's tray" in err and out is None and not log.exists()


def test_jaws_that_are_not_open_at_the_start_are_refused_before_anything_moves(cell_cfg):
    """A pick cut short by Ctrl-C can leave a part between the jaws; the pre-open at the travel height would
    drop it."""
    import contextlib
    import types

    from cell.commands import hw
    from cell.commands.hw_pick import run_pick
    from cell.errors import CellError
    from drivers import simulated_cell

    seen = {}

    @contextlib.contextmanager
    def closed_jaws(args, cell):
        with simulated_cell(cell) as (arm, drives):
            drives.gripper_object_width_mm = 20.0
            arm.gripper.grip(20.0)  # something held
            seen["drives"], seen["start"] = drives, drives.positions()
            yield arm, drives

    args = types.SimpleNamespace(scene=str(SCENE), examples=None, place_back=False, interface="virtual",
                                 channel=None, yes=False, json=True)
    with pytest.raises(CellError, match="the jaws stand at 20.0 mm, not open"):
        run_pick(args, cell_cfg, closed_jaws, hw.confirm_and_enable, hw._stop_on_interrupt, hw._emit)
    assert seen["drives"].positions() == pytest.approx(seen["start"])
