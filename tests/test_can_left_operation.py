"""A drive that leaves OPERATION ENABLED during a move without a fault (its own quick stop input, STO,
another master): the host sees it in the axis' next TPDO1, quick-stops the other axes as on a fault,
raises DriveDisabled naming the axis and the state, and sends nothing more until reset_faults(); an
idle axis found so refuses the next command before anything is sent.
And Axis.enable() out of QUICK STOP ACTIVE waits for the end of the ramp on its own."""

from __future__ import annotations

import contextlib
import time

import can
import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints
from drivers import Arm, DriveDisabled, DriveFault, FaultLatched, RealClock, codec, sim
from drivers.pump import BusPump

pytestmark = needs_sim

HOST_HEARTBEAT_ID = 0x77F  # the host's own heartbeat goes on: it tells the drives the host lives
QUICK_STOP_FRAME = codec.pack_controlword(codec.CW_QUICK_STOP)


def _long_move(arm):
    s = arm.joints()
    return Joints(s.j1_deg - 40.0, s.j2_deg - 30.0, s.j3_mm - 50.0, s.j4_deg + 90.0)


@contextlib.contextmanager
def _tap(open_test_bus, clock):
    """Every frame on the bus as (clock time, message), handled at the time it was sent."""
    heard = []
    pump = BusPump(open_test_bus(), [lambda m: heard.append((clock.now(), m))], name="test-tap")
    clock.add_settler(pump.settle)
    try:
        yield heard
    finally:
        clock.remove_settler(pump.settle)
        pump.stop()


def _host_command(msg: can.Message) -> bool:
    """A frame the host sends to drives: NMT, RPDO1-3, SDO request (not its heartbeat)."""
    i = msg.arbitration_id
    return i == codec.NMT_COB or 0x200 <= i < 0x480 or 0x600 <= i < 0x680


def _left_at_s(heard, node_id: int, state: str) -> float:
    """When the node's TPDO1 first reported `state`."""
    tpdo1 = 0x180 + node_id
    return next(t for t, m in heard if m.arbitration_id == tpdo1 and codec.unpack_tpdo1(m.data).state == state)


@pytest.mark.parametrize(("kind", "state"), [("quick_stop", "QUICK_STOP_ACTIVE"), ("disable", "SWITCH_ON_DISABLED")])
def test_a_drive_leaving_operation_mid_move_stops_the_others_and_raises_at_once(
    arm, sim_drives, open_test_bus, kind, state
):
    target = _long_move(arm)
    move_s = arm.move_time_s(arm.joints(), target)
    with _tap(open_test_bus, arm.clock) as heard:
        sim_drives.inject_fault(kind, "j2", after_s=0.2)
        t_sent = arm.clock.now()
        with pytest.raises(DriveDisabled, match=rf"j2 \(node 2\): left OPERATION ENABLED .* now in {state}") as exc:
            arm.move_joints(target)
        t_raised = arm.clock.now()
        assert isinstance(exc.value, DriveFault) and exc.value.node == "j2" and exc.value.state == state
        t_left = _left_at_s(heard, 2, state)
        assert t_left == pytest.approx(t_sent + 0.2, abs=0.02)
        # the others were quick-stopped within a watch period or two, the move not let run on to a timeout
        stops = {m.arbitration_id - 0x200: t for t, m in heard if 0x201 <= m.arbitration_id <= 0x205
                 and bytes(m.data) == QUICK_STOP_FRAME}
        assert set(stops) == {1, 3, 4, 5} and max(stops.values()) - t_left <= 0.03
        assert t_raised < t_sent + move_s  # before the move would even have ended (timeout: 1.5 x + 1 s)
        assert not [m for t, m in heard if t >= t_left and _host_command(m) and m.arbitration_id & 0x7F == 2]
        mark = len(heard)
        arm.clock.sleep(1.0)
        assert [m for _, m in heard[mark:] if _host_command(m) or m.arbitration_id == HOST_HEARTBEAT_ID] == \
            [m for _, m in heard[mark:] if m.arbitration_id == HOST_HEARTBEAT_ID]  # nothing else sent
    drives = sim_drives.drives
    assert drives["j2"].state == state
    assert all(drives[n].state == "QUICK_STOP_ACTIVE" and drives[n].motion is None for n in ("j1", "j3", "j4"))
    assert sim_drives.positions()["j1"] > target.j1_deg + 1.0  # stopped mid-way
    assert set(arm.faults) == {"j2"}  # the host's own quick stops are no DriveDisabled
    with pytest.raises(FaultLatched, match="j2: .*left OPERATION ENABLED"):
        arm.move_joints(arm.joints())
    arm.reset_faults()
    assert all(s["state"] == "OPERATION_ENABLED" for s in arm.state().values())
    arm.move_joints(target)
    assert sim_drives.positions()["j2"] == pytest.approx(target.j2_deg, abs=1e-3)


