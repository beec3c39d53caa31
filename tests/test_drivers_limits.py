"""The host's command check (pure): joint limits, workspace box, maximum step."""

from __future__ import annotations

import math

import pytest

from cell.kinematics import Joints
from drivers.limits import command_violations, gripper_violations

HOME = Joints(0.0, 90.0, 200.0, 0.0)


def test_home_is_allowed(cell_cfg):
    assert command_violations(cell_cfg, HOME, HOME) == []


@pytest.mark.parametrize(
    ("target", "needle"),
    [
        (Joints(133.0, 90.0, 200.0, 0.0), "J1 = 133.000 deg outside [-132, 132]"),
        (Joints(0.0, 151.0, 200.0, 0.0), "J2"),
        (Joints(0.0, 90.0, 200.5, 0.0), "J3"),
        (Joints(0.0, 90.0, 200.0, -361.0), "J4"),
        (Joints(120.0, 10.0, 200.0, 0.0), "outside the workspace"),
        (Joints(0.0, 90.0, 200.0, math.nan), "finite"),
    ],
)
def test_violations_name_the_reason(cell_cfg, target, needle):
    problems = command_violations(cell_cfg, target, None)
    assert any(needle in p for p in problems), problems


def test_step_larger_than_max_step(cell_cfg):
    cur = Joints(-100.0, 90.0, 200.0, -300.0)
    target = Joints(-100.0, 90.0, 200.0, 250.0)  # 550 deg on J4 > 540
    assert command_violations(cell_cfg, target, None) == []
    problems = command_violations(cell_cfg, target, cur)
    assert problems == ["J4 step 550.000 deg larger than max_step 540 deg"]


def test_gripper_violations(cell_cfg):
    assert gripper_violations(cell_cfg, 30.0, 40.0) == []
    assert gripper_violations(cell_cfg, 81.0)[0].startswith("gripper width 81.0 mm outside [0, 80]")
    assert "grip force" in gripper_violations(cell_cfg, 30.0, 0.0)[0]
    assert "grip force" in gripper_violations(cell_cfg, 30.0, 1000.0)[0]
