"""Can the jaws carry the part by friction? The planner's own check of the part's weight.

Two pads press with the grip force N (`gripper.grip_force_n` of the cell file); each holds at most
mu N along the pad face (the pads' friction coefficient and the safety factor on the weight are
`cell.physics`'s MU and SAFETY, the mass its `part_mass_g`: the judge and the planner must weigh a
part alike). Only the constants and the mass are shared: the judgement here is the planner's own,
from the contacts alone, and `cell.physics.check_grasp` stays the independent judge.

* The part. However it is held, the pad nearer the centre of gravity carries at least half the
  weight, so SAFETY x W <= 2 mu N is needed by every grasp: `too_heavy` says why a heavier part
  has none.
* Each grasp. Its own centre of gravity, e along the axis from the pads' midpoint, puts more on the
  pad nearer it: f = W (1/2 + e/d) <= mu N, d the pads' distance (the judge's slip, the tilt across
  the jaws included). `slip_demand` is SAFETY f / mu N from the contacts, which lie up to
  PAD_COMPLIANCE_MM behind the pads' faces: taken at the least (e 1/4 mm shorter, d 1 mm longer) it
  never exceeds the judge's, so a grasp above 1 slips for sure. The planner drops those (it does not
  rank by the demand: on every ordinary part it is far below 1, and the learned choice stands).
* Rolling about the jaw line (the judge's torsion) depends on where each pad's patch lies across the
  pad, which the planner does not know: `roll_demand` bounds it from below (each patch the pad's whole
  width by as much of its height as the part spans at the grasp z, the vertical load shared equally,
  which spends the least of the friction on it, the centre of gravity's distance from the contacts'
  line 1 mm shorter), and the sets above 1 are dropped likewise. Between the bound and the judge's
  demand the judge may still refuse a heavy part's grasp (a patch narrower than the pad; pads carrying
  the load unequally). Recordings made before the bound took the pad's height and shares into account
  (`roll_bound_pad_overlap` off) took each patch the whole pad and no friction spent on the load.
* Since `load_at_pad_patches` the planner works out where the pads stop and the patches they touch
  (`cell.grasp.pad_patches`, exact clipping of the outline) and keeps only the sets whose `judged_demands`,
  the judge's two demands taken at their worst over float rounding and over where the judge's jaw line
  runs, are both at most 1: the judge finds those holding (docs/grasp.md, "The part's weight"). The lower
  bounds above stay for recordings made before it.
"""

from __future__ import annotations

import numpy as np

from cell.cellconfig import Cell
from cell.grasp.bands import PAD_COMPLIANCE_MM
from cell.grasp.outline import centre_of_gravity
from cell.grasp.pad_patches import EPS_MM, pad_patches
from cell.physics import G_M_S2, MU, SAFETY, pad_load, part_mass_g, part_weight_n
from cell.scene import Part


def too_heavy(part: Part, cell: Cell) -> str | None:
    """Why no grasp can hold `part` (None: a centred grasp can)."""
    g = cell.gripper
    w = part_weight_n(part)
    carried = 2.0 * MU * g.grip_force_n  # both pads, the centre of gravity between them
    if SAFETY * w <= carried:
        return None
    needed = SAFETY * w / (2.0 * MU)
    most_g = carried / SAFETY / G_M_S2 * 1000.0
    more = (f"a grip force of at least {needed:.1f} N (the cell file's gripper.grip_force_n; its max_force_n is "
            f"{g.max_force_n:g} N)" if needed <= g.max_force_n else
            f"a grip force of {needed:.1f} N, more than the gripper's max_force_n ({g.max_force_n:g} N)")
    return (f"the part is too heavy for the gripper: {part_mass_g(part):.0f} g ({w:.1f} N), with the safety factor "
            f"{SAFETY:g} the jaws must carry {SAFETY * w:.1f} N; two pads gripping with {g.grip_force_n:g} N at "
            f"friction {MU:g} carry at most {carried:.1f} N (parts up to {most_g:.0f} g, held at their centre "
            f"of gravity). It needs {more}")


