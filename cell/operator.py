"""The simulated operator: gives grasp examples the way a careful person does, and rejects bad ones.

The planner never sees this module, only the example files it writes.

How the operator judges (the labels of the examples and of the learning study):

* A contact point is good when a flat 12 mm pad can seat on it:
  - it is on the part's outer outline and a flat pad (12 x 10 mm) centred on it, face on the
    outline's tangent, stays clear of the rest of the part: a pad does not fit into a recess
    narrower than itself, between gear teeth or right beside a lug;
  - the outline does not turn by `SHARP_TURN_DEG` or more within 1 mm each side (a sharp
    corner; chamfers and fillets are fine), unless the pad lies across tips (`_seat`: fine
    gear teeth, knurls; the pad's face on the convex hull's gentle line, on more than one
    piece of material, together at least the physical check's sharp-patch width wide);
  - it is at most `REACH_MM` from the centre of gravity: farther, no centred grasp within the
    80 mm stroke (70 mm contacts + 2 x 5 clearance) can use it.
* A grasp (two contacts) is good when both points are good, it is nearly antipodal (the
  outline normal at each contact within `ANTIPODAL_DEG` of the line through the contacts),
  centred (the grasp centre within `max(CENTRE_TOL_MM, CENTRE_TOL_FRAC x the part's
  diameter)` of the centre of gravity) and the physical check of `cell.physics` passes
  (closing, collisions, friction, centre of gravity, stroke). The reason given is the first
  of these that fails.

How it chooses its own grasp: every closing axis in 5 degree steps, lines through the
centre of gravity and parallel lines up to 30 mm beside it; the pads go where the line
first meets the outline from outside. Among the good grasps it prefers centred, antipodal
ones with wide flat patches, and picks one of its three favourites at random (people vary).

Arm configuration policy (a person is consistent): elbow right (J2 > 0) for y < 0, elbow
left (J2 <= 0) for y >= 0, the other elbow only if the preferred one cannot reach; J4 the
turn nearest zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon

from cell.cellconfig import Cell, default_cell
from cell.examples import GraspExample
from cell.grasp.height import grasp_z_mm as default_grasp_z_mm
from cell.kinematics import Joints, inverse, normalize_axis_deg
from cell.physics import PATCH_DEPTH_MM, SHARP_PATCH_MM, GraspCheck, check_grasp, outline_normal_and_turn
from cell.scene import Part

HULL_TOL_MM = 0.75
PAD_LIFT_MM = 0.3  # the pad's face this far off the outline: small bumps under it do not count
PAD_OVERLAP_MM2 = 0.5
SHARP_TURN_DEG = 50.0
REACH_MM = 36.0
ANTIPODAL_DEG = 15.0
CENTRE_TOL_MM = 8.0
CENTRE_TOL_FRAC = 0.15
AXIS_STEP_DEG = 5.0
FINE_OFFSETS_MM = tuple(np.arange(-20.0, 20.01, 0.5))
OFFSETS_MM = (0.0, -2.0, 2.0, -4.0, 4.0, -7.0, 7.0, -10.0, 10.0, -15.0, 15.0, -20.0, 20.0, -30.0, 30.0)


@dataclass(frozen=True)
class PointJudgement:
    valid: bool
    reason: str  # "" when valid


@dataclass(frozen=True)
class Judgement:
    valid: bool
    contact_valid: tuple[bool, bool]
    reason: str  # "" when valid; else what a person would say
    check: GraspCheck | None = None


@dataclass(frozen=True)
class OperatorGrasp:
    contacts_mm: np.ndarray  # (2, 2)
    axis_deg: float
    grasp_z_mm: float
    judgement: Judgement
    score: float


class Operator:
    """A careful person at the teaching station (deterministic for a given `rng`)."""

    def __init__(self, cell: Cell | None = None, rng: np.random.Generator | None = None):
        self.cell = cell or default_cell()
        self.rng = rng if rng is not None else np.random.default_rng(0)

    # --- judgement ---------------------------------------------------------------------------
    def judge_point(self, part: Part, p) -> PointJudgement:
        """Would a person put a pad here? (local judgement, see the module docstring)"""
        p = np.asarray(p, float)
        view = _view(part)
        pt = Point(*p)
        if view.outer_ring.distance(pt) > 1.0:
            return PointJudgement(False, "not on the outer outline")
        seat, normal, turn = _seat(view, p, self.cell)
        if normal is None or not _pad_fits(view.outer, seat, normal, self.cell):
            return PointJudgement(False, "in a recess: a flat pad does not fit there")
        if turn >= SHARP_TURN_DEG:
            return PointJudgement(False, f"on a sharp corner ({turn:.0f} deg)")
        if np.linalg.norm(p - view.cog) > REACH_MM:
            return PointJudgement(False, "too far from the centre of gravity")
        return PointJudgement(True, "")

    def judge_grasp(self, part: Part, contacts_mm, obstacles=(), grasp_z_mm: float | None = None,
                    axis_deg: float | None = None) -> Judgement:
        c = np.asarray(contacts_mm, float).reshape(2, 2)
        pj = [self.judge_point(part, q) for q in c]
        cv = (pj[0].valid, pj[1].valid)
        if not all(cv):
            bad = [f"pad {k} {j.reason}" for k, j in enumerate(pj) if not j.valid]
            return Judgement(False, cv, "; ".join(bad))
        view = _view(part)
        line = c[1] - c[0]
        d = float(np.linalg.norm(line))
        u = line / d
        for k, q in enumerate(c):
            _, normal, _ = _seat(view, q, self.cell)
            inward = u if k == 0 else -u  # the pad at contact k pushes along this direction
            cos = 0.0 if normal is None else max(-1.0, min(1.0, float(-normal @ inward)))
            ang = math.degrees(math.acos(cos))
            if ang > ANTIPODAL_DEG:
                return Judgement(False, cv,
                                 f"not antipodal: pad {k} pushes {ang:.0f} deg off the outline normal")
        off = float(np.linalg.norm(c.mean(axis=0) - view.cog))
        tol = max(CENTRE_TOL_MM, CENTRE_TOL_FRAC * view.extent)
        if off > tol:
            return Judgement(False, cv, f"not centred: {off:.0f} mm from the centre of gravity (at most "
                             f"{tol:.0f})")
        chk = check_grasp(part, c, axis_deg, grasp_z_mm, obstacles, self.cell)
        if not chk.ok:
            return Judgement(False, cv, chk.reasons[0], chk)
        return Judgement(True, cv, "", chk)

    # --- giving a grasp ------------------------------------------------------------------------
    def candidate_lines(self, part: Part, offsets_mm=OFFSETS_MM):
        """(contacts (2, 2), axis_deg) for every closing axis and line offset the operator tries."""
        view = _view(part)
        stroke = self.cell.gripper.opening_mm[1] - 2 * self.cell.gripper.approach_clearance_mm
        for k in range(int(round(180 / AXIS_STEP_DEG))):
            theta = k * AXIS_STEP_DEG
            a = np.array([math.cos(math.radians(theta)), math.sin(math.radians(theta))])
            n = np.array([-a[1], a[0]])
            for off in offsets_mm:
                c = line_contacts(view.outer, view.cog + off * n, a)
                if c is None or np.linalg.norm(c[1] - c[0]) > stroke:
                    continue
                yield c, theta

    def choose_grasp(self, part: Part, obstacles=(), top_k: int = 3) -> OperatorGrasp | None:
        """The operator's own grasp of `part` among `obstacles`, or None if it finds none."""
        view = _view(part)
        gz = default_grasp_z_mm(part.z_bottom_mm, part.z_top_mm, self.cell.gripper, self.cell.scara.j3_mm)
        good: list[OperatorGrasp] = []
        for offsets in (OFFSETS_MM, FINE_OFFSETS_MM):  # a finer search only when the usual one fails
            for c, theta in self.candidate_lines(part, offsets):
                j = self.judge_grasp(part, c, obstacles, gz, theta)
                if not j.valid:
                    continue
                chk = j.check
                off = float(np.linalg.norm(c.mean(axis=0) - view.cog))
                score = off / max(CENTRE_TOL_MM, CENTRE_TOL_FRAC * view.extent) - 0.3 * min(
                    min(chk.patch_width_mm), 12.0) / 12.0 + 0.2 * chk.torque_ratio
                good.append(OperatorGrasp(c, theta, gz, j, score))
            if good:
                break
        if not good:
            return None
        good.sort(key=lambda g: g.score)
        pick = int(self.rng.integers(0, min(top_k, len(good))))
        return good[pick]

    def propose_bad_grasp(self, part: Part, obstacles=(), tries: int = 60):
        """A grasp a person would reject, of a random kind (pad on a corner, off centre, slanted,
        colliding ...), with the operator's judgement; None if none was found in `tries`."""
        view = _view(part)
        gz = default_grasp_z_mm(part.z_bottom_mm, part.z_top_mm, self.cell.gripper, self.cell.scara.j3_mm)
        stroke = self.cell.gripper.opening_mm[1] - 2 * self.cell.gripper.approach_clearance_mm
        ring = view.outer_ring
        for _ in range(tries):
            kind = self.rng.choice(["corner", "off_centre", "slanted"])
            if kind == "corner":
                corners = view.corners
                if not corners:
                    continue
                v = corners[int(self.rng.integers(0, len(corners)))]
                aim = view.cog + self.rng.normal(0, 3, 2)
                a = (aim - v) / max(np.linalg.norm(aim - v), 1e-9)
                c = line_contacts(view.outer, v - 0.01 * a, a)
            elif kind == "off_centre":
                theta = float(self.rng.uniform(0, 180))
                a = np.array([math.cos(math.radians(theta)), math.sin(math.radians(theta))])
                n = np.array([-a[1], a[0]])
                c = line_contacts(view.outer, view.cog + self.rng.uniform(0.2, 0.45) * view.extent
                                  * self.rng.choice([-1, 1]) * n, a)
            else:
                s0, s1 = self.rng.uniform(0, ring.length, 2)
                c = np.array([ring.interpolate(s0).coords[0], ring.interpolate(s1).coords[0]])
            if c is None or not (3.0 < np.linalg.norm(c[1] - c[0]) <= stroke):
                continue
            theta = math.degrees(math.atan2(c[1, 1] - c[0, 1], c[1, 0] - c[0, 0]))
            j = self.judge_grasp(part, c, obstacles, gz, theta)
            if not j.valid:
                return c, theta, gz, j
        return None

    # --- the arm configuration -----------------------------------------------------------------
    def joints_for(self, x_mm: float, y_mm: float, z_mm: float, axis_deg: float) -> Joints | None:
        """The operator's arm configuration: preferred elbow by tray side, J4 nearest zero."""
        sols = inverse(x_mm, y_mm, z_mm, axis_deg, self.cell.scara)
        if not sols:
            return None
        want_right = y_mm < 0
        preferred = [s for s in sols if (s.j2_deg > 0) == want_right]
        pool = preferred or sols
        return min(pool, key=lambda s: abs(s.j4_deg))


