"""The axes of a move start together (cell file `can.coordinated_start`, default true): each takes its
set-point under halt (controlword bit 8), and once all have acknowledged, the halts are released back to
back. The way check (drivers.limits) has every axis start at once; started one after another, each axis
began a handshake's round trips after the one before, and ran on alone while a later drive did not
acknowledge. Through the real stack: python-can's virtual bus and the simulated drives."""

from __future__ import annotations

import dataclasses

import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints
from drivers import Arm, NodeSilent, codec
from drivers.simdrive import SimDrive

pytestmark = needs_sim

MOVED = ("j1", "j2", "j4")


def _target(start: Joints) -> Joints:
    return Joints(start.j1_deg + 20.0, start.j2_deg - 15.0, start.j3_mm, start.j4_deg + 30.0)


@pytest.fixture
def starts(monkeypatch):
    """Each simulated drive's motion start: (drive, the moved axes holding a set-point under halt then)."""
    seen = []
    real = SimDrive._start_move

    def start_move(drive, *a):
        holding = {d.name for d in drive_registry if d.halted is not None and d.name in MOVED}
        seen.append((drive.name, holding))
        real(drive, *a)

    drive_registry = []
    monkeypatch.setattr(SimDrive, "_start_move", start_move)
    return seen, drive_registry


def _host_controlwords(messages, cell):
    """(node name, controlword) of every RPDO1 the host sent, in order, and the other host frames' places."""
    by_rpdo1 = {codec.RPDO1_BASE + n.node_id: name for name, n in cell.can.nodes.items()}
    out = []
    for m in messages:
        if m.arbitration_id in by_rpdo1:
            out.append((by_rpdo1[m.arbitration_id], int.from_bytes(m.data[:2], "little")))
        elif m.arbitration_id < 0x180 or 0x200 <= m.arbitration_id < 0x580 or 0x600 <= m.arbitration_id < 0x680:
            out.append((None, m.arbitration_id))  # another frame of the host's (target, SDO, NMT)
    return out


def _drain(bus):
    messages = []
    while (m := bus.recv(0)) is not None:
        messages.append(m)
    return messages


def test_no_axis_starts_before_every_axis_holds_its_set_point(arm, sim_drives, starts):
    seen, registry = starts
    registry.extend(sim_drives.drives.values())
    start = arm.joints()
    sent = arm.move_joints(_target(start))
    assert [name for name, _ in seen] == list(MOVED)  # in the order released
    for name, holding in seen:
        # when each started, every axis not yet started held its set-point under halt
        started_before = {n for n, _ in seen[:[s for s, _ in seen].index(name)]}
        assert holding | started_before | {name} == set(MOVED), (name, holding)
    assert arm.joints().as_array() == pytest.approx(sent.as_array(), abs=2e-3)


def test_the_releases_follow_each_other_after_every_acknowledge(arm, sim_drives, open_test_bus):
    spy = open_test_bus()
    start = arm.joints()
    _drain(spy)
    arm.move_joints(_target(start))
    frames = _host_controlwords(_drain(spy), arm.cell)
    enable, halt, new = codec.CW_ENABLE_OPERATION, codec.CW_HALT, codec.CW_NEW_SET_POINT
    releases = [i for i, (name, cw) in enumerate(frames) if name in MOVED and cw == enable]
    # one release per moved axis, back to back (no other host frame between), the last frames of the move
    assert [frames[i][0] for i in releases] == list(MOVED)
    assert releases == list(range(releases[0], releases[0] + len(MOVED)))
    assert releases[-1] == len(frames) - 1
    # before them each axis took its set-point with the halt bit set, and cleared bit 4 keeping the halt
    armed = [(name, cw) for name, cw in frames[:releases[0]] if name in MOVED]
    assert armed == [(n, cw) for n in MOVED for cw in (enable | new | halt, enable | halt)]
    assert all(name not in ("j3", "gripper") for name, _ in frames if name)  # axes that stay are not touched


