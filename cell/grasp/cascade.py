"""Step 3: reachable pairs through a cascade of filters of increasing cost.

All pairs of valid points go through cheap, vectorised stages first (numpy over every pair),
then exact checks (shapely, closed-form IK) only on the survivors:

    stroke             contact distance within the jaw stroke (approach opening included)
    reach              pair centre inside the SCARA's annulus and the workspace (2 mm margin)
    antipodal          each normal within max_normal_angle of the line between the points, and
                       the points on one closing line (lateral offset <= contact_tol)
    precheck           the outline next to a point ahead of it in its pad's band, points every palm
                       footprint covers inside a palm-high obstacle, points on the fingers' paths
                       inside a tall obstacle or a non-convex target: a certain collision or a pad
                       stopped early (every footprint: from bounds on where the contacts can lie)
    contacts (exact)   each pad closes along the axis and stops at the first material in its
                       band: that point, found exactly, must be the candidate (within
                       contact_tol), or the candidate must be among the material touching the
                       pad (within PAD_COMPLIANCE of the first touch: a slanted face); the
                       touch becomes the reported contact, moved onto the material the pad
                       touches (the nearest point of it: the pad's line can run up to
                       PAD_COMPLIANCE in front of a slanted face or across a notch). Real
                       opening in stroke.
    ik (exact)         closed-form SCARA inverse kinematics within the joint limits
    fingers_obstacles  each finger's footprint swept from the approach opening to the contact
                       against every obstacle taller than the grasp z (lower ones are passed over)
    palm (exact)       the palm against every obstacle taller than the palm's bottom

The cheap stages only reject what an exact stage would also reject (the stroke, reach and
antipodal conditions are part of the definition of a feasible pair), so the cascade and
the brute force (every exact stage on every pair) keep the same pairs; `cell bench grasp`
checks that in every run.

nan and inf are ordinary values here (no material in a band, no touch): the stages and the band
geometry run under one np.errstate in run_cascade and run_brute_force (each errstate costs
microseconds, and a cascade is about a millisecond); call them the same way.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely

from cell.grasp.bands import PAD_COMPLIANCE_MM, BandEdges, edge_box_overlaps
from cell.grasp.footprints import axis_rect_bounds, axis_rects, rect_polygons
from cell.grasp.pairs import (
    CHEAP_MARGIN_MM,
    EPS_MM,
    Context,
    Pairs,
    convex_near,
    midpoints_surely_reachable,
    neighbour_reach,
)
from cell.kinematics import Joints, inverse, reachable_mask

# A grasp centre further than this across the axis from its pair's line (more than float noise) has
# its pads looked at again where the gripper puts them (`_pads_stop_at_contacts`).
CENTRE_SHIFT_MM = 1e-9

__all__ = ["STAGES", "EXACT_STAGES", "Context", "Pairs", "CascadeResult", "run_cascade", "run_brute_force",
           "joints_of"]

STAGES = ("stroke", "reach", "antipodal", "precheck", "contacts", "ik", "fingers_obstacles", "palm")
EXACT_STAGES = ("contacts", "ik", "fingers_obstacles", "palm")


# --- cheap stages: vectorised over the pairs idx -------------------------------------------
# Rows are gathered with take (numpy's fancy indexing of (k, 2) arrays costs several times more);
# when idx holds most pairs, a stage looks at every pair (views, no gathering) and picks idx's verdicts.

def _dense(P: Pairs, idx) -> bool:
    return 2 * len(idx) > len(P)


def _picked(ok: np.ndarray, P: Pairs, idx) -> np.ndarray:
    """idx's verdicts from a dense stage's verdicts on every pair (idx is sorted: all of them is every pair)."""
    return ok if len(idx) == len(P) else ok.take(idx)


def stage_stroke(ctx: Context, P: Pairs, idx) -> np.ndarray:
    g = ctx.cell.gripper
    dense = _dense(P, idx)
    d = P.d if dense else P.d.take(idx)
    ok = (d >= g.opening_mm[0] - EPS_MM) & (d + 2 * g.approach_clearance_mm <= g.opening_mm[1] + EPS_MM)
    return _picked(ok, P, idx) if dense else ok


def stage_reach(ctx: Context, P: Pairs, idx) -> np.ndarray:
    # every midpoint passes when the points' box does (midpoints_surely_reachable): the usual case. The
    # scene's outline samples' box holds that of pairs of samples; it is looked at once per scene
    if ((ctx.samples_reachable and P.sample_index is not None)
            or (P.points is not None and _midpoints_surely_reachable(ctx, P.points))):
        return np.ones(len(idx), bool)
    dense = _dense(P, idx)
    m = P.m if dense else P.m.take(idx, 0)
    x, y = m[:, 0], m[:, 1]
    rmin, rmax = ctx.cell.scara.reach_mm
    r = np.sqrt(x * x + y * y)
    ws, e = ctx.cell.workspace, CHEAP_MARGIN_MM
    ok = ((r >= rmin - e) & (r <= rmax + e) & (x >= ws.x_mm[0] - e) & (x <= ws.x_mm[1] + e)
          & (y >= ws.y_mm[0] - e) & (y <= ws.y_mm[1] + e))
    return _picked(ok, P, idx) if dense else ok


def _midpoints_surely_reachable(ctx: Context, points: np.ndarray) -> bool:
    return midpoints_surely_reachable(ctx.cell, points, CHEAP_MARGIN_MM)


def stage_antipodal(ctx: Context, P: Pairs, idx) -> np.ndarray:
    # n . w/|w| >= c written as n . w >= c |w|: no division, the same condition (|w| at least
    # 1e-12: two coincident points, where a hole touches the outline, face no way)
    c = math.cos(math.radians(ctx.params.max_normal_angle_deg)) - 1e-9
    dense = _dense(P, idx)
    d = np.maximum(P.d if dense else P.d.take(idx), 1e-12)
    w = P.w if dense else P.w.take(idx, 0)
    ni = P.ni if dense else P.ni.take(idx, 0)
    ok = ni[:, 0] * w[:, 0] + ni[:, 1] * w[:, 1] >= c * d
    # the other two conditions only where the first holds (most pairs fail it): same verdicts
    k = np.flatnonzero(ok)
    sub = k if dense else idx.take(k)
    w, d, u, nj = w.take(k, 0), d.take(k), P.u.take(sub, 0), P.nj.take(sub, 0)
    wx, wy = w[:, 0], w[:, 1]
    lateral = 0.5 * np.abs(wx * u[:, 1] - wy * u[:, 0])  # |w x u| / 2: the points' offset across the axis
    ok[k] = (-(nj[:, 0] * wx + nj[:, 1] * wy) >= c * d) & (lateral <= ctx.params.contact_tol_mm + EPS_MM)
    return _picked(ok, P, idx) if dense else ok


def stage_precheck(ctx: Context, P: Pairs, idx) -> np.ndarray:
    """Conservative: a point that every exact footprint of this pair would cover lies inside
    material, or the outline next to a point juts out into its pad's band (docs/grasp.md). The tests
    run in turn, each on the pairs the ones before left (the cheapest and most telling first)."""
    idx = np.asarray(idx)
    # how far across the closing line the fingers' and the palm's centre line can lie (palm-high
    # obstacles are finger-high too)
    across = None if ctx.finger_obstacles is None else _centre_across_bound_mm(ctx, P, idx)
    alive, rows, rows_across = None, idx, across  # alive: the rows no test has rejected (None: all)
    for test in _precheck_tests(ctx, P, across is not None):
        hit = test(rows, rows_across)
        if hit.any():
            left = np.flatnonzero(~hit)
            alive = left if alive is None else alive.take(left)
            if not len(alive):
                break
            rows, rows_across = idx.take(alive), None if across is None else across.take(alive)
    if alive is None:
        return np.ones(len(idx), bool)
    ok = np.zeros(len(idx), bool)
    ok[alive] = True
    return ok


def _precheck_tests(ctx: Context, P: Pairs, obstacles: bool) -> list:
    """The pre-check's tests for this scene, each (pairs idx (r,), their `across` (r,) or None) -> (r,) hit."""
    tests = []
    if ctx.samples is not None and P.sample_index is not None:
        tests.append(lambda rows, across: _outline_ahead(ctx, P, rows))
    if ctx.palm_obstacles is not None:  # few points a pair, and where there are palm-high parts it rejects many
        tests.append(lambda rows, across: _palm_blocked(ctx, P, rows, across))
    # material on the fingers' paths: tall obstacles, and the target itself unless it is convex
    # (there the material in front of a pad is the outline next to its point, which
    # _outline_ahead looks at: on the parts library the test never rejected a pair more)
    target = None if ctx.target_convex else ctx.target_geom
    offs = _path_offsets(ctx) if target is not None or obstacles else np.zeros(0)
    if len(offs):
        tests.append(lambda rows, across: _fingers_blocked(ctx, target, P, rows, offs, across))
    return tests


