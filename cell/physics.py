"""The project's own physical check of a two-jaw grasp, independent of the planner.

Written with shapely directly (it shares no code with the planner's collision filters), so
it can judge the planner. Everything happens in the grasp frame: origin at the grasp centre,
x along the closing axis, y across it.

What `check_grasp` models, and why:

* Closing. Each jaw is a flat pad `pad_width` (12 mm) across the axis and `pad_thickness`
  (10 mm) along it. It starts at the approach opening (contact distance + 2 x clearance)
  and moves along the axis until it meets the first material of the part inside its
  12 mm band. The gripper reports the distance between the two pad faces (`jaw_width_mm`).
  The reported contacts must be where the pads really stop (within `CONTACT_TOL_MM` along
  the axis); a finger whose footprint already covers the part at the approach opening would
  land on it.
* Collision. Each finger's footprint swept from the approach opening to its contact is
  checked against every other part whose top is above the grasp z; the palm (90 x 40,
  centred, long side along the axis, bottom at grasp z + 40) against parts whose top is above
  the palm's bottom, the part held included. The pads' vertical band must overlap the part.
* Friction cone (antipodal). A flat pad pushes along the axis. Where the pad face touches
  the part at an extreme point (a flat, a vertex, a tangent point of a curve) the force
  lies inside the contact's normal cone, so the contact holds. Where only the pad's edge
  touches a slope (the extreme point of the band is on the band's border), the contact
  normal is the slope's normal, and it must lie within the friction angle atan(mu) of the
  axis, or the part squeezes out. That slope is the contact patch's: `PATCH_DEPTH_MM` deep
  over its width (narrower than `SHARP_PATCH_MM`, else the compliant face seats).
  Material that turns back towards the border within the patch is a tip of the part, not a
  slope: refused the same way, and the reason says so.
* Sharp corners. A contact is on a sharp corner when the patch the pad touches is narrower
  than `SHARP_PATCH_MM` and the outline turns by at least `SHARP_TURN_DEG` within 1 mm
  each side (a patch cut by the band's border included, when the first touch is inside the
  band). One pad on a corner is tolerated; both are not (the part would pivot).
* Centre of gravity near the jaw line (friction/torque argument). The part hangs from the
  pads, weight W = m g at the centre of gravity (uniform density; `meta["mass_g"]` when the
  part carries it, else its `meta["material"]`'s density, else aluminium: `cell.materials`),
  with safety factor `SAFETY` on W. Each pad has one friction budget, mu N, for everything it
  holds:
  - vertical force: each pad carries W / 2, plus or minus the couple W e / d that holds a
    centre of gravity e along the axis off the pads' midpoint (d the jaw width), so the pad
    nearer it carries f = W (1/2 + e/d) <= mu N (slip, the tilt across the jaws included);
  - torsion: rolling about the jaw line (lever arm d_perp, the centre of gravity's distance
    from the line through the contacts) is resisted by each pad's torsional friction, mu N rho
    with rho its patch's mean radius (sqrt(w^2 + h^2) / 4 for a w x h patch: exact for a
    line, 8 % under for a square), less what its vertical force already uses: the soft-finger
    limit curve m <= mu N rho (1 - (f / mu N)^2). So W d_perp <= sum of those.
  Until 2026-12-02 slip, roll and tilt were three separate tests, each with the whole budget:
  a grasp needing up to twice the friction there is passed.
* Stroke. The approach opening must be within the gripper's opening range.

`lift_clear` checks that the part and the closed gripper can move straight up: nothing still
present may be above them in plan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LinearRing, Point, box

from cell.cellconfig import Cell, default_cell
from cell.grasp.height import grasp_z_mm as default_grasp_z_mm
from cell.materials import mass_g
from cell.scene import Part

MU = 0.3  # pad/part friction: rubber-faced pads on oily metal, conservative
SAFETY = 2.0  # margin for the arm's accelerations and an uneven grip
G_M_S2 = 9.81
CONTACT_TOL_MM = 2.0  # a reported contact farther than this from where the pad stops is wrong
PATCH_DEPTH_MM = 0.5  # material this close to the pad face touches it (pad compliance)
SHARP_PATCH_MM = 2.0
SHARP_TURN_DEG = 50.0
AXIS_TOL_DEG = 3.0  # the closing axis must run along the contacts
_BIG = 1e4
_AREA_EPS = 1e-3


@dataclass(frozen=True)
class GraspCheck:
    """The verdict of `check_grasp`. `ok` when `reasons` is empty."""

    ok: bool
    reasons: tuple[str, ...]
    jaw_width_mm: float | None  # what the gripper reports when closed on the part (None: closes on nothing)
    contacts_mm: np.ndarray | None  # (2, 2): where the pads really touch, base frame
    approach_opening_mm: float
    contact_error_mm: float  # worst distance along the axis between reported and real contacts
    collisions: tuple[str, ...]  # ids of the parts the fingers or palm would hit
    sharp: tuple[bool, bool]
    slope_angle_deg: tuple[float, float]  # contact normal vs axis, 0 where the pad face seats
    patch_width_mm: tuple[float, float]
    cog_offset_mm: float  # distance from the centre of gravity to the jaw line
    cog_along_mm: float  # centre of gravity's offset along the axis from the grasp centre
    torque_ratio: float  # SAFETY x weight over the largest weight the pads' friction holds (<= 1: holds)
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"ok": self.ok, "reasons": list(self.reasons),
                "jaw_width_mm": None if self.jaw_width_mm is None else round(self.jaw_width_mm, 3),
                "contacts": None if self.contacts_mm is None else np.round(self.contacts_mm, 3).tolist(),
                "approach_opening_mm": round(self.approach_opening_mm, 3),
                "contact_error_mm": round(self.contact_error_mm, 3), "collisions": list(self.collisions),
                "sharp": list(self.sharp), "slope_angle_deg": [round(a, 2) for a in self.slope_angle_deg],
                "patch_width_mm": [round(w, 2) for w in self.patch_width_mm],
                "cog_offset_mm": round(self.cog_offset_mm, 3), "cog_along_mm": round(self.cog_along_mm, 3),
                "torque_ratio": round(self.torque_ratio, 4)}


@dataclass(frozen=True)
class LiftCheck:
    ok: bool
    blocking: tuple[str, ...]  # ids of the parts in the way
    reasons: tuple[str, ...]


def part_weight_n(part: Part) -> float:
    return part_mass_g(part) / 1000.0 * G_M_S2


def pad_load(weight_n: float, grip_n: float) -> float:
    """The weight with its margin (SAFETY), in units of one pad's friction budget mu N."""
    return SAFETY * weight_n / (MU * grip_n)


