"""Fault injection against the simulated drives (simulated time): every fault names its node
and reason, stops the move on every axis, and nothing moves again until reset_faults()."""

from __future__ import annotations

import can
import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints
from drivers import Arm, BusFault, DriveFault, FaultLatched, NodeSilent, SdoError, sim

pytestmark = needs_sim


def _long_move(arm):
    s = arm.joints()
    return Joints(s.j1_deg - 40.0, s.j2_deg - 30.0, s.j3_mm - 50.0, s.j4_deg + 90.0)


def _assert_frozen(arm, sim_drives, seconds=0.5):
    """Nothing moves: the drives' positions stay put while time passes."""
    before = sim_drives.positions()
    arm.clock.sleep(seconds)
    assert sim_drives.positions() == before


def _assert_recovers(arm, sim_drives):
    arm.reset_faults()
    assert arm.faults == {}
    assert all(s["state"] == "OPERATION_ENABLED" for s in arm.state().values())
    start = arm.joints()
    target = Joints(start.j1_deg + 3.0, start.j2_deg, start.j3_mm, start.j4_deg)
    arm.move_joints(target)
    assert sim_drives.positions()["j1"] == pytest.approx(target.j1_deg, abs=1e-3)


def test_emcy_during_a_move_stops_every_axis_and_names_the_node(arm, sim_drives):
    target = _long_move(arm)
    sim_drives.inject_fault("emcy", "j2", code=0x2310, after_s=0.1)
    with pytest.raises(DriveFault, match=r"j2 \(node 2\).*0x2310.*over-current") as exc:
        arm.move_joints(target)
    assert exc.value.node == "j2" and exc.value.emcy_code == 0x2310
    st = arm.state()
    assert st["j2"]["state"] == "FAULT" and st["j2"]["emcy"]["code"] == 0x2310
    # the other axes were quick-stopped mid-way
    assert st["j1"]["state"] == "QUICK_STOP_ACTIVE"
    assert sim_drives.positions()["j1"] > target.j1_deg + 1.0
    _assert_frozen(arm, sim_drives)
    with pytest.raises(FaultLatched, match="j2"):
        arm.move_joints(arm.joints())
    with pytest.raises(FaultLatched):
        arm.gripper.open()
    _assert_recovers(arm, sim_drives)


def test_following_error_faults_with_its_emcy_and_status_bit(arm, sim_drives):
    sim_drives.inject_fault("following_error", "j3", after_s=0.05)
    with pytest.raises(DriveFault, match="j3.*following error") as exc:
        arm.move_joints(_long_move(arm))
    assert exc.value.emcy_code == 0x8611
    assert arm.axes["j3"].status.following_error
    _assert_frozen(arm, sim_drives)
    _assert_recovers(arm, sim_drives)


def test_silent_node_is_detected_by_its_heartbeat_deadline(arm, sim_drives):
    target = _long_move(arm)
    arm.move_joints(target, wait=False)
    sim_drives.inject_fault("silent", "j4")
    with pytest.raises(NodeSilent, match=r"j4 \(node 4\): no heartbeat"):
        arm.wait_idle()
    assert "j4" in arm.faults
    # the drive itself also stopped (it no longer hears the host) and the others were quick-stopped
    assert sim_drives.drives["j4"].state == "FAULT"
    assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
    _assert_frozen(arm, sim_drives)
    with pytest.raises(NodeSilent, match="j4"):
        arm.reset_faults()  # still silent: the reset is refused and the fault stays latched
    assert "j4" in arm.faults
    sim_drives.heal("j4")
    _assert_recovers(arm, sim_drives)


