"""A pick's commands (cell.runtime.motion) executed on the simulated cell in simulated time."""

from __future__ import annotations

import pytest

from cell.kinematics import inverse
from cell.runtime.motion import pick_commands
from drivers import simulated_cell
from drivers.execute import run_commands


def _grasp(cell):
    return min(inverse(380.0, -60.0, 10.0, 30.0, cell.scara), key=lambda q: abs(q.j2_deg - 90.0))


def test_pick_commands_run_and_hold(cell_cfg):
    with simulated_cell(cell_cfg) as (arm, drives):
        drives.gripper_object_width_mm = 28.0
        records = run_commands(arm, pick_commands(_grasp(cell_cfg), 28.0, cell_cfg))
        assert [r["label"] for r in records] == [
            "approach",
            "pre-open",
            "descend",
            "grip",
            "lift",
            "check",
            "carry",
            "lower",
            "release",
            "retreat",
        ]
        grip, check = records[3], records[5]
        assert grip["holding"] and grip["width_mm"] == pytest.approx(28.0)
        assert check["holding"] and check["width_mm"] == pytest.approx(28.0)  # still held, above the tray
        assert records[1]["width_mm"] == pytest.approx(28.0 + 2 * cell_cfg.gripper.approach_clearance_mm)
        assert all(b["t_start_s"] >= a["t_end_s"] for a, b in zip(records, records[1:], strict=False))
        cycle_s = records[-1]["t_end_s"] - records[0]["t_start_s"]
        assert 1.0 < cycle_s < 10.0  # simulated seconds, from the drives' profiles
        assert drives.positions()["j3"] == pytest.approx(records[-1]["joints"]["j3_mm"])


def test_a_missed_grip_ends_the_pick(cell_cfg):
    with simulated_cell(cell_cfg) as (arm, drives):
        drives.gripper_object_width_mm = None
        records = run_commands(arm, pick_commands(_grasp(cell_cfg), 28.0, cell_cfg))
        assert records[-1]["label"] == "grip" and records[-1]["holding"] is False


def test_a_part_lost_on_the_lift_ends_the_pick_at_the_check(cell_cfg):
    """The part slips out as the arm lifts: the check grip closes past its width and nothing more is sent
    (no carry of empty jaws to the drop-off). Without the check (recordings made before it) the pick goes on."""
    for check_grip in (True, False):
        with simulated_cell(cell_cfg) as (arm, drives):
            drives.gripper_object_width_mm = 28.0

            def world(step):
                if step["label"] == "lift":
                    drives.gripper_object_width_mm = None

            commands = pick_commands(_grasp(cell_cfg), 28.0, cell_cfg, check_grip=check_grip)
            records = run_commands(arm, commands, on_step=world)
            labels = [r["label"] for r in records]
            if check_grip:
                assert labels[-2:] == ["lift", "check"] and records[-1]["holding"] is False
                assert records[-1]["width_mm"] < 28.0 - 2 and drives.positions()["j3"] > _grasp(cell_cfg).j3_mm
            else:
                assert "check" not in labels and labels[-1] == "retreat"


def test_the_check_holds_while_the_jaws_stop_on_the_part_wherever_it_turned_or_pressed(cell_cfg):
    """Planned 30 mm, held at 28.5; at the check the part, pressed, gives 1.5 mm more (27), or it turned between
    the jaws and they stop 8 mm narrower (20.5): still held (opening the jaws there would drop it), the shift said.
    Gone, the jaws close on: lost."""
    for at_check, held, moved in ((27.0, True, None), (20.5, True, 8.0), (None, False, None)):
        with simulated_cell(cell_cfg) as (arm, drives):
            drives.gripper_object_width_mm = 28.5

            def world(step, at_check=at_check):
                if step["label"] == "lift":
                    drives.gripper_object_width_mm = at_check

            records = run_commands(arm, pick_commands(_grasp(cell_cfg), 30.0, cell_cfg), on_step=world)
            check = next(r for r in records if r["label"] == "check")
            assert check["action"] == "check" and check["holding"] is held
            assert check["width_mm"] == pytest.approx(at_check or 0.0, abs=0.01)
            assert check.get("moved_mm") == (None if moved is None else pytest.approx(moved, abs=0.01))
            assert ("carry" in [r["label"] for r in records]) is held
