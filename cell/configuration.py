"""Paper step 5: the arm configuration for the chosen contacts, learned from the examples.

Among the joint solutions that reach the chosen grasp (both elbows, J4 and J4 + k * 180 for
the symmetric jaws, all inside the joint limits) the cell keeps those whose links clear
every part taller than the link's underside, then takes the one nearest to a configuration
of the operator's valid examples (those this cell's arm could have taken: within its joint limits, reaching
their own grasp centre; `configurations_for_cell`), in a weighted joint-space distance where joints nearer
the contacts weigh more (weights from the cell file, `configuration.joint_weights`).
Without any example configuration the choice falls back to the smallest wrist turn.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence

import numpy as np
from shapely.geometry import LineString

from cell.cellconfig import JOINTS, Cell
from cell.examples import GraspExample
from cell.kinematics import Joints, elbow_points, tool_xy
from cell.scene import Part

log = logging.getLogger(__name__)
# An example's configuration is this arm's when its forward kinematics land within this of the example's grasp
# centre: the shipped examples land within 0.001 mm with the default cell, ones taught on an arm of other link
# lengths tens of mm off
MAX_CONFIGURATION_MISS_MM = 3.0
LIMIT_TOL = 1e-6  # deg, mm: an example's joints as written (4 decimals) on a limit are within it
_TOLD: set = set()  # (cell, set-aside example ids) already told: once per cell and set of examples
_LAST: tuple | None = None  # (cell, examples, their configurations): the last answer of example_configurations


def example_configurations(examples: Iterable[GraspExample], cell: Cell | None = None) -> np.ndarray:
    """The joint vectors of the valid examples that carry one, shape (k, 4); with `cell`, only those this cell's
    arm could have taken (`configurations_for_cell`)."""
    global _LAST
    chosen = tuple(e for e in examples if e.valid and e.joints is not None)
    last = _LAST  # one read: another thread may set it meanwhile
    if last is not None and last[0] is cell and len(last[1]) == len(chosen) and all(
            a is b for a, b in zip(last[1], chosen)):
        return last[2]  # every plan asks again with the same examples and cell: worked out once (0.9 ms)
    kept = configurations_for_cell(chosen, cell) if cell is not None else chosen
    configs = np.array([e.joints.as_array() for e in kept], float).reshape(-1, 4)
    configs.flags.writeable = False
    _LAST = (cell, chosen, configs)  # holds the examples: their ids stay theirs
    return configs


def configurations_for_cell(examples: Sequence[GraspExample], cell: Cell) -> list[GraspExample]:
    """The examples (each with joints) whose configuration this cell's arm can take: within its joint limits, and
    whose forward kinematics with its links put the tool within MAX_CONFIGURATION_MISS_MM of the example's own
    grasp centre (the two contacts' midpoint). Examples taught on another arm (other links, other limits) would
    otherwise steer step 5 towards configurations that do not belong to their grasps. The set-aside ones are told
    once per cell and set of examples (a warning, the rest are used)."""
    if not examples:
        return []
    s = cell.scara
    q = np.array([e.joints.as_array() for e in examples], float)
    lo, hi = (np.array([s.limits(j)[k] for j in JOINTS]) for k in (0, 1))
    outside = np.any((q < lo - LIMIT_TOL) | (q > hi + LIMIT_TOL), axis=1)
    x, y = tool_xy(q, s)
    centre = np.array([e.contacts_mm[:2].mean(axis=0) if e.n_contacts == 2 else (np.nan, np.nan) for e in examples])
    miss = np.hypot(x - centre[:, 0], y - centre[:, 1])  # nan (not checked) for another number of contacts
    missed = ~outside & (miss > MAX_CONFIGURATION_MISS_MM)
    if outside.any() or missed.any():
        _tell_set_aside(examples, cell, outside, missed, miss)
    return [e for e, bad in zip(examples, outside | missed) if not bad]


def _tell_set_aside(examples, cell: Cell, outside: np.ndarray, missed: np.ndarray, miss: np.ndarray) -> None:
    key = (cell.source, cell.name, tuple(e.id for e, bad in zip(examples, outside | missed) if bad))
    if key in _TOLD:
        return
    _TOLD.add(key)
    s, why = cell.scara, []
    if outside.any():
        limits = ", ".join(f"{j.upper()} [{s.limits(j)[0]:g}, {s.limits(j)[1]:g}]" for j in JOINTS)
        why.append(f"{int(outside.sum())} outside its joint limits ({limits})")
    if missed.any():
        why.append(f"{int(missed.sum())} whose joint angles put this arm's tool (L1 {s.l1_mm:g}, L2 {s.l2_mm:g} mm) "
                   f"more than {MAX_CONFIGURATION_MISS_MM:g} mm from their own grasp centre (up to "
                   f"{np.nanmax(miss[missed]):.1f} mm)")
    kept = len(examples) - int((outside | missed).sum())
    log.warning(f"step 5 (arm configuration): {len(examples) - kept} of {len(examples)} accepted examples' "
                f"configurations set aside for the cell {cell.name!r} ({cell.source}), taught for another arm: "
                f"{'; '.join(why)}. "
                + (f"Step 5 uses the other {kept}" if kept else "Step 5 takes the smallest wrist turn instead"))


def _fold180(a: np.ndarray) -> np.ndarray:
    """Angles folded into [-90, 90): the jaws are symmetric, so a direction is mod 180."""
    return (a + 90.0) % 180.0 - 90.0


def weighted_distance(options: np.ndarray, configs: np.ndarray, weights: dict) -> np.ndarray:
    """Distance of each option (n, 4) to its nearest example configuration (k, 4), shape (n,).

    J4 is compared in two parts. Its direction mod 180 (how the jaws sit on the arm) is
    compared after turning the example's jaws onto the option's closing axis: the example
    was taken on another part, and the wrist should be compared as a habit, not as that
    part's orientation. Its wind (how many half turns away from the fold in [-90, 90), i.e.
    which of J4, J4 +/- 180 ...) is compared as a count of half turns: an operator who always
    takes the smallest wind-up teaches wind 0. Degrees and millimetres are mixed as they are:
    J3 is the same for every option, so only the revolute joints decide."""
    w = np.array([weights[j] for j in JOINTS], float)
    d = options[:, None, :] - configs[None, :, :]
    axis_turn = _fold180((options[:, 0] + options[:, 1] + options[:, 3])[:, None]
                         - (configs[:, 0] + configs[:, 1] + configs[:, 3])[None, :])
    d_dir = _fold180(d[:, :, 3] - axis_turn)
    wind_opt = np.rint((options[:, 3] - _fold180(options[:, 3])) / 180.0)
    wind_ex = np.rint((configs[:, 3] - _fold180(configs[:, 3])) / 180.0)
    d_wind = 180.0 * (wind_opt[:, None] - wind_ex[None, :])
    sq = w[0] * d[:, :, 0] ** 2 + w[1] * d[:, :, 1] ** 2 + w[2] * d[:, :, 2] ** 2 + w[3] * (d_dir ** 2 + d_wind ** 2)
    return np.sqrt(np.min(sq, axis=1))


def link_collisions(j: Joints, cell: Cell, parts: Sequence[Part]) -> list[str]:
    """Ids of the parts that a link of the arm in configuration `j` would hit: a part
    collides with a link when it is taller than the link's underside and overlaps the
    link's plan-view footprint (the segment between its joints, as wide as the link)."""
    s = cell.scara
    highest = max((p.z_top_mm for p in parts), default=-np.inf)
    if highest <= min(s.link1_bottom_z_mm, s.link2_bottom_z_mm):
        return []  # the usual tray: every part below both links (no footprint to build)
    base, elbow, wrist = elbow_points(j, s)
    links = [(LineString(ends).buffer(width / 2), bottom_z) for ends, width, bottom_z in (
        ([base, elbow], s.link1_width_mm, s.link1_bottom_z_mm), ([elbow, wrist], s.link2_width_mm, s.link2_bottom_z_mm))
        if highest > bottom_z]
    hit = []
    for p in parts:
        for footprint, bottom_z in links:
            if p.z_top_mm > bottom_z and footprint.intersects(p.polygon):
                hit.append(p.id)
                break
    return hit