@pytest.mark.parametrize("dead", [("j1", "j2", "j3", "j4", "gripper"), ("j1",)])
def test_a_node_without_an_sdo_answer_names_the_others_silent_with_it(arm, sim_drives, dead):
    """The bus (or the drives' power) gone: the first node asked, j1, gave no SDO answer, and it alone was named,
    which sent the operator to its wiring. The others silent too are named with it; a node silent alone is not
    told about the others."""
    for node in dead:
        sim_drives.inject_fault("silent", node)
    with pytest.raises(SdoError) as raised:
        arm.move_joints(_long_move(arm))
    said = str(raised.value)
    assert said.startswith("j1 (node 1): no SDO answer")
    if len(dead) > 1:
        assert "j2, j3, j4, gripper silent too" in said and "not j1 alone" in said
        assert set(arm.faults) == set(dead)
    else:
        assert "silent too" not in said and set(arm.faults) == {"j1"}


def test_one_dropped_sdo_answer_is_retried(arm, sim_drives):
    sim_drives.inject_fault("drop_sdo", "j1", count=1)
    target = _long_move(arm)
    arm.move_joints(target)
    assert sim_drives.positions()["j1"] == pytest.approx(target.j1_deg, abs=1e-3)
    assert arm.faults == {}


def test_lost_sdo_answers_refuse_the_move_before_anything_moves(arm, sim_drives):
    before = sim_drives.positions()
    sim_drives.inject_fault("drop_sdo", "j2")  # every answer lost until healed
    with pytest.raises(SdoError, match=r"j2 \(node 2\): no SDO answer writing 0x6081"):
        arm.move_joints(_long_move(arm))
    assert sim_drives.positions() == before
    with pytest.raises(FaultLatched, match="j2"):
        arm.move_joints(_long_move(arm))
    sim_drives.heal()
    _assert_recovers(arm, sim_drives)


# a burst (one more than the cell file allows within its window) and a frame saying the host is off the bus
_BUS_FAULTS = [
    ("bus_error", "burst", r"bus: 11 error frames within 1000 ms \(more than can.error_frames_max = 10"),
    ("bus_off", 1, r"bus: error frame bus-off.*off the bus"),
]


def _count(arm, how):
    return arm.cell.can.error_frames_max + 1 if how == "burst" else how


@pytest.mark.parametrize(("error_class", "how", "message"), _BUS_FAULTS)
def test_error_frames_latch_a_bus_fault(arm, sim_drives, error_class, how, message):
    sim_drives.inject_fault("error_frames", count=_count(arm, how), error_class=error_class)
    arm.clock.sleep(0.02)
    assert "bus" in arm.faults and "error frame" in arm.faults["bus"]
    assert arm.error_frames == _count(arm, how)
    with pytest.raises(FaultLatched, match=message):
        arm.move_joints(_long_move(arm))
    _assert_frozen(arm, sim_drives)
    _assert_recovers(arm, sim_drives)


@pytest.mark.parametrize(("error_class", "how", "message"), _BUS_FAULTS)
def test_error_frames_during_a_move_stop_it(arm, sim_drives, error_class, how, message):
    target = _long_move(arm)
    arm.move_joints(target, wait=False)
    arm.clock.sleep(0.1)
    sim_drives.inject_fault("error_frames", count=_count(arm, how), error_class=error_class)
    with pytest.raises(BusFault, match=message):
        arm.wait_idle()
    assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
    assert sim_drives.positions()["j1"] > target.j1_deg + 1.0  # stopped mid-way


def test_drives_stop_when_the_host_falls_silent(arm, sim_drives):
    arm.move_joints(_long_move(arm), wait=False)
    arm.clock.sleep(0.1)
    arm._host_job.cancel()  # the host crashes: its heartbeat stops, nobody stops the drives
    for _ in range(100):  # let simulated time pass without the arm's supervision
        sim_drives.clock.sleep(0.01)
    drives = sim_drives.drives
    assert all(d.state == "FAULT" and d.error_code == 0x8130 for d in drives.values())
    before = sim_drives.positions()
    sim_drives.clock.sleep(1.0)
    assert sim_drives.positions() == before
    assert before["j1"] > _long_move(arm).j1_deg  # stopped mid-way, not at the target


