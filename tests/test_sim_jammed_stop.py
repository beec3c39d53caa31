"""A simulated axis jammed by the `following_error` injection stands: any stop of it ends at once (its
velocity actual is 0, as a drive judges standstill), as its fault reaction already did. It used to run
a ramp of the demand that never ended: no bit 10, no state after the ramp, a held enable never taken.
Over the virtual bus, in simulated time, the jam kept inside a widened following error window."""

from __future__ import annotations

import contextlib

import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints
from drivers import codec

pytestmark = needs_sim

WIDE_WINDOW_COUNTS = 300_000  # 300 deg: the demand never leaves it, the drive never trips


def _jam_j1_mid_move(arm, sim_drives) -> float:
    """j1 jams 0.1 s into a long move and the demand runs on; returns where j1 stands (counts)."""
    arm.axes["j1"].sdo_write(0x6065, 0, WIDE_WINDOW_COUNTS)
    sim_drives.inject_fault("following_error", "j1", after_s=0.1)
    s = arm.joints()
    arm.move_joints(Joints(s.j1_deg - 100.0, s.j2_deg, s.j3_mm, s.j4_deg), wait=False)
    arm.clock.sleep(0.3)
    j1 = sim_drives.drives["j1"]
    assert j1.state == "OPERATION_ENABLED" and j1.error_code == 0 and j1.motion is not None
    return j1.position_counts


@pytest.mark.parametrize(
    ("option", "command", "state", "bit10"),
    [
        ((0x605A, 6), codec.CW_QUICK_STOP, "QUICK_STOP_ACTIVE", True),  # ramp, stay: bit 10 = ended
        ((0x605A, 2), codec.CW_QUICK_STOP, "SWITCH_ON_DISABLED", False),  # ramp, then SWITCH ON DISABLED
        ((0x605C, 1), codec.CW_SWITCH_ON, "SWITCHED_ON", False),  # disable operation on the ramp
        ((0x605B, 1), codec.CW_SHUTDOWN, "READY_TO_SWITCH_ON", False),  # shutdown on the ramp
        ((0x605D, 1), codec.CW_ENABLE_OPERATION | codec.CW_HALT, "OPERATION_ENABLED", True),  # halt
    ],
    ids=["quick_stop_6", "quick_stop_2", "disable_operation_1", "shutdown_1", "halt_1"],
)
def test_a_jammed_axis_stops_at_once(arm, sim_drives, option, command, state, bit10):
    arm.axes["j1"].sdo_write(option[0], 0, option[1])
    jammed = _jam_j1_mid_move(arm, sim_drives)
    t0 = arm.clock.now()
    arm.axes["j1"].send_controlword(command)
    arm.clock.sleep(0.01)  # one step of the drives
    st = arm.axes["j1"].status
    assert (st.state, st.target_reached) == (state, bit10)
    assert sim_drives.drives["j1"].motion is None
    assert st.position_counts == round(jammed) and arm.clock.now() - t0 <= 0.011


def test_the_host_stops_a_jammed_axis_and_enables_it_again_at_once(arm, sim_drives):
    """stop() no longer waits its whole bound (2 s past the slowest quick stop ramp) for a bit 10 that
    never came, and enable operation (16), held by the drive until standstill, is taken at once."""
    jammed = _jam_j1_mid_move(arm, sim_drives)
    t0 = arm.clock.now()
    arm.stop()
    assert arm.clock.now() - t0 < 0.2
    st = arm.axes["j1"].status
    assert st.state == "QUICK_STOP_ACTIVE" and st.target_reached and st.position_counts == round(jammed)
    t0 = arm.clock.now()
    arm.axes["j1"].enable_gate = contextlib.nullcontext  # the drive's answer is under test, not the host's latch
    arm.axes["j1"].enable()
    assert sim_drives.drives["j1"].state == "OPERATION_ENABLED" and arm.clock.now() - t0 < 0.05
    assert sim_drives.drives["j1"].position_counts == jammed  # still jammed: enabling never jumps