def slip_demand(part: Part, contacts_mm: np.ndarray, axes: np.ndarray, cell: Cell) -> np.ndarray:
    """(k,) SAFETY x the force on the pad nearer the centre of gravity over its friction mu N, for grasps
    with contacts (k, 2, 2) closing along the unit `axes` (k, 2): a lower bound of the judge's (see the
    module); > 1: the part slips."""
    c = np.asarray(contacts_mm, float).reshape(-1, 2, 2)
    a = np.asarray(axes, float).reshape(-1, 2)

    def along(v):  # measured along the axis, as the judge does (the contacts may lie a few degrees off it)
        return np.abs(v[:, 0] * a[:, 0] + v[:, 1] * a[:, 1])

    d = along(c[:, 1] - c[:, 0])
    e = along(centre_of_gravity(part) - 0.5 * (c[:, 0] + c[:, 1]))
    e_least = np.maximum(e - PAD_COMPLIANCE_MM / 2, 0.0)
    return pad_load(part_weight_n(part), cell.gripper.grip_force_n) * (0.5 + e_least / (d + 2 * PAD_COMPLIANCE_MM))


# the reported contacts lie up to the pads' compliance off the points where the pads stop, which the judge's jaw
# line runs through: the centre of gravity's distance from that line is taken this much shorter
JAW_LINE_SLACK_MM = 2 * PAD_COMPLIANCE_MM


def roll_demand(part: Part, contacts_mm: np.ndarray, cell: Cell, grasp_z_mm: float | None = None) -> np.ndarray:
    """(k,) a lower bound of the judge's demand for rolling about the jaw line, for grasps with contacts
    (k, 2, 2): d the centre of gravity's distance from the line through the contacts (JAW_LINE_SLACK_MM
    shorter), each pad's torsion radius rho at its largest (a patch the pad's width by its overlap with the
    part's height at `grasp_z_mm`: sqrt(w^2 + h^2) / 4) and the vertical load shared equally (the judge's
    soft-finger curve, m <= mu N rho (1 - (f / mu N)^2), leaves the two pads the most torsion then). > 1:
    the part rolls out of the jaws whatever the patches are. Without `grasp_z_mm` as recordings made before
    it have it: the whole pad's height, no friction spent on the load, SAFETY W d / (mu N 2 rho)."""
    g = cell.gripper
    c = np.asarray(contacts_mm, float).reshape(-1, 2, 2)
    line = c[:, 1] - c[:, 0]
    length = np.maximum(np.hypot(line[:, 0], line[:, 1]), 1e-9)
    rel = centre_of_gravity(part) - c[:, 0]
    d = np.maximum(np.abs(rel[:, 0] * line[:, 1] - rel[:, 1] * line[:, 0]) / length - JAW_LINE_SLACK_MM, 0.0)
    load = pad_load(part_weight_n(part), g.grip_force_n)
    if grasp_z_mm is None:
        return load * d / (2.0 * float(np.hypot(g.pad_width_mm, g.pad_height_mm)) / 4.0)
    h = max(min(grasp_z_mm + g.pad_height_mm, part.z_top_mm) - max(grasp_z_mm, part.z_bottom_mm), 0.0)
    rho = float(np.hypot(max(g.pad_width_mm, 1.0), h)) / 4.0  # as the judge's, its patch width at most the pad's
    # the judge's quadratic (cell.physics._hold_ratios) with shares 1/2 and rho for both pads
    return load * (d + np.sqrt(d * d + 4.0 * rho * rho)) / (4.0 * rho)