def test_an_idle_axis_left_operation_refuses_the_next_command_and_sends_nothing(arm, sim_drives, open_test_bus):
    """j2 quick-stops on its own while the arm stands: the next move raises DriveDisabled before any frame.
    The host's set-point controlword (enable operation + bit 4) used to re-enable such a drive (transition
    16 out of QUICK STOP ACTIVE) behind its back, then time out waiting 1 s for the acknowledge."""
    sim_drives.inject_fault("quick_stop", "j2")
    arm.clock.sleep(0.05)
    with _tap(open_test_bus, arm.clock) as heard:
        with pytest.raises(DriveDisabled, match=r"j2 \(node 2\): left OPERATION ENABLED while idle .* QUICK_STOP"):
            arm.move_joints(_long_move(arm))
        with pytest.raises(FaultLatched, match="j2"):
            arm.gripper.open()
        arm.clock.sleep(0.5)
        assert not [m for _, m in heard if _host_command(m)]
    assert sim_drives.drives["j2"].state == "QUICK_STOP_ACTIVE"
    arm.reset_faults()
    assert sim_drives.drives["j2"].state == "OPERATION_ENABLED"


def test_another_master_quick_stopping_an_axis_in_real_time(open_test_bus, cell_cfg):
    """Wall time, as on the cell: a second master quick-stops j3 mid-move; the host raises well before
    the move's end, and the other axes stand in QUICK STOP ACTIVE."""
    clock = RealClock()
    try:
        with sim.serve(open_test_bus(), cell_cfg, clock=clock) as drives, \
                Arm(open_test_bus(), cell_cfg, clock=clock, sdo_timeout_s=0.5) as arm:
            target = _long_move(arm)
            move_s = arm.move_time_s(arm.joints(), target)
            arm.move_joints(target, wait=False)
            other_master = open_test_bus()
            other_master.send(can.Message(arbitration_id=0x203, data=QUICK_STOP_FRAME, is_extended_id=False))
            t0 = time.monotonic()
            with pytest.raises(DriveDisabled, match=r"j3 \(node 3\).* QUICK_STOP_ACTIVE"):
                arm.wait_idle()
            assert time.monotonic() - t0 < move_s + 1.0  # a MoveTimeout would come after 1.5 x move_s + 1 s
            assert {drives.drives[n].state for n in ("j1", "j2", "j4", "gripper")} == {"QUICK_STOP_ACTIVE"}
    finally:
        clock.close()


def _stopped_mid_ramp(arm, sim_drives):
    """j1 cruising, then quick-stopped from the drive's side; returns j1's ramp time left (s)."""
    start = arm.joints()
    arm.move_joints(Joints(start.j1_deg - 100.0, start.j2_deg, start.j3_mm, start.j4_deg), wait=False)
    arm.clock.sleep(0.4)  # cruising at 180 deg/s: the quick stop ramp takes 0.125 s
    sim_drives.inject_fault("quick_stop", "j1")
    arm.clock.sleep(0.02)
    m = sim_drives.drives["j1"].motion
    assert m is not None and m.stopping
    return m.t0_s + m.profile.duration_s - arm.clock.now()