def _seat(view: _View, p: np.ndarray, cell: Cell) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Where and how a flat pad seats at p: the point its face rests on, the face's outward normal and
    how sharply the seat turns (deg, +-1 mm). On a flat or smooth stretch that is the outline's own.
    Where the outline turns sharply at p or a pad on its tangent meets the part beside p, but p lies on
    the part's convex hull, the hull runs on gently there and a pad's face on it rests on more than one
    tip (fine gear teeth, knurls, serrations: separate pieces of material within the physical check's
    patch depth, spanning at least its sharp-patch width), a person seats the pad across those tips:
    the seat is the hull's. One corner under a pad on a slanted hull line is no seat."""
    normal, turn = outline_normal_and_turn([view.outer_ring], p, 1.0)
    if normal is not None and turn < SHARP_TURN_DEG and _pad_fits(view.outer, p, normal, cell):
        return p, normal, turn
    pt = Point(*p)
    if view.hull_ring.distance(pt) > HULL_TOL_MM:
        return p, normal, turn
    on_hull = view.hull_ring.interpolate(view.hull_ring.project(pt))
    q = np.array([on_hull.x, on_hull.y])
    h_normal, h_turn = outline_normal_and_turn([view.hull_ring], q, 1.0)
    if h_normal is None or h_turn >= SHARP_TURN_DEG:
        return p, normal, turn
    tips, width = _tips_under_pad(view.outer, q, h_normal, cell)
    if tips < 2 or width < SHARP_PATCH_MM:
        return p, normal, turn
    return q, h_normal, h_turn


