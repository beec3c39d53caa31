"""The fixed grasp height of the 2D normal grasp.

The finger tips go as low as seats most of the pad on the part (pad top 2 mm above the
part's top, so the pad's rounded edge is not the contact) but stay 1 mm above the part's
bottom (the tray). CONTRACT.md: z_bottom <= grasp z <= z_top - 2.
"""

from __future__ import annotations

from cell.cellconfig import Gripper

TIP_ABOVE_BOTTOM_MM = 1.0
PAD_ABOVE_TOP_MM = 2.0
TIP_BELOW_TOP_MM = 2.0  # CONTRACT: grasp z <= z_top - 2; a part less tall than this has no grasp z
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


def _printed_at_most(limit_mm: float) -> float:
    """The limit itself when it prints exactly, else the printed value just below it: a 2-3 mm
    tall part is held at z_top - 2, and rounded up (0.324575 -> 0.3246) that was above it."""
    q = round(limit_mm, PRINTED_DECIMALS)
    return q if q <= limit_mm else q - 10.0 ** -PRINTED_DECIMALS


def _printed_at_least(limit_mm: float) -> float:
    """The limit itself when it prints exactly, else the printed value just above it."""
    q = round(limit_mm, PRINTED_DECIMALS)
    return q if q >= limit_mm else q + 10.0 ** -PRINTED_DECIMALS
