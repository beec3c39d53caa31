"""A drive that reboots (a power glitch on its supply: boot-up message, then PRE-OPERATIONAL with heartbeats, its
setup back to power-on values, its axis no longer driven) is a fault like a silent one: every axis is stopped at
once, the error says the node rebooted, and reset_faults() sets the node up again as connect did before it enables
it. Before, the host only watched that heartbeats came: J1 and J4 ran their whole moves with J2 coasting (one way
the way check accepted took the tool 284 mm out of the workspace), the error was a MoveTimeout a second later, and
the reset enabled J2 with its host-heartbeat watch (0x1016) gone: on a host crash it ran its move to the end.

The reboot is the simulated drive's own (`inject_fault("reboot")`, as on a power glitch: its power-on values, the
boot-up message, PRE-OPERATIONAL), and, for drives that start themselves after boot, then NMT OPERATIONAL."""

from __future__ import annotations

import contextlib

import can
import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints
from drivers import DriveFault, FaultLatched, NodeRebooted, NodeSilent, codec

pytestmark = needs_sim


def _long_move(arm):
    s = arm.joints()
    return Joints(s.j1_deg - 40.0, s.j2_deg - 30.0, s.j3_mm, s.j4_deg + 30.0)


@pytest.mark.parametrize("auto_start", [False, True])
def test_a_drive_rebooting_mid_move_stops_every_axis_at_once_and_says_it_rebooted(arm, sim_drives, auto_start):
    target = _long_move(arm)
    j1_states = []  # (time, state) of J1's drive, every 10 ms
    job = arm.clock.every(0.01, lambda: j1_states.append((arm.clock.now(), sim_drives.drives["j1"].state)))
    arm.move_joints(target, wait=False)
    arm.clock.sleep(0.25)
    rebooted_s = arm.clock.now()
    sim_drives.inject_fault("reboot", "j2", auto_start=auto_start)
    with pytest.raises(NodeRebooted, match=r"^j2 \(node 2\) rebooted \(boot-up message\): its setup is lost") as e:
        arm.wait_idle()
    job.cancel()
    assert isinstance(e.value, DriveFault) and e.value.node == "j2"
    # J1 quick-stopped within the stop lag the way check allows (20 ms) and a poll, not run on to its target
    stopped_s = next(t for t, state in j1_states if state == "QUICK_STOP_ACTIVE")
    assert stopped_s - rebooted_s <= 0.03 + 1e-9
    assert sim_drives.positions()["j1"] > target.j1_deg + 5.0
    with pytest.raises(FaultLatched, match="j2 rebooted|j2.*rebooted"):
        arm.move_joints(arm.joints())


def test_a_reboot_after_s_into_the_next_move_is_the_drives_own_reset(arm, sim_drives, open_test_bus):
    """The fault kind: `after_s` into the next move the drive resets itself as on a power glitch (nothing on the
    bus asks it to): its boot-up frame, PRE-OPERATIONAL, SWITCH ON DISABLED, its power-on values back (the host's
    0x1016 watch and profile velocity gone), its axis coasting on from where it was."""
    tap = open_test_bus()
    drive = sim_drives.drives["j2"]
    power_on_velocity = drive._power_on[0x6081][0]
    sim_drives.inject_fault("reboot", "j2", after_s=0.2)
    arm.clock.sleep(0.3)
    assert drive.nmt == 0x05  # armed for the next move, not at once
    nmt_states = []  # (time, NMT state of J2's drive), every 10 ms
    job = arm.clock.every(0.01, lambda: nmt_states.append((arm.clock.now(), drive.nmt)))
    started_s = arm.clock.now()
    with pytest.raises(NodeRebooted, match=r"^j2 \(node 2\) rebooted"):
        arm.move_joints(_long_move(arm))
    job.cancel()
    rebooted_s = next(t for t, nmt in nmt_states if nmt != 0x05)
    assert 0.2 <= rebooted_s - started_s <= 0.2 + 0.02 + 1e-9
    frames = []
    while (m := tap.recv(timeout=0)) is not None:
        frames.append((m.arbitration_id, bytes(m.data)))
    assert (codec.HEARTBEAT_BASE + 2, b"\x00") in frames  # its boot-up message
    assert not any(cob == codec.NMT_COB for cob, _ in frames)  # no NMT command brought it
    assert (drive.nmt, drive.state, drive.mode) == (0x7F, "SWITCH_ON_DISABLED", 0)
    assert drive._get(0x1016, 1) == 0 and drive.node.data_store[0x6081][0] == power_on_velocity
    assert drive.motion is None or drive.motion.coasting


