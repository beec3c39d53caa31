"""The way between two poses, checked where every target leaves for the bus (`drivers.limits.path_violations`,
called by `Arm.move_joints`): the tool stays inside the workspace all along the coordinated move, and below the
safe height the arm goes straight up or down, or across at one height. Through the real stack: the simulated
drives on python-can's virtual bus, what they did read back from their positions (TPDO1)."""

from __future__ import annotations

import contextlib
import json
from importlib import resources
from pathlib import Path

import pytest
from conftest import run_cli
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints, forward
from drivers import LimitError, codec
from drivers.errors import DriveFault
from drivers.record import read_log


@contextlib.contextmanager
def targets_sent(bus, node_id: int):
    """The 0x607A targets (counts) sent to node `node_id` while the block runs, heard on `bus` (a tap)."""
    import can

    targets: list[int] = []
    notifier = can.Notifier(bus, [lambda m: targets.append(codec.unpack_target(m.data))
                                  if m.arbitration_id == codec.RPDO2_BASE + node_id else None])
    try:
        yield targets
    finally:
        notifier.stop()


def drives_standing_at(cell_cfg, field: str, limits: tuple[float, float], value: float):
    """The drives' own cell file: `field`'s limits widened to `limits` (so that they may stand there) and their
    home at `value`; the host keeps `cell_cfg`."""
    from dataclasses import replace

    return replace(cell_cfg, scara=replace(cell_cfg.scara, **{field: limits}), motion=replace(
        cell_cfg.motion, home_joints={**cell_cfg.motion.home_joints, field: value}))


pytestmark = needs_sim

HOME = Joints(0.0, 90.0, 200.0, 0.0)
# the first approach of recordings/shipped (the nut, elbow left) from home (elbow right): the elbow flip took
# the tool to x = 573.6 mm, 13.6 mm past the workspace's 560, with both ends inside it
SHIPPED_NUT_APPROACH = Joints(40.693, -97.7142, 150.0, -45.2933)


def _track(cell_arm, target, send=None) -> list[Joints]:
    """Send `target` without waiting (`send`: the arm's move_joints) and read the drives' positions every
    simulated 5 ms until they stand."""
    (send or cell_arm.move_joints)(target, wait=False)
    seen = []
    for _ in range(2000):
        seen.append(cell_arm.joints())
        if all(cell_arm._arrived(cell_arm.axes[n], c) for n, c in cell_arm._pending[0].items()):
            break
        cell_arm.clock.sleep(0.005)
    cell_arm.wait_idle()
    return seen


def _inside(cell, j: Joints) -> bool:
    t = forward(j, cell.scara)
    return cell.workspace.contains(t.x_mm, t.y_mm)


def test_a_move_whose_ends_lie_inside_the_workspace_but_sweeps_out_of_it_is_refused_and_nothing_moves(arm, cell_cfg):
    assert _inside(cell_cfg, HOME) and _inside(cell_cfg, SHIPPED_NUT_APPROACH)
    with pytest.raises(LimitError, match=r"the tool would leave the workspace on the way, at x = 560\.\d"):
        arm.move_joints(SHIPPED_NUT_APPROACH)
    assert arm.faults == {}  # refused before any frame: nothing to stop
    arm.clock.sleep(0.2)
    assert arm.joints() == HOME  # the drives never got a target
    # a swing past the stretched arm at one height, both ends inside (there by a way the check lets through:
    # straight from home, J1 stopping first with J2 20 ms later would take the tool 1.1 mm out)
    from cell.runtime.ways import way_to

    for move in way_to(cell_cfg, HOME, Joints(-50.0, 10.0, 200.0, 0.0), "approach"):
        arm.move_joints(move)
    with pytest.raises(LimitError, match="leave the workspace on the way"):
        arm.move_joints(Joints(40.0, 10.0, 200.0, 0.0))
    assert arm.joints() == Joints(-50.0, 10.0, 200.0, 0.0)


