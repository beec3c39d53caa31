"""Ways between two poses that the drivers take (pure, but `go_to`, which moves the arm).

`drivers.limits` refuses a move whose way leaves the workspace (two poses inside it can sweep out of
it between them: an elbow flip through the stretched arm, a swing of the stretched arm past the box)
or moves across while J3 moves below the safe height. A pick's moves, and the homes of a run, go
round such ways here by a few moves more, each checked from the one before as the drivers will.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
from collections.abc import Callable

import numpy as np

from cell.cellconfig import Cell
from cell.errors import CellError
from cell.kinematics import Joints
from cell.runtime.motion import Command, above
from drivers.limits import command_violations

# J1 angles tried for an elbow flip (the stretched arm must lie inside the workspace while J2 passes 0), and J2
# bends tried for a swing of J1: every 5 degrees, the nearest first (each try of a pick's way checks the links
# too, some milliseconds)
TRY_STEP_DEG = 5.0
TRY_NEAREST = 30  # of each: the nearest 150 degrees (a pick's way beyond them is not worth the time)
# the last resort, a search on a grid of J1 and J2 (moves of one joint between neighbours, each checked as the
# drivers will and by the caller's check): this fine, at most this many poses looked at
GRID_STEP_DEG = 5.0
GRID_MAX_NODES = 5000
LegCheck = Callable[[Joints, Joints], list[str]]  # (from, to) -> why the move must not be taken (empty: it may)
# The poses a pick's grid search reached from a start without finding a way (`_pick_grid_way`), the last this many:
# (id(cell), start J1, start J2, J3, the leg check's `key`) -> (cell, {grid nodes})
_UNREACHED: dict = {}
UNREACHED_KEPT = 32


def routed(commands: list[Command], start: Joints, cell: Cell, leg_ok: LegCheck | None = None,
           known: dict | None = None, *, grid: bool = True) -> list[Command]:
    """`commands` from `start` with every move whose way the drivers would refuse split by the moves of
    `way_to` (each also passing `leg_ok`, the caller's reasons against a move: the links hitting the parts on
    the tray), labelled '<label> (via)'. Moves whose own target is refused stay as they are (the drivers name
    the reason). CellError when a move has no such way, or (with `grid`) when a move the drivers take fails
    `leg_ok` (before a way round a later move is searched: the grid's search that finds none is long). `known`
    keeps the ways found (or refused) for the next call with the same `leg_ok` (the drop-off's options share the
    way to the grasp). `grid`: as `way_to`'s."""
    known = {} if known is None else known
    out, at = [], start
    for c in commands:
        if c.joints is None:
            out.append(c)
            continue
        if command_violations(cell, c.joints, None):
            out.append(c)
        elif not command_violations(cell, c.joints, at):
            hit = leg_ok(at, c.joints) if grid and leg_ok is not None else []
            if hit:  # the caller's check refuses the list there: no way round a later move need be looked for
                raise CellError(f"on the way to '{c.label}' {'; '.join(hit)}")
            out.append(c)
        else:
            key = (at, c.joints, c.label)
            if key not in known:
                try:
                    known[key] = way_to(cell, at, c.joints, c.label, leg_ok, grid=grid)
                except CellError as e:
                    known[key] = e
            if isinstance(known[key], CellError):
                raise known[key]
            *via, _ = known[key]
            out += [Command("move", f"{c.label} (via)", joints=v) for v in via] + [c]
        at = c.joints
    return out


def _why_not(cell: Cell, start: Joints, moves: list[Joints], leg_ok: LegCheck | None) -> list[str]:
    """Why the drivers refuse a move of `moves` (taken one after the other from `start`), or, they taking
    all, why `leg_ok` does ('the arm's links would hit ...'); empty when every move may be taken."""
    at = start
    for m in moves:
        why = command_violations(cell, m, at) or (leg_ok(at, m) if leg_ok is not None else [])
        if why:
            return why
        at = m
    return []


def _clear(cell: Cell, start: Joints, moves: list[Joints], leg_ok: LegCheck | None) -> bool:
    return not _why_not(cell, start, moves, leg_ok)


def way_to(cell: Cell, start: Joints, target: Joints, label: str = "move",
           leg_ok: LegCheck | None = None, *, grid: bool = True) -> list[Joints]:
    """Moves from `start` ending at `target` that the drivers take, each with its way checked
    (`command_violations` from the one before): directly; or J1 (with J3, J4) first, then J2; or J2 first;
    or J1 to where the stretched arm lies inside the workspace, J2 there, then J1; or J2 bent, J1 across,
    J2 back (the nearest such J1 or J2 first); else the shortest way on a grid of J1 and J2 (`_grid_way`; with
    `leg_ok`, `_pick_grid_way`, each step also passing it, its staircase cut short by `_shortcut`). `grid` False:
    no grid with `leg_ok` (recordings made before: a longer arm's elbow flip, whose stretched arm leaves the
    workspace at every J1 tried, had no way).
    CellError naming the direct way's reason when none is clear."""

    def nearest(lo_hi, a, b):
        return sorted(_grid(lo_hi, TRY_STEP_DEG), key=lambda v: abs(v - a) + abs(v - b))[:TRY_NEAREST]

    z, j4 = target.j3_mm, target.j4_deg
    candidates = itertools.chain(
        [[target],
         [Joints(target.j1_deg, start.j2_deg, z, j4), target],
         [Joints(start.j1_deg, target.j2_deg, z, j4), target]],
        ([Joints(float(a), start.j2_deg, z, j4), Joints(float(a), target.j2_deg, z, j4), target]
         for a in nearest(cell.scara.j1_deg, start.j1_deg, target.j1_deg)),
        ([Joints(start.j1_deg, float(b), z, j4), Joints(target.j1_deg, float(b), z, j4), target]
         for b in nearest(cell.scara.j2_deg, start.j2_deg, target.j2_deg)))
    round_it = []  # why the first way round the drivers take is not clear (the links would hit a part)
    for moves in candidates:
        why = _why_not(cell, start, moves, leg_ok)
        if not why:
            return moves
        if not round_it and len(moves) > 1 and not _why_not(cell, start, moves, None):
            round_it = why
    if leg_ok is None:  # a home's way, as it was (recordings replay their homes' moves)
        moves = _grid_way(cell, start, target)
    else:
        moves = _pick_grid_way(cell, start, target, leg_ok) if grid else None
        moves = moves and _shortcut(cell, start, moves, leg_ok)
    if moves:
        return moves
    direct = _why_not(cell, start, [target], leg_ok)
    raise CellError(f"no way to '{label}' the arm may take: {'; '.join(direct)}"
                    + (f"; round it, {'; '.join(round_it)}" if round_it else ""))


def _grid(lo_hi: tuple[float, float], step: float) -> list[float]:
    """Whole multiples of `step` within the limits."""
    return (np.arange(np.ceil(lo_hi[0] / step), np.floor(lo_hi[1] / step) + 1) * step).tolist()


def _grid_way(cell: Cell, start: Joints, target: Joints) -> list[Joints] | None:
    """The shortest way (in J1 + J2 degrees) over a grid of J1 and J2, one joint moving at a time, at the
    target's J3 and J4 (taken first, where the arm stands); runs of one joint merged where the drivers take
    the merged move. None when the grid holds no way."""
    s = cell.scara
    z, j4 = target.j3_mm, target.j4_deg
    first = Joints(start.j1_deg, start.j2_deg, z, j4)
    if first != start and not _clear(cell, start, [first], None):
        return None
    axes = [sorted({*_grid((lo, hi), GRID_STEP_DEG), a, b})
            for (lo, hi), a, b in ((s.j1_deg, start.j1_deg, target.j1_deg), (s.j2_deg, start.j2_deg, target.j2_deg))]
    begin = (axes[0].index(start.j1_deg), axes[1].index(start.j2_deg))
    goal = (axes[0].index(target.j1_deg), axes[1].index(target.j2_deg))

    def pose(node):
        return Joints(axes[0][node[0]], axes[1][node[1]], z, j4)

    def h(node):
        return abs(axes[0][node[0]] - target.j1_deg) + abs(axes[1][node[1]] - target.j2_deg)

    came: dict = {begin: None}
    cost = {begin: 0.0}
    todo = [(h(begin), begin)]
    while todo and len(came) < GRID_MAX_NODES:
        _, node = heapq.heappop(todo)
        if node == goal:
            break
        for axis, d in ((0, -1), (0, 1), (1, -1), (1, 1)):
            nxt = (node[0] + d, node[1]) if axis == 0 else (node[0], node[1] + d)
            if not 0 <= nxt[axis] < len(axes[axis]):
                continue
            c = cost[node] + abs(axes[axis][nxt[axis]] - axes[axis][node[axis]])
            if c < cost.get(nxt, np.inf) and _clear(cell, pose(node), [pose(nxt)], None):
                cost[nxt], came[nxt] = c, node
                heapq.heappush(todo, (c + h(nxt), nxt))
    if goal not in came:
        return None
    nodes = [goal]
    while came[nodes[-1]] is not None:
        nodes.append(came[nodes[-1]])
    path = nodes[::-1]
    head = [first] if first != start else []
    merged = head + [pose(n) for n in _corners(path)[1:-1]] + [target]
    return merged if _clear(cell, start, merged, None) else head + [pose(n) for n in path[1:-1]] + [target]


def _pick_grid_way(cell: Cell, start: Joints, target: Joints, leg_ok: LegCheck) -> list[Joints] | None:
    """The shortest way (in J1 + J2 degrees) for a pick's move: over the grid of whole multiples of GRID_STEP_DEG
    (and the start's J1 and J2), one joint moving at a time, at the target's J3 and J4 (taken first, where the arm
    stands), the target reached by one move from a corner of the grid's square around it; every move checked as
    the drivers will and by `leg_ok`. None when there is none. The grid does not depend on the target (only
    the corners do): a search from a start that found no way saw every pose the start reaches, kept for a
    `leg_ok` with a `key` (`pickway.links_clear`): a later target none of whose corners it saw is refused
    without a search (a cell with no way round searched 0.35 s for each of 91 grasps)."""
    s = cell.scara
    z, j4 = target.j3_mm, target.j4_deg
    first = Joints(start.j1_deg, start.j2_deg, z, j4)
    if first != start and not _clear(cell, start, [first], leg_ok):
        return None
    axes = [sorted({*_grid(lim, GRID_STEP_DEG), a}) for lim, a in ((s.j1_deg, start.j1_deg), (s.j2_deg, start.j2_deg))]
    corners = {(i, k) for i in _around(axes[0], target.j1_deg) for k in _around(axes[1], target.j2_deg)}
    # (J4 aside: the grid's moves keep J3 and J4, and the drivers' checks of such moves do not depend on J4)
    key = (id(cell), start.j1_deg, start.j2_deg, z, getattr(leg_ok, "key", None))
    seen = _UNREACHED.get(key) if key[-1] is not None else None
    if seen is not None and seen[0] is cell and not corners & seen[1]:
        return None

    def pose(node):
        return Joints(axes[0][node[0]], axes[1][node[1]], z, j4)

    def h(node):  # the last move's own cost from a corner: the search ends at the first corner popped that takes it
        return abs(axes[0][node[0]] - target.j1_deg) + abs(axes[1][node[1]] - target.j2_deg)

    begin = (axes[0].index(start.j1_deg), axes[1].index(start.j2_deg))
    came: dict = {begin: None}
    cost = {begin: 0.0}
    todo = [(h(begin), 0.0, begin)]
    while todo and len(came) < GRID_MAX_NODES:
        _, c0, node = heapq.heappop(todo)
        if c0 > cost[node]:
            continue  # reached more cheaply since
        if node in corners and _clear(cell, pose(node), [target], leg_ok):
            nodes = [node]
            while came[nodes[-1]] is not None:
                nodes.append(came[nodes[-1]])
            return ([first] if first != start else []) + [pose(n) for n in nodes[::-1][1:]] + [target]
        for axis, d in ((0, -1), (0, 1), (1, -1), (1, 1)):
            nxt = (node[0] + d, node[1]) if axis == 0 else (node[0], node[1] + d)
            if not 0 <= nxt[axis] < len(axes[axis]):
                continue
            c = c0 + abs(axes[axis][nxt[axis]] - axes[axis][node[axis]])
            if c < cost.get(nxt, np.inf) and _clear(cell, pose(node), [pose(nxt)], leg_ok):
                cost[nxt], came[nxt] = c, node
                heapq.heappush(todo, (c + h(nxt), c, nxt))
    if not todo and key[-1] is not None:  # every pose the start reaches seen (not cut off at GRID_MAX_NODES)
        _UNREACHED[key] = (cell, frozenset(came))
        while len(_UNREACHED) > UNREACHED_KEPT:
            del _UNREACHED[next(iter(_UNREACHED))]
    return None


def _around(values: list[float], v: float) -> set[int]:
    """The indices of the grid values next below and above `v` (one, where `v` is on the grid)."""
    i = bisect.bisect_left(values, v)
    return {k for k in (i - 1, i) if 0 <= k < len(values)} if i == len(values) or values[i] != v else {i}


def _shortcut(cell: Cell, start: Joints, moves: list[Joints], leg_ok: LegCheck | None) -> list[Joints]:
    """`moves` (taken one after the other from `start`) with each run of them that one move, checked as the
    drivers will and by `leg_ok`, can take at once (to its last) made that move: the grid's staircase of one
    joint at a time stopped at every step (a pick's way round of 22 moves took 4 s more than one of 3)."""
    out, at, i = [], start, 0
    while i < len(moves):
        while i + 1 < len(moves) and _clear(cell, at, [moves[i + 1]], leg_ok):
            i += 1
        out.append(moves[i])
        at, i = moves[i], i + 1
    return out


def _corners(nodes: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The nodes where the moving joint changes (runs of one joint as one move), the ends kept."""
    out = [nodes[0]]
    for a, b, c in zip(nodes, nodes[1:], nodes[2:]):
        if (a[0] == b[0]) != (b[0] == c[0]):
            out.append(b)
    return out + [nodes[-1]] if len(nodes) > 1 else out


def go_to(arm, target: Joints) -> None:
    """Move the arm from wherever it stands to `target` as the drivers allow: below the safe height straight
    up first (to the target's height, or the safe height), across in steps within `max_step` by ways the
    drivers take (`way_to`), then straight down. For a start the cell does not choose: home at the start of a
    run, whose arm may stand anywhere on a real cell (lifting and swinging at once dragged the fingers
    sideways through the tray)."""
    from drivers.limits import split_move

    cell, at = arm.cell, arm.joints()
    safe = cell.motion.safe_z_mm
    travel = max(at.j3_mm, target.j3_mm) if at.j3_mm >= safe or target.j3_mm >= safe else safe
    if at.j3_mm < travel:
        arm.move_joints(above(at, travel))
        at = arm.joints()
    for waypoint in split_move(at, above(target, travel), cell.scara.max_step):
        for move in way_to(cell, at, waypoint, "home"):
            arm.move_joints(move)
        at = waypoint
    if target.j3_mm < travel:
        arm.move_joints(target)
