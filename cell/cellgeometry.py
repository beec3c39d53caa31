"""The cell file's parts checked against each other as one machine.

Each value may be fine alone and the cell still make no sense: jaws that cannot open around anything, a pad taller
than its finger, a camera under the arm (`check_cell_geometry`, called by `cellconfig.parse_cell` when the file is
read). A home outside the workspace (the first move home refused) or a tray partly beyond the arm's reach (a part put
there stopped the run part-way) only matter where the arm moves: `require_cell_can_move`, called by `cell run` and
the `cell hw` commands, so that planning with such a cell (`cell grasp`, `cell plan`: a target out of reach has no
grasp, exit 3) still works. Every refusal is a `BadInput` naming the file and the key.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cell.errors import BadInput

if TYPE_CHECKING:
    from cell.cellconfig import Box2D, Camera, Cell, Gripper, Motion, Scara

# The tray is sampled on a grid of at most this many points a side (the corners and edges included) for the
# reach check: 2.5 mm apart on the default 300 x 500 mm tray, a few ms at load
TRAY_SAMPLES_PER_SIDE = 201
TRAY_SAMPLE_STEP_MM = 2.5
JOINT_TOL_DEG = 1e-9  # as kinematics.limit_violations


def check_cell_geometry(source: str, scara: Scara, gripper: Gripper, camera: Camera) -> None:
    where = f"cell file {source}"
    _check_jaws(where, gripper)
    _check_arm_heights(where, scara, gripper, camera)


def require_cell_can_move(cell: Cell) -> None:
    """Before the arm moves: home inside the workspace, every point of the tray within reach."""
    where = f"cell file {cell.source}"
    _check_home_in_workspace(where, cell.scara, cell.motion, cell.workspace)
    _check_tray_reachable(where, cell.scara, cell.tray)


def _check_jaws(where: str, g: Gripper) -> None:
    """The jaws open to the contact distance + 2 x approach_clearance_mm before descending; they close to at least
    opening_mm[0]. With no clearance a finger lands on the part's edge (every grasp of the run missed, the jaws
    closing on nothing); with no room between the two no grasp fits (the planner refused every part)."""
    c = g.approach_clearance_mm
    if c <= 0:
        raise BadInput(f"{where}: gripper.approach_clearance_mm = {c:g}: the jaws must open wider than the part "
                       "before descending (more than 0 mm each side; 0.5 mm will do): at 0 each finger comes down "
                       "on the part's edge and the jaws close on nothing")
    lo, hi = g.opening_mm
    widest = hi - 2 * c
    if widest <= lo:
        raise BadInput(f"{where}: gripper.opening_mm {hi:g} mm minus 2 x gripper.approach_clearance_mm {c:g} mm "
                       f"leaves contacts at most {widest:g} mm apart, not more than the smallest opening {lo:g} mm: "
                       "no grasp fits these jaws")
    if g.pad_height_mm > g.finger_length_mm or g.pad_height_mm > g.palm_offset_mm:
        raise BadInput(f"{where}: gripper.pad_height_mm = {g.pad_height_mm:g} is more than the finger it is on "
                       f"(gripper.finger_length_mm {g.finger_length_mm:g}, gripper.palm_offset_mm "
                       f"{g.palm_offset_mm:g}: pad bottom to palm)")


def _check_arm_heights(where: str, s: Scara, g: Gripper, camera: Camera) -> None:
    """The gripper hangs under link 2: its palm, at the bottom of J3's travel, is under link 2's underside, and
    link 1 is above the table. (At the top of the travel the palm is under link 2 too on a real arm, the default
    cell's 200 + 40 = 240 mm exactly; the repo's link-collision tests use an arm with its links at 150 and 120 mm
    under a 200 mm J3 to make tall parts hit them, so that is not refused.) The camera looks down from above the
    arm, which sweeps over the tray."""
    palm_low = s.j3_mm[0] + g.palm_offset_mm
    if s.link2_bottom_z_mm < palm_low:
        raise BadInput(f"{where}: scara.link2_bottom_z_mm = {s.link2_bottom_z_mm:g} is below the palm at the bottom "
                       f"of J3's travel (scara.j3_mm {s.j3_mm[0]:g} + gripper.palm_offset_mm {g.palm_offset_mm:g} = "
                       f"{palm_low:g} mm): the gripper hangs under link 2")
    if s.link1_bottom_z_mm <= 0:
        raise BadInput(f"{where}: scara.link1_bottom_z_mm = {s.link1_bottom_z_mm:g}: link 1 would sweep through the "
                       "table (z = 0)")
    arm = max(s.link1_bottom_z_mm, s.link2_bottom_z_mm)
    if camera.height_mm <= arm:
        raise BadInput(f"{where}: camera.height_mm = {camera.height_mm:g} is not above the arm (the links' "
                       f"undersides at {s.link1_bottom_z_mm:g} and {s.link2_bottom_z_mm:g} mm): the camera looks "
                       "down on the tray from above the arm, which sweeps over it")


def _check_home_in_workspace(where: str, s: Scara, motion: Motion, ws: Box2D) -> None:
    """drivers.limits refuses any move whose tool leaves the workspace: from a home outside it no way leads anywhere
    and the first move home is refused (`cell hw corner`: "no way to 'home'")."""
    h = motion.home_joints
    x, y = _tool_xy(s, np.array([h["j1_deg"]]), np.array([h["j2_deg"]]))
    if not ws.contains(float(x[0]), float(y[0])):
        raise BadInput(f"{where}: motion.home_joints (j1_deg {h['j1_deg']:g}, j2_deg {h['j2_deg']:g}) put the tool "
                       f"at ({x[0]:.1f}, {y[0]:.1f}) mm, outside the workspace (x {ws.x_mm[0]:g} to {ws.x_mm[1]:g}, "
                       f"y {ws.y_mm[0]:g} to {ws.y_mm[1]:g} mm): no move may leave it, the first move home would be "
                       "refused")


def _check_tray_reachable(where: str, s: Scara, tray: Box2D) -> None:
    """Every point of the tray must be reachable within J1's and J2's limits (some elbow): a part put where the
    arm cannot reach stops the run part-way. The tray is the area the cell works on, so one larger than the reach
    is a layout mistake, refused (not a warning): give the tray box the part of the table the arm reaches. Any
    closing axis is then some J4 turn (axis = J1 + J2 + J4)."""
    xs, ys = (np.linspace(lo, hi, _samples(hi - lo)) for lo, hi in (tray.x_mm, tray.y_mm))
    x, y = (a.ravel() for a in np.meshgrid(xs, ys))
    ok = reachable_xy(s, x, y)
    if ok.all():
        return
    bad = ~ok
    far = _far_from_reach(s, x, y)
    i = int(np.argmax(np.where(bad, far, -1.0)))  # the point furthest out of reach (a joint limit's: the first)
    r = math.hypot(x[i], y[i])
    why = (f"{r:.1f} mm from J1's axis, the arm reaching {s.reach_mm[0]:g} to {s.reach_mm[1]:g} mm" if far[i] > 0
           else f"within the arm's {s.reach_mm[0]:g} to {s.reach_mm[1]:g} mm but past J1 or J2's limits")
    raise BadInput(f"{where}: the arm cannot reach {100.0 * bad.mean():.3g} % of the tray within scara.j1_deg and "
                   f"scara.j2_deg (unreachable: x {x[bad].min():.1f} to {x[bad].max():.1f}, y {y[bad].min():.1f} to "
                   f"{y[bad].max():.1f} mm; e.g. ({x[i]:.1f}, {y[i]:.1f}) mm, {why}): a part put there could never "
                   "be picked; make tray.x_mm and tray.y_mm the area the arm reaches")


def _samples(side_mm: float) -> int:
    return int(min(TRAY_SAMPLES_PER_SIDE, max(2, math.ceil(side_mm / TRAY_SAMPLE_STEP_MM) + 1)))


def _far_from_reach(s: Scara, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """How far outside the annulus of reach each point lies (0 within it: out of reach by a joint limit)."""
    r = np.hypot(x, y)
    return np.maximum(np.maximum(r - s.reach_mm[1], s.reach_mm[0] - r), 0.0)


def _tool_xy(s: Scara, j1_deg: np.ndarray, j2_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t1, t12 = np.radians(j1_deg), np.radians(j1_deg + j2_deg)
    return s.l1_mm * np.cos(t1) + s.l2_mm * np.cos(t12), s.l1_mm * np.sin(t1) + s.l2_mm * np.sin(t12)


def reachable_xy(s: Scara, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Can the tool be put at each (x, y) with J1 and J2 within their limits, either elbow? J1 as
    `kinematics.inverse` solves it, in [-180, 180)."""
    l1, l2 = s.l1_mm, s.l2_mm
    c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    inside = (c2 <= 1.0 + 1e-12) & (c2 >= -1.0 - 1e-12)
    ok = np.zeros(x.shape, bool)
    for sign in (1.0, -1.0):
        t2 = sign * np.arccos(np.clip(c2, -1.0, 1.0))
        j1 = (np.degrees(np.arctan2(y, x) - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))) + 180.0) % 360.0 - 180.0
        j2 = np.degrees(t2)
        ok |= ((j1 >= s.j1_deg[0] - JOINT_TOL_DEG) & (j1 <= s.j1_deg[1] + JOINT_TOL_DEG)
               & (j2 >= s.j2_deg[0] - JOINT_TOL_DEG) & (j2 <= s.j2_deg[1] + JOINT_TOL_DEG))
    return inside & ok
