"""Where pads closing along an axis meet the target: its edges clipped to the pads' bands.

One vectorised Liang-Barsky pass over the (band, edge) pairs whose bounding boxes overlap gives
the pieces of the target's outline inside each band; the first touch and the touching point
follow from them (used by the cascade's exact `contacts` stage). nan and inf are ordinary values:
call under the cascade's np.errstate (cascade.py).

The cascade sends a few hundred bands through here, where each numpy call costs about a
microsecond whatever its size: the usual case (one piece of outline per band, as on a straight
face) skips the per-band scatters, and the far corners outside the target's convex hull are not
asked of shapely.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from cell.grasp.footprints import axis_rect_bounds
from cell.grasp.pairs import Context

PAD_COMPLIANCE_MM = 0.5  # material this close to the first-touch line touches the pad too
# a broadcast comparison of bounding boxes beats the STRtree's query for targets with up to this many
# edges (measured: 2x faster for 4-72 edges at any number of bands), or up to this many (band, edge) pairs
OVERLAP_BROADCAST_EDGES = 100
OVERLAP_BROADCAST_MAX = 20000
LB_STACKED_MAX = 5000  # segments up to which clipping to the four boundaries at once is faster


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
    one_each: bool = False  # piece b is band b's only piece (the usual case on straight faces): no scatter

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
        b = len(cx)
        one_each = _is_range(bi, b)  # one edge's box per band (a straight face): the bands as they are
        c_x, c_y, u_x, u_y, lo, hi = ((cx, cy, ux, uy, t_min, t_max) if one_each else
                                      (a.take(bi) for a in (cx, cy, ux, uy, t_min, t_max)))
        v_x = -u_y
        acx, acy = ctx.edge_ax.take(ei) - c_x, ctx.edge_ay.take(ei) - c_y
        dx, dy = ctx.edge_dx.take(ei), ctx.edge_dy.take(ei)
        tA, lA = acx * u_x + acy * u_y, acx * v_x + acy * u_x
        dt, dl = dx * u_x + dy * u_y, dx * v_x + dy * u_x
        s0, s1, inside = _liang_barsky(tA, dt, lA, dl, lo, hi, half_width)
        if inside.all():  # (no gathering)
            return cls(cx, cy, ux, uy, vx, vy, t_max, half_width, bi, s0, s1, tA, lA, dt, dl, one_each)
        k = np.flatnonzero(inside)
        bi = bi.take(k)
        return cls(cx, cy, ux, uy, vx, vy, t_max, half_width, bi, s0.take(k), s1.take(k), tA.take(k), lA.take(k),
                   dt.take(k), dl.take(k), _is_range(bi, b))

    def narrowed(self, rows: np.ndarray, half_widths: Sequence[float]) -> BandEdges:
        """The bands `rows` only, for each of half_widths (each <= this one's) across: the pieces
        clipped again. Bands (len(half_widths) * len(rows),): `rows` at the first width, then at the next."""
        if max(half_widths) > np.min(self.half_width):
            raise ValueError(f"a band {max(half_widths)} mm wide cannot be cut from one {np.min(self.half_width)} mm "
                             "wide")
        keep, bi = self._pieces_of(rows)
        n, nr = len(half_widths), len(rows)
        bi = np.concatenate([bi + w * nr for w in range(n)])
        tA, lA, dt, dl, s0, s1 = (np.concatenate([a.take(keep)] * n) for a in (self.tA, self.lA, self.dt, self.dl,
                                                                                   self.s0, self.s1))
        hw = np.repeat(np.asarray(half_widths, float), len(keep))
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

    def _pieces_of(self, rows: np.ndarray):
        """The pieces of the bands `rows`: their indices (k,) and each one's position in `rows`."""
        pos = np.full(len(self.cx), -1)
        pos[rows] = np.arange(len(rows))
        keep = np.flatnonzero(pos.take(self.bi) >= 0)
        return keep, pos.take(self.bi.take(keep))

    def _per_band(self, values: np.ndarray, empty: float, at, bands: np.ndarray | None = None) -> np.ndarray:
        """(b,): values (p,) of the pieces (or of those whose bands are `bands`, (p,)) reduced per band by the
        ufunc.at `at` (`empty` where a band has none)."""
        if bands is None and self.one_each:
            return values
        out = np.full(len(self.cx), empty)
        at(out, self.bi if bands is None else bands, values)
        return out

    def first_touch(self, ctx: Context, slanted: bool = False, touch: bool = True, width_within: float = np.inf):
        """T (b,): the largest distance along u of the target's material in each band (-inf: none), and
        (touch=True) the touching point (x, y), each (b,), on the first-touch line, in the middle
        (across the axis) of the material within PAD_COMPLIANCE_MM of it (nan: no material), and the
        width across the axis (b,) of that material within `width_within` of the band's centre line
        (the pad's half width in a band widened beside it; nan: none there)."""
        if len(self.bi):
            tt = np.maximum(self.tA + self.s0 * self.dt, self.tA + self.s1 * self.dt)  # the piece's end further out
            T = self._per_band(tt, -np.inf, np.maximum.at)
        else:
            T = np.full(len(self.cx), -np.inf)
        far_in = self._far_corners_inside(ctx)
        if far_in is not None:  # the target's far side: material fills the band up to t_max there
            T = np.where(far_in, np.maximum(T, self.t_max), T)
        if not touch:
            return T, None
        return T, self._touch(T, slanted, width_within)

    def _far_corners_inside(self, ctx: Context) -> np.ndarray | None:
        """(b,): is either far corner of each band inside the target? None: neither is, for any band.
        A band whose far side's middle lies beyond an edge of the target's convex hull by more than half
        its width has both corners beyond it (`Context.surely_outside`): shapely is not asked (its
        containment test costs 40-70 ns a point, the hull's half-planes a few ns). Usually all of them."""
        b, hw = len(self.cx), self.half_width
        far = np.empty((2, b))
        np.add(self.cx, self.ux * self.t_max, out=far[0])
        np.add(self.cy, self.uy * self.t_max, out=far[1])
        clear = ctx.surely_outside(far, float(np.max(hw)))
        if clear.all():
            return None
        r = np.flatnonzero(~clear)
        fx, fy, vx, vy = far[0].take(r), far[1].take(r), self.vx.take(r), self.vy.take(r)
        w = hw if np.ndim(hw) == 0 else hw.take(r)
        wx, wy = vx * w, vy * w
        inside = shapely.contains_xy(ctx.target_geom, np.concatenate([fx - wx, fx + wx]),
                                     np.concatenate([fy - wy, fy + wy]))
        far_in = np.zeros(b, bool)
        far_in[r] = inside[:len(r)] | inside[len(r):]
        return far_in

    def _touch(self, T: np.ndarray, slanted: bool, width_within: float = np.inf):
        # the touching material: the parts of the clipped edges within PAD_COMPLIANCE_MM of the first
        # touch (on a face slightly slanted to the pad that is a stretch from the band's side
        # inwards, not only the edge's end); the contact is the middle of its extent across the
        # axis, at the first-touch line (robust to edges that run along the band's side)
        b = len(self.cx)
        if not len(self.bi):
            return np.full(b, np.nan), np.full(b, np.nan), np.full(b, np.nan)
        pb, p0, p1, pA, pdt = self.bi, self.s0, self.s1, self.tA, self.dt
        limit = (T if self.one_each else T.take(pb)) - PAD_COMPLIANCE_MM
        if slanted:
            lo_s, hi_s, near = _behind_limit(limit, pA, pdt, p0, p1)
        else:  # as before `slanted_faces`: only the clipped edges' ends within PAD_COMPLIANCE_MM
            e0, e1 = pA + p0 * pdt >= limit, pA + p1 * pdt >= limit
            lo_s, hi_s = np.where(e0, p0, p1), np.where(e1, p1, p0)
            near = e0 | e1
        if near.all():  # (one piece per band, at its end: the usual case, no gathering)
            nb, lA, dl = None, self.lA, self.dl
        else:
            k = np.flatnonzero(near)
            nb, lA, dl, lo_s, hi_s = pb.take(k), self.lA.take(k), self.dl.take(k), lo_s.take(k), hi_s.take(k)
        lat_lo = lA + lo_s * dl  # across the axis, at both ends of the stretch
        lat_hi = lA + hi_s * dl
        lo_p, hi_p = np.minimum(lat_lo, lat_hi), np.maximum(lat_lo, lat_hi)
        lo_l = self._per_band(lo_p, np.inf, np.minimum.at, nb)
        hi_l = self._per_band(hi_p, -np.inf, np.maximum.at, nb)
        has = lo_l < np.inf  # the bands with touching material (the lateral extremes are finite)
        mid = 0.5 * (lo_l + hi_l)
        x = np.where(has, self.cx + self.ux * T + self.vx * mid, np.nan)
        y = np.where(has, self.cy + self.uy * T + self.vy * mid, np.nan)
        if width_within >= float(np.max(self.half_width)):  # the whole band is the pad's
            return x, y, np.where(has, hi_l - lo_l, np.nan)
        # each stretch cut to the pad, as material beside it (a next tooth's flank) touches no pad
        lo_c, hi_c = np.maximum(lo_p, -width_within), np.minimum(hi_p, width_within)
        under = lo_c <= hi_c
        lo_w = self._per_band(np.where(under, lo_c, np.inf), np.inf, np.minimum.at, nb)
        hi_w = self._per_band(np.where(under, hi_c, -np.inf), -np.inf, np.maximum.at, nb)
        return x, y, np.where(lo_w < np.inf, hi_w - lo_w, np.nan)

    def on_material(self, rows: np.ndarray | None, t: np.ndarray, l: np.ndarray):
        """For the bands `rows` (r,; None: every band) and a point (t, l) on each one's pad line (band
        coordinates, (r,)): the nearest point (x, y), each (r,), of the material the pad touches there, that is of the
        clipped edges no more than PAD_COMPLIANCE_MM behind t (nan: none). The pad line's point is where
        the pad stops; this one is where it touches the part (on a slanted face or across a notch the
        pad line runs up to PAD_COMPLIANCE_MM in front of the outline)."""
        one_each = rows is None and self.one_each
        if rows is None:  # every band: its pieces as they are
            r, nb = len(self.cx), self.bi
            tA, dt, lA, dl, s0, s1 = self.tA, self.dt, self.lA, self.dl, self.s0, self.s1
        else:
            r = len(rows)
            k, nb = self._pieces_of(rows)
            tA, dt, lA, dl, s0, s1 = (a.take(k) for a in (self.tA, self.dt, self.lA, self.dl, self.s0, self.s1))
        tr, lr = (t, l) if one_each else (t.take(nb), l.take(nb))
        lo, hi, touching = _behind_limit(tr - PAD_COMPLIANCE_MM, tA, dt, s0, s1)
        den = dt * dt + dl * dl
        s = np.minimum(np.maximum(np.where(den > 0, ((tr - tA) * dt + (lr - lA) * dl) / den, lo), lo), hi)  # np.clip
        et, el = tA + s * dt, lA + s * dl
        d2 = np.where(touching, (et - tr) ** 2 + (el - lr) ** 2, np.inf)
        if one_each:  # each band's one piece is its nearest
            found = np.isfinite(d2)
            bt, bl = np.where(found, et, np.nan), np.where(found, el, np.nan)
        else:
            best = np.full(r, np.inf)
            np.minimum.at(best, nb, d2)
            pick = np.flatnonzero(np.isfinite(d2) & (d2 <= best.take(nb)))  # ties: the last one written wins
            bt, bl = np.full(r, np.nan), np.full(r, np.nan)
            if len(pick) == len(d2):  # every piece (one per band): no gathering
                bt[nb], bl[nb] = et, el
            else:
                bt[nb.take(pick)], bl[nb.take(pick)] = et.take(pick), el.take(pick)
        if rows is None:
            cx, cy, ux, uy, vx, vy = self.cx, self.cy, self.ux, self.uy, self.vx, self.vy
        else:
            cx, cy, ux, uy, vx, vy = (a.take(rows) for a in (self.cx, self.cy, self.ux, self.uy, self.vx, self.vy))
        return cx + ux * bt + vx * bl, cy + uy * bt + vy * bl


def _behind_limit(limit, tA, dt, s0, s1):
    """The stretch [lo, hi] of each piece (edge A + s * D, s in [s0, s1]) that lies at t >= limit
    along the band, and whether there is one: the material a pad on the line limit + compliance touches."""
    sc = (limit - tA) / dt  # where the edge crosses the limit
    lo = np.where(dt > 0, np.maximum(s0, sc), s0)
    hi = np.where(dt < 0, np.minimum(s1, sc), s1)
    return lo, hi, (lo <= hi + 1e-12) & ((dt != 0) | (tA >= limit))


def _is_range(bi: np.ndarray, b: int) -> bool:
    """Is bi (p,) 0, 1, ..., b - 1 (b band indices, strictly increasing): one piece per band?"""
    return len(bi) == b and (b < 2 or bool((bi[1:] > bi[:-1]).all()))


def edge_box_overlaps(ctx: Context, lox, loy, hix, hiy) -> np.ndarray:
    """(b, E): does band b's bounding box overlap (or touch) the box of the target's edge e? (A
    transposed view: worked out edge by edge, numpy's loops run along the bands, far faster than
    along a few edges.)"""
    hit = (lox <= ctx.edge_hix[:, None]) & (hix >= ctx.edge_lox[:, None])
    hit &= (loy <= ctx.edge_hiy[:, None]) & (hiy >= ctx.edge_loy[:, None])
    return hit.T


def _overlapping_edges(ctx: Context, lox, loy, hix, hiy):
    """(band, edge) index pairs whose bounding boxes overlap (touching counts, as for the STRtree):
    a broadcast comparison for few edges or bands, else the STRtree (same pairs, other order)."""
    if len(ctx.edge_ax) <= OVERLAP_BROADCAST_EDGES or len(lox) * len(ctx.edge_ax) <= OVERLAP_BROADCAST_MAX:
        return np.nonzero(edge_box_overlaps(ctx, lox, loy, hix, hiy))
    return ctx.edge_tree.query(shapely.box(lox, loy, hix, hiy))


def _liang_barsky(tA, dt, lA, dl, t_min, t_max, half_width):
    """Clip segments (in band coordinates) to t_min <= t <= t_max, |l| <= half_width: s0, s1, inside.
    The entering parameter is the largest of the boundaries' where p < 0 (and 0), the leaving one the
    smallest where p > 0 (and 1)."""
    bounds = ((-dt, tA - t_min), (dt, t_max - tA), (-dl, lA + half_width), (dl, half_width - lA))
    if len(tA) <= LB_STACKED_MAX:  # few segments: the four boundaries at once, rows of (4, n)
        # (np.stack costs several times a concatenate of the same rows)
        p, q = (np.concatenate([b[c] for b in bounds]).reshape(4, -1) for c in (0, 1))
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