def part_mass_g(part: Part) -> float:
    """The part's "mass_g", else its volume times its "material"'s density, else aluminium's
    (`cell.materials`; a bad value of either key is BadInput)."""
    meta = part.meta if isinstance(part.meta, dict) else {}
    return mass_g(meta, part.polygon.area * part.height_mm / 1000.0, f"part {part.id!r}")


def check_grasp(part: Part, contacts_mm, axis_deg: float | None = None, grasp_z_mm: float | None = None,
                obstacles: tuple[Part, ...] | list[Part] = (), cell: Cell | None = None) -> GraspCheck:
    """Judge a two-jaw grasp of `part` physically.

    Parameters
    ----------
    part : the part to hold (base frame).
    contacts_mm : array-like of shape (2, 2), the reported pad contacts.
    axis_deg : the closing axis direction (mod 180); default: along the contacts.
    grasp_z_mm : finger-tip z; default: `cell.grasp.height.grasp_z_mm` of the part.
    obstacles : the other parts present (their heights decide what the fingers and palm hit).
    cell : the cell (gripper geometry); default: the shipped default cell.
    """
    cell = cell or default_cell()
    g = cell.gripper
    c = np.asarray(contacts_mm, float).reshape(2, 2)
    centre = c.mean(axis=0)
    d_rep = float(np.linalg.norm(c[1] - c[0]))
    line_deg = math.degrees(math.atan2(c[1, 1] - c[0, 1], c[1, 0] - c[0, 0])) if d_rep > 1e-9 else 0.0
    theta = line_deg if axis_deg is None else float(axis_deg)
    if math.cos(math.radians(line_deg - theta)) < 0:
        # the same axis (mod 180) turned to run from the first contact to the second: the pads come in the
        # contacts' order, so "contact k" below is the k-th one given (it was the second when the axis ran back)
        theta += 180.0
    if grasp_z_mm is None:
        grasp_z_mm = default_grasp_z_mm(part.z_bottom_mm, part.z_top_mm, g, cell.scara.j3_mm)
    reasons: list[str] = []
    if axis_deg is not None and d_rep > 1e-9:
        skew = abs((line_deg - theta + 90.0) % 180.0 - 90.0)
        if skew > AXIS_TOL_DEG:
            reasons.append(f"the closing axis is {skew:.1f} deg off the line through the contacts")

    def to_local(geom):
        return affinity.rotate(affinity.translate(geom, -centre[0], -centre[1]), -theta, origin=(0, 0),
                               use_radians=False)

    def to_base(geom):
        return affinity.translate(affinity.rotate(geom, theta, origin=(0, 0)), centre[0], centre[1])

    a = np.array([math.cos(math.radians(theta)), math.sin(math.radians(theta))])
    local_c = np.array([[(p - centre) @ a, (p - centre) @ np.array([-a[1], a[0]])] for p in c])
    x_rep = np.sort(local_c[:, 0])
    half_w, t = g.pad_width_mm / 2, g.pad_thickness_mm
    approach = d_rep + 2 * g.approach_clearance_mm
    s_open = approach / 2
    if approach > g.opening_mm[1] + 1e-9:
        reasons.append(f"approach opening {approach:.1f} mm exceeds the stroke ({g.opening_mm[1]:g} mm)")

    # vertical overlap of the pads with the part
    h_pad = min(grasp_z_mm + g.pad_height_mm, part.z_top_mm) - max(grasp_z_mm, part.z_bottom_mm)
    if h_pad <= 0:
        reasons.append(f"the pads (z {grasp_z_mm:.1f}..{grasp_z_mm + g.pad_height_mm:.1f}) miss the part "
                       f"(z {part.z_bottom_mm:g}..{part.z_top_mm:g})")

    local_part = to_local(part.polygon)
    band = box(-_BIG, -half_w, _BIG, half_w)
    material = local_part.intersection(band)
    for side, lands in zip(("first", "second"), _fingers_land(material, s_open, g)):
        if lands:
            reasons.append(f"the {side} finger lands on the part at the approach opening")
    inner = material.intersection(box(-s_open, -half_w, s_open, half_w))
    empty = inner.is_empty or inner.area <= _AREA_EPS
    if empty:
        reasons.append("the jaws close on nothing: no material of the part between the pads")
        return GraspCheck(False, tuple(reasons), None, None, approach, float("inf"), (), (False, False),
                          (0.0, 0.0), (0.0, 0.0), float("inf"), float("inf"), float("inf"))
    xl, _, xr, _ = inner.bounds
    jaw_width = xr - xl
    if jaw_width < g.opening_mm[0] - 1e-9:
        reasons.append(f"the part ({jaw_width:.1f} mm) is thinner than the smallest opening")
    if jaw_width + 2 * g.approach_clearance_mm > g.opening_mm[1] + 1e-6 >= approach:
        # the contacts fit, but the pads stop further out (on material in front of them)
        reasons.append(f"the pads stop {jaw_width:.3f} mm apart: with the approach clearance that exceeds the "
                       f"stroke ({g.opening_mm[1]:g} mm)")
    contact_error = float(max(abs(xl - x_rep[0]), abs(xr - x_rep[1])))
    if contact_error > CONTACT_TOL_MM:
        reasons.append(f"the pads stop {contact_error:.1f} mm from the reported contacts (first material "
                       "inside the pad band is elsewhere)")

    # the contact patches and where they are
    rings = _rings(local_part)
    patches, real_local, sharp, slope, widths, tips = [], [], [], [], [], []
    for k, (x0, x1) in enumerate(((xl, xl + PATCH_DEPTH_MM), (xr - PATCH_DEPTH_MM, xr))):
        patch = inner.intersection(box(x0, -half_w, x1, half_w))
        if patch.is_empty:  # numerically degenerate; fall back to the extreme point
            patch = Point(xl if k == 0 else xr, 0.0)
        y0, y1 = patch.bounds[1], patch.bounds[3]
        width = y1 - y0
        xface = xl if k == 0 else xr
        # the touching point: the patch's middle, moved onto the outline
        yc = 0.5 * (y0 + y1)
        p = _nearest_on_rings(rings, np.array([xface, yc]))
        real_local.append(p)
        patches.append(patch)
        widths.append(width)
        _, turn = _normal_and_turn(rings, p)
        # Only the pad's edge pushes when the first touch (the material's extreme along the axis)
        # lies on the band's border. A patch merely reaching the border is still the face on an
        # extreme point, and may be a sharp corner (both pads on a diamond's 90 deg tips up to
        # 0.5 mm inside the border passed). On the border the slope is the patch's own,
        # PATCH_DEPTH_MM deep over its width: a chord of the outline around p reached across a
        # corner just outside the band (tips up to 0.08 mm outside passed as 10..16 deg slopes).
        on_band_edge = width < SHARP_PATCH_MM and _touch_on_band_edge(inner, xface, half_w)
        tips.append(on_band_edge and _tip_in_patch(patch, xface, half_w))
        if on_band_edge:
            ang = math.degrees(math.atan2(PATCH_DEPTH_MM, width))
        else:
            ang = 0.0  # the pad face seats on an extreme point: force inside the normal cone
        slope.append(ang)
        sharp.append(bool(width < SHARP_PATCH_MM and turn >= SHARP_TURN_DEG and not on_band_edge))
    friction_deg = math.degrees(math.atan(MU))
    for k, ang in enumerate(slope):
        if ang > friction_deg:
            reasons.append(_edge_reason(k, ang, friction_deg, widths[k], tips[k]))
    if all(sharp):
        reasons.append("both pads sit on sharp corners")

    # centre of gravity against the jaw line
    cog = np.asarray(local_part.centroid.coords[0])
    p0, p1 = real_local
    u = (p1 - p0) / max(np.linalg.norm(p1 - p0), 1e-9)
    rel = cog - p0
    cog_offset = abs(rel[0] * u[1] - rel[1] * u[0])
    cog_along_signed = cog[0] - 0.5 * (xl + xr)  # + towards the second pad
    cog_along = abs(cog_along_signed)
    h = max(h_pad, 0.0)
    rho = [math.hypot(max(w, 1.0), h) / 4.0 for w in widths]
    shares = _pad_shares(cog_along_signed, jaw_width)
    ratios = _hold_ratios(part_weight_n(part), g.grip_force_n, cog_offset, shares, rho)
    worst = max(ratios, key=ratios.get)
    if ratios[worst] > 1.0:
        reasons.append(f"the part would {worst} out of the jaws (demand/capacity {ratios[worst]:.2f}; centre "
                       f"of gravity {cog_offset:.1f} mm from the jaw line, {cog_along:.1f} mm along it from "
                       "the pads' midpoint)")

    # collisions: fingers swept along the closing stroke, palm
    collisions: list[str] = []
    fingers = [to_base(box(-s_open - t, -half_w, xl, half_w)), to_base(box(xr, -half_w, s_open + t, half_w))]
    palm = to_base(_palm_box(g))
    palm_z = grasp_z_mm + g.palm_offset_mm
    # the obstacles skip the part itself, and the palm can come down on it too (a low grasp z on a
    # tall part): gripped at z 5, a 60 mm tall part was accepted with the palm 15 mm inside it
    if part.z_top_mm > palm_z + 1e-9 and palm.intersection(part.polygon).area > _AREA_EPS:
        reasons.append(f"the palm (bottom z {palm_z:g} mm) would hit the part held (top z {part.z_top_mm:g} mm)")
    for o in obstacles:
        if o.id == part.id:
            continue
        hit = []
        if o.z_top_mm > grasp_z_mm + 1e-9 and any(
                f.intersection(o.polygon).area > _AREA_EPS for f in fingers):
            hit.append("finger")
        if o.z_top_mm > palm_z + 1e-9 and palm.intersection(o.polygon).area > _AREA_EPS:
            hit.append("palm")
        if hit:
            collisions.append(o.id)
            reasons.append(f"the {' and '.join(hit)} would hit {o.id!r} (top z {o.z_top_mm:g} mm)")

    real_base = np.array([np.asarray(to_base(Point(*p)).coords[0]) for p in real_local])
    return GraspCheck(not reasons, tuple(reasons), float(jaw_width), real_base, float(approach),
                      contact_error, tuple(collisions), (sharp[0], sharp[1]), (slope[0], slope[1]),
                      (widths[0], widths[1]),
                      float(cog_offset), float(cog_along), float(ratios[worst]),
                      extra={"ratios": ratios, "pad_shares": shares, "grasp_z_mm": grasp_z_mm})


