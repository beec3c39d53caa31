"""The one place where a joint command is checked before any frame leaves (pure).

Joint limits, the workspace box of the cell file (x/y of the tool; the tray lies inside it)
and the largest step one command may ask for; and, from where the arm is, the way there: the
tool inside the workspace all along the coordinated move (two poses inside it can sweep out
of it between them: an elbow flip, a swing past the stretched arm), and below the safe height
straight up or down or across at one height, never across while going up or down (the
fingers would sweep sideways through what stands on the tray); and a stop anywhere on the way (each axis
ramping down on its own, off the coordinated path: all at once, or J1 or J2 first and the other up to
can.stop_lag_ms later) leaves the tool inside the workspace. The
drives' software limits (0x607D) are a second line of defence; this check comes first and refuses with a
message that says why.
"""

from __future__ import annotations

import math

import numpy as np

from cell.cellconfig import QUICK_STOP_DECEL_FACTOR, grip_force_units
from cell.kinematics import Joints, forward, limit_violations, tool_xy
from drivers import codec

JOINT_FIELDS = (
    ("j1", "j1_deg", "deg"),
    ("j2", "j2_deg", "deg"),
    ("j3", "j3_mm", "mm"),
    ("j4", "j4_deg", "deg"),
)


# the path is sampled this finely in J1 and J2: between two samples the tool strays from their chord by at
# most (l1 + 4 l2) d^2 / 8, 0.014 mm for the default cell, about one drive count
PATH_STEP_DEG = 0.5
# below the safe height, what counts as not moving: a drive settles a count or two off its target, so the
# lift from a grasp starts a few counts beside it
STILL_MM = 0.5
STILL_DEG = 0.5
OUTSIDE_TOL_MM = 0.05  # a way back into the workspace may not take the tool further out than it starts
STOP_OUTSIDE_TOL_MM = 0.5  # ... nor a stop on it more than this (an axis stopping as the move starts: 0.07 mm)


def command_violations(cell, target: Joints, current: Joints | None) -> list[str]:
    """Human-readable reasons why `target` must not be sent (empty list: it may be sent).

    The command as asked and, when that passes, as the drives get it (`as_sent`: each joint
    rounded to a whole count): a tool asked for exactly on the workspace's edge can land a few
    micrometres past it once rounded. From `current`, also the way there (`path_violations`).

    Parameters
    ----------
    cell : cell.cellconfig.Cell
    target : Joints
        The commanded joint values.
    current : Joints or None
        Where the arm is (or was last commanded to); None skips the step check.
    """
    values = (target.j1_deg, target.j2_deg, target.j3_mm, target.j4_deg)
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
        return [f"joint values must be finite numbers, got {target}"]
    out = _pose_violations(cell, target, current, "")
    if not out:
        sent = as_sent(cell, target)
        if sent != target:
            out = _pose_violations(cell, sent, current, " (as sent: each joint rounded to a whole drive count)")
    if not out and current is not None:
        out = path_violations(cell, current, target)
    return out


def path_violations(cell, start: Joints, target: Joints) -> list[str]:
    """Why the way from `start` to `target` must not be taken: the coordinated move as the drives run it
    (`drivers.profile.coordinated_path`: each axis on its own trapezoid). The tool must stay inside the
    workspace all along (unless it starts outside: the way back in is then allowed), and below the safe
    height it goes straight up or down or across at one height (J3 moving while the tool travels or J4
    turns, with either end below the safe height, is refused)."""
    from drivers.profile import coordinated_motion

    # the whole way at once: a plan checks the ways of every candidate grasp, each of hundreds of samples
    move, t_s, samples, speed = coordinated_motion(cell.scara, start, target, PATH_STEP_DEG)
    path = np.vstack([[start.j1_deg, start.j2_deg, start.j3_mm, start.j4_deg], samples])
    x, y = tool_xy(path, cell.scara)
    out = []
    safe = cell.motion.safe_z_mm
    rise = target.j3_mm - start.j3_mm
    if min(start.j3_mm, target.j3_mm) < safe and abs(rise) > STILL_MM:
        travel = float(np.hypot(x - x[0], y - y[0]).max())
        turn = abs(target.j4_deg - start.j4_deg)
        moving = ([f"the tool travels {travel:.1f} mm"] if travel > STILL_MM else []) + (
            [f"J4 turns {turn:.1f} deg"] if turn > STILL_DEG else [])
        if moving:
            out.append(f"J3 goes {'up' if rise > 0 else 'down'} from {start.j3_mm:.1f} to {target.j3_mm:.1f} mm while "
                       f"{' and '.join(moving)}: below the safe height {safe:g} mm the arm goes straight up or down, "
                       "or across at one height")
    ws = cell.workspace
    inside = ws.contains_xy(x, y)
    box = f"the workspace is x in [{ws.x_mm[0]:g}, {ws.x_mm[1]:g}], y in [{ws.y_mm[0]:g}, {ws.y_mm[1]:g}]"
    # A real arm may stand outside (switched on there, coasted out): the way back in is allowed, never further
    # out than it starts, also where it ends still outside (a jog on the way in); once in, it stays in like any
    # other way (a start 0.8 mm out let the way home sweep 119 mm out of the workspace)
    back_in = int(np.argmax(inside)) if inside.any() else len(inside)
    depth = ws.depth_xy(x[:back_in], y[:back_in])
    past = ws.overshoot_xy(x[:back_in], y[:back_in])  # further past any side than at the start: further out
    deeper = np.flatnonzero((past > past[0] + OUTSIDE_TOL_MM).any(axis=1)) if back_in else []
    outside = np.flatnonzero(~inside[back_in:]) + back_in
    if len(deeper):
        i = int(deeper[np.argmin(depth[deeper])])
        out.append(f"the tool starts {-depth[0]:.1f} mm outside the workspace and would go {-depth[i]:.1f} mm out on "
                   f"the way back in, at x = {x[i]:.1f}, y = {y[i]:.1f} mm (J1 {path[i, 0]:.1f} deg, J2 "
                   f"{path[i, 1]:.1f} deg); {box}: jog it inside first (cell hw jog)")
    elif len(outside):
        i = outside[0]
        out.append(f"the tool would leave the workspace on the way, at x = {x[i]:.1f}, y = {y[i]:.1f} mm "
                   f"(J1 {path[i, 0]:.1f} deg, J2 {path[i, 1]:.1f} deg); {box}")
    else:  # a stop on the way: from where the tool is inside, inside; on the way back in, no further out
        tool = (x[1:], y[1:])
        coming_in = max(back_in - 1, 0)  # the samples (after the start) before the tool is in: all, if it stays out
        if coming_in < len(t_s):
            out += _stop_violations(cell, move, t_s, samples, speed, tool, box, (coming_in, len(t_s)))
        if coming_in and not out:
            out += _stop_violations(cell, move, t_s, samples, speed, tool, box, (0, coming_in),
                                    float(depth[0]) - STOP_OUTSIDE_TOL_MM)
    return out


