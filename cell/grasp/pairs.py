"""The pairs of valid points the cascade filters, and what the stages know about the scene.

Context: the target (its edges by component, its outline samples and their neighbours), the
obstacles sorted by height (finger-high, palm-high), the cell. Pairs: every unordered pair of
valid points with its closing-axis geometry; the stages fill in the real contacts and the IK.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely

from cell.cellconfig import Cell
from cell.grasp.params import SynthesisParams
from cell.kinematics import box_surely_reachable, normalize_axis_deg
from cell.scene import Part

# Comparisons against a tolerance allow this much float noise, so that the verdict on a pair
# does not depend on where the part lies (mid-step samples on parallel faces sit exactly
# contact_tol apart across the axis).
EPS_MM = 1e-6
Z_EPS_MM = 1e-6
# The exact stages see a target's outline with at most one vertex per this much arc length (on
# average; `exact_outline`): half of contact_tol's 1 mm, a pixel of a 0.5 mm/px camera.
EXACT_SPACING_MM = 0.5
CHEAP_MARGIN_MM = 2.0  # the cascade's reach stage keeps pair centres this far outside the arm's reach


@dataclass
class Context:
    """What the stages need about one scene: the target, the obstacles by height, the cell."""

    target: Part
    cell: Cell
    params: SynthesisParams
    grasp_z_mm: float
    target_geom: object = None
    finger_obstacles: object = None  # union of obstacles taller than the grasp z, or None
    palm_obstacles: object = None  # union of obstacles taller than the palm bottom, or None
    finger_obstacle_ids: list = field(default_factory=list)
    edge_a: np.ndarray = None  # (E, 2) start of every target edge (outline and holes)
    edge_b: np.ndarray = None  # (E, 2) its end
    edge_tree: object = None  # STRtree over the edges
    samples: np.ndarray | None = None  # (N, 2) the target's outline samples, ring after ring
    sample_ring_first: np.ndarray | None = None  # (N,) index of the first sample of each sample's ring
    sample_ring_count: np.ndarray | None = None  # (N,) number of samples on that ring
    edge_ax: np.ndarray = None  # (E,) the edges' start, direction (end - start) and bounding boxes, by component
    edge_ay: np.ndarray = None
    edge_dx: np.ndarray = None
    edge_dy: np.ndarray = None
    edge_lox: np.ndarray = None
    edge_loy: np.ndarray = None
    edge_hix: np.ndarray = None
    edge_hiy: np.ndarray = None
    finger_boxes: np.ndarray | None = None  # (n, 4) bounding boxes of the finger obstacles' parts
    palm_boxes: np.ndarray | None = None  # (n, 4) the same for the palm obstacles
    neighbour_x: np.ndarray | None = None  # (N, 2K) the samples on the same ring within K steps of each sample
    neighbour_y: np.ndarray | None = None
    outline_shift_mm: float = 0.0  # how far the exact stages' outline lies from the given one at most
    target_convex: bool = False  # no holes and an outline that turns one way (`_turns_one_way`)
    hull_normal: np.ndarray | None = None  # (H, 2) outward unit normals of edges of the target's convex hull
    hull_limit: np.ndarray | None = None  # (H,) a point p with n . p above this is outside the target
    sample_cue: np.ndarray | None = None  # (4, N) each sample's normal (x, y), its neighbours' `neighbour_reach`
    samples_reachable: bool = False  # every midpoint of two samples passes the reach stage (its margin included)
    ik_box: tuple | None = None  # (x0, y0, x1, y1) around the target, in the workspace, every point reachable
    ring_sizes: tuple = ()  # edges per ring (the outline, then the holes), in the edge columns' order
    sample_convex: np.ndarray | None = None  # (N,) the material in `convex_region_mm` of each sample is convex
    _turns: tuple | None = field(default=None, repr=False)  # vertex_turns(), once worked out

    def vertex_turns(self) -> tuple:
        """(edge_prev, edge_ring, vertex_turn, vertex_convex) of `_vertex_turns`, worked out on first use: only
        `convex_near` asks (the pre-check, where there are finger-high obstacles), not every plan."""
        if self._turns is None:
            self._turns = _vertex_turns(self.ring_sizes, self.edge_dx, self.edge_dy)
        return self._turns

    def surely_outside(self, xy: np.ndarray, beyond_mm: float = 0.0) -> np.ndarray:
        """(n,) True for the points xy (2, n) surely outside the target by more than beyond_mm: beyond
        an edge of its convex hull by that plus the rounding of the test (HULL_MARGIN_MM)."""
        if self.hull_normal is None:
            return np.zeros(xy.shape[1], bool)
        # (a matrix product rounds otherwise than n_x x + n_y y, by far less than the margin)
        return (self.hull_normal @ xy > (self.hull_limit + beyond_mm)[:, None]).any(0)


    @classmethod
    def build(cls, target: Part, obstacles, cell: Cell, params: SynthesisParams, grasp_z_mm: float,
              samples: np.ndarray | None = None, sample_ring: np.ndarray | None = None,
              sample_normals: np.ndarray | None = None) -> Context:
        """samples (N, 2) and sample_ring (N,): the target's outline samples and their rings, for the
        pre-check's look at the outline next to each point; with sample_normals (N, 2) (the pairs' points'
        own) its bound on how far they lie ahead, and with finger-high obstacles whether the material near
        each sample is convex (`convex_near`), are worked out here, once per scene."""
        tall = [o for o in obstacles if o.z_top_mm > grasp_z_mm + Z_EPS_MM]
        palm_z = grasp_z_mm + cell.gripper.palm_offset_mm
        palm = [o for o in obstacles if o.z_top_mm > palm_z + Z_EPS_MM]

        def union(parts):
            if not parts:
                return None
            u = shapely.union_all([p.polygon for p in parts])
            if params.obstacle_margin_mm > 0:
                u = u.buffer(params.obstacle_margin_mm, quad_segs=4)
            shapely.prepare(u)
            return u

        tg, rings, shift = exact_outline(target)
        shapely.prepare(tg)
        a = np.vstack(rings)
        b = np.vstack([np.roll(r, -1, axis=0) for r in rings])
        tree = shapely.STRtree(shapely.linestrings(np.stack([a, b], axis=1)))
        first = count = None
        if samples is not None:
            ring = np.asarray(sample_ring, int)
            starts = np.searchsorted(ring, np.arange(ring.max() + 1))
            counts = np.bincount(ring)
            first, count = starts[ring], counts[ring]
        nx = ny = None
        if samples is not None:  # the samples next to each sample on its ring, for the pre-check
            samples = np.asarray(samples, float)
            offs = np.array(_neighbour_offsets(cell, params))
            near = first[:, None] + (np.arange(len(samples))[:, None] - first[:, None] + offs[None, :]) % count[:, None]
            nx, ny = samples[:, 0].take(near), samples[:, 1].take(near)
        cue = None
        if samples is not None and sample_normals is not None:
            n = np.asarray(sample_normals, float)
            by_neighbour = samples[:, 0].take(near.T), samples[:, 1].take(near.T)  # (2K, N): the bound's loops along N
            cue = np.stack([n[:, 0], n[:, 1], *neighbour_reach(samples, n, *by_neighbour)])
        fo, po = union(tall), union(palm)
        edges = _edge_columns(a, b)
        # per scene, outside the timed cascade: the hull's half-planes spare the contacts stage most of
        # its containment tests (bands.BandEdges._far_corners_inside)
        hull_n, hull_lim = _hull_half_planes(tg)
        ctx = cls(target, cell, params, grasp_z_mm, tg, fo, po, [o.id for o in tall],
                  a, b, tree, samples, first, count, *edges, _part_boxes(fo),
                  _part_boxes(po), nx, ny, shift, not target.holes_mm and _turns_one_way(edges[2], edges[3]),
                  hull_n, hull_lim, cue,
                  samples is not None and midpoints_surely_reachable(cell, samples, CHEAP_MARGIN_MM),
                  _ik_box(tg, cell, grasp_z_mm), tuple(len(r) for r in rings))
        if cue is not None and fo is not None:  # the pre-check's bound on where the fingers sit (cascade.py)
            ctx.sample_convex = convex_near(ctx, samples, n)
        return ctx


IK_BOX_MARGIN_MM = 5.0  # around the target's bounds: contacts' centres lie within its hull (or near it)


def _ik_box(geom, cell: Cell, grasp_z_mm: float) -> tuple | None:
    """The target's bounding box, IK_BOX_MARGIN_MM wider, when it lies in the workspace and every
    point of it is surely reachable at the grasp z (kinematics.box_surely_reachable): the ik stage
    then passes the pairs whose contacts' centre lies in it without solving (per scene)."""
    x0, y0, x1, y1 = (float(v) for v in shapely.bounds(geom))
    e, ws = IK_BOX_MARGIN_MM, cell.workspace
    box = (x0 - e, y0 - e, x1 + e, y1 + e)
    inside = ws.x_mm[0] <= box[0] and box[2] <= ws.x_mm[1] and ws.y_mm[0] <= box[1] and box[3] <= ws.y_mm[1]
    return box if inside and box_surely_reachable(*box, grasp_z_mm, cell.scara) else None