def path_link_collisions(path: Sequence[Joints], cell: Cell, parts: Sequence[Part]) -> list[str]:
    """Ids of the parts a link hits at any configuration of `path` (samples of a move, e.g.
    `drivers.Arm.path`: the axes do not move in proportion). Only parts taller than a link's
    underside can be hit: without any, nothing is computed."""
    s = cell.scara
    tall = [p for p in parts if p.z_top_mm > min(s.link1_bottom_z_mm, s.link2_bottom_z_mm)]
    for j in path if tall else ():
        hit = link_collisions(j, cell, tall)
        if hit:
            return hit
    return []


def choose_configuration(options: Sequence[Joints], examples: Iterable[GraspExample], cell: Cell,
                         parts: Sequence[Part] = ()) -> Joints | None:
    """The configuration for the grasp: collision-free, nearest to an example's configuration.

    Parameters
    ----------
    options : every joint solution reaching the grasp (from `cell.kinematics.inverse`).
    examples : the teaching examples; valid ones with `joints` are the reference.
    parts : the parts on the tray at that moment (the target included: the links must clear
        it too).
    Returns None when every option hits a part with a link.
    """
    free = [q for q in options if not link_collisions(q, cell, parts)]
    if not free:
        return None
    configs = example_configurations(examples, cell)
    arr = np.array([q.as_array() for q in free])
    if len(configs):
        score = weighted_distance(arr, configs, cell.joint_weights)
    else:
        score = np.abs(arr[:, 3])  # no example configuration: the smallest wrist turn
    return free[int(np.argmin(score))]
