"""A host that connects to drives another host left enabled (it died and came back within the drives'
host-heartbeat deadline, or another master) stops them first: it took a drive found in OPERATION ENABLED as
enabled and idle, checked its first command from a snapshot taken mid-move, and the axis first ran on to the
old target, off the path the new command was checked on."""

from __future__ import annotations

import logging

import pytest
from drivers_fixtures import needs_sim

from cell.cellconfig import default_cell
from cell.kinematics import Joints
from drivers import Arm, SimClock, open_bus, sim

pytestmark = needs_sim


def _die(arm: Arm) -> None:
    """The host process ends here: no stop, no disable, no more heartbeats."""
    for job in arm._jobs:
        job.cancel()
    arm._pump.stop()
    arm.clock.remove_settler(arm._pump.settle)


def test_a_drive_left_moving_by_a_dead_host_is_stopped_before_the_next_host_moves_it(caplog):
    cell = default_cell()
    clock = SimClock()
    channel = "left-running"
    buses = [open_bus("virtual", channel) for _ in range(3)]
    try:
        with sim.serve(buses[0], cell, clock=clock) as drives:
            first = Arm(buses[1], cell, clock=clock, sdo_timeout_s=1.0)
            first.connect()
            first.move_joints(Joints(0, 90, 200, 0))
            first.move_joints(Joints(-100, 90, 200, 0), wait=False)  # a long swing of J1
            clock.sleep(0.05)
            _die(first)
            second = Arm(buses[2], cell, clock=clock, sdo_timeout_s=1.0)
            with caplog.at_level(logging.WARNING, logger="drivers.arm"):
                second.connect()
            assert "found enabled at connect" in caplog.text and "j1" in caplog.text
            try:
                at = drives.positions()["j1"]
                assert at > -99.0  # stopped on its way, not run on to the old target
                clock.sleep(0.5)
                assert drives.positions()["j1"] == pytest.approx(at, abs=1e-6)  # and it stands
                assert all(s["state"] == "OPERATION_ENABLED" for s in second.state().values())
                # the next move runs from where the axis stands to its own target, never past the old one's way
                lowest = at
                second.move_joints(Joints(at + 10.0, 90, 200, 0), wait=False)
                while second._pending[0] and not all(
                        second._arrived(second.axes[n], c) for n, c in second._pending[0].items()):
                    clock.sleep(0.01)
                    lowest = min(lowest, drives.positions()["j1"])
                second.wait_idle()
                assert lowest >= at - 1e-6
                assert drives.positions()["j1"] == pytest.approx(at + 10.0, abs=1e-3)
                assert second.faults == {}
            finally:
                second.disconnect()
    finally:
        for b in buses:
            b.shutdown()
        clock.close()


def test_a_stop_before_the_arm_is_connected_keeps_every_drive_from_being_enabled():
    """Was: dropped (the arm was not connected yet), and connect enabled every drive."""
    from drivers import DriverError, simulated_cell

    with simulated_cell(enable=False) as (arm, drives):
        bus, cell, clock = arm.bus, arm.cell, arm.clock
        other = Arm(bus, cell, clock=clock, sdo_timeout_s=1.0)  # a second host object on the same bus
        arm.disconnect()
        other.stop()
        with pytest.raises(DriverError, match="quick stop requested by the operator"):
            other.connect()
        assert all(d.state != "OPERATION_ENABLED" for d in drives.drives.values())
        other.connect(enable=False)  # the way out: connected, then the stop cleared by a reset
        try:
            assert "stop" in other.faults
            other.reset_faults()
            assert other.faults == {} and all(d.state == "OPERATION_ENABLED" for d in drives.drives.values())
        finally:
            other.disconnect()


def test_ctrl_c_while_disconnect_tells_one_drive_still_disables_the_others():
    """Was: the interrupt left the loop, and the drives after it stood enabled until their host-heartbeat
    deadline ran out and they faulted."""
    from drivers import simulated_cell

    with simulated_cell() as (arm, drives):
        told = arm.axes["j1"].disable

        def interrupted():
            told()
            raise KeyboardInterrupt

        arm.axes["j1"].disable = interrupted
        with pytest.raises(KeyboardInterrupt):
            arm.disconnect()
        assert not arm.is_connected
        arm.clock.sleep(0.05)
        shut_down = {n: "READY_TO_SWITCH_ON" for n in drives.drives}
        assert {n: d.state for n, d in drives.drives.items()} == shut_down