@pytest.mark.parametrize(("start", "target", "needle"), [
    (HOME, Joints(20.0, 60.0, 20.0, 0.0), "J3 goes down from 200.0 to 20.0 mm while the tool travels"),
    (Joints(0.0, 90.0, 20.0, 0.0), Joints(10.0, 80.0, 200.0, 0.0), "J3 goes up from 20.0 to 200.0 mm while the tool"),
    (Joints(0.0, 90.0, 100.0, 0.0), Joints(0.0, 90.0, 20.0, 40.0), "while J4 turns 40.0 deg"),
])
def test_below_the_safe_height_the_arm_never_moves_across_while_going_up_or_down(arm, cell_cfg, start, target, needle):
    for move in (Joints(start.j1_deg, start.j2_deg, 200.0, start.j4_deg), start):  # there, straight down
        arm.move_joints(move)
    with pytest.raises(LimitError, match=needle):
        arm.move_joints(target)
    assert arm.joints() == start


def test_straight_up_and_down_and_across_at_one_height_are_sent(arm, cell_cfg):
    low = Joints(10.0, 80.0, 20.0, 0.0)
    for move in (Joints(10.0, 80.0, 200.0, 0.0), low, Joints(14.0, 77.0, 20.0, 5.0), Joints(14.0, 77.0, 200.0, 5.0)):
        assert arm.move_joints(move) == move
    # a lift from where a drive settled a few counts beside the grasp is straight up
    arm.move_joints(Joints(10.0, 80.0, 200.0, 0.0))
    arm.move_joints(low)
    assert arm.move_joints(Joints(10.004, 79.997, 150.0, 0.002)) == Joints(10.004, 79.997, 150.0, 0.002)


def test_the_routed_way_keeps_the_tool_inside_the_workspace_on_the_drives(arm, cell_cfg):
    from cell.runtime.ways import way_to

    moves = way_to(cell_cfg, HOME, SHIPPED_NUT_APPROACH, "approach")
    assert moves[-1] == SHIPPED_NUT_APPROACH and len(moves) > 1
    seen = [p for m in moves for p in _track(arm, m)]
    assert len(seen) > 50
    worst = max(forward(j, cell_cfg.scara).x_mm for j in seen)
    assert worst <= cell_cfg.workspace.x_mm[1]
    assert all(_inside(cell_cfg, j) for j in seen)


def test_going_home_from_low_on_the_tray_lifts_straight_up_first(arm, cell_cfg):
    from cell.runtime.ways import go_to

    low = Joints(-30.0, 70.0, 15.0, 20.0)
    for move in (Joints(-30.0, 70.0, 200.0, 20.0), low):
        arm.move_joints(move)
    seen = []
    real_move = arm.move_joints

    def tracked(target, *, wait=True):
        seen.extend(_track(arm, target, real_move))
        return target

    arm.move_joints = tracked
    try:
        go_to(arm, HOME)
    finally:
        del arm.move_joints
    assert arm.joints() == HOME
    below = [j for j in seen if j.j3_mm < cell_cfg.motion.safe_z_mm]
    assert below, "the drives were seen below the safe height"
    assert {(j.j1_deg, j.j2_deg, j.j4_deg) for j in below} == {(low.j1_deg, low.j2_deg, low.j4_deg)}


def test_hw_corner_from_a_j4_near_its_limit_takes_the_turn_within_it(tmp_path, capsys, cell_cfg):
    # J4 wrapped to the nearest turn from 355 deg asked for 409.8 deg: 'move refused' and exit 2
    raw = json.loads((Path(str(resources.files("cell"))) / "data" / "default_cell.json").read_text())
    raw["motion"]["home_joints"]["j4_deg"] = 355.0
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(raw))
    for corner in ("far-right", "near-left"):
        code, out, err = run_cli("hw", "corner", "--cell", path, "--simulated-time", "--corner", corner, "--dwell", "0",
                                 "--json", capsys=capsys)
        assert code == 0, err
        got = json.loads(out)
        assert -360.0 <= got["at_corner"]["j4_deg"] <= 360.0
        assert got["back"]["j4_deg"] == pytest.approx(355.0)