def _tips_under_pad(outer: Polygon, q: np.ndarray, normal: np.ndarray, cell: Cell) -> tuple[int, float]:
    """The material a pad face through q, square to `normal`, touches (within PATCH_DEPTH_MM of the face,
    under the pad's width): how many separate pieces, and how wide they span across the pad (mm)."""
    t = np.array([-normal[1], normal[0]])
    hw = cell.gripper.pad_width_mm / 2
    a, b = q - PATCH_DEPTH_MM * normal, q + 0.01 * normal
    touched = outer.intersection(Polygon([a - hw * t, b - hw * t, b + hw * t, a + hw * t]))
    pieces = [g for g in getattr(touched, "geoms", [touched]) if not g.is_empty and g.area > 0]
    if not pieces:
        return 0, 0.0
    along = np.concatenate([(shapely.get_coordinates(g) - q) @ t for g in pieces])
    return len(pieces), float(along.max() - along.min())


def _pad_fits(outer: Polygon, p: np.ndarray, normal: np.ndarray, cell: Cell) -> bool:
    """Does a flat pad, centred on p with its face on the outline's tangent, stay clear of the
    rest of the part? (False in recesses narrower than the pad, between teeth, next to a lug.)"""
    g = cell.gripper
    t = np.array([-normal[1], normal[0]])
    hw = g.pad_width_mm / 2
    o0, o1 = p + PAD_LIFT_MM * normal, p + (PAD_LIFT_MM + g.pad_thickness_mm) * normal
    pad = Polygon([o0 - hw * t, o1 - hw * t, o1 + hw * t, o0 + hw * t])
    return pad.intersection(outer).area <= PAD_OVERLAP_MM2