def _fingers_blocked(ctx: Context, target, P: Pairs, idx, offs: np.ndarray, across: np.ndarray | None) -> np.ndarray:
    """(k,): does material lie where every exact footprint of a finger of the pairs idx would be? offs
    (n,) beyond each candidate along the axis (`_path_offsets`); the target (None: not asked) on the
    pair's closing line, which runs through the contacts stage's bands whatever the contacts; the
    finger-high obstacles (across None: not asked) on that line and at both sides of the stretch the
    fingers surely cover, half a pad less `across` (k,) either side of it."""
    k = len(idx)
    m, u, t = P.m.take(idx, 0), P.u.take(idx, 0), P.t.take(idx)
    # both fingers' points in one pass: m + side * u * (t + off) is m + u * (side * (t + off)),
    # exactly, as side is +-1
    a = t[:, None] + offs[None, :]
    a = np.concatenate([a, -a], axis=1)  # (k, 2n)
    x, y = m[:, 0, None] + u[:, 0, None] * a, m[:, 1, None] + u[:, 1, None] * a
    hit = np.zeros(k, bool)
    if target is not None:
        xy = np.stack([x.ravel(), y.ravel()])
        hit = _in_geom(target, xy, ~ctx.surely_outside(xy)).reshape(k, -1).any(1)
    if across is not None:
        side = ctx.cell.gripper.pad_width_mm / 2 - across - EPS_MM  # (k,) covered either side of the line
        asked = (side >= 0) & ~hit
        if asked.all():  # (the usual case: no gathering)
            hit = _in_obstacles(ctx.finger_obstacles, ctx.finger_boxes, _beside(x, y, u, side, (0.0, 1.0, -1.0)), k)
        elif asked.any():
            r = np.flatnonzero(asked)
            xy = _beside(x.take(r, 0), y.take(r, 0), u.take(r, 0), side.take(r), (0.0, 1.0, -1.0))
            hit[r] = _in_obstacles(ctx.finger_obstacles, ctx.finger_boxes, xy, len(r))
    return hit