def _positions_on_the_bus(log: Path, cell) -> list[Joints]:
    """The arm as its drives reported it (TPDO1 position actual of j1-j4), after every report once all four
    have reported."""
    ids = {n.node_id: j for j, n in cell.can.nodes.items() if j != "gripper"}
    now, out = {}, []
    for msg in read_log(log):
        node = msg.arbitration_id - codec.TPDO1_BASE
        if node in ids and len(msg.data) == 7:
            joint = ids[node]
            now[joint] = codec.unpack_tpdo1(msg.data).position_counts / cell.can.nodes[joint].counts_per_unit
            if len(now) == 4:
                out.append(Joints(now["j1"], now["j2"], now["j3"], now["j4"]))
    return out


def test_cell_run_keeps_the_tool_inside_the_workspace_all_the_way_as_its_drives_report(tmp_path, capsys, cell_cfg):
    # the nut alone, first in the default sequence: its pick has every kind of move the other five have (from home,
    # to the drop-off, home again) and the elbow flip that left the workspace; the whole assembly took 4 x as long
    d = json.loads((Path(str(resources.files("cell"))) / "data" / "assemblies" / "default.json").read_text())
    d["parts"], d["sequence"] = [p for p in d["parts"] if p["id"] == "nut"], ["nut"]
    (tmp_path / "nut.json").write_text(json.dumps(d))
    code, out, err = run_cli("run", tmp_path / "nut.json", "--record", tmp_path / "rec", capsys=capsys)
    assert code == 0, err
    seen = _positions_on_the_bus(tmp_path / "rec" / "can.log", cell_cfg)
    assert len(seen) > 800  # (968: the drives' reports all through the nut's 6 s pick)
    outside = [j for j in seen if not _inside(cell_cfg, j)]
    assert outside == []
    decisions = [json.loads(line) for line in (tmp_path / "rec" / "decisions.jsonl").read_text().splitlines()]
    labels = [c["label"] for d in decisions if d["type"] == "commands" for c in d["commands"]]
    assert "approach (via)" in labels  # the nut's elbow flip went round
    code, out, err = run_cli("replay", tmp_path / "rec", capsys=capsys)
    assert code == 0, err + out


# the hunt's pose: a real arm switched on 0.8 mm outside the workspace (tool at x -28.8, y 450.8)
JUST_OUTSIDE = Joints(130.8, -82.675, 200.0, 0.0)


def test_from_a_start_outside_the_workspace_the_way_back_may_not_go_further_out(cell_cfg):
    """A start outside switched the way's check off: going home from 0.8 mm out swept the tool 119 mm out of the
    workspace on the drives. The way back in may not go further out than it starts; once in, it stays in."""
    import numpy as np

    from drivers.limits import path_violations

    t = forward(JUST_OUTSIDE, cell_cfg.scara)
    assert -0.9 < cell_cfg.workspace.depth_xy(np.array(t.x_mm), np.array(t.y_mm)) < -0.7
    home = Joints.from_dict(cell_cfg.motion.home_joints)
    (why,) = path_violations(cell_cfg, JUST_OUTSIDE, home)
    assert why.startswith("the tool starts 0.8 mm outside the workspace and would go ") and "jog it inside" in why
    # straight back in along J2 (the tool moves inwards) is allowed, and from there home is an ordinary way
    back = Joints(130.8, -84.0, 200.0, 0.0)
    assert _inside(cell_cfg, back) and path_violations(cell_cfg, JUST_OUTSIDE, back) == []
    # further out is refused, also when the way ends inside
    assert "would go" in path_violations(cell_cfg, JUST_OUTSIDE, Joints(131.5, -60.0, 200.0, 0.0))[0]


# 2.5 mm past x = 560 mm; the way to TO_INSIDE comes back in, but J2 stopping on its own (its fault reaction) as it
# starts, with J1 stopped 20 ms later, leaves the tool 3.16 mm out
FURTHER_OUTSIDE = Joints(-1.7, 31.9, 200.0, 0.0)
TO_INSIDE = Joints(-11.2, 87.7, 200.0, -256.5)