def line_contacts(outer: Polygon, p0: np.ndarray, a: np.ndarray) -> np.ndarray | None:
    """Where pads closing along direction `a` on the line through `p0` first meet the outline:
    the outermost crossings of that line with the polygon, shape (2, 2), or None."""
    far = 1000.0
    seg = LineString([p0 - far * a, p0 + far * a])
    cut = outer.intersection(seg)
    if cut.is_empty:
        return None
    pts = np.asarray([xy for g in getattr(cut, "geoms", [cut]) for xy in g.coords], float)
    if len(pts) < 2:
        return None
    s = (pts - p0) @ a
    c = np.array([pts[int(np.argmin(s))], pts[int(np.argmax(s))]])
    if np.linalg.norm(c[1] - c[0]) < 1e-6:
        return None
    return c


@dataclass
class _View:
    outer: Polygon
    outer_ring: object
    hull_ring: object
    cog: np.ndarray
    extent: float
    corners: list


_VIEWS: dict[int, _View] = {}


def _view(part: Part) -> _View:
    """Cached geometry of a part (keyed by object identity; parts are immutable)."""
    v = _VIEWS.get(id(part))
    if v is not None and v.outer is not None and getattr(v, "_part", None) is part:
        return v
    from shapely.geometry import LinearRing
    from shapely.geometry.polygon import orient

    outer = orient(Polygon(part.outline_mm), 1.0)
    ring = LinearRing(outer.exterior.coords)
    hull = orient(outer.convex_hull, 1.0)  # counter-clockwise as the outline: the same outward normals
    cog = np.asarray(part.polygon.centroid.coords[0])
    hxy = np.asarray(hull.exterior.coords)[:-1]
    extent = float(max(np.max(np.linalg.norm(hxy[:, None] - hxy[None], axis=2)), 1.0))  # the diameter
    corners = []
    for q in np.asarray(outer.exterior.coords)[:-1]:
        if hull.exterior.distance(Point(*q)) <= HULL_TOL_MM:
            _, turn = outline_normal_and_turn([ring], q, 1.0)
            if turn >= SHARP_TURN_DEG:
                corners.append(q)
    v = _View(outer, ring, LinearRing(hull.exterior.coords), cog, extent, corners)
    v._part = part
    if len(_VIEWS) > 4096:
        _VIEWS.clear()
    _VIEWS[id(part)] = v
    return v


