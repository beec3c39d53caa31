"""The host's own CAN interface lost mid-move (a USB adapter pulled, the interface down, bus-off: every send
and receive fails): a fault of the bus, latched and reported as one (`BusFault`, a CellError), not a bare
python-can exception past the supervision; the drives, no longer hearing the host's heartbeat, fault and stop
on their own. Through the real stack: the arm's own bus object shut down on python-can's virtual bus."""

from __future__ import annotations

import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.errors import CellError
from cell.kinematics import Joints
from drivers import BusFault, FaultLatched

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