def test_a_stop_on_the_way_back_in_may_not_take_the_tool_further_out(cell_cfg):
    """Stops on the way back in were not followed: once the tool was in, a stop had to leave it inside, but
    before, one axis stopping on its own could leave it further out than it started (up to 9.7 mm further over
    random ways from up to 5 mm out). Now such a stop may leave it at most STOP_OUTSIDE_TOL_MM further out; a
    way moving one joint (cell hw jog) keeps its stops on its own arc, so it is always allowed."""
    import dataclasses

    import numpy as np

    from drivers.limits import STOP_OUTSIDE_TOL_MM, path_violations

    t = forward(FURTHER_OUTSIDE, cell_cfg.scara)
    start_depth = float(cell_cfg.workspace.depth_xy(np.array(t.x_mm), np.array(t.y_mm)))
    assert -2.6 < start_depth < -2.4
    (why,) = path_violations(cell_cfg, FURTHER_OUTSIDE, TO_INSIDE)
    assert why.startswith("J2 stopping on its own on the way (its fault reaction, its quick stop input) with J1 "
                          "stopped 20 ms later (can.stop_lag_ms) would take the tool 3.16 mm out of the workspace, "
                          f"further than the {-start_depth + STOP_OUTSIDE_TOL_MM:.3g} mm it may be on its way back in")
    assert why.endswith("jog it inside first, one joint at a time (cell hw jog)")
    # the way itself comes straight back in: with no lag (every axis stopped at once) it is allowed
    no_lag = dataclasses.replace(cell_cfg, can=dataclasses.replace(cell_cfg.can, stop_lag_ms=0.0))
    assert path_violations(no_lag, FURTHER_OUTSIDE, TO_INSIDE) == []
    # one joint at a time, inwards, is allowed: J1, then J2, then on to the target from inside
    j1_in = Joints(FURTHER_OUTSIDE.j1_deg + 10.0, FURTHER_OUTSIDE.j2_deg, 200.0, 0.0)
    assert _inside(cell_cfg, j1_in) and path_violations(cell_cfg, FURTHER_OUTSIDE, j1_in) == []
    j2_in = Joints(FURTHER_OUTSIDE.j1_deg, FURTHER_OUTSIDE.j2_deg + 10.0, 200.0, 0.0)
    assert _inside(cell_cfg, j2_in) and path_violations(cell_cfg, FURTHER_OUTSIDE, j2_in) == []


def test_an_arm_40_mm_outside_the_workspace_is_jogged_back_in_one_step_at_a_time(cell_cfg):
    """J1 = J2 = 0 puts the tool at x = 600 mm, 40 mm past the workspace: every command was refused there, a lift
    and every jog too (their targets still outside), so nothing but hands brought it back. A target outside is
    now allowed where it is no further out than the tool stands; so is the way there."""
    import numpy as np

    from drivers.limits import command_violations

    ws = cell_cfg.workspace

    def depth(j):
        t = forward(j, cell_cfg.scara)
        return float(ws.depth_xy(np.array(t.x_mm), np.array(t.y_mm)))

    here = Joints(0.0, 0.0, 3.0, 0.0)
    assert depth(here) == pytest.approx(-40.0, abs=0.01)
    assert command_violations(cell_cfg, Joints(0.0, 0.0, 8.0, 0.0), here) == []  # a lift
    steps = 0
    while depth(here) < 0:  # J2 10 deg at a time (cell hw jog's largest step)
        back = Joints(here.j1_deg, here.j2_deg + 10.0, here.j3_mm, here.j4_deg)
        nearer = Joints(here.j1_deg, here.j2_deg - 10.0, here.j3_mm, here.j4_deg)
        if here.j2_deg < 0:
            assert depth(back) < depth(here) and "outside the workspace" in command_violations(cell_cfg, back, here)[0]
        assert command_violations(cell_cfg, nearer, here) == [], (here, command_violations(cell_cfg, nearer, here))
        here, steps = nearer, steps + 1
    assert steps == 4 and _inside(cell_cfg, here)
    # past another side is further out too (the nearest side alone let a jog from 40 mm past y = -450 end 33 mm
    # past it and 32 mm past x = -50), and tiny jogs add up to nothing (0.05 mm each took it 4 mm further)
    from cell.kinematics import inverse

    corner = inverse(-10.0, -490.0, 100.0, 0.0, cell_cfg.scara)[0]
    sideways = Joints(corner.j1_deg - 8.5, corner.j2_deg, corner.j3_mm, corner.j4_deg)
    assert "outside the workspace" in command_violations(cell_cfg, sideways, corner)[0]
    nudge = Joints(corner.j1_deg, corner.j2_deg + 0.005, corner.j3_mm, corner.j4_deg)
    t0, t1 = forward(corner, cell_cfg.scara), forward(nudge, cell_cfg.scara)
    if (ws.overshoot_xy(t1.x_mm, t1.y_mm) > ws.overshoot_xy(t0.x_mm, t0.y_mm)).any():
        assert command_violations(cell_cfg, nudge, corner)
    # with no pose to compare with (a first command), a target outside is refused as before
    assert "outside the workspace" in command_violations(cell_cfg, Joints(0.0, -10.0, 3.0, 0.0), None)[0]