def close_jaws(part: Part, centre_mm, axis_deg: float, opening_mm: float, grasp_z_mm: float | None = None,
               cell: Cell | None = None) -> float | None:
    """The width the simulated gripper reports when its jaws, open at `opening_mm` around
    `centre_mm` along `axis_deg`, close on `part` (None: they close on nothing).

    The pads stop at the first material of the part inside their 12 mm band (see
    `check_grasp`); a part outside the band or above the pads leaves the jaws closing fully,
    and so does one that a finger lands on (jaws opened narrower than the part): no grip.
    """
    cell = cell or default_cell()
    g = cell.gripper
    a = np.array([math.cos(math.radians(axis_deg)), math.sin(math.radians(axis_deg))])
    c = np.asarray(centre_mm, float)
    # the fingers open at +-opening/2 (check_grasp's approach opening cannot be narrower than
    # 2 x clearance): one landing on the part does not grip it; a 40 mm square closed from 30 mm
    # reported 30 mm
    local = affinity.rotate(affinity.translate(part.polygon, -c[0], -c[1]), -axis_deg, origin=(0, 0))
    if any(_fingers_land(local, opening_mm / 2, g)):
        return None
    half = max(opening_mm / 2 - g.approach_clearance_mm, 1e-3)
    v = check_grasp(part, [c - half * a, c + half * a], axis_deg, grasp_z_mm, (), cell)
    if v.jaw_width_mm is None:
        return None
    zg = default_grasp_z_mm(part.z_bottom_mm, part.z_top_mm, g, cell.scara.j3_mm) if grasp_z_mm is None else grasp_z_mm
    if min(zg + g.pad_height_mm, part.z_top_mm) <= max(zg, part.z_bottom_mm):
        return None
    return v.jaw_width_mm