def test_a_drive_that_never_acknowledges_leaves_every_axis_standing(arm, sim_drives):
    """Started one after another, j1 ran its whole move while the host waited for j2's acknowledge."""
    sim_drives.inject_fault("ignore_set_point", "j2")
    start = sim_drives.positions()
    joints = arm.joints()
    with pytest.raises(NodeSilent, match=r"j2 \(node 2\): no answer \(set-point acknowledge under halt; a drive "
                                         r"that takes no set-point while halted needs can.coordinated_start false\)"):
        arm.move_joints(Joints(joints.j1_deg - 40.0, joints.j2_deg - 30.0, joints.j3_mm, joints.j4_deg))
    arm.clock.sleep(1.0)
    assert sim_drives.positions() == pytest.approx(start, abs=1e-9)  # j1 had its set-point: it never ran it
    assert sim_drives.drives["j1"].halted is None  # the quick stop dropped it: no later release can start it


def test_without_coordinated_start_each_axis_starts_at_its_own_handshake(sim_drives, open_test_bus, sim_clock,
                                                                         cell_cfg, starts):
    cell = dataclasses.replace(cell_cfg, can=dataclasses.replace(cell_cfg.can, coordinated_start=False))
    arm = Arm(open_test_bus(), cell, clock=sim_clock, sdo_timeout_s=1.0)
    arm.connect()
    try:
        seen, registry = starts
        registry.extend(sim_drives.drives.values())
        spy = open_test_bus()
        start = arm.joints()
        sent = arm.move_joints(_target(start))
        assert [name for name, _ in seen] == list(MOVED)
        assert all(not holding for _, holding in seen)  # nothing held under halt: j1 ran before j2 had a set-point
        assert not any(cw & codec.CW_HALT for name, cw in _host_controlwords(_drain(spy), cell) if name)
        assert arm.joints().as_array() == pytest.approx(sent.as_array(), abs=2e-3)
    finally:
        arm.disconnect()


def test_a_move_of_one_axis_is_not_held_under_halt(arm, sim_drives, open_test_bus):
    spy = open_test_bus()
    start = arm.joints()
    _drain(spy)
    arm.move_joints(Joints(start.j1_deg, start.j2_deg, start.j3_mm - 10.0, start.j4_deg))
    assert not any(cw & codec.CW_HALT for name, cw in _host_controlwords(_drain(spy), arm.cell) if name)
    assert arm.joints().j3_mm == pytest.approx(start.j3_mm - 10.0, abs=2e-3)


@pytest.mark.parametrize("value", [1, 0, "yes", None, "true"])
def test_the_cell_file_takes_only_true_or_false(tmp_path, capsys, value):
    import json

    from conftest import run_cli

    from cell.cellconfig import default_cell_path, load_cell
    from cell.errors import BadInput

    raw = json.loads(default_cell_path().read_text())
    raw["can"]["coordinated_start"] = value
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(raw))
    with pytest.raises(BadInput, match=r"can.coordinated_start must be true or false, got"):
        load_cell(path)
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", str(path), capsys=capsys)
    assert code == 2 and "can.coordinated_start must be true or false" in err and "Traceback" not in err
    raw["can"]["coordinated_start"] = False
    path.write_text(json.dumps(raw))
    assert load_cell(path).can.coordinated_start is False
    del raw["can"]["coordinated_start"]
    path.write_text(json.dumps(raw))
    assert load_cell(path).can.coordinated_start is True


def _arming_hook(monkeypatch, node: str, action):
    """Run `action` when the arm starts to arm `node` (the axes before it hold their set-points)."""
    from drivers.axis import Axis

    real = Axis.arm_move

    def arm_move(ax, counts):
        if ax.name == node:
            action()
        return real(ax, counts)

    monkeypatch.setattr(Axis, "arm_move", arm_move)


def test_an_armed_axis_stopped_from_its_side_is_not_re_enabled_by_the_release(arm, sim_drives, monkeypatch):
    """j1 holds its set-point when its quick stop input trips: the release (enable operation) would have taken
    it out of QUICK STOP ACTIVE without its set-point, and j2 ran its whole move alone."""
    from drivers import DriveDisabled

    _arming_hook(monkeypatch, "j2", lambda: sim_drives.inject_fault("quick_stop", "j1"))
    start = sim_drives.positions()
    joints = arm.joints()
    with pytest.raises(DriveDisabled, match=r"j1 \(node 1\): left OPERATION ENABLED while its set-point waited"):
        arm.move_joints(Joints(joints.j1_deg - 30.0, joints.j2_deg - 20.0, joints.j3_mm, joints.j4_deg))
    arm.clock.sleep(0.5)
    assert sim_drives.positions() == pytest.approx(start, abs=1e-9)
    assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"  # left as its side stopped it