def test_drive_refuses_a_target_outside_its_software_limits(arm, sim_drives):
    # bypass the host's check to test the second line of defence (0x607D in the drive)
    j1 = arm.axes["j1"]
    with pytest.raises(DriveFault, match="j1"):
        j1.start_move(j1.to_counts(arm.cell.scara.j1_deg[1] + 1.0))
    assert sim_drives.drives["j1"].error_code == 0x8612
    arm.clock.sleep(0.02)
    assert "0x8612" in arm.faults["j1"] and "reference limit" in arm.faults["j1"]
    _assert_recovers(arm, sim_drives)


def test_target_without_the_set_point_edge_does_not_move(arm, sim_drives):
    j1 = arm.axes["j1"]
    start = sim_drives.positions()["j1"]
    j1.send_target(j1.to_counts(start + 10.0))
    arm.clock.sleep(0.5)
    assert sim_drives.positions()["j1"] == start
    j1.start_move(j1.to_counts(start + 10.0))  # now with the handshake
    arm.clock.sleep(0.5)
    assert sim_drives.positions()["j1"] == pytest.approx(start + 10.0)


def test_boot_up_deadline(open_test_bus, sim_clock, cell_cfg):
    sim_bus = open_test_bus()
    with sim.serve(sim_bus, cell_cfg, clock=sim_clock) as drives:
        drives.inject_fault("silent", "gripper")
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock, boot_timeout_s=0.5)  # opened after boot-up
        with pytest.raises(NodeSilent, match=r"gripper \(node 5\): no boot-up or heartbeat within 0.5 s"):
            arm.connect()
        assert not arm.is_connected
        assert sim_clock.now() == pytest.approx(0.5, abs=0.01)


def test_drives_faulted_before_connect_stay_latched_until_reset(sim_drives, open_test_bus, sim_clock, cell_cfg):
    first = Arm(open_test_bus(), cell_cfg, clock=sim_clock)
    first.connect()
    first._host_job.cancel()  # the host crashes: the drives fault on their host watch
    sim_clock.sleep(0.6)
    first._pump.stop()  # ... and its process is gone
    assert all(d.state == "FAULT" for d in sim_drives.drives.values())
    with Arm(open_test_bus(), cell_cfg, clock=sim_clock) as arm:  # the host restarts
        assert set(arm.faults) == {"j1", "j2", "j3", "j4", "gripper"}
        assert "error code 0x8130" in arm.faults["j3"]
        assert arm.state()["j3"]["state"] == "FAULT"
        with pytest.raises(FaultLatched, match="0x8130"):
            arm.move_joints(arm.joints())
        _assert_recovers(arm, sim_drives)
    first.disconnect()


def test_following_error_trips_when_the_demand_leaves_the_window(arm, sim_drives):
    window_deg = sim_drives.drives["j1"]._get(0x6065) / 1000.0  # 2 degrees in the EDS
    start = arm.joints()
    sim_drives.inject_fault("following_error", "j1", after_s=0.1)
    with pytest.raises(DriveFault, match="following error"):
        arm.move_joints(Joints(start.j1_deg - 40.0, start.j2_deg, start.j3_mm, start.j4_deg))
    j1 = sim_drives.drives["j1"]
    demand_gap = abs(j1.position() - start.j1_deg)
    assert 0 < demand_gap < 40.0 - window_deg  # jammed early, far from the target


def _stop_while_cruising(arm, sim_drives, stop) -> float:
    """Send a long j1 move without waiting, `stop()` it at cruising speed; assert it ran out on the
    quick-stop ramp (v^2 / 2d = 11.25 deg past where it was stopped); j1's position after it."""
    start = arm.joints()
    arm.move_joints(Joints(start.j1_deg - 100.0, start.j2_deg, start.j3_mm, start.j4_deg), wait=False)
    arm.clock.sleep(0.4)  # cruising at the j1 speed limit
    v = arm.cell.scara.max_velocity["j1"]
    at_stop = sim_drives.positions()["j1"]
    stop()
    stopped = sim_drives.positions()["j1"]
    decel = 2.0 * arm.cell.scara.max_acceleration["j1"]  # QUICK_STOP_DECEL_FACTOR
    assert at_stop - stopped == pytest.approx(v * v / (2 * decel), abs=0.5)
    return stopped