def test_an_arm_standing_outside_the_workspace_goes_home_without_going_further_out(open_test_bus, sim_clock, cell_cfg):
    """Through the stack: drives that stand 0.8 mm outside (their own cell file's home), the host's default cell,
    `go_to(home)` (cell hw home, cell run's first move): the way it takes never has the tool further out than at
    the start, as the drives' own positions show (it swept 119 mm out)."""
    from dataclasses import replace

    import numpy as np

    from cell.runtime.ways import go_to
    from drivers import Arm, sim

    drives_cell = replace(cell_cfg, motion=replace(cell_cfg.motion, home_joints=JUST_OUTSIDE.as_dict()))
    ws = cell_cfg.workspace
    with sim.serve(open_test_bus(), drives_cell, clock=sim_clock) as drives:
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock, sdo_timeout_s=1.0)
        arm.connect()
        depths = []

        def probe():
            j = Joints(*(drives.drives[n].position_counts / cell_cfg.can.nodes[n].counts_per_unit
                         for n in ("j1", "j2", "j3", "j4")))
            t = forward(j, cell_cfg.scara)
            depths.append(float(ws.depth_xy(np.array(t.x_mm), np.array(t.y_mm))))

        try:
            sim_clock.every(0.002, probe, name="probe")
            home = Joints.from_dict(cell_cfg.motion.home_joints)
            go_to(arm, home)
            assert arm.joints().rounded(2) == home.rounded(2)
        finally:
            arm.disconnect()
    assert -0.9 < depths[0] < -0.7 and min(depths) >= depths[0] - 0.05 and depths[-1] > 0, (depths[0], min(depths))


def test_a_drive_standing_outside_its_joints_limits_is_not_enabled_and_no_target_goes_out(open_test_bus, sim_clock,
                                                                                         cell_cfg):
    """Enabling sends the axis' position as its target (so that it never jumps): after a coast past J1's limit
    (safe torque off mid-move: 146.3 deg of 132) a reset sent 0x607A = 146.3 deg and enabled J1 without a word.
    Now the drive is left disabled and a fault names where it stands; nothing is sent to it as a target."""

    from drivers import Arm, sim
    from drivers.errors import FaultLatched

    drives_cell = drives_standing_at(cell_cfg, "j1_deg", (-150.0, 150.0), 140.0)
    with sim.serve(open_test_bus(), drives_cell, clock=sim_clock), targets_sent(open_test_bus(), 1) as targets:
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock, sdo_timeout_s=1.0)
        try:
            arm.connect()
            assert "stands at 140.000 deg, outside its limits [-132, 132]; not enabled" in str(arm.faults["j1"])
            assert arm.axes["j1"].state != "OPERATION_ENABLED"
            with pytest.raises(FaultLatched):
                arm.move_joints(HOME)
            with pytest.raises(DriveFault, match="stands at 140.000 deg"):
                arm.reset_faults()
        finally:
            arm.disconnect()
    assert targets == []