def gripper_footprint(contacts_mm, jaw_width_mm: float | None = None, cell: Cell | None = None):
    """Plan-view footprints (fingers closed at the contacts, palm) of a grasp, base frame.

    Returns (fingers: list of 2 polygons, palm: polygon).
    """
    cell = cell or default_cell()
    g = cell.gripper
    c = np.asarray(contacts_mm, float).reshape(2, 2)
    centre = c.mean(axis=0)
    theta = math.degrees(math.atan2(c[1, 1] - c[0, 1], c[1, 0] - c[0, 0]))
    half = (np.linalg.norm(c[1] - c[0]) if jaw_width_mm is None else jaw_width_mm) / 2
    hw, t = g.pad_width_mm / 2, g.pad_thickness_mm

    def to_base(geom):
        return affinity.translate(affinity.rotate(geom, theta, origin=(0, 0)), centre[0], centre[1])

    fingers = [to_base(box(-half - t, -hw, -half, hw)), to_base(box(half, -hw, half + t, hw))]
    return fingers, to_base(_palm_box(g))


def _fingers_land(local_part, s_open: float, g) -> list[bool]:
    """Whether each finger's footprint, open with its pad face at -s_open / +s_open on the
    grasp frame's axis, covers the part (grasp frame)."""
    hw, t = g.pad_width_mm / 2, g.pad_thickness_mm
    return [local_part.intersection(box(x0, -hw, x0 + t, hw)).area > _AREA_EPS for x0 in (-s_open - t, s_open)]