def test_stop_ramps_down_with_the_quick_stop_deceleration(arm, sim_drives):
    _stop_while_cruising(arm, sim_drives, arm.stop)
    assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
    _assert_frozen(arm, sim_drives)
    assert set(arm.faults) == {"stop"}
    with pytest.raises(FaultLatched, match="stop: quick stop requested"):
        arm.move_joints(arm.joints())
    _assert_recovers(arm, sim_drives)


def test_disconnect_during_a_move_stops_it_on_the_ramp_before_disabling(arm, sim_drives):
    """A move sent without waiting, then disconnect: the axis stops on its quick-stop ramp (a real
    drive told to shut down mid-move may coast), then every drive is left without torque."""
    stopped = _stop_while_cruising(arm, sim_drives, arm.disconnect)
    arm.clock.sleep(1.0)
    assert {d.state for d in sim_drives.drives.values()} <= {"READY_TO_SWITCH_ON", "SWITCH_ON_DISABLED"}
    assert sim_drives.positions()["j1"] == stopped


def test_disconnect_after_a_stop_leaves_the_drives_without_torque(arm, sim_drives):
    """Quick stop ACTIVE holds torque, and shutdown is no transition from it: disconnect disables
    voltage there (402 transition 12), so no drive is left holding after the host is gone."""
    arm.stop()
    assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
    arm.disconnect()
    arm.clock.sleep(1.0)
    assert all(d.state == "SWITCH_ON_DISABLED" for d in sim_drives.drives.values())


def test_an_axis_quick_stopped_just_short_of_its_target_has_not_arrived(arm, sim_drives, open_test_bus):
    """Statusword bit 10 also reports the end of a quick stop ramp in QUICK STOP ACTIVE: a move whose
    axis another master quick-stops 3 ms before its end (it stands 1.6 counts short, within the host's
    2-count tolerance, bit 10 set) has not arrived; it ends in DriveDisabled naming the axis and the state
    (was MoveTimeout before the host watched for it), not as a finished move."""
    import can

    from drivers import DriveDisabled

    start = arm.joints()
    arm.move_joints(Joints(start.j1_deg + 5.0, start.j2_deg, start.j3_mm, start.j4_deg), wait=False)
    j1 = sim_drives.drives["j1"]
    arm.clock.advance_to(j1.motion.t0_s + j1.motion.profile.duration_s - 0.003)
    other_master = open_test_bus()
    other_master.send(can.Message(arbitration_id=0x201, data=b"\x02\x00", is_extended_id=False))
    arm.clock.settle()
    arm.clock.sleep(0.05)
    st = arm.axes["j1"].status
    assert st.state == "QUICK_STOP_ACTIVE" and st.target_reached
    assert abs(st.position_counts - arm.axes["j1"].to_counts(start.j1_deg + 5.0)) <= 2
    with pytest.raises(DriveDisabled, match=r"j1 \(node 1\): left OPERATION ENABLED .* QUICK_STOP_ACTIVE"):
        arm.wait_idle()