def test_a_drive_settled_a_few_counts_past_a_home_at_the_limit_is_enabled_holding_the_limit(open_test_bus, sim_clock,
                                                                                           cell_cfg):
    """The shipped home has J3 at its upper limit, 200 mm: a real drive may come to rest a few counts past it. It is
    enabled (it was refused, and the operator told to move the vertical axis by hand) with the limit as its target,
    not its position, and moves as usual."""
    from dataclasses import replace

    from drivers import Arm, sim

    drives_cell = drives_standing_at(cell_cfg, "j3_mm", (0.0, 205.0), 200.002)
    with sim.serve(open_test_bus(), drives_cell, clock=sim_clock), targets_sent(open_test_bus(), 3) as targets:
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock, sdo_timeout_s=1.0)
        try:
            arm.connect()
            assert arm.faults == {} and arm.axes["j3"].state == "OPERATION_ENABLED"
            arm.move_joints(replace(arm.joints(), j3_mm=190.0))
            assert arm.joints().j3_mm == pytest.approx(190.0, abs=1e-3)
        finally:
            arm.disconnect()
    per_mm = cell_cfg.can.nodes["j3"].counts_per_unit
    assert targets and max(targets) <= 200.0 * per_mm, targets  # nothing past the limit was sent


@pytest.mark.parametrize("node, field, limits, stands, limit", [
    ("j1", "j1_deg", (-150.0, 150.0), 132.4, 132.0),  # the hunter's: J1 0.4 deg past its limit
    ("j3", "j3_mm", (0.0, 205.0), 200.3, 200.0),
])
@pytest.mark.parametrize("wall_time", [False, True])
def test_no_target_past_a_limit_goes_out_while_the_drive_is_enabled(request, open_test_bus, sim_clock, cell_cfg, node,
                                                                    field, limits, stands, limit, wall_time):
    """A drive standing up to 0.5 past a joint's limit is enabled holding the limit; but when the drive took a
    while to answer the enable (in wall time: its next tick), the target was set again where it stood, unclamped
    (0x607A = 132.4 deg of 132, past the drive's own software limit 0x607D)."""

    from drivers import Arm, RealClock, sim

    if wall_time:
        sim_clock = RealClock()
        request.addfinalizer(sim_clock.close)

    drives_cell = drives_standing_at(cell_cfg, field, limits, stands)
    node_id = cell_cfg.can.nodes[node].node_id
    with sim.serve(open_test_bus(), drives_cell, clock=sim_clock), targets_sent(open_test_bus(), node_id) as targets:
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock, sdo_timeout_s=1.0)
        try:
            arm.connect()
            assert arm.faults == {} and arm.axes[node].state == "OPERATION_ENABLED"
            sim_clock.sleep(1.0)
        finally:
            arm.disconnect()
    per_unit = cell_cfg.can.nodes[node].counts_per_unit
    assert targets and max(targets) <= round(limit * per_unit), [t / per_unit for t in targets]


@pytest.mark.parametrize("stands_mm", [80.3, 85.0, -2.0])
def test_jaws_found_outside_their_range_are_enabled_holding_its_end(open_test_bus, sim_clock, cell_cfg, stands_mm):
    """The gripper was enabled with its opening as its target whatever it was: jaws found at 85 mm (range 0 - 80)
    were sent 85. It is enabled holding the end of its range, however far out (a joint further out than 0.5 is
    not enabled; jaws pressed past 0 kept the whole arm off): nothing outside the range is sent."""
    from dataclasses import replace

    from drivers import Arm, sim

    lo, hi = cell_cfg.gripper.opening_mm
    drives_cell = replace(cell_cfg, gripper=replace(cell_cfg.gripper, opening_mm=(-5.0, 90.0)))
    node_id = cell_cfg.can.nodes["gripper"].node_id
    with sim.serve(open_test_bus(), drives_cell, clock=sim_clock) as drives, \
            targets_sent(open_test_bus(), node_id) as targets:
        drives.drives["gripper"].position_counts = round(stands_mm * cell_cfg.can.nodes["gripper"].counts_per_unit)
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock, sdo_timeout_s=1.0)
        try:
            arm.connect()
            assert arm.faults == {} and arm.axes["gripper"].state == "OPERATION_ENABLED"
        finally:
            arm.disconnect()
    per_mm = cell_cfg.can.nodes["gripper"].counts_per_unit
    sent = [t / per_mm for t in targets]
    assert sent and all(lo <= t <= hi for t in sent), sent