def _in_obstacles(obstacles, boxes: np.ndarray, xy: np.ndarray, k: int) -> np.ndarray:
    """(k,): is one of each of k pairs' points xy (2, k n) (pair by pair) inside the obstacles? Only the
    points in one of their parts' boxes (n, 4) are asked of shapely."""
    return _in_geom(obstacles, xy, _in_boxes(boxes, xy)).reshape(k, -1).any(1)


def _beside(x: np.ndarray, y: np.ndarray, u: np.ndarray, side: np.ndarray, sides: tuple) -> np.ndarray:
    """(2, len(sides) r n): the points (x, y) (r, n) of r pairs (axis u (r, 2)) moved across the axis by
    each of `sides` times side (r,)."""
    s = np.array(sides)[None, :, None]
    return np.stack([(x[:, None, :] + s * (-u[:, 1] * side)[:, None, None]).ravel(),
                     (y[:, None, :] + s * (u[:, 0] * side)[:, None, None]).ravel()])


def _palm_blocked(ctx: Context, P: Pairs, idx, across: np.ndarray) -> np.ndarray:
    """(k,): does a palm-high obstacle lie where every exact palm footprint of the pairs idx would be? The
    palm is centred on the contacts' centre, which lies within `_contact_along_bounds_mm` along the axis of
    the pair's midpoint and across (k,) across it: it surely covers the rectangle round the midpoint that
    much smaller. Its corners, its sides' middles and its centre are asked."""
    g = ctx.cell.gripper
    behind, ahead = _contact_along_bounds_mm(ctx)
    along = g.palm_length_mm / 2 - 0.5 * (behind + ahead) - EPS_MM
    side = g.palm_width_mm / 2 - across - EPS_MM  # (k,)
    if along < 0:  # (a palm shorter than the contacts' play: no point is surely under it)
        return np.zeros(len(idx), bool)
    m, u = P.m.take(idx, 0), P.u.take(idx, 0)
    a = np.array([0.0, along, -along])
    x, y = m[:, 0, None] + u[:, 0, None] * a, m[:, 1, None] + u[:, 1, None] * a  # (k, 3) along the axis
    hit = _in_obstacles(ctx.palm_obstacles, ctx.palm_boxes, _beside(x, y, u, side, (0.0, 1.0, -1.0)), len(idx))
    return hit & (side >= 0)  # (a palm narrower than the contacts' play across: none either)


def _path_offsets(ctx: Context) -> np.ndarray:
    """Where beyond the candidate (along the closing axis) the points lie that every exact footprint
    covers (along the axis; `_centre_across_bound_mm` says where across): a contact lies from the
    compliance and the outline's shift behind the candidate to tol ahead of it (`_contact_along_bounds_mm`),
    and the finger reaches clearance + pad thickness beyond it. Thin pads with little clearance leave
    none (the points were then past the finger's end or behind the contact)."""
    g, tol = ctx.cell.gripper, ctx.params.contact_tol_mm
    reach = g.approach_clearance_mm + g.pad_thickness_mm
    behind, _ = _contact_along_bounds_mm(ctx)
    return np.array([o for o in (tol + 1.5, 0.5 * (tol + reach), reach - 1.5)
                     if tol + PAD_COMPLIANCE_MM <= o <= reach - max(tol + PAD_COMPLIANCE_MM, behind)])


# Where the contacts stage puts a pair's contacts, from the pair alone (the pre-check's footprints rest
# on it). Band coordinates: t along the closing axis u from the pair's midpoint m, l across it. The pad
# of p_i (at t along u, at most contact_tol across) stops on the line T of the first material in its band
# (the pad + contact_tol each side, centred on m's line), at most tol ahead of p_i (the stage asks that)
# and not behind it by more than the outline's shift (the exact material comes that near p_i); the touch
# on that line lies at most tol across (asked too). _onto_material then moves it to the nearest material
# within PAD_COMPLIANCE_MM behind that line: t' in [t - shift - compliance, t + tol], and anywhere in the
# band across (a notch under the touch, its rims at the band's sides: up to half the pad + tol across,
# tests/test_cascade_boundaries.py). Where the material in convex_region_mm of p_i is convex, the band
# has material under the touch within the compliance (the touch lies between the touching material's
# sides), so the move is at most that (`_onto_material_move_mm`).

def _contact_along_bounds_mm(ctx: Context) -> tuple[float, float]:
    """How far behind and ahead of its candidate (along the closing axis) a contact can lie."""
    return ctx.outline_shift_mm + PAD_COMPLIANCE_MM, ctx.params.contact_tol_mm + EPS_MM


def _onto_material_move_mm(ctx: Context) -> float:
    """How far the contacts stage can move a touch onto the material when the material near the candidate
    is convex: the compliance (from the touch's line to the material under it), with a pressing pad the
    thin band's half width on the closing line, and where the outline was thinned a little more per mm of
    shift (the candidate then lies up to that shift off the exact material: the move runs towards the
    first touch, at most half the pad + tol + shift across, rising compliance + shift over it)."""
    g, tol, shift = ctx.cell.gripper, ctx.params.contact_tol_mm, ctx.outline_shift_mm
    beside = g.pad_width_mm / 2 + tol + shift
    return PAD_COMPLIANCE_MM + CLOSING_LINE_BAND_MM + shift * (1 + beside / (PAD_COMPLIANCE_MM + shift))


