"""Where the arm goes when it is stopped on the way. A quick stop (the operator's stop, a fault the host sees)
ramps each axis down on its own at its quick stop deceleration (0x6085 = 2 x its max acceleration): the axes
do not stop in proportion and the tool leaves the coordinated path. The way check (`drivers.limits`) follows
those stops from every sample of the way: a way whose stop would take the tool out of the workspace is
refused before any frame. The host stops every axis at once (quick stops back to back, confirmations after),
as that check has them. Through the real stack: python-can's virtual bus and the simulated drives."""

from __future__ import annotations

import numpy as np
import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim, random_way

from cell.cellconfig import QUICK_STOP_DECEL_FACTOR, default_cell
from cell.kinematics import Joints, forward, tool_xy
from drivers import LimitError, limits
from drivers.axis import Axis
from drivers.profile import coordinated_motion_array, quick_stop_deg, quick_stop_poses_array

# both ends and the whole coordinated path inside the workspace; stopped at the worst moment, the tool
# ends 8.8 mm past y = 450 mm (found among random moves; J2 stops later than J1 in proportion)
START = Joints(85.0, -100.1, 150.0, 0.0)
TARGET = Joints(4.8, 104.9, 150.0, 0.0)


def _inside(cell, j1, j2) -> np.ndarray:
    x, y = tool_xy(np.column_stack([j1, j2]), cell.scara)
    return cell.workspace.contains_xy(x, y)


def test_a_way_inside_the_workspace_whose_quick_stop_leaves_it_is_refused():
    cell = default_cell()
    samples, _ = coordinated_motion_array(cell.scara, START, TARGET, limits.PATH_STEP_DEG)
    assert _inside(cell, samples[:, 0], samples[:, 1]).all() and _inside(cell, [START.j1_deg], [START.j2_deg])[0]
    problems = limits.command_violations(cell, TARGET, START)
    assert len(problems) == 1
    assert problems[0].startswith("a quick stop on the way would take the tool 8.")
    assert "mm out of the workspace (to x = " in problems[0] and "y = 458." in problems[0]
    assert "each on its own ramp (2 x its max acceleration), off the coordinated path" in problems[0]


def test_the_stops_are_looked_at_where_they_can_reach_the_edge_and_nowhere_is_one_missed():
    """The check follows only the samples whose stop can reach the workspace's edge (a bound on how far the
    tool moves while J1 and J2 stop): on 400 random ways it refuses exactly the ways that following every
    sample's stop refuses."""
    cell = default_cell()
    sc, ws = cell.scara, cell.workspace
    rng = np.random.default_rng(11)
    checked = refused = 0
    while checked < 400:
        a, b = random_way(rng, sc)
        tool = forward(a, sc)
        if not ws.contains(tool.x_mm, tool.y_mm) or limits.command_violations(cell, b, None):
            continue
        samples, speed = coordinated_motion_array(sc, a, b, limits.PATH_STEP_DEG)
        if not _inside(cell, samples[:, 0], samples[:, 1]).all():
            continue  # refused for the path itself
        checked += 1
        every = quick_stop_poses_array(sc, samples, speed, limits.PATH_STEP_DEG, QUICK_STOP_DECEL_FACTOR)
        leaves = not _inside(cell, every[:, 0], every[:, 1]).all()
        said = any(p.startswith("a quick stop") for p in limits.path_violations(cell, a, b))
        assert said == leaves, (a, b)
        refused += said
    assert 2 <= refused <= 40  # the check has something to find on such ways, and lets most through


def test_a_stop_ends_where_each_axis_ramps_down_on_its_own():
    cell = default_cell()
    pose, speed = np.array([[10.0, 20.0, 0, 0]]), np.array([[120.0, -200.0, 0, 0]])
    poses = quick_stop_poses_array(cell.scara, pose, speed, 0.5, QUICK_STOP_DECEL_FACTOR)
    turn = quick_stop_deg(cell.scara, speed, QUICK_STOP_DECEL_FACTOR)[0]
    assert turn == pytest.approx([120.0**2 / (2 * 2 * 720.0), 200.0**2 / (2 * 2 * 960.0)])
    assert poses[0] == pytest.approx([10.0, 20.0]) and poses[-1] == pytest.approx([10.0 + turn[0], 20.0 - turn[1]])
    steps = np.abs(np.diff(poses, axis=0))
    assert steps.max() <= 0.5 + 1e-9  # sampled finely enough
    # J1 (the shorter stop) stands while J2 still turns: not in proportion
    j1_done = np.flatnonzero(np.isclose(poses[:, 0], poses[-1, 0]))[0]
    assert poses[j1_done, 1] != pytest.approx(poses[-1, 1])


