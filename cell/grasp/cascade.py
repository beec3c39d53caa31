"""Step 3: reachable pairs through a cascade of filters of increasing cost.

All pairs of valid points go through cheap, vectorised stages first (numpy over every pair),
then exact checks (shapely, closed-form IK) only on the survivors:

    stroke             contact distance within the jaw stroke (approach opening included)
    reach              pair centre inside the SCARA's annulus and the workspace (2 mm margin)
    antipodal          each normal within max_normal_angle of the line between the points, and
                       the points on one closing line (lateral offset <= contact_tol)
    precheck           points on the fingers' paths inside the target, a tall obstacle, or
                       the pair centre inside a palm-high obstacle: a certain collision
    contacts (exact)   each pad closes along the axis and stops at the first material in its
                       band: that point, found exactly, must be the candidate (within
                       contact_tol), or the candidate must be among the material touching the
                       pad (within PAD_COMPLIANCE of the first touch: a slanted face); the
                       touch becomes the reported contact. Real opening in stroke.
    ik (exact)         closed-form SCARA inverse kinematics within the joint limits
    fingers_obstacles  each finger's footprint swept from the approach opening to the contact
                       against every obstacle taller than the grasp z (lower ones are passed over)
    palm (exact)       the palm against every obstacle taller than the palm's bottom

The cheap stages only reject what an exact stage would also reject (the stroke, reach and
antipodal conditions are part of the definition of a feasible pair), so the cascade and
the brute force (every exact stage on every pair) keep the same pairs; `cell bench grasp`
checks that in every run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import shapely

from cell.cellconfig import Cell
from cell.grasp.footprints import axis_rect_bounds, axis_rects, rect_polygons
from cell.grasp.params import SynthesisParams
from cell.kinematics import Joints, inverse, normalize_axis_deg, reachable_mask
from cell.scene import Part

STAGES = ("stroke", "reach", "antipodal", "precheck", "contacts", "ik", "fingers_obstacles", "palm")
EXACT_STAGES = ("contacts", "ik", "fingers_obstacles", "palm")
PAD_COMPLIANCE_MM = 0.5  # material this close to the first-touch line touches the pad too
CHEAP_MARGIN_MM = 2.0
# a broadcast comparison of bounding boxes beats the STRtree's query for targets with up to this many
# edges (measured: 2x faster for 4-72 edges at any number of bands), or up to this many (band, edge) pairs
OVERLAP_BROADCAST_EDGES = 100
OVERLAP_BROADCAST_MAX = 20000
LB_STACKED_MAX = 5000  # segments up to which clipping to the four boundaries at once is faster
# Comparisons against a tolerance allow this much float noise, so that the verdict on a pair
# does not depend on where the part lies (mid-step samples on parallel faces sit exactly
# contact_tol apart across the axis).
EPS_MM = 1e-6
Z_EPS_MM = 1e-6


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

    @classmethod
    def build(cls, target: Part, obstacles, cell: Cell, params: SynthesisParams, grasp_z_mm: float,
              samples: np.ndarray | None = None, sample_ring: np.ndarray | None = None) -> Context:
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

        tg = shapely.Polygon(target.polygon.exterior, target.polygon.interiors)
        shapely.prepare(tg)
        rings = [target.outline_mm, *target.holes_mm]
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
        fo, po = union(tall), union(palm)
        return cls(target, cell, params, grasp_z_mm, tg, fo, po, [o.id for o in tall],
                   a, b, tree, samples, first, count, *_edge_columns(a, b), _part_boxes(fo),
                   _part_boxes(po), nx, ny)


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
    si: np.ndarray | None = None  # (s, 2) outline-sample index of p_i and p_j

    w: np.ndarray | None = None  # (s, 2) p_i - p_j, the stages reuse it

    def __post_init__(self):
        if self.w is None:
            self.w = self.pi - self.pj

    def __len__(self) -> int:
        return len(self.ij)

    @classmethod
    def of(cls, points: np.ndarray, normals: np.ndarray, sample_index: np.ndarray | None = None) -> Pairs:
        """sample_index (z',): each point's index among the target's outline samples (enables the
        pre-check's look at the outline next to each point)."""
        i, j = np.triu_indices(len(points), k=1)
        points, normals = np.asarray(points, float), np.asarray(normals, float)
        pi, pj, ni, nj = points.take(i, 0), points.take(j, 0), normals.take(i, 0), normals.take(j, 0)
        w = pi - pj
        d = _norm2(w)
        u = ni - nj
        un = _norm2(u)
        degenerate = un < 1e-9
        if degenerate.any():
            u[degenerate] = w[degenerate]
            un = _norm2(u)
        u /= np.maximum(un, 1e-12)[:, None]
        m = 0.5 * (pi + pj)
        t = 0.5 * (w[:, 0] * u[:, 0] + w[:, 1] * u[:, 1])
        nan2 = np.full((len(i), 2), np.nan)
        si = None if sample_index is None else np.column_stack([sample_index[i], sample_index[j]])
        return cls(np.column_stack([i, j]), pi, pj, ni, nj, d, u, m, t, nan2.copy(), nan2.copy(), nan2.copy(),
                   np.full(len(i), np.nan), si=si, w=w)

    def axis_deg(self, k: int) -> float:
        return normalize_axis_deg(math.degrees(math.atan2(self.u[k, 1], self.u[k, 0])))


def _norm2(a: np.ndarray) -> np.ndarray:
    """Row lengths of a (k, 2): np.linalg.norm(a, axis=1), bit for bit, without its reduction's cost."""
    return np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1])