def _centre_across_bound_mm(ctx: Context, P: Pairs, idx) -> np.ndarray:
    """(k,): how far across the closing line the contacts' centre (the fingers' and the palm's centre
    line) can lie for the pairs idx: the mean of the contacts' bounds, each anywhere in its band or, where
    the material near its candidate is convex, within tol + the move onto the material."""
    g, tol = ctx.cell.gripper, ctx.params.contact_tol_mm
    convex = _points_convex(ctx, P)
    near = tol + EPS_MM + _onto_material_move_mm(ctx)
    band = g.pad_width_mm / 2 + tol
    ij = P.ij.take(idx, 0)
    return 0.5 * (np.where(convex.take(ij[:, 0]), near, band) + np.where(convex.take(ij[:, 1]), near, band))


def _points_convex(ctx: Context, P: Pairs) -> np.ndarray:
    """(z',): is the material near each of the pairs' points convex (`convex_near`)? The scene's samples'
    verdicts when Context.build had them (per scene), else worked out for the points."""
    if ctx.sample_convex is not None and P.sample_index is not None:
        return ctx.sample_convex.take(P.sample_index)
    return convex_near(ctx, P.points, P.normals)


def _in_geom(geom, xy: np.ndarray, maybe: np.ndarray) -> np.ndarray:
    """(n,) are the points xy (2, n) inside the prepared geom? Only the points `maybe` (n,) (inside the
    target's convex hull, or an obstacle part's box) are asked of shapely (about 40-70 ns a point); the
    others cannot be inside."""
    hit = np.zeros(xy.shape[1], bool)
    r = np.flatnonzero(maybe)
    if len(r):
        hit[r] = shapely.contains_xy(geom, xy[0].take(r), xy[1].take(r))
    return hit


def _in_boxes(boxes: np.ndarray | None, xy: np.ndarray) -> np.ndarray | None:
    """(n,) is each point xy (2, n) in (or on) one of the boxes (m, 4) (x0, y0, x1, y1)? None for None."""
    if boxes is None:
        return None
    x, y = xy[0], xy[1]
    return ((x >= boxes[:, :1]) & (x <= boxes[:, 2:3]) & (y >= boxes[:, 1:2]) & (y <= boxes[:, 3:])).any(0)


def _outline_ahead(ctx: Context, P: Pairs, idx) -> np.ndarray:
    """(k,) True where an outline sample next to p_i or p_j (same ring, within the pad's reach along
    the outline) lies in that pad's band further out than the candidate point by more than
    contact_tol: the pad would stop there first, so the `contacts` stage would reject the pair."""
    g, tol = ctx.cell.gripper, ctx.params.contact_tol_mm
    # the samples lie on the outline as given, the exact stages' material up to the shift from it
    # (a thinned outline, pairs.exact_outline): by that much further inside the band, to be sure
    shift = ctx.outline_shift_mm
    hw = g.pad_width_mm / 2 + tol - shift
    k = len(idx)
    # the 2k rows: p_i's pad closes along -u from the +u side (side +1), p_j's from -u
    pt = P.ij.take(idx, 0).T.ravel()  # (2k,) p_i's point, then p_j's
    sample = P.sample_index.take(pt)
    u = P.u.take(idx, 0)
    us = np.concatenate([u.T, -u.T], axis=1)  # (2, 2k)
    # each point's neighbours, and how far ahead of it they can lie: a neighbour r from the point
    # (a along its normal n, b across) lies a cos(th) + b sin(th) <= max(a, 0) + |b| |sin(th)| ahead
    # along a closing axis th from n (|th| < 90 degrees). Where that bound is within tol (a point on a
    # straight stretch, an axis along its normal: the usual case) no neighbour can be ahead; the
    # test below (same verdicts) looks at the other rows only
    cue = _row_cues(ctx, P, pt, sample)  # (4, 2k): n_x, n_y, ahead, across
    c, s = us * cue[:2], us * cue[1::-1]
    cos, sin = c[0] + c[1], np.abs(s[0] - s[1])
    rows = np.flatnonzero((cos <= 0) | (cue[2] + cue[3] * sin > tol + shift))
    if not len(rows):
        return np.zeros(k, bool)
    m, t = P.m.take(idx, 0), P.t.take(idx)
    pair = rows % k
    mx, my, tr = m[:, 0].take(pair), m[:, 1].take(pair), t.take(pair)
    ux_r, uy_r = us[0].take(rows), us[1].take(rows)
    t_max = tr + g.approach_clearance_mm + g.pad_thickness_mm - shift
    q = sample.take(rows)
    dx, dy = ctx.neighbour_x.take(q, 0) - mx[:, None], ctx.neighbour_y.take(q, 0) - my[:, None]  # (r, 2K)
    tq = dx * ux_r[:, None] + dy * uy_r[:, None]
    lq = dx * -uy_r[:, None] + dy * ux_r[:, None]
    hit = np.zeros(2 * k, bool)
    hit[rows] = ((np.abs(lq) <= hw - EPS_MM) & (tq <= t_max[:, None] - EPS_MM)
                 & (tq > tr[:, None] + tol + shift + EPS_MM)).any(1)
    return hit[:k] | hit[k:]