def midpoints_surely_reachable(cell: Cell, points: np.ndarray, margin_mm: float) -> bool:
    """Does every midpoint of two of the points (n, 2) lie in the SCARA's annulus and the workspace,
    margin_mm widened? It does when the points' bounding box lies inside the workspace and inside the
    annulus's outer circle (both convex: they hold the midpoints) and clear of its inner disc (1e-6 mm
    to spare for rounding): the usual case, decided from the points instead of their pairs."""
    if not len(points):
        return True
    x, y = points[:, 0], points[:, 1]
    x0, x1, y0, y1 = float(x.min()), float(x.max()), float(y.min()), float(y.max())
    ws, e, spare = cell.workspace, margin_mm, 1e-6
    if not (x0 >= ws.x_mm[0] - e + spare and x1 <= ws.x_mm[1] + e - spare
            and y0 >= ws.y_mm[0] - e + spare and y1 <= ws.y_mm[1] + e - spare):
        return False
    rmin, rmax = cell.scara.reach_mm
    far = math.hypot(max(-x0, x1), max(-y0, y1))  # the box's corner furthest from the base
    near = math.hypot(max(x0, -x1, 0.0), max(y0, -y1, 0.0))  # the box's distance from the base
    return far <= rmax + e - spare and near >= rmin - e + spare