def test_a_reboot_while_the_arm_stands_is_latched_and_the_status_no_longer_shown_as_enabled(arm, sim_drives):
    sim_drives.inject_fault("reboot", "j2")
    arm.clock.sleep(0.15)  # a heartbeat (100 ms) after the boot-up message
    assert "rebooted" in arm.faults.get("j2", "")
    row = arm.state()["j2"]
    # PRE-OPERATIONAL: no TPDO, the last status is stale (it said OPERATION_ENABLED beside nmt PRE-OPERATIONAL)
    assert (row["nmt"], row["state"]) == ("PRE-OPERATIONAL", "UNKNOWN")
    with pytest.raises(FaultLatched, match="rebooted"):
        arm.move_joints(Joints(-10.0, 80.0, 200.0, 0.0))


@pytest.mark.parametrize("auto_start", [False, True])
def test_reset_after_a_reboot_sets_the_node_up_again_before_enabling_it(arm, sim_drives, auto_start):
    """After the reset the drive watches the host again (0x1016) and stops on a host crash, and its profile
    velocity is what the host believes (the host's cache of what it wrote skipped writing a velocity the
    drive no longer held: J2 ran the next coordinated move at its power-on speed, off the checked path)."""
    start, there = arm.joints(), Joints(-60.0, 80.0, 200.0, 0.0)  # J1 sets the time: J2 goes slower than its max
    arm.move_joints(there)
    j2 = arm.axes["j2"]
    velocity_counts = j2.sdo_read(0x6081)
    sim_drives.inject_fault("reboot", "j2", auto_start=auto_start)
    arm.clock.sleep(0.05)
    arm.reset_faults()
    assert arm.faults == {}
    assert sim_drives.drives["j2"].nmt == 0x05 and sim_drives.drives["j2"].state == "OPERATION_ENABLED"
    assert j2.sdo_read(0x1016, 1) == arm.axes["j1"].sdo_read(0x1016, 1) != 0
    arm.move_joints(start)  # the same way back: the same coordinated speed for J2
    assert j2.sdo_read(0x6081) == velocity_counts
    # the host crashes mid-move: J2 stops on its own like the others
    arm.move_joints(there, wait=False)
    arm.clock.sleep(0.05)
    arm._host_job.cancel()
    for _ in range(100):
        sim_drives.clock.sleep(0.01)
    assert sim_drives.drives["j2"].state == "FAULT" and sim_drives.drives["j2"].error_code == 0x8130


def test_a_reboot_whose_boot_up_was_lost_is_set_up_again_at_the_reset(arm, sim_drives):
    """J2 rebooted and started itself, and its boot-up message was lost (a bus may lose one frame): its heartbeat
    says OPERATIONAL, so nothing tells the host its setup is gone. The reset reads the host-heartbeat watch back
    and sets it up again; before, it enabled J2 with 0x1016 = 0 (no stop on a host crash)."""
    drive = sim_drives.drives["j2"]
    with drive._lock:  # the reboot without its boot-up frame: resets, then OPERATIONAL as an auto-start drive is
        drive._reset_application()
        drive._reset_communication()
        drive.state, drive.nmt = "SWITCH_ON_DISABLED", 0x05
    arm.clock.sleep(0.1)
    with contextlib.suppress(DriveFault):  # (the host may see the drive leave OPERATION ENABLED)
        arm.move_joints(arm.joints())
    assert drive._get(0x1016, 1) == 0
    arm.reset_faults()
    assert drive._get(0x1016, 1) == arm.axes["j2"].host_watch_entry != 0
    assert drive.state == "OPERATION_ENABLED"


