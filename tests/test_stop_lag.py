"""One axis stopping on its own, the others later. When a drive faults (or its quick stop input opens) its axis
ramps down at once; the host hears of it and stops the others up to can.stop_lag_ms later, and meanwhile they go
on along the move. The arm leaves the coordinated path further than when every axis stops at once (up to 17 mm
past the workspace on 4 % of random ways with 20 ms): the way check (`drivers.limits`) follows these stops too.
The host keeps its side: during a move it looks at the drives every poll, within the lag. Through the real
stack where drives are involved: python-can's virtual bus and the simulated drives."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim, random_way

from cell.cellconfig import QUICK_STOP_DECEL_FACTOR, default_cell, default_cell_path, load_cell
from cell.errors import BadInput
from cell.kinematics import Joints, forward, tool_xy
from drivers import DriveFault, limits
from drivers.axis import Axis
from drivers.profile import (
    _stop_decel,
    _stops,
    coordinated_motion,
    quick_stop_poses_array,
    quick_stop_reach_mm,
    stops_one_first,
)

# accepted when every axis stops at once; J2 faulting on the way with J1 stopped 20 ms later takes the tool
# 8.8 mm past x = 560 mm (found among random ways)
START = Joints(98.0, -101.3, 150.0, 0.0)
TARGET = Joints(-11.7, 48.5, 150.0, 0.0)


def _quick_stops_sent(monkeypatch) -> list:
    """The names of the axes the host sends a quick stop, in order, from now on."""
    sent, send = [], Axis.send_quick_stop
    monkeypatch.setattr(Axis, "send_quick_stop", lambda ax: sent.append(ax.name) or send(ax))
    return sent


def _with_lag(cell, lag_ms: float):
    return dataclasses.replace(cell, can=dataclasses.replace(cell.can, stop_lag_ms=lag_ms))


def test_a_way_whose_stop_with_one_axis_first_leaves_the_workspace_is_refused():
    cell = default_cell()
    assert cell.can.stop_lag_ms == 20
    assert limits.command_violations(_with_lag(cell, 0.0), TARGET, START) == []  # all at once: inside
    problems = limits.command_violations(cell, TARGET, START)
    assert len(problems) == 1
    assert problems[0].startswith("J2 stopping on its own on the way (its fault reaction, its quick stop input) "
                                  "with J1 stopped 20 ms later (can.stop_lag_ms) would take the tool 8.")
    assert "x = 568." in problems[0] and "J1 goes on along the way until the host stops it" in problems[0]
    # the later the host stops J1, the further out
    out_mm = [float(limits.command_violations(_with_lag(cell, lag), TARGET, START)[0].split("take the tool ")[1]
                    .split(" mm")[0]) for lag in (5.0, 20.0, 40.0)]
    assert out_mm[0] < out_mm[1] < out_mm[2]


def test_with_no_lag_one_axis_first_is_every_axis_at_once():
    """The lagged stops' model with a lag of 0 ends where the stop of every axis at once ends."""
    sc = default_cell().scara
    move, t, path, speed = coordinated_motion(sc, START, TARGET, limits.PATH_STEP_DEG)
    rows = np.arange(0, len(t) - 1, 7)
    decel = _stop_decel(sc, QUICK_STOP_DECEL_FACTOR)
    lagged = _stops(move, t.take(rows), (0.0, 0.0), decel, 0.1).reshape(len(rows), -1, 2)
    at_once = quick_stop_poses_array(sc, path.take(rows, 0), speed.take(rows, 0), 0.1, QUICK_STOP_DECEL_FACTOR)
    at_once = at_once.reshape(len(rows), -1, 2)
    assert lagged[:, -1] == pytest.approx(at_once[:, -1], abs=1e-9)
    assert lagged[:, 0] == pytest.approx(path.take(rows, 0)[:, :2], abs=1e-9)


def test_the_other_axis_goes_on_along_the_move_until_its_stop():
    """J1 first: J2's poses during the lag are the move's own, and from the lag on J2 ramps down from the speed
    it has then; J1 ramps from the first moment."""
    sc = default_cell().scara
    move, t, path, speed = coordinated_motion(sc, START, TARGET, limits.PATH_STEP_DEG)
    k = len(t) // 3
    lag = 0.05
    poses = _stops(move, t[k:k + 1], (0.0, lag), _stop_decel(sc, QUICK_STOP_DECEL_FACTOR), 0.01)
    p2, v2 = move.axis_at(1, np.array([t[k] + lag]))
    d2 = _stop_decel(sc, QUICK_STOP_DECEL_FACTOR)[1]
    assert poses[-1, 1] == pytest.approx(p2[0] + np.sign(v2[0]) * v2[0] ** 2 / (2 * d2), abs=1e-9)
    d1 = _stop_decel(sc, QUICK_STOP_DECEL_FACTOR)[0]
    assert poses[-1, 0] == pytest.approx(path[k, 0] + np.sign(speed[k, 0]) * speed[k, 0] ** 2 / (2 * d1), abs=1e-9)
    # the turn of J2 over the lag is the move's (a straight continuation would differ where J2 speeds up)
    assert abs(p2[0] - path[k, 1]) > abs(speed[k, 1]) * lag * 0.5