@pytest.mark.parametrize(("quick_stop_code", "through"), [(6, "QUICK_STOP_ACTIVE"), (2, "SWITCH_ON_DISABLED")])
def test_axis_enable_out_of_quick_stop_waits_for_the_end_of_the_ramp(
    sim_drives, open_test_bus, sim_clock, cell_cfg, quick_stop_code, through
):
    """Axis.enable() alone (not the arm's wait): from QUICK STOP ACTIVE while the axis still ramps it
    waits on the clock for bit 10 (0x605A = 6, then transition 16) or SWITCH ON DISABLED (2, then the
    walk from there), and enables where the axis stands, the target set there. It used to send enable
    operation at once and wait 1 s of wall time for a state that needs simulated time to come."""
    sim_drives.configure_option_codes(values={0x605A: quick_stop_code}, accepted={0x605A: {quick_stop_code}})
    with Arm(open_test_bus(), cell_cfg, clock=sim_clock) as arm, _tap(open_test_bus, sim_clock) as heard:
        ramp_left_s = _stopped_mid_ramp(arm, sim_drives)
        assert ramp_left_s > 0.05
        t0 = sim_clock.now()
        arm.axes["j1"].enable()
        j1 = sim_drives.drives["j1"]
        assert j1.state == "OPERATION_ENABLED" and j1.motion is None
        assert sim_clock.now() - t0 >= ramp_left_s
        assert j1._get(0x607A) == round(j1.position_counts)  # enabling never jumps
        assert through in {codec.unpack_tpdo1(m.data).state for _, m in heard if m.arbitration_id == 0x181}
        before = j1.position()
        sim_clock.sleep(0.2)
        assert j1.position() == before


def test_axis_enable_gives_up_on_a_quick_stop_that_never_ends(sim_drives, open_test_bus, sim_clock, cell_cfg):
    with Arm(open_test_bus(), cell_cfg, clock=sim_clock) as arm:
        _stopped_mid_ramp(arm, sim_drives)
        with pytest.raises(DriveFault, match=r"j1 \(node 1\): still in QUICK STOP ACTIVE 0.05 s on .*bit 10 clear"):
            arm.axes["j1"].enable(quick_stop_timeout_s=0.05)


def test_axis_enable_while_the_axis_coasts_waits_on_the_clock_for_standstill(sim_drives, open_test_bus, sim_clock,
                                                                                cell_cfg):
    """STO mid-move (SWITCH ON DISABLED, the axis coasts), then Axis.enable(): the drive holds enable operation
    until the axis stands, and the host waits for that on the clock. It used to wait 1 s of wall time, in
    which simulated time does not move, and raise NodeSilent."""
    with Arm(open_test_bus(), cell_cfg, clock=sim_clock) as arm, _tap(open_test_bus, sim_clock) as heard:
        start = arm.joints()
        arm.move_joints(Joints(start.j1_deg - 100.0, start.j2_deg, start.j3_mm, start.j4_deg), wait=False)
        arm.clock.sleep(0.4)  # cruising at 180 deg/s: coasting (0.5 x 720 deg/s^2) takes 0.5 s
        sim_drives.inject_fault("disable", "j1")
        arm.clock.sleep(0.02)
        j1 = sim_drives.drives["j1"]
        assert j1.state == "SWITCH_ON_DISABLED" and j1.motion is not None and j1.motion.coasting
        coast_left_s = j1.motion.t0_s + j1.motion.profile.duration_s - sim_clock.now()
        assert coast_left_s > 0.3
        t0 = sim_clock.now()
        arm.axes["j1"].enable()
        assert j1.state == "OPERATION_ENABLED" and j1.motion is None
        assert sim_clock.now() - t0 >= coast_left_s
        assert j1._get(0x607A) == round(j1.position_counts)  # enabling never jumps
        # it reported SWITCHED ON, holding the command, while the axis ran out
        assert "SWITCHED_ON" in {codec.unpack_tpdo1(m.data).state for t, m in heard if m.arbitration_id == 0x181
                                 and t >= t0}
        before = j1.position()
        sim_clock.sleep(0.2)
        assert j1.position() == before
