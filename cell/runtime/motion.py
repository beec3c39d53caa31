"""The pick as a list of commands (pure): approach above, open, descend, grip, lift along the
disassembly direction (straight up), check the grip, carry to the drop-off, release.

The check closes the jaws again under the same force limit once the part is off the tray: still
held, they stop on it at once; slipped out (too heavy for the grip, stuck to the tray, caught on
a neighbour), they close past its width, and the pick ends there, over the tray where the part fell
back, not after a carry to the drop-off and a frame that shows it still lying there.

Every joint target keeps the chosen configuration's elbow; the carry to the drop-off takes
the drop-off solution nearest to the grasp configuration (the least joint motion).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cell.cellconfig import Cell
from cell.errors import CellError
from cell.kinematics import Joints, inverse
from drivers.limits import command_violations


@dataclass(frozen=True)
class Command:
    """One step of a pick: a joint move, or a gripper action."""

    action: str  # "move" | "open" | "grip" | "check" (grip again: still where the jaws held the part?)
    label: str  # approach, descend, lift, carry, release ...
    joints: Joints | None = None
    width_mm: float | None = None  # open: the opening; grip, check: the expected width (the part's)
    force_n: float | None = None

    def to_json(self) -> dict:
        d = {"action": self.action, "label": self.label}
        if self.joints is not None:
            d["joints"] = {k: round(v, 4) for k, v in self.joints.as_dict().items()}
        if self.width_mm is not None:
            d["width_mm"] = round(self.width_mm, 4)
        if self.force_n is not None:
            d["force_n"] = round(self.force_n, 3)
        return d


TRANSIT_CHECK = "check at drop-off"  # the label of the grip checked above the drop-off, before the lowering


def _check(label: str, width_mm: float, cell: Cell) -> Command:
    """The grip again under the grip's force limit (`drivers.execute`: against the width the list gripped at,
    else `width_mm`)."""
    return Command("check", label, width_mm=width_mm, force_n=cell.gripper.grip_force_n)


def above(j: Joints, z_mm: float) -> Joints:
    return Joints(j.j1_deg, j.j2_deg, z_mm, j.j4_deg)


def dropoff_options(cell: Cell, near: Joints) -> list[Joints]:
    """Every configuration reaching the drop-off (both elbows, the J4 turns), nearest to `near`
    first (J1, J2, J4 distance: the least motion from the grasp)."""
    x, y, z = cell.motion.dropoff_mm
    options = inverse(x, y, z, 0.0, cell.scara)
    if not options:
        raise CellError(f"the drop-off {cell.motion.dropoff_mm} is not reachable with the cell's joint limits")
    # only what the arm may be sent: on the workspace's edge a configuration can land a few micrometres
    # past it once its joints are rounded to the drives' counts (drivers.limits.as_sent)
    refused = [command_violations(cell, o, None) for o in options]
    if all(refused):
        raise DropoffRefused(cell.motion.dropoff_mm, refused[0][0])
    options = [o for o, why in zip(options, refused, strict=True) if not why]
    q = near.as_array()
    return sorted(options, key=lambda o: float(np.sum(np.abs((o.as_array() - q)[[0, 1, 3]]))))


class DropoffRefused(CellError):
    """The drop-off is reachable, but the arm may be sent none of its configurations (`why`: the
    first one's reason)."""

    def __init__(self, dropoff_mm, why: str):
        super().__init__(f"the drop-off {dropoff_mm} cannot be sent to the arm: {why}")
        self.why = why


def dropoff_joints(cell: Cell, near: Joints) -> Joints:
    return dropoff_options(cell, near)[0]


def pick_commands(grasp_joints: Joints, opening_mm: float, cell: Cell, safe_z_mm: float | None = None,
                  drop: Joints | None = None, *, check_grip: bool = True,
                  check_in_transit: bool = False) -> list[Command]:
    """Commands of one pick; `grasp_joints` is the configuration at the grasp (J3 = grasp z);
    travel at `safe_z_mm` (default: the cell's safe height), which must be above the grasp; let
    go at `drop` (default: the drop-off configuration nearest to the grasp's). `check_grip`: the
    grip again after the lift (off: as the loop picked before 2026-12-04; recordings replay so);
    `check_in_transit`: and above the drop-off (`carry_off_commands`)."""
    safe = cell.motion.safe_z_mm if safe_z_mm is None else safe_z_mm
    return [
        *_take(grasp_joints, opening_mm, cell, safe),
        *carry_off_commands(grasp_joints, grasp_joints, cell, safe, drop,
                            check_width_mm=opening_mm if check_grip else None,
                            transit_width_mm=opening_mm if check_in_transit else None),
    ]


def place_back_commands(grasp_joints: Joints, opening_mm: float, cell: Cell, safe_z_mm: float) -> list[Command]:
    """A pick that puts the part back where it lay (a hardware-in-loop trial, `cell hw pick --place-back`):
    approach, pre-open, descend, grip, lift, check, down again to the grasp, open to the approach opening (the
    width the planner cleared the fingers for there), up, and open fully there (the next trial starts with the
    jaws open: it refuses jaws that are not, as they may hold something)."""
    take = _take(grasp_joints, opening_mm, cell, safe_z_mm)
    up = above(grasp_joints, safe_z_mm)
    return [
        *take,
        Command("move", "lift", up),
        Command("check", "check", width_mm=opening_mm, force_n=cell.gripper.grip_force_n),
        Command("move", "put back", grasp_joints),
        Command("open", "release", width_mm=approach_opening_mm(opening_mm, cell)),
        Command("move", "retreat", up),
        Command("open", "open", width_mm=cell.gripper.opening_mm[1]),
    ]


def _take(grasp_joints: Joints, opening_mm: float, cell: Cell, safe_z_mm: float) -> list[Command]:
    """Approach above the grasp at the travel height (which must be above it), open to the approach opening,
    descend, grip."""
    if safe_z_mm <= grasp_joints.j3_mm:
        raise CellError(f"the travel height {safe_z_mm:g} mm is not above the grasp z {grasp_joints.j3_mm:g} mm")
    return [
        Command("move", "approach", above(grasp_joints, safe_z_mm)),
        Command("open", "pre-open", width_mm=approach_opening_mm(opening_mm, cell)),
        Command("move", "descend", grasp_joints),
        Command("grip", "grip", width_mm=opening_mm, force_n=cell.gripper.grip_force_n),
    ]


def approach_opening_mm(opening_mm: float, cell: Cell) -> float:
    """How far the jaws open above and around a grasp: the contacts' distance + 2 x the approach
    clearance (CONTRACT), within the stroke. The planner cleared the fingers up to this opening at
    the grasp's depth, and no further."""
    g = cell.gripper
    return min(opening_mm + 2 * g.approach_clearance_mm, g.opening_mm[1])


def retreat_opening_mm(opening_mm: float, standing_mm: float | None, cell: Cell) -> float:
    """How far the jaws open before going up from a grasp of `opening_mm` they did not hold: its approach
    opening (the width the planner cleared the fingers for there), never narrower than they stand
    (`standing_mm`: they stopped wider on something), within the stroke."""
    return min(max(approach_opening_mm(opening_mm, cell), standing_mm or 0.0), cell.gripper.opening_mm[1])


def carry_off_commands(from_joints: Joints, grasp_joints: Joints, cell: Cell, safe_z_mm: float,
                       drop: Joints | None = None, *, check_width_mm: float | None = None,
                       transit_width_mm: float | None = None) -> list[Command]:
    """A held part from where the arm is (`from_joints`) to the drop-off: straight up to the travel
    height, (with `check_width_mm`, the part's expected width: the grip checked there, against the width the
    jaws held it at when this list gripped it), across, (with `transit_width_mm`, the same: checked again above
    the drop-off, `TRANSIT_CHECK`), down, let go, up; at `drop` (default: the drop-off configuration nearest to
    `grasp_joints`)."""
    drop = drop or dropoff_joints(cell, grasp_joints)
    check = [] if check_width_mm is None else [_check("check", check_width_mm, cell)]
    # a part lost on the way (off the tray: the floor) is not let go at the drop-off; without this check it
    # counted as removed once the next frame showed it gone. Before the lowering: what falls there is off anyway
    in_transit = [] if transit_width_mm is None else [_check(TRANSIT_CHECK, transit_width_mm, cell)]
    return [
        Command("move", "lift", above(from_joints, safe_z_mm)),
        *check,
        Command("move", "carry", above(drop, safe_z_mm)),
        *in_transit,
        Command("move", "lower", drop),
        Command("open", "release", width_mm=cell.gripper.opening_mm[1]),
        Command("move", "retreat", above(drop, safe_z_mm)),
    ]