def test_the_tool_moves_no_further_than_the_bound_the_check_prunes_with():
    """The check follows only the samples whose stops can reach the workspace's edge, by `quick_stop_reach_mm`
    with the lag: on random moves and moments, either axis first, the tool stays within it."""
    cell = default_cell()
    sc = cell.scara
    rng = np.random.default_rng(8)
    for lag in (0.005, 0.02, 0.1):
        for _ in range(60):
            a, b = random_way(rng, sc)
            move, t, path, speed = coordinated_motion(sc, a, b, limits.PATH_STEP_DEG)
            rows = rng.choice(len(t), size=min(5, len(t)), replace=False)
            bound = quick_stop_reach_mm(sc, speed.take(rows, 0), QUICK_STOP_DECEL_FACTOR, lag)
            x0, y0 = tool_xy(path.take(rows, 0), sc)
            for _, poses in stops_one_first(sc, move, t.take(rows), lag, 0.1, QUICK_STOP_DECEL_FACTOR):
                x, y = tool_xy(poses, sc)
                moved = np.hypot(x.reshape(len(rows), -1) - x0[:, None], y.reshape(len(rows), -1) - y0[:, None])
                assert (moved.max(1) <= bound + 1e-9).all(), (a, b, lag)


def test_the_pruned_check_refuses_exactly_what_following_every_sample_refuses():
    cell = default_cell()
    sc, ws = cell.scara, cell.workspace
    rng = np.random.default_rng(12)
    checked = refused = 0
    while checked < 300:
        a, b = random_way(rng, sc)
        tool = forward(a, sc)
        if not ws.contains(tool.x_mm, tool.y_mm) or limits.command_violations(_with_lag(cell, 0.0), b, a):
            continue  # refused for the pose, the path or a stop of every axis at once
        checked += 1
        move, t, _, _ = coordinated_motion(sc, a, b, limits.PATH_STEP_DEG)
        out = any(ws.depth_xy(*tool_xy(p, sc)).min() < 0
                  for _, p in stops_one_first(sc, move, t, 0.02, limits.PATH_STEP_DEG, QUICK_STOP_DECEL_FACTOR))
        assert bool(limits.command_violations(cell, b, a)) == out, (a, b)
        refused += out
    assert refused >= 3  # the lagged stops do refuse ways (about 3 % of these)


def test_the_cell_file_sets_the_lag_within_what_the_host_can_keep(tmp_path):
    raw = json.loads(default_cell_path().read_text())
    for bad, why in ((5, "must be 15 to 1000 ms"), (2000, "must be 15 to 1000 ms"), ("20", "must be a finite number"),
                     (None, "must be a finite number")):
        raw["can"]["stop_lag_ms"] = bad
        path = tmp_path / "cell.json"
        path.write_text(json.dumps(raw))
        with pytest.raises(BadInput, match=rf"can\.stop_lag_ms.*{why}"):
            load_cell(path)
    raw["can"]["stop_lag_ms"] = 50
    path.write_text(json.dumps(raw))
    slow = load_cell(path)
    assert slow.can.stop_lag_ms == 50
    # a host that answers later must refuse more: this way passes with 20 ms
    way = (Joints(-40.1, 32.9, 150.0, 0.0), Joints(23.7, -103.7, 150.0, 0.0))
    assert limits.command_violations(_with_lag(slow, 5.0), way[1], way[0]) == []
    assert "with J1 stopped 50 ms later" in limits.command_violations(slow, way[1], way[0])[0]
    del raw["can"]["stop_lag_ms"]
    path.write_text(json.dumps(raw))
    assert load_cell(path).can.stop_lag_ms == 20  # optional, the default


def test_the_host_refuses_to_poll_slower_than_the_lag_allows(open_test_bus):
    from drivers import Arm

    cell = default_cell()
    with pytest.raises(ValueError, match=r"no more than can\.stop_lag_ms = 20 ms"):
        Arm(open_test_bus(), cell, poll_s=0.02)
    Arm(open_test_bus(), _with_lag(cell, 30), poll_s=0.02)  # a cell file that allows it


