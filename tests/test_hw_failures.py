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
    with pytest.raises(NodeSilent, match=r"j2 \(node 2\): no answer \(set-point acknowledge\) within 1 s"):
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