def test_stop_waits_for_a_quick_stop_ramp_longer_than_two_seconds(open_test_bus, sim_clock, cell_cfg):
    """A slow j1 (4 deg/s^2; the quick stop at 8 deg/s^2 from 20 deg/s takes 2.5 s): stop() returns once
    every axis stands, and reset_faults() enables j1 where it stands (a drive enables a moving axis only
    at standstill). stop() gave up waiting after 2 s while j1 still ran down."""
    import dataclasses

    s = dataclasses.replace(cell_cfg.scara, max_velocity={**cell_cfg.scara.max_velocity, "j1": 30.0},
                            max_acceleration={**cell_cfg.scara.max_acceleration, "j1": 4.0})
    cell = dataclasses.replace(cell_cfg, scara=s)
    with sim.serve(open_test_bus(), cell, clock=sim_clock) as drives, \
            Arm(open_test_bus(), cell, clock=sim_clock) as arm:
        start = arm.joints()
        arm.move_joints(Joints(start.j1_deg - 100.0, start.j2_deg, start.j3_mm, start.j4_deg), wait=False)
        arm.clock.sleep(5.0)  # 20 deg/s at the top of its triangle
        arm.stop()
        assert drives.drives["j1"].motion is None
        assert arm.axes["j1"].status.state == "QUICK_STOP_ACTIVE" and arm.axes["j1"].status.target_reached
        _assert_frozen(arm, drives)
        _assert_recovers(arm, drives)


def test_heal_refuses_an_unknown_node_as_inject_fault_does(sim_drives):
    """A misspelt node healed nobody without a word: the test then ran on with the fault in place."""
    sim_drives.inject_fault("silent", "j4")
    unknown = r"unknown node 'J4'; one of \['gripper', 'j1', 'j2', 'j3', 'j4'\]"
    with pytest.raises(ValueError, match=unknown):
        sim_drives.inject_fault("silent", "J4")
    with pytest.raises(ValueError, match=unknown):
        sim_drives.heal("J4")
    assert sim_drives.drives["j4"].silent  # nothing was healed
    sim_drives.heal("j4")
    assert not sim_drives.drives["j4"].silent



def test_every_drive_watches_the_host_as_soon_as_connect_returns(open_test_bus, sim_clock, cell_cfg):
    """A host gone right after connect, before its next periodic heartbeat, is still caught: connect sends
    one once every 0x1016 is set (CiA 301: a drive watches from the first heartbeat it hears after that).
    With a 1 s host heartbeat and a 0.2 s connect no drive heard one and none watched; with 100 ms, the
    last node configured (the gripper) now and then heard none on a loaded machine (test_can_stall)."""
    import dataclasses

    cell = dataclasses.replace(cell_cfg, can=dataclasses.replace(cell_cfg.can, host_heartbeat_ms=1000))
    with sim.serve(open_test_bus(), cell, clock=sim_clock) as drives:
        arm = Arm(open_test_bus(), cell, clock=sim_clock)
        arm.connect()
        assert sim_clock.now() < 1.0  # connect took less than a host heartbeat period
        arm._host_job.cancel()  # the host is gone
        sim_clock.sleep(3.0 + 0.05)  # its deadline: 3 periods
        assert {n: d.error_code for n, d in drives.drives.items()} == dict.fromkeys(drives.drives, 0x8130)
        arm.disconnect()


def test_two_looks_at_the_drives_at_once_do_not_pass_an_emcy_for_a_poll(arm, open_test_bus, sim_clock, monkeypatch):
    """The watchdog's job and a waiting command both look at the drives. An EMCY (here one the drive sends
    before its statusword says FAULT) that one look has marked seen but not yet latched must not let the other
    look report all well: the looks take turns."""
    import threading

    from drivers import codec

    latch, entered, go = Arm._latch, threading.Event(), threading.Event()

    def slow_latch(self, err, key=None):
        if getattr(err, "emcy_code", None) == 0x2310:
            entered.set()
            go.wait(2.0)  # the first look is between marking the EMCY seen and latching it
        return latch(self, err, key)

    monkeypatch.setattr(Arm, "_latch", slow_latch)
    bus = open_test_bus()
    bus.send(can.Message(arbitration_id=codec.EMCY_BASE + arm.axes["j2"].node_id,
                         data=codec.pack_emcy(codec.Emcy(0x2310, 0x01)), is_extended_id=False))
    sim_clock.settle()
    assert arm.axes["j2"].last_emcy is not None and arm.axes["j2"].state == "OPERATION_ENABLED"
    first = threading.Thread(target=arm._watch)
    first.start()
    assert entered.wait(2.0)
    second_saw = []

    def second_look():
        arm._watch()
        try:
            arm._check_faults(during_move=False)
            second_saw.append("all well")
        except FaultLatched as e:
            second_saw.append(str(e))

    second = threading.Thread(target=second_look)
    second.start()
    second.join(0.2)  # it waits for the first look
    go.set()
    first.join(2.0)
    second.join(2.0)
    assert len(second_saw) == 1 and "EMCY 0x2310" in second_saw[0]