def neighbour_reach(points: np.ndarray, normals: np.ndarray, nbx: np.ndarray, nby: np.ndarray):
    """How far each point's (n, 2) neighbours (nbx, nby, each (2K, n): neighbour by neighbour) lie ahead of
    it along its normal (not below 0) and across it at most, each (n,): the pre-check's bound
    (cascade._outline_ahead)."""
    rx, ry = nbx - points[:, 0], nby - points[:, 1]
    n_x, n_y = normals[:, 0], normals[:, 1]
    return np.maximum((rx * n_x + ry * n_y).max(0), 0.0), np.abs(ry * n_x - rx * n_y).max(0)


def exact_outline(target: Part):
    """The target's material as the exact stages see it: its polygon, its rings (outline, then
    holes) and how far they lie from the given ones at most (mm). Each ring is thinned to one vertex
    per EXACT_SPACING_MM of arc length where it has more on average (a finely tessellated CAD
    outline, a camera's at finer than 0.5 mm per pixel): the contacts stage's cost grows with the
    edges in each pad's band. Rings no denser than that, as the parts library's are, are kept."""
    rings = [np.asarray(r, float) for r in (target.outline_mm, *target.holes_mm)]
    kept = [_kept(r, EXACT_SPACING_MM) for r in rings]
    if any(k is not None for k in kept):
        thinned = [r if k is None else r[k] for r, k in zip(rings, kept, strict=True)]
        poly = shapely.Polygon(thinned[0], thinned[1:])
        if poly.is_valid:  # thinning a sliver narrower than the spacing could make it cross itself
            return poly, thinned, max(_shift(r, k) for r, k in zip(rings, kept, strict=True))
    given = target.polygon  # a new Polygon at every read
    return shapely.Polygon(given.exterior, given.interiors), rings, 0.0