def _stop_violations(cell, move, t_s: np.ndarray, samples: np.ndarray, speed: np.ndarray, tool: tuple,
                     box: str, span: tuple[int, int], floor_mm: float = 0.0) -> list[str]:
    """A stop anywhere on the way must leave the tool inside the workspace too. Each axis ramps down on its
    own (its quick stop ramp 0x6085, which the host sets at connect, or its fault reaction on the same ramp),
    so the arm leaves the coordinated path (up to 17 mm past the workspace on 2 % of random moves the path
    check let through), in two ways:
    - the host stops every axis at once (the operator's stop, a fault the host sees);
    - J1 or J2 stops on its own (its fault reaction, its quick stop input) and the host stops the other up to
      can.stop_lag_ms later (it looks at the drives every poll during a move): that one goes on along the
      move meanwhile (4 % of random moves leave the workspace, up to 17 mm, with 20 ms).
    Not covered: drives on another ramp (option_codes warns at connect), a drive that coasts (STO, power
    lost), an axis that stops dead (a jam: the other runs on until the jammed drive's following-error window
    trips; docs/drivers.md), a host slower than the lag. J3 or J4 stopping first leaves J1 and J2 on the path
    until they stop together. move, t_s (n,): the way (`coordinated_motion`), samples (n, 4) and speed (n, 4)
    at t_s; tool: its tool x, y (n,). Only the samples in `span` (first, end) whose stop may reach `floor_mm`
    of the workspace's depth (`quick_stop_reach_mm`) are followed: the workspace's edge (0) once the tool is
    in; on the way back in from outside, a little further out than it starts (a stop may not take it out
    further)."""
    from drivers.profile import quick_stop_poses_array, quick_stop_reach_mm, stops_one_first

    sc, ws, lag_s = cell.scara, cell.workspace, cell.can.stop_lag_ms / 1000.0
    reach = quick_stop_reach_mm(sc, speed, QUICK_STOP_DECEL_FACTOR, lag_s, move.top_speed()[:2])
    near = np.flatnonzero(reach >= ws.depth_xy(*tool) - floor_mm)
    near = near[(near >= span[0]) & (near < span[1])]
    if not len(near):
        return []
    ramps = f"each on its own ramp ({QUICK_STOP_DECEL_FACTOR:g} x its max acceleration), off the coordinated path"
    together = quick_stop_poses_array(sc, samples.take(near, 0), speed.take(near, 0), PATH_STEP_DEG,
                                      QUICK_STOP_DECEL_FACTOR)
    ways = [("a quick stop on the way", together, f"the axes stop {ramps}")]
    if lag_s > 0:
        for first, poses in stops_one_first(sc, move, t_s.take(near), lag_s, PATH_STEP_DEG, QUICK_STOP_DECEL_FACTOR):
            other = "J2" if first == "j1" else "J1"
            ways.append((f"{first.upper()} stopping on its own on the way (its fault reaction, its quick stop input) "
                         f"with {other} stopped {cell.can.stop_lag_ms:g} ms later (can.stop_lag_ms)", poses,
                         f"{other} goes on along the way until the host stops it; the axes ramp down {ramps}"))
    for what, stops, why in ways:  # the first way out is told (the host's own stop first)
        x, y = tool_xy(stops, sc)
        depth = ws.depth_xy(x, y)
        i = int(np.argmin(depth))
        if depth[i] < floor_mm:
            further, jog = ((f", further than the {-floor_mm:.3g} mm it may be on its way back in",
                             ": jog it inside first, one joint at a time (cell hw jog)") if floor_mm < 0 else ("", ""))
            return [f"{what} would take the tool {-depth[i]:.3g} mm out of the workspace{further} (to x = {x[i]:.1f}, "
                    f"y = {y[i]:.1f} mm, J1 {stops[i, 0]:.1f} deg, J2 {stops[i, 1]:.1f} deg): {why}; {box}{jog}"]
    return []