def _dot2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row dot products of two (k, 2): (a * b).sum(1), bit for bit (a sum over an axis of length 2 costs
    ten times the two products and the addition)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]


# --- cheap stages: vectorised over the pairs idx -------------------------------------------
# Rows are gathered with take (numpy's fancy indexing of (k, 2) arrays costs several times more);
# when idx holds most pairs, a stage looks at every pair (views, no gathering) and picks idx's verdicts.

def _dense(P: Pairs, idx) -> bool:
    return 2 * len(idx) > len(P)


def stage_stroke(ctx: Context, P: Pairs, idx) -> np.ndarray:
    g = ctx.cell.gripper
    dense = _dense(P, idx)
    d = P.d if dense else P.d.take(idx)
    ok = (d >= g.opening_mm[0] - EPS_MM) & (d + 2 * g.approach_clearance_mm <= g.opening_mm[1] + EPS_MM)
    return ok.take(idx) if dense else ok


def stage_reach(ctx: Context, P: Pairs, idx) -> np.ndarray:
    dense = _dense(P, idx)
    m = P.m if dense else P.m.take(idx, 0)
    x, y = m[:, 0], m[:, 1]
    rmin, rmax = ctx.cell.scara.reach_mm
    r = np.sqrt(x * x + y * y)
    ws, e = ctx.cell.workspace, CHEAP_MARGIN_MM
    ok = ((r >= rmin - e) & (r <= rmax + e) & (x >= ws.x_mm[0] - e) & (x <= ws.x_mm[1] + e)
          & (y >= ws.y_mm[0] - e) & (y <= ws.y_mm[1] + e))
    return ok.take(idx) if dense else ok


def stage_antipodal(ctx: Context, P: Pairs, idx) -> np.ndarray:
    c = math.cos(math.radians(ctx.params.max_normal_angle_deg))
    dense = _dense(P, idx)
    d = P.d if dense else P.d.take(idx)
    w = (P.w if dense else P.w.take(idx, 0)) / np.maximum(d, 1e-12)[:, None]  # unit, p_j towards p_i
    ok = _dot2(P.ni if dense else P.ni.take(idx, 0), w) >= c - 1e-9
    # the other two conditions only where the first holds (most pairs fail it): same verdicts
    k = np.flatnonzero(ok)
    w, d = w.take(k, 0), d.take(k)
    sub = k if dense else idx.take(k)
    u = P.u.take(sub, 0)
    lateral = 0.5 * np.abs(w[:, 0] * u[:, 1] - w[:, 1] * u[:, 0]) * d
    # (n_j . -w) >= c, written as -(n_j . w) >= c: negation is exact, the verdict the same
    ok[k] = (-_dot2(P.nj.take(sub, 0), w) >= c - 1e-9) & (lateral <= ctx.params.contact_tol_mm + EPS_MM)
    return ok.take(idx) if dense else ok