@needs_sim
def test_the_simulated_drives_stop_where_the_check_says(arm, sim_drives, cell_cfg):
    """The operator's stop at 0.2 s into a fast move: every axis ends where its own ramp from the speed it had
    takes it (the check's model of a stop), all from one moment of the way. (In simulated time the host's
    stops land at one moment whatever their order: the next test holds the order.)"""
    start = arm.joints()
    target = Joints(start.j1_deg + 30.0, start.j2_deg - 80.0, start.j3_mm, start.j4_deg)
    assert not limits.command_violations(cell_cfg, target, start)
    samples, speed = coordinated_motion_array(cell_cfg.scara, start, target, 0.02)
    ends = samples[:, :2] + np.sign(speed[:, :2]) * quick_stop_deg(cell_cfg.scara, speed, QUICK_STOP_DECEL_FACTOR)
    arm.move_joints(target, wait=False)
    arm.clock.sleep(0.2)
    arm.stop()
    stood = arm.joints()
    assert stood.j1_deg != pytest.approx(target.j1_deg, abs=1.0)  # stopped on the way
    miss = np.hypot(ends[:, 0] - stood.j1_deg, ends[:, 1] - stood.j2_deg).min()
    assert miss < 0.05, miss  # one moment of the way fits both axes' ends


@needs_sim
def test_the_host_sends_every_quick_stop_before_it_waits_for_any_confirmation(arm, sim_drives, monkeypatch):
    events = []
    send, confirm = Axis.send_quick_stop, Axis.confirm_quick_stop

    def sent(ax):
        events.append(("send", ax.name))
        return send(ax)

    def confirmed(ax, *a):
        events.append(("confirm", ax.name))
        return confirm(ax, *a)

    monkeypatch.setattr(Axis, "send_quick_stop", sent)
    monkeypatch.setattr(Axis, "confirm_quick_stop", confirmed)
    start = arm.joints()
    arm.move_joints(Joints(start.j1_deg + 30.0, start.j2_deg - 30.0, start.j3_mm, start.j4_deg), wait=False)
    arm.clock.sleep(0.1)
    arm.stop()
    kinds = [k for k, _ in events]
    assert kinds == ["send"] * 5 + ["confirm"] * 5, events
    assert {n for k, n in events if k == "send"} == {"j1", "j2", "j3", "j4", "gripper"}


@needs_sim
def test_the_arm_refuses_such_a_way_before_any_frame(arm, sim_drives, open_test_bus, cell_cfg):
    from cell.runtime.ways import way_to

    for move in way_to(cell_cfg, arm.joints(), START, "approach"):
        arm.move_joints(move)
    spy = open_test_bus()
    with pytest.raises(LimitError, match=r"move refused, nothing sent: a quick stop on the way would take the tool"):
        arm.move_joints(TARGET)
    arm.clock.sleep(0.2)
    host = [m for m in iter(lambda: spy.recv(0), None)
            if 0x200 <= m.arbitration_id < 0x580 or 0x600 <= m.arbitration_id < 0x680]
    assert host == [] and arm.faults == {}
    assert arm.joints().as_array() == pytest.approx(START.as_array(), abs=2e-3)


def test_a_stop_moves_the_tool_no_further_than_the_bound_the_check_prunes_with():
    """The check follows only the samples whose stop can reach the workspace's edge, by `quick_stop_reach_mm`:
    a bound that is too small would let a stop out unseen. On random poses and speeds up to the limits it
    holds, and it is not loose by more than about half (the stops' tool points fill most of it)."""
    from drivers.profile import quick_stop_reach_mm

    cell = default_cell()
    sc = cell.scara
    rng = np.random.default_rng(5)
    n = 500
    pose = np.column_stack([rng.uniform(*sc.j1_deg, n), rng.uniform(*sc.j2_deg, n)])
    speed = np.column_stack([rng.uniform(-1, 1, n) * sc.max_velocity["j1"],
                             rng.uniform(-1, 1, n) * sc.max_velocity["j2"]])
    bound = quick_stop_reach_mm(sc, speed, QUICK_STOP_DECEL_FACTOR)
    ratios = []
    for k in range(n):
        stops = quick_stop_poses_array(sc, pose[k:k + 1], speed[k:k + 1], 0.1, QUICK_STOP_DECEL_FACTOR)
        x, y = tool_xy(stops, sc)
        moved = np.hypot(x - x[0], y - y[0]).max()
        assert moved <= bound[k] + 1e-9, (pose[k], speed[k])
        ratios.append(moved / bound[k])
    assert np.median(ratios) > 0.4