def judged_demands(part: Part, contacts_mm: np.ndarray, axes: np.ndarray, cell: Cell,
                   grasp_z_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(k,) slip, (k,) roll: for grasps with contacts (k, 2, 2) closing along `axes` (k, 2) at `grasp_z_mm`,
    the judge's demands for slipping and for rolling about the jaw line taken at their worst over what the
    planner cannot know to the last float (`cell.grasp.pad_patches`) and over where the judge moves each patch's
    middle onto the outline. Both <= 1: the judge finds the grasp holding. Its condition for rolling,
    L d <= sum_k rho_k (1 - (L s_k)^2) (L the load in friction budgets, s_k each pad's share of it), only gets
    harder with a longer distance d, smaller radii rho_k and larger shares while L s_k <= 1 (the slip): this
    takes d at its longest, rho_k at their least and the shares at their largest (docs/grasp.md, "The part's
    weight"). inf: the pads close on nothing."""
    g = cell.gripper
    pp = pad_patches(part, contacts_mm, axes, g.pad_width_mm, g.approach_clearance_mm)
    load = pad_load(part_weight_n(part), g.grip_force_n)
    cog = centre_of_gravity(part)
    cog_x = np.einsum("kj,kj->k", cog - pp.centre, pp.u)
    with np.errstate(divide="ignore", invalid="ignore"):
        # the couple's share e / d (e the centre of gravity's offset from the faces' midpoint, d their distance)
        # at the four corners of the faces' intervals: it is monotone in each face
        couple = np.array([(cog_x - 0.5 * (xl + xr)) / (xr - xl) for xl in pp.x_left for xr in pp.x_right])
        lo, hi = couple.min(axis=0) - EPS_MM, couple.max(axis=0) + EPS_MM  # (the centroid's rounding: d >= 1 mm)
        share = np.stack([np.maximum(np.abs(0.5 - lo), np.abs(0.5 - hi)),
                          np.maximum(np.abs(0.5 + lo), np.abs(0.5 + hi))], axis=1)  # (k, 2) |f_k| / W at most
        slip = load * share.max(axis=1)
        h = max(min(grasp_z_mm + g.pad_height_mm, part.z_top_mm) - max(grasp_z_mm, part.z_bottom_mm), 0.0)
        rho = np.hypot(np.maximum(pp.width_least, 1.0), h) / 4.0  # the judge's radii, at the least
        # the jaw line runs through the points of the outline nearest each patch's middle: each lies within
        # its distance from the outline (and twice the middle's rounding) of it
        reach = pp.reach
        z0, z1 = pp.middle[:, 0], pp.middle[:, 1]
        line = z1 - z0
        t = np.einsum("kj,kj->k", cog - z0, line) / np.einsum("kj,kj->k", line, line)
        foot = z0 + t[:, None] * line
        d = np.hypot(*(cog - foot).T) + np.abs(1.0 - t) * reach[:, 0] + np.abs(t) * reach[:, 1] + EPS_MM
        r_sum, a2 = rho.sum(axis=1), (rho * share * share).sum(axis=1)
        roll = load * (d + np.sqrt(d * d + 4.0 * a2 * r_sum)) / (2.0 * r_sum)
    unknown = ~(np.isfinite(slip) & np.isfinite(roll))
    return np.where(unknown, np.inf, slip), np.where(unknown, np.inf, roll)


def holding(part: Part, contacts_mm: np.ndarray, axes: np.ndarray, cell: Cell,
            grasp_z_mm: float | None = None, judged_at_z_mm: float | None = None) -> tuple[np.ndarray, str | None]:
    """(k,) which of the sets with contacts (k, 2, 2) closing along `axes` (k, 2) the planner keeps, and, where
    none, why (None: some do): those that do not surely slip or roll (`slip_demand`, `roll_demand` at
    `grasp_z_mm`) and, with `judged_at_z_mm`, of those the ones the judge finds holding at that grasp z
    (`judged_demands`; recordings made before it have only the first)."""
    slip = slip_demand(part, contacts_mm, axes, cell)
    roll = roll_demand(part, contacts_mm, cell, grasp_z_mm)
    maybe = np.flatnonzero((slip <= 1.0) & (roll <= 1.0))
    if judged_at_z_mm is not None and len(maybe):  # (those the lower bounds drop are dropped as before, cheaply)
        c, a = np.asarray(contacts_mm, float).reshape(-1, 2, 2), np.asarray(axes, float).reshape(-1, 2)
        slip[maybe], roll[maybe] = judged_demands(part, c[maybe], a[maybe], cell, judged_at_z_mm)
    holds = (slip <= 1.0) & (roll <= 1.0)
    if holds.any() or not len(holds):
        return holds, None
    way = ("slip out of the jaws: its centre of gravity lies too far along the closing axis from the pads' midpoint "
           f"(demand/capacity {slip.min():.2f} at the least" if (slip > 1.0).all() else
           "roll out of the jaws: its centre of gravity lies too far from the jaw line (demand/capacity "
           f"{np.maximum(slip, roll).min():.2f} at the least")
    return holds, (f"every one of the {len(holds)} valid contact sets would let the part ({part_mass_g(part):.0f} g) "
                   f"{way}; grip force {cell.gripper.grip_force_n:g} N, friction {MU:g}, safety factor {SAFETY:g})")