def test_a_drive_that_leaves_operational_on_a_communication_error_is_told_with_its_emcy(arm, sim_drives):
    """CiA 301's default reaction to a communication error (0x1029) takes a drive to PRE-OPERATIONAL after its
    EMCY: the fault names that EMCY, not only "another master's NMT command, or a lost boot-up" (the EMCY was
    marked seen and dropped from the message)."""
    drive = sim_drives.drives["j2"]
    with drive._lock:  # its host-heartbeat watch timed out (as it saw it), and it went PRE-OPERATIONAL at once
        drive.nmt = 0x7F
        drive._report(0x8130)
        drive.network.send_message(codec.HEARTBEAT_BASE + drive.node_id, codec.pack_heartbeat(0x7F))
    arm.clock.sleep(0.1)
    with pytest.raises((DriveFault, FaultLatched), match=r"reports PRE.OPERATIONAL.*0x1029.*its EMCY before: 0x8130"):
        arm.move_joints(arm.joints())


def test_the_grippers_force_is_written_again_after_it_rebooted(arm, sim_drives):
    sim_drives.gripper_object_width_mm = 30.0
    force_n = arm.cell.gripper.grip_force_n / 2
    arm.gripper.grip(30.0, force_n)
    arm.gripper.open()
    sim_drives.inject_fault("reboot", "gripper")  # back to its power-on force
    arm.clock.sleep(0.05)
    arm.reset_faults()
    arm.gripper.grip(30.0, force_n)
    assert sim_drives.drives["gripper"].grip_force_n == pytest.approx(force_n, abs=0.1)


def test_a_node_left_pre_operational_by_another_master_is_a_fault_and_reset_starts_it(arm, sim_drives,
                                                                                     open_test_bus):
    """No boot-up message heard (lost, or another master's NMT): a heartbeat saying PRE-OPERATIONAL from a node
    the host set OPERATIONAL is a fault too: such a node takes no set-point and sends no status."""
    open_test_bus().send(can.Message(arbitration_id=codec.NMT_COB, data=codec.pack_nmt(codec.NMT_PREOP, 3),
                                     is_extended_id=False))
    arm.clock.sleep(0.3)  # a heartbeat period and more
    assert "PRE-OPERATIONAL" in arm.faults.get("j3", "")
    with pytest.raises(FaultLatched, match="j3"):
        arm.move_joints(Joints(-10.0, 80.0, 200.0, 0.0))
    arm.reset_faults()
    assert sim_drives.drives["j3"].nmt == 0x05
    arm.move_joints(Joints(-10.0, 80.0, 190.0, 0.0))
    assert sim_drives.positions()["j3"] == pytest.approx(190.0, abs=1e-3)


def test_a_handshake_with_a_node_not_operational_names_its_nmt_state_not_the_coordinated_start(arm, sim_drives,
                                                                                             monkeypatch):
    """The axis alone (without the arm's gate, which refuses it once the reboot is latched): the handshake's
    timeout said to set can.coordinated_start false, where the node took no PDO at all."""
    sim_drives.inject_fault("reboot", "j2")
    arm.clock.sleep(0.15)
    j2 = arm.axes["j2"]
    monkeypatch.setattr(j2, "move_gate", contextlib.nullcontext)
    with pytest.raises(NodeSilent, match="PRE-OPERATIONAL") as e:
        j2.arm_move(j2.to_counts(70.0))
    assert "coordinated_start" not in str(e.value)


def test_a_node_lost_while_the_jaws_hold_a_part_says_so_and_where_the_arm_stood(arm, sim_drives):
    sim_drives.gripper_object_width_mm = 30.0
    assert arm.gripper.grip(30.0).holding
    sim_drives.inject_fault("reboot", "j2")
    arm.clock.sleep(0.05)
    assert arm.faults["j2"].endswith("; a part may still be in the jaws (they closed on something at 30.0 mm); "
                                     "the arm stood at j1 0.0 deg, j2 90.0 deg, j3 200.0 mm, j4 0.0 deg "
                                     "(tool x 325.0, y 275.0, z 200.0 mm, as last heard)")
    arm.reset_faults()
    arm.gripper.open()  # empty jaws: nothing more to say
    sim_drives.inject_fault("silent", "j4")
    arm.clock.sleep(0.5)
    assert arm.faults["j4"].endswith("(deadline 0.3 s)")


