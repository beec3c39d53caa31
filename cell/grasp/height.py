"""The grasp height of the 2D normal grasp: one fixed z per attempt.

The finger tips go as low as seats most of the pad on the part (pad top 2 mm above the
part's top, so the pad's rounded edge is not the contact) but stay 1 mm above the part's
bottom (the tray). CONTRACT.md: z_bottom <= grasp z <= z_top - 2. Where that z gives no grasp,
the planner tries the z 1 mm above each lower neighbour's top (`raised_grasp_z_mm`): the fingers
then pass over that neighbour (CONTRACT: only obstacles taller than the grasp z are collision
regions).
"""

from __future__ import annotations

from cell.cellconfig import Gripper

TIP_ABOVE_BOTTOM_MM = 1.0
PAD_ABOVE_TOP_MM = 2.0
# The tips above a neighbour's top they pass over: the margin they keep above the tray (its top at
# exactly the grasp z would not collide by CONTRACT's rule, but the tips would rest on it)
TIP_ABOVE_NEIGHBOUR_MM = TIP_ABOVE_BOTTOM_MM
TIP_BELOW_TOP_MM = 2.0  # CONTRACT: grasp z <= z_top - 2; a part less tall than this has no grasp z
Z_EPS_MM = 1e-6  # a neighbour's top above the grasp z by more than this is a collision region (cell.grasp.pairs)
PRINTED_DECIMALS = 4  # grasp z and J3 as `cell grasp --json` prints them (cell.grasp.synthesis)


def grasp_z_mm(z_bottom_mm: float, z_top_mm: float, gripper: Gripper,
               j3_mm: tuple[float, float] | None = None) -> float:
    """The grasp z of a part from z_bottom to z_top. With the arm's J3 range (finger-tip z), a z the
    arm cannot take moves to the nearest it can, as long as that stays within CONTRACT.md's
    [z_bottom, z_top - 2] (the pads then cover less of the part) and, moving down, keeps the palm
    (palm_offset above the tips) above the part: a cell whose J3 stops above the usual tip height
    still grasps the parts tall enough for it."""
    top = _printed_at_most(z_top_mm - TIP_BELOW_TOP_MM)
    z = max(z_bottom_mm + TIP_ABOVE_BOTTOM_MM, z_top_mm - gripper.pad_height_mm + PAD_ABOVE_TOP_MM)
    z = max(min(z, top), z_bottom_mm)
    if j3_mm is not None:
        lo, hi = _printed_at_least(j3_mm[0]), _printed_at_most(j3_mm[1])
        if z < lo and lo <= top:
            z = lo
        elif z > hi and hi >= z_bottom_mm and hi + gripper.palm_offset_mm >= z_top_mm:
            z = hi  # lower, but the palm stays above the part's top
    return z


def raised_grasp_z_mm(z_bottom_mm: float, z_top_mm: float, usual_z_mm: float, neighbour_tops_mm,
                      j3_mm: tuple[float, float], top_fallback: bool = True) -> list[float]:
    """The grasp z over each neighbour top above the usual grasp z (TIP_ABOVE_NEIGHBOUR_MM above it),
    lowest first, each once, those within CONTRACT.md's [z_bottom, z_top - 2] and J3's range (the
    finger-tip z the arm takes): a neighbour too tall for that still blocks. A z that would put the tips
    on or less than TIP_ABOVE_NEIGHBOUR_MM above another neighbour's top is left out (that neighbour's own
    z follows): the tips keep the margin over every neighbour they pass over.
    top_fallback: a neighbour whose top lies less than the margin under the highest z the part allows
    (z_top - 2) has that z last, the tips less than the margin above it: CONTRACT.md makes only obstacles
    taller than the grasp z collision regions (a box 20 mm tall in a ring 17.5 mm tall had no grasp)."""
    top = _printed_at_most(z_top_mm - TIP_BELOW_TOP_MM)
    lo, hi = _printed_at_least(j3_mm[0]), _printed_at_most(j3_mm[1])
    step = 10.0 ** -PRINTED_DECIMALS
    tops = [t for t in neighbour_tops_mm if t > usual_z_mm + Z_EPS_MM]
    zs = {_printed_at_least(t + TIP_ABOVE_NEIGHBOUR_MM, slack_mm=Z_EPS_MM) for t in tops}
    # a z one printed step over the highest z the part allows (a top at exactly z_top - 3: z_top - 2 in floats,
    # 4.02 - 2 = 2.0199999999999996, prints 2.0199) is taken at that highest z, the tips a tenth of a micrometre
    # less above the neighbour, rather than left out
    zs = sorted(min(z, top) if top < z <= top + step + Z_EPS_MM else z for z in zs)
    out = [z for z in zs if max(z_bottom_mm, lo) <= z <= min(top, hi)
           and not any(z - TIP_ABOVE_NEIGHBOUR_MM + step + Z_EPS_MM < t <= z + Z_EPS_MM for t in tops)]
    if (top_fallback and top not in out and max(z_bottom_mm, lo) <= top <= hi
            and any(t < top - Z_EPS_MM and t + TIP_ABOVE_NEIGHBOUR_MM > top for t in tops)
            and not any(top - Z_EPS_MM <= t <= top + Z_EPS_MM for t in tops)):
        out.append(top)
    return out


def _printed_at_most(limit_mm: float) -> float:
    """The limit itself when it prints exactly, else the printed value just below it: a 2-3 mm
    tall part is held at z_top - 2, and rounded up (0.324575 -> 0.3246) that was above it."""
    q = round(limit_mm, PRINTED_DECIMALS)
    return q if q <= limit_mm else q - 10.0 ** -PRINTED_DECIMALS


def _printed_at_least(limit_mm: float, slack_mm: float = 0.0) -> float:
    """The limit itself when it prints exactly, else the printed value just above it; with a slack, the
    printed value it is float noise above (a neighbour's top of 1.03 mm plus 1 mm is 2.0300000000000002: 2.03,
    not 2.0301, which lay above the z_top - 2 of a part 4.03 mm tall)."""
    q = round(limit_mm, PRINTED_DECIMALS)
    return q if q >= limit_mm - slack_mm else q + 10.0 ** -PRINTED_DECIMALS