def _row_cues(ctx: Context, P: Pairs, pt: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """(4, r) for rows of points pt (r,) (their outline samples `sample`): the point's normal (x, y)
    and how far its neighbours lie ahead of it along the normal and across it at most. From the
    scene's samples when Context.build had their normals (per scene, outside the timed cascade),
    else worked out for the pairs' points."""
    if ctx.sample_cue is not None:
        return ctx.sample_cue.take(sample, axis=1)
    n = P.normals
    ahead, across = neighbour_reach(P.points, n, ctx.neighbour_x.T.take(P.sample_index, axis=1),
                                    ctx.neighbour_y.T.take(P.sample_index, axis=1))
    return np.stack([n[:, 0], n[:, 1], ahead, across]).take(pt, axis=1)


# --- exact stages: shapely and IK on the survivors only -------------------------------------


# The contacts stage clips every edge whose box overlaps a pad's band: on a comb of 0.25 mm teeth
# that is a hundred edges per band, and 70000 pairs made 14 million pieces (3 GB). The pairs go
# through in chunks of at most about this many pieces (same verdicts: each band is on its own).
CONTACT_PIECES_PER_CHUNK = 400_000
CLOSING_LINE_BAND_MM = 0.05  # half the width of the thin band on the pair's closing line a pressing pad is asked about
CHUNK_ESTIMATE_ABOVE = 4_000_000  # bands x edges below which one pass is surely small enough
MIN_CHUNK_PAIRS = 256  # fewer would cost more in numpy's per-call overhead than they save


def stage_contacts(ctx: Context, P: Pairs, idx) -> np.ndarray:
    """Close each pad along the axis; it stops at the first material in its band. That point must
    be the candidate's (within contact_tol, along and across the axis)."""
    size = _pairs_per_chunk(ctx, P, idx)
    if size >= len(idx):
        return _contacts(ctx, P, idx)
    return np.concatenate([_contacts(ctx, P, idx[a:a + size]) for a in range(0, len(idx), size)])


def _pairs_per_chunk(ctx: Context, P: Pairs, idx) -> int:
    """How many pairs the contacts stage takes at once: all of them unless their bands would
    overlap more than CONTACT_PIECES_PER_CHUNK edges' boxes, estimated from about 256 bands."""
    k, n_edges = len(idx), len(ctx.edge_ax)
    if 2 * k * n_edges <= CHUNK_ESTIMATE_ABOVE:
        return k
    some = idx[::max(1, k // 128)]
    m = P.m.take(some, 0)
    bands = _pad_bands(ctx, P.u.take(some, 0), P.t.take(some), m[:, 0], m[:, 1], ctx.params.contact_tol_mm)
    per_band = edge_box_overlaps(ctx, *axis_rect_bounds(*bands)).sum(1).mean()
    return max(MIN_CHUNK_PAIRS, int(CONTACT_PIECES_PER_CHUNK / (2 * max(float(per_band), 1.0))))


def _pad_bands(ctx: Context, u: np.ndarray, t: np.ndarray, cx: np.ndarray, cy: np.ndarray, beside_mm: float):
    """The 2k bands the pads of k pairs (axis u (k, 2), half distance t (k,)) close through: p_i's pad
    (closing along -u from the +u side), then p_j's; each from 2 x contact_tol inside the candidate
    to the approach opening's outer face, the pad's half width plus beside_mm across, centred on
    the line through (cx, cy) (k,) along u. Returns cx, cy, ux, uy, t_min, t_max, half_width, as
    BandEdges.clip and axis_rect_bounds take them."""
    g = ctx.cell.gripper
    tt = np.concatenate([t, t])
    return (np.concatenate([cx, cx]), np.concatenate([cy, cy]), np.concatenate([u[:, 0], -u[:, 0]]),
            np.concatenate([u[:, 1], -u[:, 1]]), tt - 2 * ctx.params.contact_tol_mm,
            tt + g.approach_clearance_mm + g.pad_thickness_mm, g.pad_width_mm / 2 + beside_mm)


def _contacts(ctx: Context, P: Pairs, idx) -> np.ndarray:
    k = len(idx)
    if k == 0:
        return np.zeros(0, bool)
    g, tol = ctx.cell.gripper, ctx.params.contact_tol_mm
    m, u, t = P.m.take(idx, 0), P.u.take(idx, 0), P.t.take(idx)
    # (material exactly on the band's side, tol beside the pad, is outside it whatever the float noise:
    # an edge running along that side (an L's inner corner) must not count at one pose and not another)
    cx, cy, ux, uy, t_min, t_max, half_width = _pad_bands(ctx, u, t, m[:, 0], m[:, 1], tol - EPS_MM)
    tt = np.concatenate([t, t])
    slanted = bool(ctx.params.slanted_faces)
    band = BandEdges.clip(ctx, cx, cy, ux, uy, t_min, t_max, half_width)
    T, (x, y, touch_width) = band.first_touch(ctx, slanted, width_within=g.pad_width_mm / 2)
    vx, vy = band.vx, band.vy
    dx, dy = x - cx, y - cy  # the touches from the bands' centres, and across them (kept for _onto_material)
    l_touch = dx * vx + dy * vy
    lateral = np.abs(l_touch)
    # the pad stops at the candidate: the first touch is within tol of it along and across the
    # axis. A face slightly slanted to the pad (a tapered web) is first touched at the band's
    # side and the middle of the touching stretch lies mm from the candidate; when the
    # candidate itself is within PAD_COMPLIANCE_MM of the first touch the pad presses on it
    # too: the contact is then on the first-touch line, on the pair's closing line when the
    # pad presses there as well, else across from the candidate
    finite = np.isfinite(lateral)
    stops = T <= tt + tol + EPS_MM  # the pad stops within tol of the candidate along the axis
    pressed = finite & (lateral > tol + EPS_MM) & stops if slanted else None
    ahead = None  # (2k,) how far the band's first touch lies in front of the line each touch is on
    if pressed is not None and pressed.any():
        q = np.flatnonzero(pressed)
        nq = len(q)
        pi, pj = P.pi.take(idx, 0), P.pj.take(idx, 0)  # p_i is on the +u side (its normal is near u)
        ax, ay = np.concatenate([pi[:, 0], pj[:, 0]]) - cx, np.concatenate([pi[:, 1], pj[:, 1]]) - cy
        # the pad itself (not the band widened by tol), and a thin band on the pair's closing line,
        # in one pass (the thin band's verdict is used only where the pad presses on the candidate)
        Tn, _ = band.narrowed(q, (g.pad_width_mm / 2, CLOSING_LINE_BAND_MM)).first_touch(ctx, touch=False)
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
        ahead = np.zeros(2 * k)
        ahead[q] = np.where(press, T.take(q) - Tp, 0.0)  # pressed: on the pad's own first-touch line
        dx, dy = x - cx, y - cy
        l_touch = dx * vx + dy * vy
        lateral = np.abs(l_touch)
        finite = np.isfinite(lateral)
    ok2 = finite & stops & (lateral <= tol + EPS_MM)
    ok = ok2[:k] & ok2[k:]
    if ctx.params.min_touch_width_mm > 0:  # both pads on a point each (two corners): the part pivots
        # where the band's first touch lies beside the pad (in the tol strip: nothing under the pad within the
        # compliance of it) or the pad presses a slanted face, the pad's own first touch says what it rests on
        again = np.isnan(touch_width) if pressed is None else np.isnan(touch_width) | pressed
        again = np.flatnonzero(again & np.concatenate([ok, ok]))
        if len(again):
            _, (_, _, on_pad) = band.narrowed(again, (g.pad_width_mm / 2,)).first_touch(ctx, slanted)
            touch_width[again] = on_pad
        narrow = touch_width < ctx.params.min_touch_width_mm
        pivots = ok & narrow[:k] & narrow[k:]
        if pivots.any():
            P.pivot_refused += int(pivots.sum())  # for the message when no pair is left
            ok &= ~pivots
    if ctx.params.contacts_on_material:  # report where the pads touch the part, not the pad line in front of it
        x, y = _onto_material(band, ok, x, y, (dx, dy, l_touch), cx, cy, ux, uy, vx, vy)
    xi, yi, xj, yj = x[:k], y[:k], x[k:], y[k:]
    h = 0.5 * ((xi - xj) * u[:, 0] + (yi - yj) * u[:, 1])
    gap = 2 * h
    ok &= (gap >= g.opening_mm[0] - EPS_MM) & (gap + 2 * g.approach_clearance_mm <= g.opening_mm[1] + EPS_MM)
    if ctx.params.max_contact_skew_deg < 90:  # the contacts' line along the axis (params.py)
        across = np.abs((xi - xj) * -u[:, 1] + (yi - yj) * u[:, 0])
        ok &= across <= math.tan(math.radians(ctx.params.max_contact_skew_deg)) * np.abs(gap) + EPS_MM
    mid_x, mid_y = 0.5 * (xi + xj), 0.5 * (yi + yj)  # the grasp centre
    if ctx.params.contacts_on_material and ctx.params.pads_at_grasp_centre:  # the pads move with the centre
        ahead_pair = None if ahead is None else np.maximum(ahead[:k], ahead[k:])
        ok &= _pads_stop_at_contacts(ctx, P, idx, m, u, ok, ahead_pair, (xi, yi, xj, yj), mid_x, mid_y)
    if ctx.params.stroke_at_pad_lines:
        fits = _pads_clear_in_stroke(ctx, P, idx, ok, gap, mid_x, mid_y)
        if fits is not None:
            P.stroke_refused += int((ok & ~fits).sum())  # for the message when no pair is left
            ok &= fits
    # written column by column: numpy's row assignment into (s, 2) arrays costs several times more
    for col, vi, vj, mid in ((0, xi, xj, mid_x), (1, yi, yj, mid_y)):
        P.ci[:, col][idx], P.cj[:, col][idx], P.center[:, col][idx] = vi, vj, mid
    P.h[idx] = h
    return ok


def _onto_material(band: BandEdges, ok: np.ndarray, x, y, d, cx, cy, ux, uy, vx, vy):
    """The touches (x, y) (2k,) of the pairs `ok` (k,) moved onto the material the pads touch
    (`BandEdges.on_material`); the other bands' as they are. d: the touches from the bands' centres
    (x - cx, y - cy) and their l. Every band when every pair is ok (the cascade's usual case: no
    gathering)."""
    dx, dy, l = d
    if ok.all():
        sx, sy = band.on_material(None, dx * ux + dy * uy, l)
        found = np.isfinite(sx)
        return np.where(found, sx, x), np.where(found, sy, y)
    rows = np.flatnonzero(np.concatenate([ok, ok]))
    if len(rows):
        dx, dy = dx.take(rows), dy.take(rows)
        sx, sy = band.on_material(rows, dx * ux.take(rows) + dy * uy.take(rows), l.take(rows))
        found = np.isfinite(sx)
        x[rows], y[rows] = np.where(found, sx, x.take(rows)), np.where(found, sy, y.take(rows))
    return x, y


def _pads_clear_in_stroke(ctx: Context, P: Pairs, idx, ok: np.ndarray, gap: np.ndarray, cx, cy) -> np.ndarray | None:
    """(k,) for the pairs `ok` among idx (k,), contacts `gap` (k,) apart: does the gap between the
    lines where the pads stop, plus the approach clearance on both sides, fit the stroke? The
    reported contacts can lie up to the pad's compliance behind those lines (a slanted face, a
    notch, a face the pad presses on at its side): a part wider than the stroke must not fit
    because its contacts do. The pads are centred on the line through the contacts' midpoint (cx,
    cy), as the gripper and the physical check have them. Only pairs whose contacts are within
    2 x (contact_tol + compliance) of the limit are looked at: elsewhere the contacts stage has
    found no material that far in front of the contacts in the (wider) band around them. None: no
    pair is that near (all fit)."""
    g, tol, k = ctx.cell.gripper, ctx.params.contact_tol_mm, len(idx)
    limit = g.opening_mm[1] + EPS_MM - 2 * g.approach_clearance_mm
    near = np.flatnonzero(ok & (gap > limit - 2 * (tol + PAD_COMPLIANCE_MM)))
    if not len(near):
        return None
    _, _, _, Tp = _pads_on_centre_line(ctx, P, np.asarray(idx).take(near), cx.take(near), cy.take(near))
    fits = np.ones(k, bool)
    fits[near] = Tp[:len(near)] + Tp[len(near):] <= limit
    return fits


def _pads_on_centre_line(ctx: Context, P: Pairs, rows, cx, cy):
    """The pads (no tol beside them) of the pairs `rows` (r,) centred on the line along u through the
    grasp centres (cx, cy), as the gripper and the physical check have them: the band centres bx, by
    (r,) on that line level with the pair midpoints (t along u is the same from them as from m), u
    (r, 2) and each pad's first touch T (2r,: p_i's pads, then p_j's; along u, then along -u)."""
    u, t, m = P.u.take(rows, 0), P.t.take(rows), P.m.take(rows, 0)
    off = (cx - m[:, 0]) * -u[:, 1] + (cy - m[:, 1]) * u[:, 0]
    bx, by = m[:, 0] - u[:, 1] * off, m[:, 1] + u[:, 0] * off
    T, _ = BandEdges.clip(ctx, *_pad_bands(ctx, u, t, bx, by, 0.0)).first_touch(ctx, touch=False)
    return bx, by, u, T


def _pads_stop_at_contacts(ctx: Context, P: Pairs, idx, m, u, ok: np.ndarray, ahead, contacts, cx, cy) -> np.ndarray:
    """(k,): do the pads of the pairs idx (midpoints m, axes u, each (k, 2), as the contacts stage took them),
    centred on the line through the contacts' midpoint (cx, cy) (k,), stop at the
    contacts (within the pad's compliance)? Contacts moved onto the material (or pressed at a pad's
    side) can move that midpoint across the axis by up to the band's half width, away from the line
    the bands were found on; the pads there can meet other material first (a star's slanted arm 4.9 mm
    in front of both contacts, the jaws stopping 10 mm wider than the opening). Only pairs that may fail
    are looked at: a pad moved |off| <= contact_tol lies inside the contacts stage's band (the pad
    widened by contact_tol each side), so it first touches no further out than that band did, and each
    contact lies at most the compliance behind the line its touch was put on (BandEdges.on_material),
    which is that band's first touch or, pressed on a slanted face, `ahead` (k,: the larger of the two
    pads') behind it; so a pair with ahead 0 passes (with `touch_within_compliance` off, the pads may stop
    up to |off| tan(max_normal_angle) further out: a pair with ahead <= that passes). The centre moves off
    its line only where contacts move across the axis; almost every pair is not looked at."""
    xi, yi, xj, yj = contacts
    off = np.abs((cx - m[:, 0]) * -u[:, 1] + (cy - m[:, 1]) * u[:, 0])
    slant = 0.0 if ctx.params.touch_within_compliance else math.tan(math.radians(ctx.params.max_normal_angle_deg))
    look = off > ctx.params.contact_tol_mm - EPS_MM
    if ahead is not None:
        look |= (off > CENTRE_SHIFT_MM) & (ahead > off * slant)
    moved = np.flatnonzero(ok & look)
    fits = np.ones(len(ok), bool)
    if not len(moved):
        return fits
    bx, by, uu, T = _pads_on_centre_line(ctx, P, np.asarray(idx).take(moved), cx.take(moved), cy.take(moved))
    ti = (xi.take(moved) - bx) * uu[:, 0] + (yi.take(moved) - by) * uu[:, 1]
    tj = (bx - xj.take(moved)) * uu[:, 0] + (by - yj.take(moved)) * uu[:, 1]
    # the face under a contact slants by up to max_normal_angle to the pad: moved |off| across, the pad
    # meets it up to |off| tan(that) further out; more is other material (an arm, a rim)
    reach = PAD_COMPLIANCE_MM + off.take(moved) * slant
    n = len(moved)
    fits[moved] = (np.isfinite(T[:n]) & np.isfinite(T[n:]) & (T[:n] <= ti + reach + EPS_MM)
                   & (T[n:] <= tj + reach + EPS_MM))
    return fits


def stage_ik(ctx: Context, P: Pairs, idx) -> np.ndarray:
    idx = np.asarray(idx, int)
    c = P.center.take(idx, 0)
    x, y = c[:, 0], c[:, 1]
    P.ik = (ctx.grasp_z_mm, ctx.cell.scara)  # the solutions, for the pairs that get looked at: joints_of
    if ctx.ik_box is not None:  # every point of this box is reachable (Context.build): the usual case
        x0, y0, x1, y1 = ctx.ik_box
        sure = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        if sure.all():
            return sure
    u = P.u.take(idx, 0)
    ws = ctx.cell.workspace
    axis = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    inside = (np.isfinite(x) & (x >= ws.x_mm[0]) & (x <= ws.x_mm[1]) & (y >= ws.y_mm[0]) & (y <= ws.y_mm[1]))
    if inside.all():  # no subset to gather
        return reachable_mask(x, y, ctx.grasp_z_mm, axis, ctx.cell.scara)
    ok = np.zeros(len(idx), bool)
    ok[inside] = reachable_mask(x[inside], y[inside], ctx.grasp_z_mm, axis[inside], ctx.cell.scara)
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


class CascadeResult:
    """survivors: pair indices that passed every stage; kept: stage -> number of pairs it kept;
    exact_checks: pair evaluations in the exact stages; time_ms: stage -> wall time; rejected_by (s,):
    index into STAGES of the stage that rejected each pair, -1 if kept (worked out when first read,
    from each stage's verdicts: only `cell grasp --explain` looks at it)."""

    def __init__(self, n_pairs: int, survivors: np.ndarray, verdicts: list, kept: dict, exact_checks: int,
                 time_ms: dict):
        self.survivors, self.kept, self.exact_checks, self.time_ms = survivors, kept, exact_checks, time_ms
        self._n, self._verdicts, self._rejected_by = n_pairs, verdicts, None

    @property
    def rejected_by(self) -> np.ndarray:
        if self._rejected_by is None:
            rb = np.full(self._n, -1)
            for stage, pairs, ok in reversed(self._verdicts):  # the first stage that rejects a pair wins
                rb[pairs.compress(~ok)] = stage
            self._rejected_by = rb
        return self._rejected_by


# The cheap stages that look at every pair when most are alive (`_dense`): while only they have run and
# most pairs are left, the cascade keeps the survivors as a mask and asks them about every pair (the
# same verdicts; compressing 10^4 indices costs ~13 us, a stage's pick of its survivors' verdicts ~4 us)
MASKED_STAGES = ("stroke", "reach", "antipodal")


def run_cascade(ctx: Context, P: Pairs, stages=STAGES) -> CascadeResult:
    import time

    every = np.arange(len(P))
    alive, mask, n_alive = every, np.ones(len(P), bool), len(P)  # mask: None once alive holds the survivors
    verdicts, kept, times, exact = [], {}, {}, 0
    with np.errstate(divide="ignore", invalid="ignore"):  # once here (the module's docstring)
        for name in stages:
            t0 = time.perf_counter()
            if mask is not None and (name not in MASKED_STAGES or not 2 * n_alive > len(P)):
                alive, mask = np.flatnonzero(mask), None
            if mask is not None:
                ok = STAGE_FUNCS[name](ctx, P, every)
                if not ok.all():
                    verdicts.append((STAGES.index(name), every, ok))
                    mask &= ok
                    n_alive = int(np.count_nonzero(mask))
            else:
                if name in EXACT_STAGES:
                    exact += len(alive)
                ok = STAGE_FUNCS[name](ctx, P, alive) if len(alive) else np.zeros(0, bool)
                if not ok.all():
                    verdicts.append((STAGES.index(name), alive, ok))
                    alive = alive.compress(ok)
                n_alive = len(alive)
            kept[name] = n_alive
            times[name] = (time.perf_counter() - t0) * 1e3
    if mask is not None:
        alive = np.flatnonzero(mask)
    return CascadeResult(len(P), alive, verdicts, kept, exact, times)


def run_brute_force(ctx: Context, P: Pairs) -> CascadeResult:
    """Every pair through every stage (the exact ones included), for the benchmark: the
    feasible pairs are those no stage rejects."""
    import time

    every = np.arange(len(P))
    ok = np.ones(len(P), bool)
    verdicts, times, exact = [], {}, 0
    with np.errstate(divide="ignore", invalid="ignore"):
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
            verdicts.append((STAGES.index(name), every, r))
            ok &= r
            times[name] = (time.perf_counter() - t0) * 1e3
    return CascadeResult(len(P), np.flatnonzero(ok), verdicts, {"feasible": int(ok.sum())}, exact, times)


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