def _edge_reason(k: int, slope_deg: float, friction_deg: float, width_mm: float, tip: bool) -> str:
    """Why contact k, where only the pad's edge touches, fails: a slope outside the friction cone, or
    a tip of the part barely inside the band, where the patch's "slope" is no face of the part (a
    tooth tip 0.05 mm inside read "84.1 deg > 16.7 deg: the pad's edge pushes on a slope")."""
    if tip:
        return (f"contact {k}: only the pad's edge touches the part, on a tip reaching {width_mm:.2f} mm into "
                f"its band (under the {PATCH_DEPTH_MM / MU:.2f} mm an edge needs to hold)")
    for decimals in (1, 2, 3):  # as many as tell the two apart (16.70 > 16.70 read "16.7 deg > 16.7 deg")
        if round(slope_deg, decimals) > round(friction_deg, decimals):
            break
    return (f"contact {k} is outside the friction cone ({slope_deg:.{decimals}f} deg > {friction_deg:.{decimals}f} "
            "deg): the pad's edge pushes on a slope")


def _tip_in_patch(patch, xface: float, half_w: float) -> bool:
    """Whether the material the pad's edge touches turns back towards the band's border within the
    patch (its farthest point from the border lies short of the patch's far side): a tip, not a slope."""
    xy = shapely.get_coordinates(patch)
    from_border = half_w - np.abs(xy[:, 1])
    far = from_border >= from_border.max() - 1e-9
    return bool(np.abs(xy[far, 0] - xface).max() < PATCH_DEPTH_MM - 1e-6)