def stage_precheck(ctx: Context, P: Pairs, idx) -> np.ndarray:
    """Conservative: a point that every exact footprint of this pair would cover lies inside
    material, or the outline next to a point juts out into its pad's band (docs/grasp.md)."""
    g = ctx.cell.gripper
    m, u, t = P.m.take(idx, 0), P.u.take(idx, 0), P.t.take(idx)
    tol = ctx.params.contact_tol_mm
    reach = g.approach_clearance_mm + g.pad_thickness_mm
    offs = np.array([tol + 1.5, 0.5 * (tol + reach), reach - 1.5])
    # both fingers' points in one shapely call: m + side * u * (t + off) is m + u * (side * (t + off)),
    # exactly, as side is +-1
    a = t[:, None] + offs[None, :]
    a = np.concatenate([a, -a], axis=1)  # (k, 6)
    x = (m[:, 0, None] + u[:, 0, None] * a).ravel()
    y = (m[:, 1, None] + u[:, 1, None] * a).ravel()
    hit = shapely.contains_xy(ctx.target_geom, x, y)
    if ctx.finger_obstacles is not None:
        hit |= shapely.contains_xy(ctx.finger_obstacles, x, y)
    ok = ~hit.reshape(len(idx), -1).any(1)
    if ctx.palm_obstacles is not None:
        ok &= ~shapely.contains_xy(ctx.palm_obstacles, m[:, 0], m[:, 1])
    if ctx.samples is not None and P.si is not None:
        ok &= ~_outline_ahead(ctx, P, idx)
    return ok


def _outline_ahead(ctx: Context, P: Pairs, idx) -> np.ndarray:
    """(k,) True where an outline sample next to p_i or p_j (same ring, within the pad's reach along
    the outline) lies in that pad's band further out than the candidate point by more than
    contact_tol: the pad would stop there first, so the `contacts` stage would reject the pair."""
    g, tol = ctx.cell.gripper, ctx.params.contact_tol_mm
    hw = g.pad_width_mm / 2 + tol
    k = len(idx)
    # both points at once: p_i's pad closes along -u from the +u side (side +1), p_j's from -u
    s = P.si.take(idx, 0).T.ravel()  # (2k,) p_i's samples, then p_j's
    m, u, t = P.m.take(idx, 0), P.u.take(idx, 0), P.t.take(idx)
    mx, my, t = np.concatenate([m[:, 0], m[:, 0]]), np.concatenate([m[:, 1], m[:, 1]]), np.concatenate([t, t])
    usx, usy = np.concatenate([u[:, 0], -u[:, 0]]), np.concatenate([u[:, 1], -u[:, 1]])
    t_max = t + g.approach_clearance_mm + g.pad_thickness_mm
    dx, dy = ctx.neighbour_x.take(s, 0) - mx[:, None], ctx.neighbour_y.take(s, 0) - my[:, None]  # (2k, 2K)
    tq = dx * usx[:, None] + dy * usy[:, None]
    lq = dx * -usy[:, None] + dy * usx[:, None]
    hit = ((np.abs(lq) <= hw - EPS_MM) & (tq <= t_max[:, None] - EPS_MM) & (tq > t[:, None] + tol + EPS_MM)).any(1)
    return hit[:k] | hit[k:]


# --- exact stages: shapely and IK on the survivors only -------------------------------------

