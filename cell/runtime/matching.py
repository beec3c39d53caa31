"""Which segmented region is which part of the assembly model, and where it lies now.

Each model part (at its last known pose) is looked for among the observed regions, mapped
to mm on the plane of that part's top (parallax: a 60 mm tall part seen 250 mm off the
optical axis from 800 mm shifts by about 19 mm at z = 0). The part's pose is then refined
by maximising the overlap of the model outline with the region (Nelder-Mead over x, y and
rotation): the model outline at the measured pose is what the planner uses, so holes and
fine detail come from the model and the position from the camera. A region flagged as
merged (touching parts the image could not separate) is matched by coverage of the model
instead of intersection over union.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.optimize import minimize
from shapely.geometry import Polygon

from cell.scene import Part


@dataclass(frozen=True)
class Region:
    """An observed region; `polygon_at(z_top_mm, z_bottom_mm)` maps its outline to mm for a
    part with those heights (the top face's plane, walls at the bottom where they show). A
    `RegionOutline` there maps each pair of heights once and can rule a part out without mapping."""

    index: int
    polygon_at: Callable[[float, float], Polygon]
    merged: bool = False
    cut_off: bool = False

    def surely_farther(self, part: Part, limit_mm: float) -> bool:
        """Is this region's outline at the part's heights surely more than limit_mm from the part's outline?
        Told from boxes, without mapping the region; False when it cannot be told that way."""
        box = getattr(self.polygon_at, "box_mm", None)
        reach = None if box is None else box(part.z_top_mm, part.z_bottom_mm)
        return reach is not None and box_gap_mm(reach, part.polygon.bounds) > limit_mm


FACE_MARGIN_PX = 4.0  # how far outside the box of a silhouette's rings a top face's rings can lie (see box_mm)


class RegionOutline:
    """A region's outline in mm as `Region.polygon_at` gives it, with what makes matching scale with the parts.

    `to_mm(z_top_mm, z_bottom_mm)` (segment_to_mm: a top face search and a wall test, ms each) is called once per
    pair of heights: `locate` asks every region at every part's heights, and `unexplained` again. `box_mm` bounds
    that outline without mapping it: `locate` rules out the regions far from a part (most of them on a full tray)
    by it, so a frame of n parts maps about the few regions near each part instead of all n + 1 at every part's
    heights. `rings_px` are the silhouette's outline and holes (pixels); `cal` its calibration."""

    def __init__(self, to_mm: Callable[[float, float], Polygon], rings_px: Sequence[np.ndarray], cal):
        self._to_mm = to_mm
        self._mapped: dict[tuple[float, float], Polygon] = {}
        self._rings_px, self._cal = rings_px, cal
        self._reach: tuple[float, tuple[float, float, float, float]] | None = None  # (z_ref, box there)

    def __call__(self, z_top_mm: float, z_bottom_mm: float) -> Polygon:
        key = (float(z_top_mm), float(z_bottom_mm))
        if key not in self._mapped:
            self._mapped[key] = self._to_mm(z_top_mm, z_bottom_mm)
        return self._mapped[key]

    def box_mm(self, z_top_mm: float, z_bottom_mm: float) -> tuple[float, float, float, float] | None:
        """(min x, min y, max x, max y), mm: a box holding every point of `self(z_top_mm, z_bottom_mm)`; None
        without a camera pose or where the box's pixels do not map.

        Why it holds. (1) segment_to_mm maps pixels q of the silhouette's rings, or of the top face's, each at
        z_top or z_bottom; a valid-area fix adds only crossings of its edges: the outline lies in the hull of
        those points. The face's rings lie within FACE_MARGIN_PX of the box of the silhouette's (topface.py:
        the centres of face pixels inside the silhouette's raster, at most a pixel out, then moved at most
        2 px along their normal by refine_rings, or 0.5 px out): every q is in the pixel box B grown by that.
        (2) With a pose, px_to_mm(q, z) = t + s r(q) with s = (z - t_z) / r_z(q) (t the optical centre, r(q)
        the pixel's ray), so px_to_mm(q, z) - t_xy = k(z) (px_to_mm(q, z_ref) - t_xy), k(z) = (z - t_z) /
        (z_ref - t_z) > 0: every pixel's point at z is its point at z_ref scaled by the same k about the
        camera's foot, and a box holding B's points at z_ref, scaled so, holds them at z. (3) The mapping at
        z_ref is continuous and one to one (the calibration checks that its lens undistorts back), so B's
        image lies inside the image of B's border, sampled every pixel: the samples' box grown by the
        largest step between neighbouring samples holds it (a border point is within half a step of one)."""
        cal = self._cal
        if not getattr(cal, "has_pose", False):
            return None
        if self._reach is None:
            self._reach = self._reach_at(float(z_top_mm))
        z_ref, box = self._reach
        if box is None:
            return None
        foot_x, foot_y, cam_z = (float(v) for v in cal.cam2base[:3, 3])
        corners = []
        for z in (z_top_mm, z_bottom_mm):
            k = (z - cam_z) / (z_ref - cam_z)
            if not k > 0:  # a plane on the camera's other side: the mapping refuses it, and so does no box
                return None
            corners += [(foot_x + k * (box[0] - foot_x), foot_y + k * (box[1] - foot_y)),
                        (foot_x + k * (box[2] - foot_x), foot_y + k * (box[3] - foot_y))]
        xs, ys = [c[0] for c in corners], [c[1] for c in corners]
        return min(xs), min(ys), max(xs), max(ys)

    def _reach_at(self, z_ref: float) -> tuple[float, tuple[float, float, float, float] | None]:
        """(z_ref, the box at z_ref holding every point segment_to_mm can map the region's pixels to)."""
        from cell.errors import BadInput

        pts = np.vstack([np.asarray(r, float).reshape(-1, 2) for r in self._rings_px])
        u0, v0 = pts.min(axis=0) - FACE_MARGIN_PX
        u1, v1 = pts.max(axis=0) + FACE_MARGIN_PX
        border = _box_border_px(u0, v0, u1, v1)
        try:
            mm = self._cal.px_to_mm(border, z_ref)
        except BadInput:  # part of the grown box beyond the plane's horizon: rule nothing out
            return z_ref, None
        step = float(np.max(np.hypot(*np.diff(mm, axis=0, append=mm[:1]).T)))
        lo, hi = mm.min(axis=0) - step, mm.max(axis=0) + step
        return z_ref, (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def _box_border_px(u0: float, v0: float, u1: float, v1: float) -> np.ndarray:
    """Points around the border of the pixel box, in order, no more than a pixel apart."""
    nu, nv = max(int(math.ceil(u1 - u0)), 1), max(int(math.ceil(v1 - v0)), 1)
    us, vs = np.linspace(u0, u1, nu + 1), np.linspace(v0, v1, nv + 1)
    return np.vstack([np.column_stack([us, np.full(nu + 1, v0)])[:-1],
                      np.column_stack([np.full(nv + 1, u1), vs])[:-1],
                      np.column_stack([us[::-1], np.full(nu + 1, v1)])[:-1],
                      np.column_stack([np.full(nv + 1, u0), vs[::-1]])[:-1]])


def box_gap_mm(a: Sequence[float], b: Sequence[float]) -> float:
    """The distance between two boxes (min x, min y, max x, max y), 0 when they meet: no point of one lies
    nearer than that to a point of the other."""
    dx = max(a[0] - b[2], b[0] - a[2], 0.0)
    dy = max(a[1] - b[3], b[1] - a[3], 0.0)
    return math.hypot(dx, dy)


@dataclass(frozen=True)
class Located:
    part_id: str
    region: int
    dx_mm: float
    dy_mm: float
    dtheta_deg: float  # about the model part's centroid, then the shift
    overlap: float  # IoU (or coverage for merged regions) at the refined pose
    merged: bool

    def apply(self, part: Part) -> Part:
        return part.moved(self.dx_mm, self.dy_mm, self.dtheta_deg)


SIMPLIFY_MM = 0.25
GOOD_OVERLAP = 0.95  # a start that reaches this needs no other start
MIN_OVERLAP = 0.55  # below this the region is not that part (or the part is not seen)
MAX_SHIFT_MM = 60.0
MAX_MERGED_SHIFT_MM = 15.0
NEARER_WEIGHT = 0.05  # overlap given up per MAX_SHIFT_MM of shift when choosing among matches
MIN_UNFLAGGED_RATIO = 1.6  # an unflagged region this much larger than a missing part may hold it
MAX_UNFLAGGED_RATIO = 3.0  # ... up to this much (the part and a neighbour's wall or a small part)


def _preference(c: Located) -> float:
    """Sort key of candidate matches, best first: the overlap, and between equally good fits the
    nearer (identical parts side by side)."""
    return -(c.overlap - NEARER_WEIGHT * math.hypot(c.dx_mm, c.dy_mm) / MAX_SHIFT_MM)


def _score(model: Polygon, region: Polygon, merged: bool) -> float:
    inter = model.intersection(region).area
    if merged:
        return inter / model.area
    return inter / (model.area + region.area - inter)


class Poser:
    """The model outline turned by x[2] degrees about c, then shifted by (x[0], x[1]): what shapely's
    `affinity.rotate` then `affinity.translate` give, coordinate for coordinate the same floats (the same
    products and sums in the same order), in about a third of the time: the coordinates are worked out in place
    and put into one geometry instead of two transforms building two. The registration poses the model
    some hundred times a region; two transforms took a third of its time."""

    def __init__(self, model: Polygon, c):
        if model.has_z:
            raise ValueError("Poser takes outlines in the plane (affinity would keep z)")
        xy = shapely.get_coordinates(model)
        self._x, self._y = xy[:, 0].copy(), xy[:, 1].copy()
        self._out, self._tmp = np.empty_like(xy), np.empty(len(xy))
        self._geom = np.array([model], dtype=object)  # its coordinates are replaced at each call
        self._x0, self._y0 = float(c[0]), float(c[1])

    def __call__(self, x) -> Polygon:
        angle = x[2] * math.pi / 180.0  # as affinity.rotate, in degrees
        cosp, sinp = math.cos(angle), math.sin(angle)
        if abs(cosp) < 2.5e-16:
            cosp = 0.0
        if abs(sinp) < 2.5e-16:
            sinp = 0.0
        x0, y0 = self._x0, self._y0
        xoff, yoff = x0 - x0 * cosp + y0 * sinp, y0 - x0 * sinp - y0 * cosp
        tmp = self._tmp
        # a x + b y + xoff, then (translate) 1 x' + 0 y' + dx, which is x' + dx
        for col, (a, b, off, shift) in enumerate(((cosp, -sinp, xoff, x[0]), (sinp, cosp, yoff, x[1]))):
            out = self._out[:, col]
            np.multiply(a, self._x, out=out)
            np.multiply(b, self._y, out=tmp)
            out += tmp
            out += off
            out += shift
        shapely.set_coordinates(self._geom, self._out)
        return self._geom[0]


def register(model: Polygon, region: Polygon, merged: bool = False, axis=None) -> tuple[np.ndarray, float]:
    """Best (dx, dy, dtheta_deg) placing `model` onto `region`, and the overlap there."""
    c = model.centroid.coords[0]
    # Fine detail (gear teeth, 1 mm steps of a resampled outline) only slows the search down.
    model, region = model.simplify(SIMPLIFY_MM), region.simplify(SIMPLIFY_MM)
    starts = [np.zeros(3)]
    if not merged:
        d = np.subtract(region.centroid.coords[0], c)
        starts.append(np.array([d[0], d[1], 0.0]))
        axis = axis or _axis_deg  # (axis_deg_eigh: how recordings made before 2026-12-05 started)
        turn = axis(region) - axis(model)
        starts += [np.array([d[0], d[1], turn]), np.array([d[0], d[1], turn + 180.0])]
    posed = Poser(model, c)
    best_x, best_s = None, -1.0
    for x0 in starts:
        if best_s >= GOOD_OVERLAP:
            break
        res = minimize(lambda x: -_score(posed(x), region, merged), x0, method="Nelder-Mead",
                       options={"xatol": 0.02, "fatol": 1e-5, "initial_simplex": x0 + np.array(
                           [[0, 0, 0], [3, 0, 0], [0, 3, 0], [0, 0, 8]]), "maxiter": 400})
        s = -res.fun
        if s > best_s:
            best_x, best_s = res.x, s
    return best_x, best_s


def locate(parts: Sequence[Part], regions: Sequence[Region], axis=None) -> tuple[dict[str, Located], list[int]]:
    """Match model parts to regions. Returns the located parts by id and the indices of
    regions no part claimed (something unexpected on the tray).

    A region of its own (intersection over union) always beats a merged region: coverage of a
    merged region is 1 almost anywhere inside it, so it is only asked for the parts that have
    no region of their own, with the parts already placed in it taken out, and the part may
    not wander further than MAX_MERGED_SHIFT_MM from where it was. A region no part claimed that is
    much larger than a part still missing is asked the same way: touching parts split along the
    wrong line (a tall part's wall given to its low neighbour) are merged without the flag."""
    located: dict[str, Located] = {}
    claimed: set[int] = set()
    # every (part, region of its own) match that could be, then the best first over all parts: a
    # part taken in turn would take a look-alike's region (a pulley 58 mm off on the flange's)
    # before the look-alike, which fits it better, is asked
    candidates: list[Located] = []
    for part in parts:
        for r in regions:
            if r.merged or r.surely_farther(part, MAX_SHIFT_MM):  # (the test below would say so too)
                continue
            poly = r.polygon_at(part.z_top_mm, part.z_bottom_mm)
            if poly.is_empty or poly.distance(part.polygon) > MAX_SHIFT_MM:
                continue
            if not 0.6 < poly.area / part.polygon.area < 1.6:
                continue  # another part: registration could only make it overlap worse
            x, s = register(part.polygon, poly, axis=axis)
            if s >= MIN_OVERLAP and math.hypot(x[0], x[1]) <= MAX_SHIFT_MM:
                candidates.append(Located(part.id, r.index, float(x[0]), float(x[1]), float(x[2]), float(s), False))
    for c in sorted(candidates, key=_preference):
        if c.part_id not in located and c.region not in claimed:
            located[c.part_id] = c
            claimed.add(c.region)
    placed: dict[int, list[Polygon]] = {}
    own = set(claimed)  # regions matched to a part of their own size
    for part in parts:
        if part.id in located:
            continue
        best = None
        for r in regions:
            if r.index in own or r.surely_farther(part, MAX_MERGED_SHIFT_MM):  # (taking pieces out only moves it off)
                continue
            poly = r.polygon_at(part.z_top_mm, part.z_bottom_mm)
            if not r.merged and not (MIN_UNFLAGGED_RATIO * part.polygon.area <= poly.area
                                     <= MAX_UNFLAGGED_RATIO * part.polygon.area):
                # about its size: the first pass judged it (not this part); far larger (a tray
                # against a table of another colour): coverage would place the part anywhere in it
                continue
            for other in placed.get(r.index, []):
                poly = poly.difference(other)
            if poly.is_empty or poly.distance(part.polygon) > MAX_MERGED_SHIFT_MM:
                continue
            x, s = register(part.polygon, poly, merged=True, axis=axis)
            near = math.hypot(x[0], x[1]) <= MAX_MERGED_SHIFT_MM
            if s >= MIN_OVERLAP and near and (best is None or s > best.overlap):
                best = Located(part.id, r.index, float(x[0]), float(x[1]), float(x[2]), float(s), True)
        if best is None:
            best, pieces = _in_pieces(part, [r for r in regions if not r.merged and r.index not in claimed], axis)
            claimed.update(pieces)
            own.update(pieces)  # every piece is this part's: no later part is looked for in one
        if best is not None:
            located[part.id] = best
            claimed.add(best.region)
            placed.setdefault(best.region, []).append(best.apply(part).polygon)
    return located, [r.index for r in regions if r.index not in claimed]


def locate_anywhere(part: Part, regions: Sequence[Region], axis=None) -> Located | None:
    """`part` in whichever of `regions` (of about its size) it fits best, however far from where it was: the
    part picked last, not found near where it lay (`locate` looks MAX_SHIFT_MM about), may have fallen back
    onto the tray further off. None when no region fits it (MIN_OVERLAP)."""
    best = None
    for r in regions:
        if r.merged:
            continue
        poly = r.polygon_at(part.z_top_mm, part.z_bottom_mm)
        if poly.is_empty or not 0.6 < poly.area / part.polygon.area < 1.6:
            continue
        x, s = register(part.polygon, poly, axis=axis)
        if s >= MIN_OVERLAP and (best is None or s > best.overlap):
            best = Located(part.id, r.index, float(x[0]), float(x[1]), float(x[2]), float(s), False)
    return best


def _in_pieces(part: Part, free: Sequence[Region], axis=None) -> tuple[Located | None, list[int]]:
    """A part the segmentation cut into pieces (a washer's highlight split off by colour): the
    unclaimed regions near it, smaller than MIN_UNFLAGGED_RATIO x the part, registered together
    (intersection over union of their union). The match (region: the largest piece) and the pieces'
    indices, or (None, [])."""
    from shapely import union_all

    near = []
    for r in free:
        if r.surely_farther(part, MAX_MERGED_SHIFT_MM):
            continue
        poly = r.polygon_at(part.z_top_mm, part.z_bottom_mm)
        if not poly.is_empty and poly.area < MIN_UNFLAGGED_RATIO * part.polygon.area \
                and poly.distance(part.polygon) <= MAX_MERGED_SHIFT_MM:
            near.append((poly.area, r.index, poly))
    if len(near) < 2:
        return None, []
    x, s = register(part.polygon, union_all([poly for *_, poly in near]).buffer(0), axis=axis)
    if s < MIN_OVERLAP or math.hypot(x[0], x[1]) > MAX_MERGED_SHIFT_MM:
        return None, []
    largest = max(near, key=lambda t: t[0])[1]
    return Located(part.id, largest, float(x[0]), float(x[1]), float(x[2]), float(s), True), [i for _, i, _ in near]


def axis_deg_eigh(poly: Polygon) -> float:
    """The principal axis as recordings made before 2026-12-05 took it: LAPACK's eigenvector, of either sign as
    the CPU's kernels have it (replay of those recordings only: `LoopOptions.axis_closed_form` off)."""
    hull = poly.convex_hull
    if hull.geom_type != "Polygon":
        return 0.0
    xy = np.asarray(hull.exterior.coords)[:-1]
    xy = xy - xy.mean(axis=0)
    w, v = np.linalg.eigh(xy.T @ xy)
    major = v[:, int(np.argmax(w))]
    return math.degrees(math.atan2(major[1], major[0]))


def _axis_deg(poly: Polygon) -> float:
    """Direction of the principal axis of the outline's hull vertices, in (-90, 90] (good enough as a start).
    In closed form from exactly rounded sums: the same on every machine (LAPACK's eigenvector took either sign
    as the CPU's BLAS kernel had it, and a replay on another CPU started the search half a turn round)."""
    hull = poly.convex_hull  # any region geometry (a squeezed outline may map to several pieces)
    if hull.geom_type != "Polygon":
        return 0.0
    xy = np.asarray(hull.exterior.coords)[:-1]
    x, y = xy[:, 0].tolist(), xy[:, 1].tolist()
    mx, my = math.fsum(x) / len(x), math.fsum(y) / len(y)
    dx, dy = [v - mx for v in x], [v - my for v in y]
    sxx = math.fsum(v * v for v in dx)
    syy = math.fsum(v * v for v in dy)
    sxy = math.fsum(a * b for a, b in zip(dx, dy, strict=True))
    angle = 0.5 * math.degrees(math.atan2(2.0 * sxy, sxx - syy))  # the major axis, in [-90, 90]
    return 90.0 if angle == -90.0 else angle


EXPLAINED_MARGIN_MM = 2.0  # material this close to a located part's outline is that part (outline noise)
MISFIT_SHARE = 0.5  # x a located part's area: more left over beside it than a misfit leaves (measured 0.27)
MIN_UNEXPLAINED_MM2 = 30.0  # (outline noise left 21-23 mm2 pieces; a clip's smallest piece seen: 45)


def unexplained(regions: Sequence[Region], seen: dict[str, Part], located: dict[str, Located], z_top_mm: float,
                stranger_z_mm: float | None = None, missing: bool = True) -> list[Part]:
    """Material the camera sees that no located part explains, as obstacles from the table up to
    z_top_mm (e.g. a part not found because it was merged into its neighbour's region, or split
    into pieces that match nothing): planning beside it as if the tray were empty there would put
    a finger on it. In a region no part was located in (something that is not in the assembly,
    perhaps a tool) up to stranger_z_mm (default z_top_mm). With no part `missing`, what is left
    beside located parts is most likely their own misfit (a poor registration, a wall): it counts
    only from MISFIT_SHARE of the smallest of them, and then as unknown (stranger_z_mm).

    A region is mapped to mm at the heights of the parts located in it (as it was matched; parallax
    moves a tall part's outline by mm between planes), else at z_top_mm; the located parts'
    outlines (widened by EXPLAINED_MARGIN_MM) are taken out, and what is left, opened by 1 mm
    against slivers, is kept where it covers MIN_UNEXPLAINED_MM2."""
    from shapely import union_all
    from shapely.geometry.polygon import orient

    explained = union_all([p.polygon for p in seen.values()]).buffer(EXPLAINED_MARGIN_MM) if seen else Polygon()
    out: list[Part] = []
    unknown = max(z_top_mm, stranger_z_mm or 0.0)
    for r in regions:
        inside = [seen[pid] for pid, loc in located.items() if loc.region == r.index and pid in seen]
        height = z_top_mm if inside and missing else unknown
        least = MIN_UNEXPLAINED_MM2
        if inside and not missing:
            least = max(least, MISFIT_SHARE * min(p.polygon.area for p in inside))
        z_top = max((p.z_top_mm for p in inside), default=height)
        z_bottom = min((p.z_bottom_mm for p in inside), default=0.0)
        left = r.polygon_at(z_top, z_bottom).difference(explained).buffer(-0.5).buffer(0.5)
        for piece in getattr(left, "geoms", [left]):
            if piece.geom_type == "Polygon" and piece.area >= least:
                piece = orient(piece, 1.0)  # outline counter-clockwise, holes clockwise (a ring round a part
                # keeps its hole: filled, it would cover the part)
                out.append(Part(f"unexplained-{len(out)}", np.asarray(piece.exterior.coords)[:-1],
                                tuple(np.asarray(h.coords)[:-1] for h in piece.interiors), z_bottom_mm=0.0,
                                z_top_mm=height, meta={"region": r.index}))
    return out
