"""Failures on a real line, through the real stack (python-can's virtual bus, the simulated drives):

- the host's own CAN interface lost mid-move (a USB adapter pulled, the interface down, bus-off: every send
  and receive fails): a fault of the bus, latched and reported as one (`BusFault`, a CellError), not a bare
  python-can exception past the supervision; the drives, no longer hearing the host's heartbeat, fault and
  stop on their own (the arm's own bus object shut down);
- a drive alive but deaf to the set-point edge (it never acknowledges): the move fails, every axis is
  quick-stopped, that drive included (it was left enabled holding the set-point controlword)."""

from __future__ import annotations

import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.errors import CellError
from cell.kinematics import Joints
from drivers import BusFault, FaultLatched, NodeSilent

pytestmark = needs_sim


def test_the_host_interface_gone_mid_move_is_a_latched_bus_fault_and_the_drives_stop_on_their_own(arm, sim_drives):
    start = arm.joints()
    arm.move_joints(Joints(start.j1_deg, start.j2_deg, start.j3_mm, start.j4_deg + 90.0), wait=False)
    arm.clock.sleep(0.1)
    arm.bus.shutdown()  # the interface is gone: python-can refuses every frame from now on
    with pytest.raises(BusFault, match=r"^bus: (sending|receiving) .*failed") as raised:
        arm.wait_idle()
    assert isinstance(raised.value, CellError)  # the cell loop stops and asks; it was a raw can.CanOperationError
    assert set(arm.faults) == {"bus"}
    with pytest.raises(FaultLatched):
        arm.move_joints(start)
    arm.clock.sleep(0.5)  # 3 host heartbeat periods: every drive faults on the silence (EMCY 0x8130) and stands
    assert {d.state for d in sim_drives.drives.values()} == {"FAULT"}
    stood = sim_drives.positions()
    arm.clock.sleep(0.2)
    assert sim_drives.positions() == stood


def test_a_frame_the_interface_refuses_is_a_bus_fault_naming_the_node_and_the_frame(arm, sim_drives):
    start = arm.joints()
    arm.bus.shutdown()
    frames = "SDO write 0x6081:0|controlword|target position"
    with pytest.raises(BusFault, match=rf"bus: sending ({frames}).* to j4 \(node 4\) failed"):
        arm.move_joints(Joints(start.j1_deg, start.j2_deg, start.j3_mm, start.j4_deg + 10.0))
    assert "bus" in arm.faults


def test_a_drive_that_never_acknowledges_the_set_point_is_quick_stopped_with_the_others(arm, sim_drives):
    sim_drives.inject_fault("ignore_set_point", "j2")
    start = arm.joints()
    target = Joints(start.j1_deg - 40.0, start.j2_deg - 30.0, start.j3_mm, start.j4_deg)
    silent = r"j2 \(node 2\): no answer \(set-point acknowledge under halt; .*\) within 1 s"
    with pytest.raises(NodeSilent, match=silent):
        arm.move_joints(target)
    assert set(arm.faults) == {"j2"}
    # j2 was left in OPERATION ENABLED with controlword 0x001F (enable operation + new set-point): a drive that
    # only answered late would have run its move alone after the others stopped
    assert sim_drives.drives["j2"].state == "QUICK_STOP_ACTIVE"
    assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
    sim_drives.heal("j2")  # it hears set-points again: still nothing moves
    stood = sim_drives.positions()
    arm.clock.sleep(1.0)
    assert sim_drives.positions() == stood and stood["j2"] == start.j2_deg
    with pytest.raises(FaultLatched):
        arm.move_joints(start)
    arm.reset_faults()
    assert arm.move_joints(target) == target


def test_jaws_stopped_wider_than_the_part_are_not_holding_and_never_close_further_on_the_way_up(tmp_path):
    """The jaws stop 20 mm wider than the nut (on a neighbour, a jammed finger): the grip is blocked, not held
    (it lifted whatever stopped them), and the retreat opens them no narrower than they stand (it 'opened' them
    to the approach opening, 10 mm narrower: a squeeze on what blocked them)."""
    import json
    from importlib import resources
    from pathlib import Path

    from calibration import load_calibration
    from cell.cellconfig import default_cell
    from cell.examples import default_examples_path
    from cell.runtime.control import RunControl
    from cell.runtime.loop import CellLoop
    from cell.scene import Scene, parse_assembly
    from drivers import codec, open_bus, simulated_cell
    from drivers.execute import run_commands

    cell = default_cell()
    default = json.loads((Path(str(resources.files("cell"))) / "data" / "assemblies" / "default.json").read_text())
    channel = f"blocked-grip-{tmp_path.name}"
    tap = open_bus("virtual", channel)
    try:
        with simulated_cell(cell, channel=channel) as (arm, drives):
            loop = CellLoop(cell=cell, calibration=load_calibration(), assembly=parse_assembly(default), camera=None,
                            arm=arm, control=RunControl(), examples_path=default_examples_path())
            grasp = loop.planner.plan(Scene(tuple(loop._on_tray()), "nut")).grasp
            to_grip = loop._clear_pick("nut", grasp)
            to_grip = to_grip[:[c.label for c in to_grip].index("grip") + 1]
            # the jaws go down fully open: something 20 mm wider than the nut between them (a neighbour pushed in on
            # the descent) would have stopped the pre-open to the approach opening, a fault of its own
            # (tests/test_gripper_open_width.py)
            to_grip = [c for c in to_grip if c.label != "pre-open"]
            drives.gripper_object_width_mm = grasp.opening_mm + 20.0
            grip = run_commands(arm, to_grip)[-1]
            assert grip["holding"] is False and grip["blocked"] is True
            assert grip["width_mm"] == pytest.approx(grasp.opening_mm + 20.0, abs=1e-3)
            while tap.recv(0) is not None:
                pass
            loop._retreat(grasp)
            assert arm.joints().j3_mm >= cell.motion.safe_z_mm
            assert drives.positions()["gripper"] == pytest.approx(cell.gripper.opening_mm[1])
            node = cell.can.nodes["gripper"]
            targets = []
            while (msg := tap.recv(0)) is not None:
                if msg.arbitration_id == codec.RPDO2_BASE + node.node_id:
                    targets.append(int.from_bytes(msg.data[:4], "little", signed=True) / node.counts_per_unit)
            assert targets and min(targets) >= grip["width_mm"] - 1e-3, targets
    finally:
        tap.shutdown()
