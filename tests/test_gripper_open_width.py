"""Jaws told to open (or close) to a width that stop elsewhere: something between them (the pre-open above a
part closes them from 80 mm to the approach opening). The drive ends such a move with its internal limit
(statusword bit 11), which the host took for arrival: the pick record said 60 mm where 50 were commanded, and
the arm descended with the jaws 10 mm wider than the planner cleared. Now it is a fault naming both widths, and
the loop stops there, the arm up at the travel height."""

from __future__ import annotations

import json

import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim
from test_runtime_safety_boundaries import DEFAULT, make_loop

from drivers import DriveFault, FaultLatched

pytestmark = needs_sim


def test_jaws_stopping_wider_than_commanded_are_a_fault_naming_both_widths(arm, sim_drives):
    sim_drives.gripper_object_width_mm = 60.0
    with pytest.raises(DriveFault, match=r"^gripper \(node 5\): the jaws stopped at 60\.0 mm opening to 50\.0 mm: "
                                         r"something between them\?"):
        arm.gripper.open(50.0)
    assert "gripper" in arm.faults
    with pytest.raises(FaultLatched):
        arm.move_joints(arm.joints())
    sim_drives.gripper_object_width_mm = None  # taken out
    arm.reset_faults()
    assert arm.gripper.open(50.0) == pytest.approx(50.0, abs=1e-3)


def test_jaws_that_reach_the_commanded_width_pass(arm, sim_drives):
    sim_drives.gripper_object_width_mm = 40.0  # narrower than the opening: not in the way
    assert arm.gripper.open(50.0) == pytest.approx(50.0, abs=1e-3)
    assert arm.faults == {}


def test_a_pre_open_stopped_on_something_stops_the_loop_before_the_descent(cell_cfg):
    """The whole loop on the simulated world: the jaws stop at 60 mm in the nut's pre-open (something between
    them). The run stops with the jaws' message, and J3 never goes below where it stood at the pre-open."""
    from calibration import load_calibration
    from cell.runtime.loop import StopRun
    from cell.runtime.session import SimCameraSource, home_joints
    from cell.runtime.simworld import SimWorld
    from cell.scene import parse_assembly
    from drivers import simulated_cell

    assembly = parse_assembly(json.loads(DEFAULT.read_text()))
    with simulated_cell(cell_cfg) as (arm, drives):
        world = SimWorld(list(assembly.parts), cell_cfg, drives)
        gripper = drives.drives["gripper"]
        between_jaws = gripper.object_width_fn
        stalled_at = {}  # J3 where the first closing move began: the pre-open

        def stall_the_first_closing():
            if stalled_at:
                return between_jaws()
            stalled_at["j3_mm"] = drives.drives["j3"].position()
            return 60.0

        gripper.object_width_fn = stall_the_first_closing
        lowest = [200.0]
        job = drives.clock.every(0.01, lambda: stalled_at and lowest.__setitem__(
            0, min(lowest[0], drives.drives["j3"].position())))
        loop = make_loop(cell_cfg, arm, assembly, camera=SimCameraSource(world, load_calibration(), 0))
        arm.move_joints(home_joints(cell_cfg))
        loop.control.run(by="test")
        try:
            with pytest.raises(StopRun, match=r"the jaws stopped at 60\.0 mm opening to \d+\.\d mm"):
                loop.run()
        finally:
            job.cancel()
            world.close()
    assert stalled_at and lowest[0] >= stalled_at["j3_mm"] - 1e-3
    assert world.removed == [] and world.held is None