@needs_sim
@pytest.mark.parametrize("watchdog", [True, False])
def test_the_host_stops_the_others_within_the_lag_and_they_end_where_the_check_says(
        arm, sim_drives, sim_clock, cell_cfg, monkeypatch, watchdog):
    """J2's drive faults 0.15 s into a fast move and ramps down at once (its fault reaction); the host stops J1
    within a poll (can.stop_lag_ms allows for a poll and the frames), with its watchdog or without: waiting for
    the move, it looks at the drives itself. Both axes end where the check's model of that stop says, for the
    lag the host took."""
    if not watchdog:
        for job in arm._jobs:
            if job.name == "arm-watchdog":
                job.cancel()
    sent = []
    send = Axis.send_quick_stop

    def timed(ax):
        sent.append((ax.name, sim_clock.now()))
        return send(ax)

    monkeypatch.setattr(Axis, "send_quick_stop", timed)
    drive = sim_drives.drives["j2"]
    faulted = []
    fault = type(drive)._fault

    def timed_fault(self, code, **kw):
        faulted.append(sim_clock.now())
        return fault(self, code, **kw)

    monkeypatch.setattr(drive, "_fault", timed_fault.__get__(drive))
    start = arm.joints()
    target = Joints(start.j1_deg + 40.0, start.j2_deg - 90.0, start.j3_mm, start.j4_deg)
    assert not limits.command_violations(cell_cfg, target, start)
    sim_drives.inject_fault("emcy", "j2", code=0x2310, after_s=0.15)
    arm.move_joints(target, wait=False)
    t0 = sim_drives.drives["j1"].motion.t0_s
    assert sim_drives.drives["j2"].motion.t0_s == t0  # the axes started together
    sim_clock.sleep(0.004)  # the host's polls between the drives' ticks (10 ms): it hears of the fault later
    with pytest.raises(DriveFault, match="j2"):
        arm.wait_idle()
    t_fault = faulted[0]
    t_stop = min(t for name, t in sent if name == "j1")
    lag = t_stop - t_fault
    assert 0 < lag <= arm.poll_s + 1e-9 < cell_cfg.can.stop_lag_ms / 1000.0, lag
    stood = arm.joints()
    assert stood.j1_deg != pytest.approx(target.j1_deg, abs=1.0)  # stopped on the way
    move, _, _, _ = coordinated_motion(cell_cfg.scara, start, target, limits.PATH_STEP_DEG)
    end = _stops(move, np.array([t_fault - t0]), (lag, 0.0), _stop_decel(cell_cfg.scara, QUICK_STOP_DECEL_FACTOR),
                 0.1)[-1]
    # (the sim drives count whole counts of 0.001 deg; the move's start was rounded to them)
    assert end == pytest.approx([stood.j1_deg, stood.j2_deg], abs=0.01)
    # the check's model for the lag it allows goes further than this stop did, not less
    worst = _stops(move, np.array([t_fault - t0]), (cell_cfg.can.stop_lag_ms / 1000.0, 0.0),
                   _stop_decel(cell_cfg.scara, QUICK_STOP_DECEL_FACTOR), 0.1)[-1]
    assert abs(worst[0] - start.j1_deg) >= abs(stood.j1_deg - start.j1_deg) - 0.01


@needs_sim
def test_an_axis_stopped_on_its_own_as_its_move_starts_stops_the_others_at_once(arm, sim_drives, sim_clock,
                                                                                monkeypatch):
    """J2's quick stop input opens right after the release, while the host still waits for every axis to
    show it started: the host looks at every drive each poll there too, so it stops the others at once
    (DriveDisabled), instead of waiting out J2's start confirmation (0.2 s) while J1 ran on alone."""
    from drivers import DriveDisabled

    release = Axis.release

    def release_then_stop(ax):
        seq = release(ax)
        if ax.name == "j2":
            sim_clock.settle()  # the drive has taken the release
            sim_drives.inject_fault("quick_stop", "j2")
        return seq

    monkeypatch.setattr(Axis, "release", release_then_stop)
    sent = _quick_stops_sent(monkeypatch)
    start = arm.joints()
    t0 = sim_clock.now()
    with pytest.raises(DriveDisabled, match=r"^j2 \(node 2\): left OPERATION ENABLED as its move started"):
        arm.move_joints(Joints(start.j1_deg + 40.0, start.j2_deg - 90.0, start.j3_mm, start.j4_deg + 30.0))
    assert "j1" in sent and sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
    assert sim_drives.drives["j2"].state == "QUICK_STOP_ACTIVE"
    assert sim_clock.now() - t0 < 0.6  # the stops' ramps, no waiting for a start confirmation first
    assert abs(arm.joints().j1_deg - start.j1_deg) < 0.5  # J1 barely moved


