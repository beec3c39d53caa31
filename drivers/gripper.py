"""The parallel gripper as seen by the cell: open, grip under a force limit, report the width.

A CiA 402 node whose position is the jaw opening (mm). `grip` closes fully under the force
limit (0x2100); the drive stops on the part (statusword bit 11, internal limit) or closes
past it when there is none, and the final width tells a held part from a missed one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cell.cellconfig import GRIPPER_ACCEL_FACTOR, grip_force_units
from drivers.arm_moves import at_counts
from drivers.eds import GRIP_FORCE_INDEX
from drivers.errors import DriveFault, LimitError
from drivers.limits import gripper_violations
from drivers.profile import trapezoid

if TYPE_CHECKING:
    from drivers.arm import Arm



@dataclass(frozen=True)
class GripResult:
    """Where the jaws stopped. `holding` is False when they closed past the expected width, or stopped on
    something wider (`blocked`: a neighbour, a finger jammed, another part between the jaws). `stopped`: on
    something, at any width (the force limit reached before they closed fully)."""

    width_mm: float
    holding: bool
    expected_width_mm: float
    blocked: bool = False
    stopped: bool = False


class Gripper:
    """The parallel gripper (node 'gripper'): open, grip with a force limit, report the width."""

    def __init__(self, arm: Arm):
        self._arm = arm
        self._force_n: float | None = None
        # the width the jaws last closed on something at, until they open again: a part may be in them
        self.closed_on_mm: float | None = None

    @property
    def width_mm(self) -> float | None:
        ax = self._arm.axes.get("gripper")
        return ax.position if ax is not None else None

    def require_open(self, tolerance_mm: float = 1.0) -> None:
        """Refuse (CellError) jaws that do not stand open: something may be between them (a pick cut short
        by Ctrl-C, a part left in them), and the first pre-open, high over the tray, would drop it."""
        width, top = self.width_mm, self._arm.cell.gripper.opening_mm[1]
        if width is not None and width < top - tolerance_mm:
            from cell.errors import CellError

            raise CellError(f"the jaws stand at {width:.1f} mm, not open ({top:g} mm): something may be between "
                            "them; take it out and open them (`cell hw gripper open`) first; nothing moved")

    def move_time_s(self, from_mm: float, to_mm: float) -> float:
        g = self._arm.cell.gripper
        return trapezoid(to_mm - from_mm, g.speed_mm_s, GRIPPER_ACCEL_FACTOR * g.speed_mm_s).duration_s

    def _move(self, width_mm: float, *, wait: bool = True) -> None:
        arm = self._arm
        ax = arm.axes["gripper"]
        duration = self.move_time_s(ax.position, width_mm)
        arm._run_moves({"gripper": ax.to_counts(width_mm)}, wait=wait, timeout_s=1.5 * duration + 1.0)

    def open(self, width_mm: float | None = None) -> float:
        """Open the jaws (fully by default) or close them to `width_mm` (the pre-open above a part); returns the
        width reached. Jaws that end the move farther from `width_mm` than the gripper's arrival tolerance
        stopped on something: a latched `DriveFault` naming both widths, every axis stopped (`_require_reached`)."""
        arm = self._arm
        arm._begin_command()
        width_mm = arm.cell.gripper.opening_mm[1] if width_mm is None else width_mm
        problems = gripper_violations(arm.cell, width_mm)
        if problems:
            raise LimitError("gripper command refused, nothing sent: " + "; ".join(problems))
        self._move(width_mm)
        self._require_reached(width_mm)
        self.closed_on_mm = None
        return self.width_mm

    def _require_reached(self, width_mm: float) -> None:
        """The drive ends a move stopped on something with its internal limit (bit 11), which the host takes for
        arrival (a grip closes on the part that way). An opening is to reach its width: jaws of the pre-open
        stopped at 60 mm of 50 went down 10 mm wider than the planner cleared. More than the arrival tolerance
        (`POSITION_TOLERANCE_COUNTS`, 0.002 mm on the shipped cell) off is a fault."""
        ax = self._arm.axes["gripper"]
        if at_counts(ax.status, ax.to_counts(width_mm)):  # as `Arm._arrived`
            return
        self._arm._stop_on(DriveFault(
            f"gripper (node {ax.node_id}): the jaws stopped at {ax.position:.1f} mm opening to {width_mm:.1f} mm: "
            "something between them? Every axis stopped: take it out, then reset", node="gripper",
            node_id=ax.node_id))

    def grip(self, expected_width_mm: float, force_n: float | None = None, *, tolerance_mm: float = 2.0) -> GripResult:
        """Close with the force limit (default: the cell file's grip force) and report where the
        jaws stopped: holding when they stopped on something within `tolerance_mm` of
        `expected_width_mm`; a miss closes past it; jaws stopped wider than that are blocked, not holding
        (they reported holding whatever they stopped on, 60 mm for a 24 mm part, and the arm lifted)."""
        arm = self._arm
        arm._begin_command()
        force_n = arm.cell.gripper.grip_force_n if force_n is None else force_n
        problems = gripper_violations(arm.cell, expected_width_mm, force_n)
        if not (isinstance(tolerance_mm, (int, float)) and 0 <= tolerance_mm < math.inf):
            problems.append(f"grip tolerance {tolerance_mm} mm must be 0 or more and finite (jaws blocked wide "
                            "open would count as holding)")
        if problems:
            raise LimitError("grip refused, nothing sent: " + "; ".join(problems))
        ax = arm.axes["gripper"]
        if force_n != self._force_n:
            arm._guarded(ax.sdo_write, GRIP_FORCE_INDEX, 0, grip_force_units(force_n))
            self._force_n = force_n
        self._move(arm.cell.gripper.opening_mm[0])
        width = self.width_mm
        st = ax.status
        stopped = bool(st.internal_limit)
        blocked = stopped and width > expected_width_mm + tolerance_mm
        holding = stopped and not blocked and width >= expected_width_mm - tolerance_mm
        self.closed_on_mm = width if stopped else None
        return GripResult(width, holding, expected_width_mm, blocked, stopped)