def as_sent(cell, target: Joints) -> Joints:
    """The joint values the drives are sent: each rounded to a whole count of its node
    (`can.nodes.*.counts_per_unit` of the cell file), as `Arm.move_joints` sends them."""
    nodes = cell.can.nodes
    return Joints(*(codec.from_counts(codec.to_counts(getattr(target, field), nodes[joint].counts_per_unit),
                                      nodes[joint].counts_per_unit) for joint, field, _ in JOINT_FIELDS))


def _pose_violations(cell, target: Joints, current: Joints | None, suffix: str) -> list[str]:
    out = [v + suffix for v in limit_violations(target, cell.scara)]
    tool = forward(target, cell.scara)
    ws = cell.workspace
    if not ws.contains(tool.x_mm, tool.y_mm) and not _closer_in(cell, tool, current):
        out.append(
            f"tool at x = {_mm(tool.x_mm, ws.x_mm)}, y = {_mm(tool.y_mm, ws.y_mm)} mm outside the workspace "
            f"x in [{ws.x_mm[0]:g}, {ws.x_mm[1]:g}], y in [{ws.y_mm[0]:g}, {ws.y_mm[1]:g}]{suffix}"
        )
    if current is not None:
        for joint, field, unit in JOINT_FIELDS:
            step = abs(getattr(target, field) - getattr(current, field))
            if step > cell.scara.max_step[joint] + 1e-9:
                out.append(f"{joint.upper()} step {step:.3f} {unit} larger than max_step "
                           f"{cell.scara.max_step[joint]:g} {unit}{suffix}")
    return out


def _closer_in(cell, tool, current: Joints | None) -> bool:
    """A tool standing outside the workspace (switched on there, coasted out) may be sent to a pose outside it
    too, where that is no further out (OUTSIDE_TOL_MM): a lift, a jog on the way back in (the ways are checked
    the same way: `path_violations`). Else nothing brought an arm 40 mm out back in but hands: every jog was
    refused, its target still outside."""
    if current is None:
        return False
    here = forward(current, cell.scara)
    ws = cell.workspace
    past_here, past_there = ws.overshoot_xy(here.x_mm, here.y_mm), ws.overshoot_xy(tool.x_mm, tool.y_mm)
    # past no side further than now, with no tolerance (one would add up over many small jogs), and none newly
    # (the nearest side alone let a jog from 40 mm past y end 33 mm past x as well)
    return bool(past_here.any() and (past_there <= past_here).all())


def _mm(value: float, bounds: tuple[float, float]) -> str:
    """A coordinate to 0.1 mm, or to the nanometre, or to the last digit, where fewer digits would show
    it on a bound it is past."""
    for text in (f"{value:.1f}", f"{value:.6f}".rstrip("0")):
        if float(text) not in bounds:
            return text
    return repr(value)


def gripper_violations(cell, width_mm: float, force_n: float | None = None) -> list[str]:
    lo, hi = cell.gripper.opening_mm
    out = []
    if not (isinstance(width_mm, (int, float)) and math.isfinite(width_mm)) or not lo <= width_mm <= hi:
        out.append(f"gripper width {width_mm} mm outside [{lo:g}, {hi:g}]")
    if force_n is not None:
        if (
            not (isinstance(force_n, (int, float)) and math.isfinite(force_n))
            or not 0 < force_n <= cell.gripper.max_force_n
        ):
            out.append(f"grip force {force_n} N outside (0, {cell.gripper.max_force_n:g}]")
        elif grip_force_units(force_n) < 1:  # 0 is no limit, or full current, on many grippers
            out.append(f"grip force {force_n} N is 0 in the drive's 0.1 N steps (object 0x2100)")
    return out


def split_move(start: Joints, target: Joints, max_step: dict) -> list[Joints]:
    """Waypoints from `start` to `target` (linear in joint space, target last) such that no
    step exceeds `max_step` (per joint name). One waypoint when the move is small enough."""
    n = 1
    for joint, field, _ in JOINT_FIELDS:
        n = max(n, math.ceil(abs(getattr(target, field) - getattr(start, field)) / max_step[joint] - 1e-12))
    a, b = start.as_array(), target.as_array()
    return [Joints(*(a + (b - a) * (i / n)).tolist()) for i in range(1, n)] + [target]