def _kept(ring: np.ndarray, spacing_mm: float) -> np.ndarray | None:
    """Indices of the first vertex in each stretch of spacing_mm of arc length along the ring; None
    when the ring has no more than a vertex per spacing_mm on average (it is kept whole)."""
    seg = np.hypot(*(np.roll(ring, -1, axis=0) - ring).T)
    perimeter = float(seg.sum())
    if len(ring) * spacing_mm <= perimeter:
        return None
    at = np.concatenate([[0.0], np.cumsum(seg[:-1])])  # arc length at each vertex
    stretch = np.floor(at / spacing_mm)
    keep = np.flatnonzero(np.diff(stretch, prepend=-1.0) > 0)
    if perimeter - at[keep[-1]] < 0.5 * spacing_mm:  # the last kept vertex next to the first
        keep = keep[:-1]
    return keep if len(keep) >= 3 else None


def _shift(ring: np.ndarray, keep: np.ndarray | None) -> float:
    """The largest distance of a vertex of `ring` from the chord between the kept vertices around it:
    how far any point of the ring lies from the thinned ring at most (the distance to a segment is
    convex along each edge, so its largest value is at a vertex)."""
    if keep is None:
        return 0.0
    span = np.searchsorted(keep, np.arange(len(ring)), side="right") - 1  # the kept vertex before each
    span[span < 0] = len(keep) - 1  # before the first kept vertex: on the closing chord
    p, q = ring[keep[span]], ring[keep[(span + 1) % len(keep)]]
    d = q - p
    s = np.clip(((ring - p) * d).sum(1) / np.maximum((d * d).sum(1), 1e-300), 0.0, 1.0)
    return float(np.hypot(*(ring - (p + s[:, None] * d)).T).max())


def _vertex_turns(ring_sizes: tuple, dx: np.ndarray, dy: np.ndarray):
    """For the edges of rings of ring_sizes edges each (directions dx, dy (E,), ring after ring, one edge from
    each vertex to the next): the edge before each on its ring, its ring, and the turn at its start (rad;
    the material lies left of every edge, so > 0 is round the material) and whether that is a turn round
    the material or a straight run on (as `_turns_one_way` has it), each (E,)."""
    sizes = np.array(ring_sizes)
    first = np.repeat(np.cumsum(sizes) - sizes, sizes)
    e = np.arange(int(sizes.sum()))
    prev = first + (e - first - 1) % np.repeat(sizes, sizes)
    d = np.column_stack([dx, dy])
    a, b = d.take(prev, 0), d
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    dot = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]
    straight = (np.abs(cross) <= 1e-9 * np.hypot(*a.T) * np.hypot(*b.T)) & (dot > 0)
    return prev, np.repeat(np.arange(len(sizes)), sizes), np.arctan2(cross, dot), (cross > 0) | straight


def convex_region_mm(ctx: Context) -> tuple[float, float]:
    """The region around a candidate whose material decides where its pad's contact ends up (the cascade's
    bound on it): how far from the candidate (radius) and how far behind it along its normal (behind). The
    pad's band reaches half the pad + contact_tol across beyond the candidate's own offset (contact_tol);
    along the closing axis from contact_tol ahead to the compliance plus twice the outline's shift behind;
    the axis is within max_normal_angle_deg of the normal. 1e-3 mm to spare."""
    from cell.grasp.bands import PAD_COMPLIANCE_MM

    tol, shift = ctx.params.contact_tol_mm, ctx.outline_shift_mm
    across, back = ctx.cell.gripper.pad_width_mm / 2 + 2 * tol, PAD_COMPLIANCE_MM + 2 * shift
    tilt = math.sin(min(math.radians(ctx.params.max_normal_angle_deg) + 1e-6, math.pi / 2))
    return math.hypot(across, max(tol, back)) + 1e-3, back + across * tilt + 1e-3