# --- the operator at the teaching station: a session of examples --------------------------------

EXAMPLE_EPOCH = datetime(2026, 11, 23, 8, 0, 0, tzinfo=UTC)  # fixed: files are reproducible


def random_pose(part: Part, cell: Cell, rng: np.random.Generator) -> tuple[float, float, float]:
    """A pose (x, y, theta) that keeps the (origin-centred) part wholly inside the tray."""
    r = float(np.linalg.norm(part.outline_mm, axis=1).max())
    (x0, x1), (y0, y1) = cell.tray.x_mm, cell.tray.y_mm
    return (float(rng.uniform(x0 + r, x1 - r)), float(rng.uniform(y0 + r, y1 - r)),
            float(rng.uniform(-180.0, 180.0)))


def place_neighbour(target: Part, other: Part, gap_mm: float, direction_deg: float, theta_deg: float,
                    part_id: str) -> Part:
    """`other` (origin-centred) placed beside `target` along `direction_deg`, `gap_mm` apart."""
    from cell.parts_library import place

    c = np.asarray(target.polygon.centroid.coords[0])
    u = np.array([math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))])
    lo, hi = 0.0, 400.0
    for _ in range(40):  # bisection on the centre distance: the gap grows with it
        mid = 0.5 * (lo + hi)
        q = place(other, *(c + mid * u), theta_deg, part_id)
        if q.polygon.distance(target.polygon) < gap_mm:
            lo = mid
        else:
            hi = mid
    return place(other, *(c + hi * u), theta_deg, part_id)


def generate_examples(count: int = 60, seed: int = 0, families=None, cell: Cell | None = None,
                      rejection_share: float = 1 / 3, neighbour_share: float = 0.15,
                      progress=None) -> list[GraspExample]:
    """A teaching session: `count` accepted grasps on parts drawn from the library
    (`FamilyRounds`: every family once per round, a part of it at random; the same part may
    come twice), each at a random pose in the tray, standalone or (a share
    `neighbour_share`) with one or two neighbours; before about `rejection_share` of them the
    operator is shown a bad grasp and rejects it, saying why. Deterministic for a seed.

    Returns the examples in session order: `count` accepted + the rejections.
    """
    from cell import parts_library

    cell = cell or default_cell()
    rng = np.random.default_rng(seed)
    op = Operator(cell, rng)
    draw = FamilyRounds(parts_library.parts(families), rng)
    everything = parts_library.parts()
    out: list[GraspExample] = []
    accepted = 0
    k = 0
    while accepted < count:
        k += 1
        if k > 20 * count + 100:
            raise RuntimeError("the operator could not grasp enough parts (library or cell too restrictive)")
        lib = draw.next()
        x, y, th = random_pose(lib, cell, rng)
        part = parts_library.place(lib, x, y, th, lib.id)
        obstacles = random_neighbours(part, everything, rng, cell) if rng.random() < neighbour_share else []
        grasp = op.choose_grasp(part, obstacles)
        if grasp is None:
            continue  # a person would put this one aside; the next part is drawn
        pose = {"library_part": lib.id, "x_mm": round(x, 3), "y_mm": round(y, 3), "theta_deg": round(th, 3)}
        if rng.random() < rejection_share:
            bad = op.propose_bad_grasp(part, obstacles)
            if bad is not None:
                c, theta, gz, j = bad
                out.append(_example(op, f"op-s{seed}-{len(out) + 1:04d}", part, c, theta, gz, j, obstacles,
                                    pose, len(out)))
        out.append(_example(op, f"op-s{seed}-{len(out) + 1:04d}", part, grasp.contacts_mm, grasp.axis_deg,
                            grasp.grasp_z_mm, grasp.judgement, obstacles, pose, len(out)))
        accepted += 1
        if progress is not None:
            progress(accepted, count)
    return out


