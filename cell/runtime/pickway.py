"""A pick's commands with a way clear of the parts on the tray: how high to travel, and which drop-off
configuration (and ways round what the drivers refuse) keeps the arm's links off them. Shared by the cell
loop and `cell hw pick`; the arm is asked only for the paths its drives take (`Arm.path`)."""

from __future__ import annotations

from collections.abc import Callable

from cell.cellconfig import Cell
from cell.configuration import path_link_collisions
from cell.errors import CellError
from cell.kinematics import Joints
from cell.runtime.motion import Command, dropoff_options
from cell.runtime.ways import routed
from cell.scene import Part

TRAVEL_MARGIN_MM = 20.0  # above the tallest part on the tray, when travelling


class LinksWouldHit(CellError):
    """A grasp whose moves would sweep a link of the arm over a part taller than its underside."""


def travel_z_mm(cell: Cell, part: Part, others: list[Part], grasp_z_mm: float) -> float:
    """Travel height of the finger tips for a pick of `part` among `others`: the cell's safe height, or higher
    when the parts on the tray are tall: the empty jaws and the held part hanging below them (from the tips
    down to its bottom) must pass over every part with a margin."""
    tops = [p.z_top_mm for p in others]
    empty = max([part.z_top_mm, *tops]) + TRAVEL_MARGIN_MM  # the open jaws, to and from the grasp
    loaded = max(tops, default=0.0) + TRAVEL_MARGIN_MM + (grasp_z_mm - part.z_bottom_mm)
    safe = max(cell.motion.safe_z_mm, empty, loaded)
    if safe > cell.scara.j3_mm[1]:
        raise CellError(f"{part.id} cannot be carried over the parts on the tray: it needs a travel "
                        f"height of {safe:.0f} mm, J3 reaches {cell.scara.j3_mm[1]:g} mm")
    return safe


def check_links(arm, cell: Cell, others: list[Part], commands, why: str, start: Joints | None = None) -> None:
    """The links along every move of `commands`, from where the arm is (or `start`), against `others` (the
    parts on the tray, not the one in the jaws); a hit refuses the whole list before anything moves."""
    at = arm.joints() if start is None else start
    for c in commands:
        if c.joints is None:
            continue
        hit = path_link_collisions(arm.path(at, c.joints), cell, others)
        if hit:
            raise LinksWouldHit(f"{why}on the way to '{c.label}' the arm's links would hit {', '.join(hit)}")
        at = c.joints


def links_clear(arm, cell: Cell, others: list[Part]) -> Callable[[Joints, Joints], list[str]]:
    """A move's reasons against it (`ways.LegCheck`): the links on the drives' path hitting `others`."""
    s = cell.scara
    tall = [p for p in others if p.z_top_mm > min(s.link1_bottom_z_mm, s.link2_bottom_z_mm)]

    def reasons(a: Joints, b: Joints) -> list[str]:
        hit = path_link_collisions(arm.path(a, b), cell, tall) if tall else []  # (none: no path to sample)
        return [f"the arm's links would hit {', '.join(hit)}"] if hit else []

    # what its answers depend on (`ways._pick_grid_way` keeps the poses a search reached without a way): the parts,
    # and the arm's profiles (`Arm.path`), not the arm (kept, it would keep its bus)
    reasons.key = (repr(arm.cell.scara), tuple((p.id, p.z_top_mm, p.polygon.wkb) for p in tall)) if tall else ()
    return reasons


def clear_commands(arm, cell: Cell, others: list[Part], commands: list[Command], why: str,
                   start: Joints | None = None, *, check: Callable[[list[Command]], None] | None = None,
                   known: dict | None = None, grid: bool = True) -> list[Command]:
    """`commands` from where the arm is (or `start`), ways the drivers refuse gone round (`ways.routed`, the
    ways found kept in `known`; `grid`: the grid's ways too, each step with the links checked), the links clear
    of `others` all along (`check`: how the whole list is checked, by default `check_links`); LinksWouldHit
    when they are not."""
    start = arm.joints() if start is None else start
    check = check or (lambda listed: check_links(arm, cell, others, listed, why, start))
    try:
        routed_commands = routed(commands, start, cell, links_clear(arm, cell, others), known, grid=grid)
        check(routed_commands)
    except LinksWouldHit:
        raise
    except CellError as e:
        raise LinksWouldHit(f"{why}{e}") from None
    return routed_commands


def clear_way(arm, cell: Cell, others: list[Part], grasp_joints: Joints, why: str,
              commands_to: Callable[[Joints], list[Command]],
              check: Callable[[list[Command]], None] | None = None, start: Joints | None = None, *,
              grid: bool = True) -> list[Command]:
    """`commands_to(drop)` for the first drop-off configuration (nearest to the grasp's first: the other
    elbow, the J4 turns) whose moves keep the links clear of `others` (`clear_commands`, with `grid`), from where
    the arm is (or `start`); LinksWouldHit (the first one's reason) when none does."""
    first = None
    start = arm.joints() if start is None else start  # (read once: every drop-off's way starts there)
    known: dict = {}  # the ways round, found once for every drop-off (the way to the grasp is the same)
    for drop in dropoff_options(cell, grasp_joints):
        try:
            return clear_commands(arm, cell, others, commands_to(drop), why, start, check=check, known=known,
                                  grid=grid)
        except LinksWouldHit as e:
            first = first or e
        except CellError as e:  # commands_to's own (a travel height not above the grasp)
            first = first or LinksWouldHit(f"{why}{e}")
    raise first