def test_a_drive_that_does_not_run_its_set_point_at_the_release_stops_the_others(arm, sim_drives, monkeypatch):
    """A drive that takes a set-point under halt but forgets it at the release (the behaviour is the drive
    maker's): the host sees no start and stops every axis, before the others ran their moves alone."""
    real = SimDrive._resume

    def forgets(drive):
        if drive.name == "j2":
            drive.halted = None
            return None
        return real(drive)

    monkeypatch.setattr(SimDrive, "_resume", forgets)
    start = sim_drives.positions()
    joints = arm.joints()
    with pytest.raises(NodeSilent, match=r"j2 \(node 2\): no answer \(start of the set-point at the halt's release; "
                                         r"a drive that does not run a set-point taken under halt needs "
                                         r"can.coordinated_start false\) within 0.2 s"):
        arm.move_joints(Joints(joints.j1_deg - 30.0, joints.j2_deg - 20.0, joints.j3_mm, joints.j4_deg))
    assert set(arm.faults) == {"j2"}
    arm.clock.sleep(0.5)
    stood = sim_drives.positions()
    assert stood["j2"] == pytest.approx(start["j2"], abs=1e-9)
    assert abs(stood["j1"] - start["j1"]) < 0.5  # j1 started with the release and was stopped at once


def test_an_interrupt_while_the_axes_take_their_set_points_leaves_none_armed(arm, sim_drives, monkeypatch):
    from drivers import FaultLatched

    def interrupt():
        raise KeyboardInterrupt

    _arming_hook(monkeypatch, "j2", interrupt)
    joints = arm.joints()
    with pytest.raises(KeyboardInterrupt):
        arm.move_joints(Joints(joints.j1_deg - 30.0, joints.j2_deg - 20.0, joints.j3_mm, joints.j4_deg))
    assert sim_drives.drives["j1"].halted is None  # j1 had its set-point: the quick stop dropped it
    assert "stop" in arm.faults
    with pytest.raises(FaultLatched):
        arm.move_joints(joints)


@pytest.mark.parametrize("error", [KeyboardInterrupt, RuntimeError])
def test_an_interrupt_while_the_host_waits_for_a_move_stops_every_axis(arm, sim_drives, monkeypatch, error):
    """Ctrl-C during the move, or an error in a look at the drives: the axes do not run on while it goes up
    (before, they ran to their targets unless the caller stopped them); the stop is latched."""
    from drivers import Arm, FaultLatched

    watch, looks = Arm._watch, []

    def fails_mid_move(self, stops=False):
        looks.append(self.clock.now())
        if len(looks) == 20:  # 0.2 s into the move (a poll is 10 ms)
            raise error("interrupted")
        return watch(self, stops)

    monkeypatch.setattr(Arm, "_watch", fails_mid_move)
    joints = arm.joints()
    target = Joints(joints.j1_deg - 60.0, joints.j2_deg - 40.0, joints.j3_mm, joints.j4_deg)
    with pytest.raises(error):
        arm.move_joints(target)
    arm.clock.sleep(1.0)  # a move of this length takes about 0.6 s more
    stood = arm.joints()
    assert {n: d.state for n, d in sim_drives.drives.items() if n != "gripper"} == dict.fromkeys(
        ("j1", "j2", "j3", "j4"), "QUICK_STOP_ACTIVE")
    assert 5.0 < joints.j1_deg - stood.j1_deg < 55.0  # stopped on the way, short of the target
    assert "stop" in arm.faults
    with pytest.raises(FaultLatched):
        arm.move_joints(joints)