@dataclass
class BandEdges:
    """The target's edges clipped to bands along u (one Liang-Barsky pass): pieces (p,) of edges,
    each the stretch s in [s0, s1] of edge A + s * D, in band coordinates (t along u from the
    band's centre, l across). Narrower bands with the same t range reuse the pieces (`narrowed`).
    Bands are columns (b,) of x and y components: the stages gather and combine them without the
    cost of numpy's (b, 2) fancy indexing and axis sums."""

    cx: np.ndarray  # (b,) centre
    cy: np.ndarray
    ux: np.ndarray  # (b,) u, the direction along the band (unit)
    uy: np.ndarray
    vx: np.ndarray  # (b,) v: u turned by +90 degrees
    vy: np.ndarray
    t_max: np.ndarray  # (b,)
    half_width: float | np.ndarray  # one for all bands, or (b,)
    bi: np.ndarray  # (p,) band of each piece
    s0: np.ndarray
    s1: np.ndarray
    tA: np.ndarray  # t and l of the edge's start, and their change along the edge
    lA: np.ndarray
    dt: np.ndarray
    dl: np.ndarray

    @classmethod
    def clip(cls, ctx: Context, cx, cy, ux, uy, t_min, t_max, half_width: float) -> BandEdges:
        """Where pads closing along -u towards the centres meet the target. Each band (b,) is the
        rectangle from t_min to t_max along u from its centre, half_width across (t_min just
        inside the candidate point: material further in cannot be the first touch when the
        candidate itself is in the band). The target's material in it is bounded by the target's
        edges clipped to the band (Liang-Barsky over the (band, edge) pairs whose bounding boxes
        overlap) and, when the band's far corners lie inside the target, by its far side
        (`first_touch`)."""
        vx, vy = -uy, ux
        lox, loy, hix, hiy = axis_rect_bounds(cx, cy, ux, uy, t_min, t_max, half_width)
        bi, ei = _overlapping_edges(ctx, lox, loy, hix, hiy)  # the clip below is exact
        c_x, c_y, u_x, u_y = cx.take(bi), cy.take(bi), ux.take(bi), uy.take(bi)
        v_x = -u_y
        acx, acy = ctx.edge_ax.take(ei) - c_x, ctx.edge_ay.take(ei) - c_y
        dx, dy = ctx.edge_dx.take(ei), ctx.edge_dy.take(ei)
        tA, lA = acx * u_x + acy * u_y, acx * v_x + acy * u_x
        dt, dl = dx * u_x + dy * u_y, dx * v_x + dy * u_x
        s0, s1, inside = _liang_barsky(tA, dt, lA, dl, t_min.take(bi), t_max.take(bi), half_width)
        k = np.flatnonzero(inside)
        return cls(cx, cy, ux, uy, vx, vy, t_max, half_width, bi.take(k), s0.take(k), s1.take(k), tA.take(k),
                   lA.take(k), dt.take(k), dl.take(k))

    def narrowed(self, rows: np.ndarray, half_widths: Sequence[float]) -> BandEdges:
        """The bands `rows` only, for each of half_widths (each <= this one's) across: the pieces
        clipped again. Bands (len(half_widths) * len(rows),): `rows` at the first width, then at the next."""
        if max(half_widths) > np.min(self.half_width):
            raise ValueError(f"a band {max(half_widths)} mm wide cannot be cut from one {np.min(self.half_width)} mm "
                             "wide")
        pos = np.full(len(self.cx), -1)
        pos[rows] = np.arange(len(rows))
        keep = np.flatnonzero(pos.take(self.bi) >= 0)
        bi = pos.take(self.bi.take(keep))
        n, nr = len(half_widths), len(rows)
        bi = np.concatenate([bi + w * nr for w in range(n)])
        tA, lA, dt, dl, s0, s1 = (np.concatenate([a.take(keep)] * n) for a in (self.tA, self.lA, self.dt, self.dl,
                                                                                   self.s0, self.s1))
        hw = np.repeat(np.asarray(half_widths, float), len(keep))
        with np.errstate(divide="ignore", invalid="ignore"):
            inside = np.ones(len(bi), bool)
            for p, q in ((-dl, lA + hw), (dl, hw - lA)):
                r = q / p
                s0 = np.where(p < 0, np.maximum(s0, r), s0)
                s1 = np.where(p > 0, np.minimum(s1, r), s1)
                inside &= ~((p == 0) & (q < 0))
            inside &= s0 <= s1
        k = np.flatnonzero(inside)
        rr = np.concatenate([rows] * n)
        return BandEdges(self.cx.take(rr), self.cy.take(rr), self.ux.take(rr), self.uy.take(rr), self.vx.take(rr),
                         self.vy.take(rr), self.t_max.take(rr), np.repeat(np.asarray(half_widths, float), nr),
                         bi.take(k), s0.take(k), s1.take(k), tA.take(k), lA.take(k), dt.take(k), dl.take(k))

    def first_touch(self, ctx: Context, slanted: bool = False, touch: bool = True):
        """T (b,): the largest distance along u of the target's material in each band (-inf: none), and
        (touch=True) the touching point (x, y), each (b,), on the first-touch line, in the middle
        (across the axis) of the material within PAD_COMPLIANCE_MM of it (nan: no material)."""
        b = len(self.cx)
        T = np.full(b, -np.inf)
        if len(self.bi):
            tt = np.maximum(self.tA + self.s0 * self.dt, self.tA + self.s1 * self.dt)  # the piece's end further out
            np.maximum.at(T, self.bi, tt)
        # the target's far side: material fills the band up to t_max where its far corners are inside
        hw = self.half_width
        fx, fy = self.cx + self.ux * self.t_max, self.cy + self.uy * self.t_max
        wx, wy = self.vx * hw, self.vy * hw
        far_in = shapely.contains_xy(ctx.target_geom, np.concatenate([fx - wx, fx + wx]),
                                     np.concatenate([fy - wy, fy + wy]))
        far_in = far_in[:b] | far_in[b:]
        T = np.where(far_in, np.maximum(T, self.t_max), T)
        if not touch:
            return T, None
        return T, self._touch(T, slanted)

    def _touch(self, T: np.ndarray, slanted: bool):
        # the touching material: the parts of the clipped edges within PAD_COMPLIANCE_MM of the first
        # touch (on a face slightly slanted to the pad that is a stretch from the band's side
        # inwards, not only the edge's end); the contact is the middle of its extent across the
        # axis, at the first-touch line (robust to edges that run along the band's side)
        b = len(self.cx)
        if not len(self.bi):
            return np.full(b, np.nan), np.full(b, np.nan)
        pb, p0, p1, pA, pdt = self.bi, self.s0, self.s1, self.tA, self.dt
        limit = T.take(pb) - PAD_COMPLIANCE_MM
        if slanted:
            with np.errstate(divide="ignore", invalid="ignore"):
                sc = (limit - pA) / pdt  # where the edge is PAD_COMPLIANCE_MM behind T
            lo_s = np.where(pdt > 0, np.maximum(p0, sc), p0)
            hi_s = np.where(pdt < 0, np.minimum(p1, sc), p1)
            near = (lo_s <= hi_s + 1e-12) & ((pdt != 0) | (pA >= limit))
        else:  # as before `slanted_faces`: only the clipped edges' ends within PAD_COMPLIANCE_MM
            e0, e1 = pA + p0 * pdt >= limit, pA + p1 * pdt >= limit
            lo_s, hi_s = np.where(e0, p0, p1), np.where(e1, p1, p0)
            near = e0 | e1
        k = np.flatnonzero(near)
        nb, lA, dl = pb.take(k), self.lA.take(k), self.dl.take(k)
        lat_lo = lA + lo_s.take(k) * dl  # across the axis, at both ends of the stretch
        lat_hi = lA + hi_s.take(k) * dl
        lo_l = np.full(b, np.inf)
        hi_l = np.full(b, -np.inf)
        np.minimum.at(lo_l, nb, np.minimum(lat_lo, lat_hi))
        np.maximum.at(hi_l, nb, np.maximum(lat_lo, lat_hi))
        has = lo_l < np.inf  # the bands with touching material (the lateral extremes are finite)
        with np.errstate(invalid="ignore"):
            mid = 0.5 * (lo_l + hi_l)
            x = np.where(has, self.cx + self.ux * T + self.vx * mid, np.nan)
            y = np.where(has, self.cy + self.uy * T + self.vy * mid, np.nan)
        return x, y