def _pad_shares(cog_along_mm: float, jaw_width_mm: float) -> tuple[float, float]:
    """Each pad's vertical friction as a multiple of the weight W: half each, plus and minus the
    couple that holds a centre of gravity `cog_along_mm` (+ towards the second pad) off the pads'
    midpoint (f1 - f0 = 2 W e / d). Pressure shifting over the pads' height could also carry part
    of that moment; it is left out, which only errs on the safe side."""
    couple = cog_along_mm / max(jaw_width_mm, 1e-9)
    return 0.5 - couple, 0.5 + couple


def _hold_ratios(weight_n: float, grip_n: float, cog_offset_mm: float, shares, rho_mm) -> dict[str, float]:
    """SAFETY x the weight over the largest weight the pads hold, per way it is lost (<= 1: holds).

    Both ways draw on one friction budget per pad (N the grip force, f_k = shares[k] W its vertical
    force, m_k its part of the torsion W d_perp): f_k <= mu N, and the soft-finger limit curve of a
    pad patch, m_k <= mu N rho_k (1 - (f_k / mu N)^2). That parabola is the exact limit curve of a
    uniformly pressed line across the load (a thin plate's edge) and lies inside that of every
    rectangular patch; the usual ellipse lies outside it (2x the torsion at f = 0.87 mu N).
    The torsion splits between the pads as it must, so the grip holds while
    W d_perp <= sum_k mu N rho_k (1 - (f_k / mu N)^2): a quadratic in W, solved below.
    """
    load = pad_load(weight_n, grip_n)
    rho_sum = max(sum(rho_mm), 1e-9)
    a2 = sum(r * s * s for r, s in zip(rho_mm, shares, strict=True))  # torsion lost per unit load^2
    d = cog_offset_mm
    return {"slip": load * max(abs(s) for s in shares),  # the pad carrying more
            "roll about the jaw line": load * (d + math.sqrt(d * d + 4.0 * a2 * rho_sum)) / (2.0 * rho_sum)}


def _palm_box(g):
    return box(-g.palm_length_mm / 2, -g.palm_width_mm / 2, g.palm_length_mm / 2, g.palm_width_mm / 2)