def test_an_interrupt_during_one_by_one_starts_stops_the_axis_already_running(sim_drives, open_test_bus, sim_clock,
                                                                               cell_cfg, monkeypatch):
    """Without coordinated start each axis starts at its own handshake: a Ctrl-C at j2's leaves j1 running
    unless the start is stopped as a whole (before, j1 ran on to its target with no stop latched)."""
    from drivers import FaultLatched
    from drivers.axis import Axis

    cell = dataclasses.replace(cell_cfg, can=dataclasses.replace(cell_cfg.can, coordinated_start=False))
    arm = Arm(open_test_bus(), cell, clock=sim_clock, sdo_timeout_s=1.0)
    arm.connect()
    try:
        real = Axis.start_move

        def start_move(ax, counts):
            if ax.name == "j2":
                raise KeyboardInterrupt
            return real(ax, counts)

        monkeypatch.setattr(Axis, "start_move", start_move)
        joints = arm.joints()
        with pytest.raises(KeyboardInterrupt):
            arm.move_joints(Joints(joints.j1_deg - 60.0, joints.j2_deg - 20.0, joints.j3_mm, joints.j4_deg))
        arm.clock.sleep(1.0)
        assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
        assert abs(joints.j1_deg - arm.joints().j1_deg) < 10.0  # stopped near where it started, not at -60
        assert "stop" in arm.faults
        with pytest.raises(FaultLatched):
            arm.move_joints(joints)
    finally:
        arm.disconnect()


def test_a_second_interrupt_during_the_stop_still_stops_every_axis_and_latches(arm, sim_drives, monkeypatch):
    """Ctrl-C mid-move, then again between two axes' quick stops: every axis still gets its quick stop and the
    stop is latched (before, the second one left j2 running and nothing latched: the next move was taken)."""
    from drivers import Arm, FaultLatched
    from drivers.axis import Axis

    watch, looks = Arm._watch, []

    def interrupted(self, stops=False):
        looks.append(stops)
        if looks.count(True) == 20:
            raise KeyboardInterrupt
        return watch(self, stops)

    send, sent = Axis.send_quick_stop, []

    def send_quick_stop(ax):
        sent.append(ax.name)
        if len(sent) == 1:
            raise KeyboardInterrupt  # the second Ctrl-C, as j1's quick stop goes out
        return send(ax)

    monkeypatch.setattr(Arm, "_watch", interrupted)
    monkeypatch.setattr(Axis, "send_quick_stop", send_quick_stop)
    joints = arm.joints()
    with pytest.raises(KeyboardInterrupt):
        arm.move_joints(Joints(joints.j1_deg - 60.0, joints.j2_deg - 40.0, joints.j3_mm, joints.j4_deg))
    assert sent == ["j1", "j2", "j3", "j4", "gripper"]
    monkeypatch.setattr(Axis, "send_quick_stop", send)
    arm.clock.sleep(1.0)
    assert sim_drives.drives["j2"].state == "QUICK_STOP_ACTIVE"
    assert "stop" in arm.faults
    with pytest.raises(FaultLatched):
        arm.move_joints(joints)


@pytest.mark.parametrize("coordinated", [True, False])
def test_an_axis_stopped_from_its_side_as_the_command_begins_is_caught_before_its_handshake(
        sim_drives, open_test_bus, sim_clock, cell_cfg, monkeypatch, coordinated):
    """j2's quick stop input opens after the command's look at the idle drives, while it reads the joints and
    writes the speeds (SDO round trips on a real bus): before j2's handshake the host stops and says so (before,
    the handshake's enable operation re-enabled j2 without its set-point, and the move failed a second later
    blaming coordinated start)."""
    from drivers import DriveDisabled

    cell = dataclasses.replace(cell_cfg, can=dataclasses.replace(cell_cfg.can, coordinated_start=coordinated))
    arm = Arm(open_test_bus(), cell, clock=sim_clock, sdo_timeout_s=1.0)
    arm.connect()
    try:
        start = arm.joints()
        joints, fired = Arm.joints, []

        def joints_then_stopped(self):
            out = joints(self)
            if not fired:
                fired.append(True)
                sim_drives.inject_fault("quick_stop", "j2")
                sim_clock.settle()
            return out

        monkeypatch.setattr(Arm, "joints", joints_then_stopped)
        with pytest.raises(DriveDisabled, match=r"^j2 \(node 2\): left OPERATION ENABLED while the axes took their "
                                                r"set-points without a fault, now in QUICK_STOP_ACTIVE"):
            arm.move_joints(Joints(start.j1_deg + 20.0, start.j2_deg - 15.0, start.j3_mm, start.j4_deg + 30.0))
        assert sim_drives.drives["j2"].state == "QUICK_STOP_ACTIVE"  # not re-enabled
        assert set(arm.faults) == {"j2"}
    finally:
        arm.disconnect()