def _connect_with_a_reboot(monkeypatch, sim_drives, open_test_bus, sim_clock, cell_cfg, node: str, when):
    """The real connect with `node` rebooting (its own reset, a power glitch) at the point `when(name, what)` picks:
    what is ('setup', axis being set up), ('write', index) of the node's own SDO writes, or ('start', None) just
    after the node took its NMT start. Returns the arm, connected."""
    from drivers import Arm
    from drivers.axis import Axis

    booted = []

    def reboot_if(name, what):
        if not booted and when(name, what):
            booted.append(what)
            sim_drives.inject_fault("reboot", node)
            sim_clock.settle()  # the host has heard its boot-up message

    configure, sdo_write, nmt = Arm._configure, Axis.sdo_write, Axis.nmt

    def configure_watched(self, ax):
        reboot_if(ax.name, ("setup", ax.name))
        configure(self, ax)

    def sdo_write_watched(self, index, subindex, value):
        reboot_if(self.name, ("write", index))
        sdo_write(self, index, subindex, value)

    def nmt_watched(self, command):
        nmt(self, command)
        if command == codec.NMT_START:
            sim_clock.settle()  # the node took it: OPERATIONAL
            reboot_if(self.name, ("start", None))

    monkeypatch.setattr(Arm, "_configure", configure_watched)
    monkeypatch.setattr(Axis, "sdo_write", sdo_write_watched)
    monkeypatch.setattr(Axis, "nmt", nmt_watched)
    arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock, sdo_timeout_s=1.0)
    arm.connect()
    assert booted, "the reboot never came"
    return arm


def _assert_set_up_as_connect_does(arm, sim_drives, node: str):
    drive, ax = sim_drives.drives[node], arm.axes[node]
    lo, hi = arm.cell.scara.limits(node)
    assert drive._get(0x1016, 1) == ax.host_watch_entry != 0
    assert (drive._get(0x607D, 1), drive._get(0x607D, 2)) == (ax.to_counts(lo), ax.to_counts(hi))
    assert (drive.nmt, drive.state) == (0x05, "OPERATION_ENABLED")
    there = Joints(-10.0, 80.0, 190.0, 10.0)
    arm.move_joints(there)
    assert sim_drives.positions()[node] == pytest.approx(there.j2_deg, abs=1e-3)


@pytest.mark.parametrize("when", [
    ("before its setup", lambda name, what: what == ("setup", "j1")),
    ("within its setup", lambda name, what: name == "j2" and what == ("write", 0x607D)),
    ("after its setup", lambda name, what: what == ("setup", "j3")),
], ids=lambda w: w[0])
def test_a_boot_up_during_connect_before_the_nmt_start_is_no_fault(monkeypatch, sim_drives, open_test_bus, sim_clock,
                                                                    cell_cfg, when):
    """A drive that boots again while the host connects (its power came up meanwhile; a drive that boots twice)
    before the host started it: no fault; where the boot-up came after some of its setup, it is set up again.
    Before, a boot-up after its first SDO write was latched "rebooted" until a reset."""
    arm = _connect_with_a_reboot(monkeypatch, sim_drives, open_test_bus, sim_clock, cell_cfg, "j2", when[1])
    try:
        assert arm.faults == {}
        assert arm.axes["j2"].boot_count == 1  # the one during connect (the first was before the host listened)
        _assert_set_up_as_connect_does(arm, sim_drives, "j2")
    finally:
        arm.disconnect()


def test_a_reboot_after_the_nmt_start_during_connect_says_it_rebooted(monkeypatch, sim_drives, open_test_bus,
                                                                      sim_clock, cell_cfg):
    """After the host started it, a boot-up is a reboot: latched as one, at once (not NodeSilent "heartbeat did
    not report OPERATIONAL within 1 s (last: PRE-OPERATIONAL)" a second later, connect failed), and the reset
    sets it up again."""
    arm = _connect_with_a_reboot(monkeypatch, sim_drives, open_test_bus, sim_clock, cell_cfg, "j2",
                                 lambda name, what: name == "j2" and what == ("start", None))
    try:
        assert sim_clock.now() < 0.5
        assert set(arm.faults) == {"j2"}
        assert arm.faults["j2"].startswith("j2 (node 2) rebooted (boot-up message): its setup is lost")
        assert sim_drives.drives["j2"].nmt == 0x7F  # it lost the start too
        arm.reset_faults()
        assert arm.faults == {}
        _assert_set_up_as_connect_does(arm, sim_drives, "j2")
    finally:
        arm.disconnect()