def _overlapping_edges(ctx: Context, lox, loy, hix, hiy):
    """(band, edge) index pairs whose bounding boxes overlap (touching counts, as for the STRtree):
    a broadcast comparison for few edges or bands, else the STRtree (same pairs, other order)."""
    if len(ctx.edge_ax) <= OVERLAP_BROADCAST_EDGES or len(lox) * len(ctx.edge_ax) <= OVERLAP_BROADCAST_MAX:
        hit = (lox[:, None] <= ctx.edge_hix) & (hix[:, None] >= ctx.edge_lox)
        hit &= (loy[:, None] <= ctx.edge_hiy) & (hiy[:, None] >= ctx.edge_loy)
        return np.nonzero(hit)
    return ctx.edge_tree.query(shapely.box(lox, loy, hix, hiy))


def _liang_barsky(tA, dt, lA, dl, t_min, t_max, half_width):
    """Clip segments (in band coordinates) to t_min <= t <= t_max, |l| <= half_width: s0, s1, inside.
    The entering parameter is the largest of the boundaries' where p < 0 (and 0), the leaving one the
    smallest where p > 0 (and 1)."""
    bounds = ((-dt, tA - t_min), (dt, t_max - tA), (-dl, lA + half_width), (dl, half_width - lA))
    with np.errstate(divide="ignore", invalid="ignore"):
        if len(tA) <= LB_STACKED_MAX:  # few segments: the four boundaries at once, rows of (4, n)
            p, q = np.stack([b[0] for b in bounds]), np.stack([b[1] for b in bounds])
            r = q / p
            s0 = np.maximum(np.where(p < 0, r, -np.inf).max(0), 0.0)
            s1 = np.minimum(np.where(p > 0, r, np.inf).min(0), 1.0)
            return s0, s1, ~((p == 0) & (q < 0)).any(0) & (s0 <= s1)
        s0, s1 = np.zeros(len(tA)), np.ones(len(tA))
        inside = np.ones(len(tA), bool)
        for p, q in bounds:
            r = q / p
            s0 = np.where(p < 0, np.maximum(s0, r), s0)
            s1 = np.where(p > 0, np.minimum(s1, r), s1)
            inside &= ~((p == 0) & (q < 0))
    return s0, s1, inside & (s0 <= s1)