@pytest.mark.parametrize("axis", ["j1", "j2"])
def test_an_axis_stopped_on_its_own_before_its_release_takes_stops_the_others_at_once(arm, sim_drives, sim_clock,
                                                                                    monkeypatch, axis):
    """The axis' quick stop input opens while it stands armed, and the host's release reaches it after: the
    release's enable operation re-enables it (transition 16, 0x605A = 6) without its set-point, and the host
    sees it in OPERATION ENABLED, standing. The host remembers the QUICK STOP ACTIVE it reported meanwhile and
    stops the others at once, instead of waiting out the axis' start confirmation (0.2 s) while they ran."""
    from drivers import DriveDisabled

    release = Axis.release

    def stopped_then_released(ax):
        if ax.name == axis:
            sim_drives.inject_fault("quick_stop", axis)
            sim_clock.settle()  # the host heard QUICK STOP ACTIVE
        seq = release(ax)
        if ax.name == axis:
            sim_clock.settle()  # the drive took the release: OPERATION ENABLED again, standing
            assert sim_drives.drives[axis].state == "OPERATION_ENABLED" and ax.state == "OPERATION_ENABLED"
        return seq

    monkeypatch.setattr(Axis, "release", stopped_then_released)
    sent = _quick_stops_sent(monkeypatch)
    start = arm.joints()
    said = (rf"^{axis} \(node {arm.axes[axis].node_id}\): left OPERATION ENABLED as its move started \(reported "
            r"QUICK_STOP_ACTIVE\) and was enabled again without its set-point")
    # (the code before raised NodeSilent at the start confirmation's timeout; on the simulated clock the others
    # do not move meanwhile, so the error is what tells the two apart)
    with pytest.raises(DriveDisabled, match=said):
        arm.move_joints(Joints(start.j1_deg + 40.0, start.j2_deg - 90.0, start.j3_mm, start.j4_deg + 30.0))
    other = "j2" if axis == "j1" else "j1"
    assert other in sent and sim_drives.drives[other].state == "QUICK_STOP_ACTIVE"
    assert abs(getattr(arm.joints(), f"{other}_deg") - getattr(start, f"{other}_deg")) < 0.5  # barely moved
    assert set(arm.faults) == {axis}


@needs_sim
def test_the_host_reports_looks_at_the_drives_later_than_the_lag_allows(arm, sim_drives, sim_clock):
    """A host that keeps its poll looks at the drives within the lag all through a move; one whose wait falls
    behind (here: polling every 30 ms, as a loaded machine might) is told in `look_timing` and in `cell run`'s
    summary: the way check's stop model did not hold then. The watchdog's looks, still every 10 ms, do not hide
    it: they only latch, the waiting command stops the axes."""
    import io

    from cell.commands.run import _print_summary

    start = arm.joints()
    away = Joints(start.j1_deg + 30.0, start.j2_deg - 30.0, start.j3_mm, start.j4_deg)
    arm.move_joints(away)
    kept = arm.look_timing()
    assert kept["looks"] > 20 and kept["late"] == 0 and 0 < kept["worst_gap_ms"] <= 10.0
    assert kept["allowed_gap_ms"] == 15.0  # can.stop_lag_ms 20 less 5 ms for the frames
    arm.poll_s = 0.03  # (Arm refuses this poll; a host falling behind keeps no poll at all)
    arm.move_joints(start)
    behind = arm.look_timing()
    assert behind["late"] > 5  # (the start confirmation's own looks come sooner)
    assert behind["worst_gap_ms"] == pytest.approx(30.0, abs=0.5)
    summary = {"assembly": "a", "parts_removed": 0, "parts_total": 1, "status": "complete", "grasps": 0,
               "parts": [], "host_looks": behind}
    out = io.StringIO()
    _print_summary(summary, out)
    assert (f"host: {behind['late']} of {behind['looks']} looks at the drives during moves came later than 15 ms "
            "after the one before (worst 30 ms)") in out.getvalue()
    out = io.StringIO()
    _print_summary({**summary, "host_looks": kept}, out)
    assert "host:" not in out.getvalue()


@needs_sim
def test_a_poll_of_exactly_the_allowed_gap_is_on_time(sim_drives, open_test_bus, sim_clock, cell_cfg):
    """At the least lag the cell file allows (15 ms) the allowed gap is the poll (10 ms): looks a poll apart are on
    time, whatever the float sums of the clock say."""
    from drivers import Arm

    arm = Arm(open_test_bus(), _with_lag(cell_cfg, 15.0), clock=sim_clock, sdo_timeout_s=0.2)
    arm.connect()
    try:
        start = arm.joints()
        arm.move_joints(Joints(start.j1_deg + 30.0, start.j2_deg - 30.0, start.j3_mm, start.j4_deg))
        looks = arm.look_timing()
        assert looks["looks"] > 20 and looks["allowed_gap_ms"] == 10.0 and looks["worst_gap_ms"] == 10.0
        assert looks["late"] == 0
    finally:
        arm.disconnect()