class FamilyRounds:
    """The teaching session's draw of parts: the families in shuffled rounds (every family once
    per round, in a new random order each round), within a family a part not shown yet (its
    parts without replacement, then again from all of them). A person teaching the cell shows
    it every kind of part early rather than, by chance, six nuts and no lever; the paper drew
    its 60 at random from a varied database, and a uniform draw over parts leaves small
    families (two links, two heat sinks) out of a 60-grasp session about a third of the time."""

    def __init__(self, pool: list[Part], rng: np.random.Generator):
        self.rng = rng
        self.by_family: dict[str, list[Part]] = {}
        for p in pool:
            self.by_family.setdefault(str(p.meta.get("family", "")), []).append(p)
        self.unseen = {f: list(ps) for f, ps in self.by_family.items()}
        self.round: list[str] = []

    def next(self) -> Part:
        if not self.round:
            fams = sorted(self.by_family)
            self.round = [fams[i] for i in self.rng.permutation(len(fams))]
        fam = self.round.pop(0)
        if not self.unseen[fam]:
            self.unseen[fam] = list(self.by_family[fam])
        left = self.unseen[fam]
        return left.pop(int(self.rng.integers(0, len(left))))


def random_neighbours(part: Part, pool: list[Part], rng: np.random.Generator, cell: Cell) -> list[Part]:
    """One or two parts of `pool` placed 3..15 mm around `part` at random, apart from each
    other and inside the tray (the clutter a part may be presented in)."""
    obstacles: list[Part] = []
    for j in range(int(rng.integers(1, 3))):
        nb = pool[int(rng.integers(0, len(pool)))]
        q = place_neighbour(part, nb, float(rng.uniform(3, 15)), float(rng.uniform(0, 360)),
                            float(rng.uniform(-180, 180)), f"{nb.id}#n{j}")
        if all(q.polygon.distance(o.polygon) > 2 for o in obstacles) and _inside_tray(q, cell):
            obstacles.append(q)
    return obstacles


def _inside_tray(p: Part, cell: Cell) -> bool:
    (x0, x1), (y0, y1) = cell.tray.x_mm, cell.tray.y_mm
    bx = p.polygon.bounds
    return bx[0] >= x0 and bx[2] <= x1 and bx[1] >= y0 and bx[3] <= y1


def _example(op: Operator, eid: str, part: Part, contacts, axis_deg: float, grasp_z: float, j: Judgement,
             obstacles, pose: dict, n: int) -> GraspExample:
    c = np.asarray(contacts, float)
    centre = c.mean(axis=0)
    joints = op.joints_for(float(centre[0]), float(centre[1]), grasp_z, normalize_axis_deg(axis_deg))
    if not j.valid:
        note = f"rejected: {j.reason}"
    elif (off := float(np.linalg.norm(centre - _view(part).cog))) <= 2.0 or part.polygon.contains(
            Point(*_view(part).cog)):
        note = "accepted: centred, antipodal, pads on flat stretches"
    else:  # an L, a U, a clip: no grasp can be centred on material that is not there
        note = (f"accepted: the centre of gravity lies off the material; the nearest stable grasp to it "
                f"({off:.0f} mm away), antipodal, pads on flat stretches")
    source = {"kind": "simulated-operator", "by": "cell.operator",
              "at": (EXAMPLE_EPOCH + timedelta(seconds=30 * n)).strftime("%Y-%m-%dT%H:%M:%SZ"), "note": note}
    return GraspExample(eid, part, c, bool(j.valid), source, tuple(bool(v) for v in j.contact_valid),
                        tuple(obstacles), grasp_z, joints.rounded() if joints else None, {"pose": pose})