def convex_near(ctx: Context, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(n,): is the target's material (exact_outline) in the region `convex_region_mm` of each point (n, 2)
    with its outward normal (n, 2) convex? The region is the disc of that radius less what lies further
    behind the point along its normal. True where the edges that meet it are consecutive edges of one ring
    turning only round the material (or straight on), by less than a half turn in all, or a whole ring
    turning so (a convex part): the material in the region is then the region cut by those edges'
    half-planes (the edges before and after the run end outside it, so beyond their ends the half-planes'
    other sides are air there). False where this cannot tell (a notch, a slot, a hole or the far side of a
    thin part just behind the point)."""
    n, n_edges = len(points), len(ctx.edge_ax)
    if n == 0:
        return np.zeros(0, bool)
    edge_prev, edge_ring, vertex_turn, vertex_convex = ctx.vertex_turns()
    near_point, edge = _edges_meeting(ctx, np.asarray(points, float), np.asarray(normals, float),
                                      *convex_region_mm(ctx))
    key = near_point * n_edges + edge
    order = np.argsort(key, kind="stable")
    key, near_point, edge = key.take(order), near_point.take(order), edge.take(order)
    prev_key = near_point * n_edges + edge_prev.take(edge)
    at = np.minimum(np.searchsorted(key, prev_key), max(len(key) - 1, 0))
    after_near = key.take(at) == prev_key if len(key) else np.zeros(0, bool)  # the vertex before lies in the run
    count = np.bincount(near_point, minlength=n)
    runs = np.bincount(near_point, weights=~after_near, minlength=n)
    reflex = np.bincount(near_point, weights=after_near & ~vertex_convex.take(edge), minlength=n)
    turning = np.bincount(near_point, weights=np.where(after_near, vertex_turn.take(edge), 0.0), minlength=n)
    ring = edge_ring.take(edge)
    ring_lo, ring_hi = np.full(n, n_edges), np.full(n, -1)
    np.minimum.at(ring_lo, near_point, ring)
    np.maximum.at(ring_hi, near_point, ring)
    one_run = (runs == 1) & (turning < math.pi - 1e-9)
    whole_ring = (runs == 0) & (count > 0)
    return (count == 0) | ((ring_lo == ring_hi) & (reflex == 0) & (one_run | whole_ring))


NEAR_EDGES_BROADCAST_MAX = 16_000  # points x edges up to which all of them are compared (else the STRtree
# first): the crossover measured on the library (broadcast 0.3 ms at 15 000, the tree 0.4; at 107 000, from a
# camera outline, 6 ms against 1.2)


def _edges_meeting(ctx: Context, points: np.ndarray, normals: np.ndarray, radius_mm: float, behind_mm: float):
    """(point, edge) index pairs (each (p,)) of the points (n, 2) and the target's edges that meet the disc of
    radius_mm round the point less what lies more than behind_mm behind it along its normal (n, 2): each
    edge clipped to that half-plane, then its distance from the point (1e-9 mm to spare: an edge is left
    out only where it surely misses the region)."""
    if len(points) * len(ctx.edge_ax) <= NEAR_EDGES_BROADCAST_MAX:
        q, e = np.indices((len(points), len(ctx.edge_ax))).reshape(2, -1)
    else:  # the edges within the radius first
        q, e = ctx.edge_tree.query(shapely.points(points), predicate="dwithin", distance=radius_mm + 1e-6)
    ax, ay, dx, dy = (c.take(e) for c in (ctx.edge_ax, ctx.edge_ay, ctx.edge_dx, ctx.edge_dy))
    rx, ry = points[:, 0].take(q) - ax, points[:, 1].take(q) - ay  # from each edge's start to the point
    nx, ny = normals[:, 0].take(q), normals[:, 1].take(q)
    # along the edge a + s d, the point's normal reads n . (a - p) + s n . d: at least -behind from s0 to s1
    h0, hd = -(nx * rx + ny * ry) + behind_mm + 1e-9, nx * dx + ny * dy
    cut = -h0 / np.where(hd != 0, hd, 1.0)
    s0 = np.where(hd > 0, np.maximum(cut, 0.0), 0.0)
    s1 = np.where(hd < 0, np.minimum(cut, 1.0), 1.0)
    inside = (s0 <= s1) & ((hd != 0) | (h0 >= 0))
    s = np.minimum(np.maximum((rx * dx + ry * dy) / np.maximum(dx * dx + dy * dy, 1e-300), s0), s1)
    ex, ey = rx - s * dx, ry - s * dy
    meets = inside & (ex * ex + ey * ey <= (radius_mm + 1e-9) ** 2)
    return q.compress(meets), e.compress(meets)


def _turns_one_way(dx: np.ndarray, dy: np.ndarray) -> bool:
    """Does a ring of edges (directions dx, dy, (E,)) turn the same way at every vertex, repeated
    vertices left out? Near-straight vertices (not turning back), within 1e-9 of the edges'
    lengths' product, turn neither way. A valid polygon's outline that does is convex."""
    length2 = dx * dx + dy * dy
    if not (length2 > 0).all():
        dx, dy, length2 = dx[length2 > 0], dy[length2 > 0], length2[length2 > 0]
    nx, ny, nl2 = (np.concatenate([a[1:], a[:1]]) for a in (dx, dy, length2))  # the next edge (np.roll costs more)
    cross = dx * ny - dy * nx
    straight = (np.abs(cross) <= 1e-9 * np.sqrt(length2 * nl2)) & (dx * nx + dy * ny > 0)
    return bool(((cross > 0) | straight).all() or ((cross < 0) | straight).all())


def _part_boxes(geom) -> np.ndarray | None:
    """(n, 4) bounding boxes (x0, y0, x1, y1) of the parts of a (multi)polygon; None for None."""
    return None if geom is None else shapely.bounds(shapely.get_parts(geom))


def _neighbour_offsets(cell: Cell, params: SynthesisParams) -> list[int]:
    """Steps along the outline, -K..-1, 1..K, that reach past a pad band's half width (contact_tol included)."""
    K = math.ceil((cell.gripper.pad_width_mm / 2 + params.contact_tol_mm) / params.step_mm) + 1
    return [*range(-K, 0), *range(1, K + 1)]


def _edge_columns(a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """Edges from a to b (E, 2): start x, y, direction x, y, bounding box lo x, y, hi x, y, each (E,)."""
    d = b - a
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return [np.ascontiguousarray(c) for c in (a[:, 0], a[:, 1], d[:, 0], d[:, 1], lo[:, 0], lo[:, 1], hi[:, 0],
                                              hi[:, 1])]


HULL_EDGES_MAX = 16  # the longest hull edges kept: each costs a numpy row per band corner tested
HULL_MARGIN_MM = 1e-6  # far above the rounding of n . p (1e-13 mm at 1 m)


def _hull_half_planes(geom):
    """The target's convex hull as half-planes n . p <= limit (n (H, 2) outward unit normals, limit
    (H,) with HULL_MARGIN_MM to spare): a point beyond any of them is outside the target. Only the
    HULL_EDGES_MAX longest edges (any subset is such a test). None, None for a degenerate hull."""
    hull = shapely.convex_hull(geom)
    if not isinstance(hull, shapely.Polygon) or hull.area <= 0:
        return None, None
    ring = np.asarray(hull.exterior.coords, float)
    if not hull.exterior.is_ccw:
        ring = ring[::-1]
    d = np.diff(ring, axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    keep = np.argsort(-length, kind="stable")[:HULL_EDGES_MAX]
    keep = keep[length[keep] > 0]
    n = np.stack([d[keep, 1], -d[keep, 0]], axis=1) / length[keep, None]  # walking direction turned right
    return n, (n * ring[keep]).sum(1) + HULL_MARGIN_MM


@dataclass
class Pairs:
    """Every unordered pair (i, j) of valid points with its closing-axis geometry, arrays (s, ...).

    u: closing axis (unit, from p_j towards p_i), the bisector of n_i and -n_j; m: pair midpoint;
    t: half the points' distance along u. The `contacts` stage fills ci, cj (the real touching
    points), center and h (half the jaw gap at the contacts); `ik` fills joints.
    """

    ij: np.ndarray
    pi: np.ndarray
    pj: np.ndarray
    ni: np.ndarray
    nj: np.ndarray
    d: np.ndarray
    u: np.ndarray
    m: np.ndarray
    t: np.ndarray
    ci: np.ndarray = None
    cj: np.ndarray = None
    center: np.ndarray = None
    h: np.ndarray = None
    joints: dict = field(default_factory=dict)
    ik: tuple | None = None  # (grasp z, scara) once the ik stage ran: joints_of solves from it
    stroke_refused: int = 0  # pairs the contacts stage refused only for the stroke at the pads' lines
    pivot_refused: int = 0  # pairs the contacts stage refused for both pads touching narrow material
    w: np.ndarray | None = None  # (s, 2) p_i - p_j, the stages reuse it
    points: np.ndarray | None = None  # (z', 2) the valid points the pairs are made of
    normals: np.ndarray | None = None  # (z', 2) their outward normals
    sample_index: np.ndarray | None = None  # (z',) each point's index among the target's outline samples

    def __post_init__(self):
        if self.w is None:
            self.w = self.pi - self.pj

    def __len__(self) -> int:
        return len(self.ij)

    @classmethod
    def of(cls, points: np.ndarray, normals: np.ndarray, sample_index: np.ndarray | None = None) -> Pairs:
        """sample_index (z',): each point's index among the target's outline samples (enables the
        pre-check's look at the outline next to each point)."""
        i, j, ij = _pair_indices(len(points))
        points, normals = np.asarray(points, float), np.asarray(normals, float)
        pi, pj, ni, nj = points.take(i, 0), points.take(j, 0), normals.take(i, 0), normals.take(j, 0)
        w = pi - pj
        d = _norm2(w)
        u = ni - nj
        un = _norm2(u)
        degenerate = un < 1e-9  # the same normal twice (one face): the axis is the line between the points
        if degenerate.any():
            np.copyto(u, w, where=degenerate[:, None])  # (boolean row indexing costs several times more)
            un = _norm2(u)
        u /= np.maximum(un, 1e-12)[:, None]
        m = 0.5 * (pi + pj)
        t = 0.5 * (w[:, 0] * u[:, 0] + w[:, 1] * u[:, 1])
        nan2 = np.full((len(i), 2), np.nan)
        sample_index = None if sample_index is None else np.asarray(sample_index, int)
        return cls(ij, pi, pj, ni, nj, d, u, m, t, nan2.copy(), nan2.copy(), nan2.copy(),
                   np.full(len(i), np.nan), w=w, points=points, normals=normals, sample_index=sample_index)

    def fresh(self) -> Pairs:
        """The same pairs with nothing the stages computed (contacts, IK) carried over."""
        nan2 = np.full((len(self), 2), np.nan)
        return Pairs(self.ij, self.pi, self.pj, self.ni, self.nj, self.d, self.u, self.m, self.t, nan2.copy(),
                     nan2.copy(), nan2.copy(), np.full(len(self), np.nan), w=self.w, points=self.points,
                     normals=self.normals, sample_index=self.sample_index)

    def axis_deg(self, k: int) -> float:
        return normalize_axis_deg(math.degrees(math.atan2(self.u[k, 1], self.u[k, 0])))


def _pair_indices(n: int):
    """i, j (s,) and ij (s, 2) of every pair i < j of n points, in np.triu_indices(n, k=1)'s order
    (row by row), built from ranges: triu_indices builds and scans an n x n mask, 4x slower."""
    after = np.arange(n - 1, -1, -1)  # each point's partners after it
    first = np.cumsum(after) - after  # the place of each point's first pair
    i = np.repeat(np.arange(n), after)
    j = np.arange(int(after.sum())) + np.repeat(np.arange(1, n + 1) - first, after)
    ij = np.empty((len(i), 2), i.dtype)
    ij[:, 0], ij[:, 1] = i, j
    return i, j, ij


def _norm2(a: np.ndarray) -> np.ndarray:
    """Row lengths of a (k, 2): np.linalg.norm(a, axis=1), bit for bit, without its reduction's cost."""
    return np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1])