def stage_contacts(ctx: Context, P: Pairs, idx) -> np.ndarray:
    """Close each pad along the axis; it stops at the first material in its band. That point must
    be the candidate's (within contact_tol, along and across the axis)."""
    k = len(idx)
    if k == 0:
        return np.zeros(0, bool)
    g, tol = ctx.cell.gripper, ctx.params.contact_tol_mm
    m, u, t = P.m.take(idx, 0), P.u.take(idx, 0), P.t.take(idx)
    # the 2k bands: p_i's pad (closing along -u from the +u side), then p_j's
    cx, cy = np.concatenate([m[:, 0], m[:, 0]]), np.concatenate([m[:, 1], m[:, 1]])
    ux, uy = np.concatenate([u[:, 0], -u[:, 0]]), np.concatenate([u[:, 1], -u[:, 1]])
    tt = np.concatenate([t, t])
    slanted = bool(ctx.params.slanted_faces)
    band = BandEdges.clip(ctx, cx, cy, ux, uy, tt - 2 * tol, tt + g.approach_clearance_mm + g.pad_thickness_mm,
                          g.pad_width_mm / 2 + tol)
    T, (x, y) = band.first_touch(ctx, slanted)
    vx, vy = band.vx, band.vy
    lateral = np.abs((x - cx) * vx + (y - cy) * vy)
    with np.errstate(invalid="ignore"):
        # the pad stops at the candidate: the first touch is within tol of it along and across the
        # axis. A face slightly slanted to the pad (a tapered web) is first touched at the band's
        # side and the middle of the touching stretch lies mm from the candidate; when the
        # candidate itself is within PAD_COMPLIANCE_MM of the first touch the pad presses on it
        # too: the contact is then on the first-touch line, on the pair's closing line when the
        # pad presses there as well, else across from the candidate
        pi, pj = P.pi.take(idx, 0), P.pj.take(idx, 0)  # p_i is on the +u side (its normal is near u)
        ax, ay = np.concatenate([pi[:, 0], pj[:, 0]]) - cx, np.concatenate([pi[:, 1], pj[:, 1]]) - cy
        pressed = np.isfinite(lateral) & (lateral > tol + EPS_MM) & (T <= tt + tol + EPS_MM)
        pressed &= slanted
        if pressed.any():
            q = np.flatnonzero(pressed)
            nq = len(q)
            # the pad itself (not the band widened by tol), and a thin band on the pair's closing line,
            # in one pass (the thin band's verdict is used only where the pad presses on the candidate)
            Tn, _ = band.narrowed(q, (g.pad_width_mm / 2, 0.05)).first_touch(ctx, touch=False)
            Tp, T0 = Tn[:nq], Tn[nq:]
            ax_q, ay_q = ax.take(q), ay.take(q)
            uxq, uyq, vxq, vyq = ux.take(q), uy.take(q), vx.take(q), vy.take(q)
            press = np.isfinite(Tp) & (Tp <= ax_q * uxq + ay_q * uyq + PAD_COMPLIANCE_MM + EPS_MM)
            # the contact on the first-touch line: on the pair's closing line when the pad presses
            # there too, else across from the candidate
            lat_c = np.where(T0 >= Tp - PAD_COMPLIANCE_MM, 0.0, ax_q * vxq + ay_q * vyq)
            cxq, cyq = cx.take(q), cy.take(q)
            px, py = cxq + uxq * Tp + vxq * lat_c, cyq + uyq * Tp + vyq * lat_c
            x[q] = np.where(press, px, x.take(q))
            y[q] = np.where(press, py, y.take(q))
            lateral[q] = np.where(press, np.abs((px - cxq) * vxq + (py - cyq) * vyq), lateral.take(q))
        ok2 = np.isfinite(lateral) & (T <= tt + tol + EPS_MM) & (lateral <= tol + EPS_MM)
    ok = ok2[:k] & ok2[k:]
    ci, cj = np.column_stack([x[:k], y[:k]]), np.column_stack([x[k:], y[k:]])
    h = 0.5 * _dot2(ci - cj, u)
    with np.errstate(invalid="ignore"):
        ok &= (2 * h >= g.opening_mm[0] - EPS_MM) & (2 * h + 2 * g.approach_clearance_mm <= g.opening_mm[1] + EPS_MM)
    P.ci[idx], P.cj[idx] = ci, cj
    P.center[idx] = 0.5 * (ci + cj)
    P.h[idx] = h
    return ok