@pytest.mark.parametrize("poll_ms", [10, 200, 500])
def test_a_silent_node_is_found_whatever_the_hosts_poll(poll_ms):
    """The watchdog takes a run that comes late for a held-up host and counts silence from it (heartbeats may
    still be queued behind it). Late was half a deadline (150 ms here): a host polling every 200 ms, which a
    cell file with can.stop_lag_ms 1000 allows, took every run for a late one and never found a node silent."""
    import dataclasses

    from cell.cellconfig import default_cell
    from drivers import simulated_cell

    cell = default_cell()
    cell = dataclasses.replace(cell, can=dataclasses.replace(cell.can, stop_lag_ms=1000))
    with simulated_cell(cell, poll_s=poll_ms / 1000) as (arm, drives):
        arm.clock.sleep(1.0)
        assert arm.faults == {}  # (the others keep beating: no false alarm from the slow poll)
        drives.inject_fault("silent", "j2")
        arm.clock.sleep(3.0)
        assert set(arm.faults) == {"j2"} and "no heartbeat" in arm.faults["j2"]


def test_an_axis_stopped_short_by_an_internal_limit_is_a_fault_not_an_arrival(arm, sim_drives):
    """Bit 11 (internal limit active) with bit 10 ends a move short of its target on a limit switch or a torque
    limit. It was taken for arrival on every axis, as it is for the gripper's jaws on a part: move_joints returned
    the target and J3 stood 40 mm above it."""
    start = arm.joints()
    target = Joints(start.j1_deg, start.j2_deg, start.j3_mm - 60.0, start.j4_deg)  # straight down
    sim_drives.inject_fault("internal_limit", "j3", after_s=0.1)
    with pytest.raises(DriveFault, match=r"j3 \(node 3\): stopped at [\d.]+ mm, short of [\d.]+ mm.*internal limit"):
        arm.move_joints(target)
    assert sim_drives.positions()["j3"] > target.j3_mm + 5.0
    assert "j3" in arm.faults
    _assert_frozen(arm, sim_drives)
    with pytest.raises(FaultLatched, match="j3"):
        arm.move_joints(arm.joints())
    _assert_recovers(arm, sim_drives)


def test_a_drive_another_master_took_out_of_profile_position_gets_no_set_point():
    """A commissioning tool left on the bus writes 0x6060: the host checked the mode only when it enabled the
    drive, and sent its next set-point (controlword bit 4: homing operation start in mode 6) all the same."""
    import canopen

    from drivers import open_bus, simulated_cell
    from drivers.eds import eds_path

    with simulated_cell(channel="another-master") as (arm, drives):
        tool = open_bus("virtual", "another-master")
        net = canopen.Network(tool)
        node = canopen.RemoteNode(2, str(eds_path("j2.eds")))
        net.add_node(node)
        listening = can.Notifier(tool, [net.listeners[0]])
        try:
            node.sdo.RESPONSE_TIMEOUT = 1.0
            node.sdo[0x6060].raw = 0  # no mode
            arm.clock.sleep(0.1)
            before = drives.positions()
            with pytest.raises(DriveFault, match=r"j2 \(node 2\): its mode of operation \(0x6061\) is 0 while idle"):
                arm.move_joints(_long_move(arm))
            assert drives.positions() == before and "j2" in arm.faults
            _assert_recovers(arm, drives)
            assert arm.axes["j2"].status.mode == 1  # the reset put it back in profile position
        finally:
            listening.stop()
            tool.shutdown()
