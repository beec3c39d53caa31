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
            "carry",
            "lower",
            "release",
            "retreat",
        ]
        grip = records[3]
        assert grip["holding"] and grip["width_mm"] == pytest.approx(28.0)
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