def stage_ik(ctx: Context, P: Pairs, idx) -> np.ndarray:
    idx = np.asarray(idx, int)
    c, u = P.center.take(idx, 0), P.u.take(idx, 0)
    x, y = c[:, 0], c[:, 1]
    ws = ctx.cell.workspace
    axis = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    with np.errstate(invalid="ignore"):
        inside = (np.isfinite(x) & (x >= ws.x_mm[0]) & (x <= ws.x_mm[1]) & (y >= ws.y_mm[0]) & (y <= ws.y_mm[1]))
    if inside.all():  # the usual case: no subset to gather
        ok = reachable_mask(x, y, ctx.grasp_z_mm, axis, ctx.cell.scara)
    else:
        ok = np.zeros(len(idx), bool)
        ok[inside] = reachable_mask(x[inside], y[inside], ctx.grasp_z_mm, axis[inside], ctx.cell.scara)
    P.ik = (ctx.grasp_z_mm, ctx.cell.scara)  # the solutions, for the pairs that get looked at: joints_of
    return ok


def _rects_hitting(obstacles, boxes: np.ndarray, cx, cy, ux, uy, t0, t1, half_width: float) -> np.ndarray:
    """(k,) does the rectangle of `axis_rects` (centre and u by component, (k,)) intersect the prepared
    `obstacles`? Only the rectangles whose bounding box overlaps the box (n, 4) of one of the obstacles'
    parts are built and tested by shapely: the others cannot touch it (same verdicts, less work)."""
    lox, loy, hix, hiy = axis_rect_bounds(cx, cy, ux, uy, t0, t1, half_width)
    near = ((lox[:, None] <= boxes[:, 2]) & (hix[:, None] >= boxes[:, 0]) & (loy[:, None] <= boxes[:, 3])
            & (hiy[:, None] >= boxes[:, 1])).any(1)
    hit = np.zeros(len(cx), bool)
    r = np.flatnonzero(near)
    if len(r):
        c = np.column_stack([cx.take(r), cy.take(r)])
        u = np.column_stack([ux.take(r), uy.take(r)])
        t0, t1 = np.broadcast_to(t0, len(cx)).take(r), np.broadcast_to(t1, len(cx)).take(r)
        hit[r] = shapely.intersects(rect_polygons(axis_rects(c, u, t0, t1, half_width)), obstacles)
    return hit


def stage_fingers_obstacles(ctx: Context, P: Pairs, idx) -> np.ndarray:
    if ctx.finger_obstacles is None or len(idx) == 0:
        return np.ones(len(idx), bool)
    g = ctx.cell.gripper
    c, u, h = P.center.take(idx, 0), P.u.take(idx, 0), P.h.take(idx)
    hh = np.concatenate([h, h])
    hit = _rects_hitting(ctx.finger_obstacles, ctx.finger_boxes, np.concatenate([c[:, 0], c[:, 0]]),
                         np.concatenate([c[:, 1], c[:, 1]]), np.concatenate([u[:, 0], -u[:, 0]]),
                         np.concatenate([u[:, 1], -u[:, 1]]), hh,
                         hh + g.approach_clearance_mm + g.pad_thickness_mm, g.pad_width_mm / 2)
    return ~(hit[:len(idx)] | hit[len(idx):])