def lift_clear(part: Part, others, contacts_mm=None, grasp_z_mm: float | None = None,
               cell: Cell | None = None) -> LiftCheck:
    """Can `part` (and the gripper holding it at `contacts_mm`) move straight up?

    A part still present blocks the lift when it overlaps the part in plan and is not wholly
    below it (its top above the part's bottom), or when it overlaps the closed gripper's
    footprint above the grasp z (fingers) or above the palm's bottom (palm).
    """
    cell = cell or default_cell()
    blocking: list[str] = []
    reasons: list[str] = []
    fingers, palm = ([], None)
    if contacts_mm is not None:
        fingers, palm = gripper_footprint(contacts_mm, None, cell)
        if grasp_z_mm is None:
            grasp_z_mm = default_grasp_z_mm(part.z_bottom_mm, part.z_top_mm, cell.gripper, cell.scara.j3_mm)
    for o in others:
        if o.id == part.id:
            continue
        why = None
        if o.z_top_mm > part.z_bottom_mm + 1e-9 and o.polygon.intersection(part.polygon).area > _AREA_EPS:
            why = f"{o.id!r} lies above {part.id!r} (overlap in plan, top z {o.z_top_mm:g})"
        elif fingers and o.z_top_mm > grasp_z_mm + 1e-9 and any(
                f.intersection(o.polygon).area > _AREA_EPS for f in fingers):
            why = f"{o.id!r} is in the way of a finger"
        elif palm is not None and o.z_top_mm > grasp_z_mm + cell.gripper.palm_offset_mm + 1e-9 and \
                palm.intersection(o.polygon).area > _AREA_EPS:
            why = f"{o.id!r} is in the way of the palm"
        if why:
            blocking.append(o.id)
            reasons.append(why)
    return LiftCheck(not blocking, tuple(blocking), tuple(reasons))


# --- outline geometry helpers ------------------------------------------------------------------

def _rings(poly) -> list[LinearRing]:
    """Exterior CCW and holes CW, so the outward normal is the tangent turned right."""
    from shapely.geometry.polygon import orient

    if poly.geom_type != "Polygon":
        poly = max(poly.geoms, key=lambda q: q.area)
    poly = orient(poly, 1.0)
    return [LinearRing(poly.exterior.coords)] + [LinearRing(r.coords) for r in poly.interiors]


def _nearest_on_rings(rings, p: np.ndarray) -> np.ndarray:
    pt = Point(*p)
    ring = min(rings, key=lambda r: r.distance(pt))
    q = ring.interpolate(ring.project(pt))
    return np.array([q.x, q.y])


def outline_normal_and_turn(rings, p, delta_mm: float = 1.0):
    """Outward unit normal (chord over +-delta) and the convex turning angle (deg) at p.

    The turning angle is positive where the outline turns outward-convex (a corner a pad can
    sit on), negative in a concave corner.
    """
    return _normal_and_turn(rings, np.asarray(p, float), delta_mm)


def _touch_on_band_edge(inner, xface: float, half_w: float, tol: float = 1e-7) -> bool:
    """Whether all of `inner`'s material at x = xface (its extreme along the axis, where the pad
    first touches) lies on one edge of the band (y = -half_w or +half_w)."""
    xy = shapely.get_coordinates(inner)
    ys = xy[np.abs(xy[:, 0] - xface) <= tol, 1]
    return any(np.all(np.abs(ys - e) <= tol) for e in (-half_w, half_w)) if ys.size else False


def _normal_and_turn(rings, p: np.ndarray, delta_mm: float = 1.0):
    pt = Point(*p)
    ring = min(rings, key=lambda r: r.distance(pt))
    L = ring.length
    s = ring.project(pt)
    q = [np.asarray(ring.interpolate((s + k * delta_mm) % L).coords[0]) for k in (-1, 0, 1)]
    t_in, t_out = q[1] - q[0], q[2] - q[1]
    chord = q[2] - q[0]
    n = np.linalg.norm(chord)
    if n < 1e-9:
        return None, 0.0
    normal = np.array([chord[1], -chord[0]]) / n
    a_in, a_out = math.atan2(t_in[1], t_in[0]), math.atan2(t_out[1], t_out[0])
    turn = math.degrees((a_out - a_in + math.pi) % (2 * math.pi) - math.pi)
    return normal, turn