def stage_palm(ctx: Context, P: Pairs, idx) -> np.ndarray:
    if ctx.palm_obstacles is None or len(idx) == 0:
        return np.ones(len(idx), bool)
    g = ctx.cell.gripper
    c, u = P.center.take(idx, 0), P.u.take(idx, 0)
    return ~_rects_hitting(ctx.palm_obstacles, ctx.palm_boxes, c[:, 0], c[:, 1], u[:, 0], u[:, 1],
                           -g.palm_length_mm / 2, g.palm_length_mm / 2, g.palm_width_mm / 2)


STAGE_FUNCS = {"stroke": stage_stroke, "reach": stage_reach, "antipodal": stage_antipodal,
               "precheck": stage_precheck, "contacts": stage_contacts, "ik": stage_ik,
               "fingers_obstacles": stage_fingers_obstacles, "palm": stage_palm}


@dataclass
class CascadeResult:
    survivors: np.ndarray  # pair indices that passed every stage
    rejected_by: np.ndarray  # (s,) index into STAGES of the stage that rejected each pair, -1 if kept
    kept: dict  # stage -> number of pairs it kept
    exact_checks: int  # pair evaluations in the exact stages
    time_ms: dict  # stage -> wall time


def run_cascade(ctx: Context, P: Pairs, stages=STAGES) -> CascadeResult:
    import time

    alive = np.arange(len(P))
    rejected_by = np.full(len(P), -1)
    kept, times, exact = {}, {}, 0
    for name in stages:
        t0 = time.perf_counter()
        if name in EXACT_STAGES:
            exact += len(alive)
        ok = STAGE_FUNCS[name](ctx, P, alive) if len(alive) else np.zeros(0, bool)
        rejected_by[alive[~ok]] = STAGES.index(name)
        alive = alive[ok]
        kept[name] = len(alive)
        times[name] = (time.perf_counter() - t0) * 1e3
    return CascadeResult(alive, rejected_by, kept, exact, times)


def run_brute_force(ctx: Context, P: Pairs) -> CascadeResult:
    """Every pair through every stage (the exact ones included), for the benchmark: the
    feasible pairs are those no stage rejects."""
    import time

    every = np.arange(len(P))
    ok = np.ones(len(P), bool)
    rejected_by = np.full(len(P), -1)
    times, exact = {}, 0
    for name in ("stroke", "reach", "antipodal", *EXACT_STAGES):
        t0 = time.perf_counter()
        if name in EXACT_STAGES:
            exact += len(P)
        if name in ("fingers_obstacles", "palm", "ik"):
            # these need the contacts' geometry, which exists where the contacts stage found one
            has = np.isfinite(P.center[:, 0])
            r = np.zeros(len(P), bool)
            r[has] = STAGE_FUNCS[name](ctx, P, every[has])
        else:
            r = STAGE_FUNCS[name](ctx, P, every)
        rejected_by[(rejected_by < 0) & ~r] = STAGES.index(name)
        ok &= r
        times[name] = (time.perf_counter() - t0) * 1e3
    return CascadeResult(np.flatnonzero(ok), rejected_by, {"feasible": int(ok.sum())}, exact, times)


class _Solutions(Sequence):
    """Every IK solution of pair k, worked out on first use (most reachable pairs never are)."""

    def __init__(self, P: Pairs, k: int):
        self._P, self._k = P, int(k)

    def _list(self) -> list[Joints]:
        P, k = self._P, self._k
        if k not in P.joints:
            z, scara = P.ik
            x, y = P.center[k]
            P.joints[k] = inverse(float(x), float(y), z, P.axis_deg(k), scara)
        return P.joints[k]

    def __getitem__(self, i):
        return self._list()[i]

    def __len__(self) -> int:
        return len(self._list())


def joints_of(P: Pairs, k: int) -> Sequence[Joints]:
    """The joint solutions of pair k (both elbows, every J4 turn), computed when first read."""
    return _Solutions(P, k)
