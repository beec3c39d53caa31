"""Where pads closing along an axis meet the target: its edges clipped to the pads' bands.

One vectorised Liang-Barsky pass over the (band, edge) pairs whose bounding boxes overlap gives
the pieces of the target's outline inside each band; the first touch and the touching point
follow from them (used by the cascade's exact `contacts` stage). nan and inf are ordinary values:
call under the cascade's np.errstate (cascade.py).

The cascade sends a few hundred bands through here, where a numpy call costs about a microsecond
whatever its size: the bands' x and y components are stacked (one call does both), and so are a
piece's quantities. The arithmetic per element is the one written out component by component
(sums of two terms as np.add of two rows, not .sum(0), which turns -0.0 + -0.0 into +0.0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from cell.grasp.pairs import Context

PAD_COMPLIANCE_MM = 0.5  # material this close to the first-touch line touches the pad too
# a broadcast comparison of bounding boxes beats the STRtree's query for targets with up to this many
# edges (measured: 2x faster for 4-72 edges at any number of bands), or up to this many (band, edge) pairs
OVERLAP_BROADCAST_EDGES = 100
OVERLAP_BROADCAST_MAX = 20000
LB_STACKED_MAX = 5000  # segments up to which clipping to the four boundaries at once is faster
_NEG_POS = np.array([-1.0, 1.0])[:, None]  # the Liang-Barsky boundaries' p: -d and d (exact negation)


def band_frame(cx, cy, ux, uy) -> np.ndarray:
    """(2, 3, b): x then y of each band's centre, u (along the band, unit) and v (u turned +90 degrees)."""
    frame = np.empty((2, 3, len(cx)))
    frame[0, 0], frame[1, 0], frame[0, 1], frame[1, 1], frame[1, 2] = cx, cy, ux, uy, ux
    np.negative(uy, out=frame[0, 2])
    return frame


def band_bounds(frame: np.ndarray, t_min, t_max, half_width):
    """Bounding boxes of the bands (frame (2, 3, b), from t_min to t_max along u, half_width across):
    lo, hi, each (2, b) (x then y), bit for bit the extremes of `axis_rects`' corners."""
    c, u, v = frame[:, 0], frame[:, 1], frame[:, 2]
    a0, a1 = c + u * t_min, c + u * t_max
    w = np.abs(v * half_width)
    return np.minimum(a0, a1) - w, np.maximum(a0, a1) + w


@dataclass
class BandEdges:
    """The target's edges clipped to bands along u (one Liang-Barsky pass): pieces (p,) of edges,
    each the stretch s in [s0, s1] of edge A + s * D, in band coordinates (t along u from the
    band's centre, l across). Narrower bands with the same t range reuse the pieces (`narrowed`)."""

    frame: np.ndarray  # (2, 3, b): `band_frame`
    t_max: np.ndarray  # (b,)
    half_width: float | np.ndarray  # one for all bands, or (b,)
    bi: np.ndarray  # (p,) band of each piece
    piece: np.ndarray  # (3, 2, p): [s0, s1], [tA, lA] (the edge's start), [dt, dl] (its change along the edge)
    one_each: bool = False  # piece b is band b's only piece (the usual case on straight faces): no scatter

    cx = property(lambda self: self.frame[0, 0])
    cy = property(lambda self: self.frame[1, 0])
    ux = property(lambda self: self.frame[0, 1])
    uy = property(lambda self: self.frame[1, 1])
    vx = property(lambda self: self.frame[0, 2])
    vy = property(lambda self: self.frame[1, 2])
    s0 = property(lambda self: self.piece[0, 0])
    s1 = property(lambda self: self.piece[0, 1])
    tA = property(lambda self: self.piece[1, 0])
    lA = property(lambda self: self.piece[1, 1])
    dt = property(lambda self: self.piece[2, 0])
    dl = property(lambda self: self.piece[2, 1])

    @classmethod
    def clip(cls, ctx: Context, cx, cy, ux, uy, t_min, t_max, half_width: float) -> BandEdges:
        """`clip_frame` for bands given by component."""
        return cls.clip_frame(ctx, band_frame(cx, cy, ux, uy), t_min, t_max, half_width)

    @classmethod
    def clip_frame(cls, ctx: Context, frame: np.ndarray, t_min, t_max, half_width: float) -> BandEdges:
        """Where pads closing along -u towards the centres meet the target. Each band (b,) is the
        rectangle from t_min to t_max along u from its centre, half_width across (t_min just
        inside the candidate point: material further in cannot be the first touch when the
        candidate itself is in the band). The target's material in it is bounded by the target's
        edges clipped to the band (Liang-Barsky over the (band, edge) pairs whose bounding boxes
        overlap) and, when the band's far corners lie inside the target, by its far side
        (`first_touch`)."""
        b = frame.shape[2]
        bi, ei = _overlapping_edges(ctx, *band_bounds(frame, t_min, t_max, half_width))  # the clip below is exact
        g = frame.take(bi, axis=2)  # (2, 3, p): each piece's band
        e = ctx.edge_ad.take(ei, axis=2)  # (2, 2, p): each piece's edge, start and direction
        e[:, 0] -= g[:, 0]  # the start from the band's centre
        piece = np.empty((3, 2, len(bi)))  # rows 1 and 2: [tA, lA], [dt, dl], the x terms plus the y terms
        np.multiply(e[0, :, None], g[0, None, 1:], out=piece[1:])
        piece[1:] += e[1, :, None] * g[1, None, 1:]
        limits = np.concatenate([t_min, t_max]).reshape(2, b).take(bi, axis=1)
        inside = _liang_barsky_stacked(piece, limits, half_width)
        if inside.all():
            return cls(frame, t_max, half_width, bi, piece, _is_range(bi, b))
        k = np.flatnonzero(inside)
        bi = bi.take(k)
        return cls(frame, t_max, half_width, bi, piece.take(k, axis=2), _is_range(bi, b))

    def narrowed(self, rows: np.ndarray, half_widths: Sequence[float]) -> BandEdges:
        """The bands `rows` only, for each of half_widths (each <= this one's) across: the pieces
        clipped again. Bands (len(half_widths) * len(rows),): `rows` at the first width, then at the next."""
        if max(half_widths) > np.min(self.half_width):
            raise ValueError(f"a band {max(half_widths)} mm wide cannot be cut from one {np.min(self.half_width)} mm "
                             "wide")
        keep, bi = self._pieces_of(rows)
        n, nr = len(half_widths), len(rows)
        bi = np.concatenate([bi + w * nr for w in range(n)])
        piece = np.concatenate([self.piece.take(keep, axis=2)] * n, axis=2)
        s0, s1, lA, dl = piece[0, 0], piece[0, 1], piece[1, 1], piece[2, 1]
        hw = np.repeat(np.asarray(half_widths, float), len(keep))
        inside = np.ones(len(bi), bool)
        for p, q in ((-dl, lA + hw), (dl, hw - lA)):
            r = q / p
            s0[:] = np.where(p < 0, np.maximum(s0, r), s0)
            s1[:] = np.where(p > 0, np.minimum(s1, r), s1)
            inside &= ~((p == 0) & (q < 0))
        inside &= s0 <= s1
        k = np.flatnonzero(inside)
        rr = np.concatenate([rows] * n)
        return BandEdges(self.frame.take(rr, axis=2), self.t_max.take(rr), np.repeat(np.asarray(half_widths, float), nr),
                         bi.take(k), piece.take(k, axis=2))

    def _pieces_of(self, rows: np.ndarray):
        """The pieces of the bands `rows`: their indices (k,) and each one's position in `rows`."""
        pos = np.full(self.frame.shape[2], -1)
        pos[rows] = np.arange(len(rows))
        keep = np.flatnonzero(pos.take(self.bi) >= 0)
        return keep, pos.take(self.bi.take(keep))

    def first_touch(self, ctx: Context, slanted: bool = False, touch: bool = True):
        """T (b,): the largest distance along u of the target's material in each band (-inf: none), and
        (touch=True) the touching point (2, b) (x, y) on the first-touch line, in the middle
        (across the axis) of the material within PAD_COMPLIANCE_MM of it (nan: no material)."""
        if len(self.bi):
            ends = self.tA + self.piece[0] * self.dt  # (2, p): t at s0 and s1
            T = self._per_band(np.maximum(ends[0], ends[1]), -np.inf, np.maximum.at)  # the piece's end further out
        else:
            T = np.full(self.frame.shape[2], -np.inf)
        far_in = self._far_corners_inside(ctx)
        if far_in is not None:  # the target's far side: material fills the band up to t_max there
            T = np.where(far_in, np.maximum(T, self.t_max), T)
        if not touch:
            return T, None
        return T, self._touch(T, slanted)

    def _per_band(self, values: np.ndarray, empty: float, at) -> np.ndarray:
        """(b,): the pieces' values reduced per band by the ufunc.at `at` (`empty` where a band has none)."""
        if self.one_each:
            return values
        out = np.full(self.frame.shape[2], empty)
        at(out, self.bi, values)
        return out

    def _far_corners_inside(self, ctx: Context) -> np.ndarray | None:
        """(b,) is either far corner of each band inside the target? None: neither is, for any band.
        Corners outside the target's convex hull (`Context.surely_outside`) are not asked of shapely
        (its containment test costs 40-70 ns a point; the hull's half-planes, a few numpy calls)."""
        b = self.frame.shape[2]
        far = self.frame[:, 0] + self.frame[:, 1] * self.t_max
        w = self.frame[:, 2] * self.half_width
        corners = np.concatenate([far - w, far + w], axis=1)  # (2, 2b)
        maybe = ~ctx.surely_outside(corners)
        if not maybe.any():
            return None
        inside = np.zeros(2 * b, bool)
        r = np.flatnonzero(maybe)
        inside[r] = shapely.contains_xy(ctx.target_geom, corners[0].take(r), corners[1].take(r))
        return inside[:b] | inside[b:]

    def _touch(self, T: np.ndarray, slanted: bool) -> np.ndarray:
        # the touching material: the parts of the clipped edges within PAD_COMPLIANCE_MM of the first
        # touch (on a face slightly slanted to the pad that is a stretch from the band's side
        # inwards, not only the edge's end); the contact is the middle of its extent across the
        # axis, at the first-touch line (robust to edges that run along the band's side)
        b = self.frame.shape[2]
        if not len(self.bi):
            return np.full((2, b), np.nan)
        pb, p0, p1, pA, pdt = self.bi, self.s0, self.s1, self.tA, self.dt
        limit = (T if self.one_each else T.take(pb)) - PAD_COMPLIANCE_MM
        if slanted:
            lo_s, hi_s, near = _behind_limit(limit, pA, pdt, p0, p1)
        else:  # as before `slanted_faces`: only the clipped edges' ends within PAD_COMPLIANCE_MM
            e0, e1 = pA + p0 * pdt >= limit, pA + p1 * pdt >= limit
            lo_s, hi_s = np.where(e0, p0, p1), np.where(e1, p1, p0)
            near = e0 | e1
        lA, dl = self.lA, self.dl
        lat = lA + np.concatenate([lo_s, hi_s]).reshape(2, -1) * dl  # across the axis, at both ends of the stretch
        lat_lo, lat_hi = np.minimum(lat[0], lat[1]), np.maximum(lat[0], lat[1])
        if self.one_each and near.all():  # (one piece per band, at its end: the usual case, no gathering)
            lo_l, hi_l = lat_lo, lat_hi
        else:
            k = np.flatnonzero(near)
            lo_l, hi_l = np.full(b, np.inf), np.full(b, -np.inf)
            np.minimum.at(lo_l, pb.take(k), lat_lo.take(k))
            np.maximum.at(hi_l, pb.take(k), lat_hi.take(k))
        has = lo_l < np.inf  # the bands with touching material (the lateral extremes are finite)
        mid = 0.5 * (lo_l + hi_l)
        c, u, v = self.frame[:, 0], self.frame[:, 1], self.frame[:, 2]
        return np.where(has, c + u * T + v * mid, np.nan)

    def on_material(self, rows: np.ndarray | None, tl: np.ndarray) -> np.ndarray:
        """For the bands `rows` (r,; None: every band) and a point tl (2, r) (t, l) on each one's pad line
        (band coordinates): the nearest point (2, r) (x, y) of the material the pad touches there, that
        is of the clipped edges no more than PAD_COMPLIANCE_MM behind t (nan: none). The pad line's point
        is where the pad stops; this one is where it touches the part (on a slanted face or across a
        notch the pad line runs up to PAD_COMPLIANCE_MM in front of the outline)."""
        if rows is None:  # every band: its pieces as they are
            r, nb, piece, one_each = self.frame.shape[2], self.bi, self.piece, self.one_each
            frame = self.frame
        else:
            k, nb = self._pieces_of(rows)
            r, piece, one_each = len(rows), self.piece.take(k, axis=2), False
            frame = self.frame.take(rows, axis=2)
        s0, s1, A, D = piece[0, 0], piece[0, 1], piece[1], piece[2]
        tl_p = tl if one_each else tl.take(nb, axis=1)  # (2, p): the pad line's point, per piece
        lo, hi, touching = _behind_limit(tl_p[0] - PAD_COMPLIANCE_MM, A[0], D[0], s0, s1)
        sq = D * D
        den = sq[0] + sq[1]
        rel = (tl_p - A) * D
        s = np.minimum(np.maximum(np.where(den > 0, (rel[0] + rel[1]) / den, lo), lo), hi)  # np.clip
        near = A + s * D  # (2, p): [t, l] of the nearest point of each piece
        off = (near - tl_p) ** 2
        d2 = np.where(touching, off[0] + off[1], np.inf)
        if one_each:  # one piece per band: it is the nearest
            best = np.where(np.isfinite(d2), near, np.nan)
        else:
            least = np.full(r, np.inf)
            np.minimum.at(least, nb, d2)
            pick = np.flatnonzero(np.isfinite(d2) & (d2 <= least.take(nb)))  # ties: the last one written wins
            best = np.full((2, r), np.nan)
            for row in (0, 1):  # row by row: with ties the last one written wins, as numpy writes 1-d indices
                best[row, nb.take(pick)] = near[row].take(pick)
        return frame[:, 0] + frame[:, 1] * best[0] + frame[:, 2] * best[1]


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


def edge_box_overlaps(ctx: Context, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(b, E): does band b's bounding box (lo, hi, each (2, b)) overlap (or touch) the box of the
    target's edge e? (A transposed view: worked out edge by edge, numpy's loops run along the bands,
    far faster than along a few edges.)"""
    hit = (lo[:, None] <= ctx.edge_hi[:, :, None]) & (hi[:, None] >= ctx.edge_lo[:, :, None])  # (2, E, b)
    return (hit[0] & hit[1]).T


def _overlapping_edges(ctx: Context, lo: np.ndarray, hi: np.ndarray):
    """(band, edge) index pairs whose bounding boxes overlap (touching counts, as for the STRtree):
    a broadcast comparison for few edges or bands, else the STRtree (same pairs, other order)."""
    n_edges = ctx.edge_ad.shape[2]
    if n_edges <= OVERLAP_BROADCAST_EDGES or lo.shape[1] * n_edges <= OVERLAP_BROADCAST_MAX:
        return np.nonzero(edge_box_overlaps(ctx, lo, hi))
    return ctx.edge_tree.query(shapely.box(lo[0], lo[1], hi[0], hi[1]))


def _liang_barsky_stacked(piece: np.ndarray, limits: np.ndarray, half_width: float) -> np.ndarray:
    """Clip the pieces' segments (piece (3, 2, p): [tA, lA] and [dt, dl] in rows 1 and 2) to
    limits[0] <= t <= limits[1] (limits (2, p)), |l| <= half_width: s0, s1 written into row 0; returns
    inside (p,). The boundaries in `_liang_barsky`'s order: the same values."""
    tA, lA = piece[1, 0], piece[1, 1]
    if piece.shape[2] > LB_STACKED_MAX:  # many: boundary by boundary, as _liang_barsky has them
        s0, s1, inside = _liang_barsky(tA, piece[2, 0], lA, piece[2, 1], limits[0], limits[1], half_width)
    else:  # the four boundaries' p and q as (4, p) rows built in place (fewer numpy calls)
        p_ = piece[2][:, None] * _NEG_POS  # (2, 2, p): -dt, dt, -dl, dl
        q_ = np.empty_like(p_)
        np.subtract(tA, limits[0], out=q_[0, 0])
        np.subtract(limits[1], tA, out=q_[0, 1])
        np.add(lA, half_width, out=q_[1, 0])
        np.subtract(half_width, lA, out=q_[1, 1])
        s0, s1, inside = _liang_barsky_rows(p_.reshape(4, -1), q_.reshape(4, -1))
    piece[0, 0], piece[0, 1] = s0, s1
    return inside


def _liang_barsky(tA, dt, lA, dl, t_min, t_max, half_width):
    """Clip segments (in band coordinates) to t_min <= t <= t_max, |l| <= half_width: s0, s1, inside."""
    bounds = ((-dt, tA - t_min), (dt, t_max - tA), (-dl, lA + half_width), (dl, half_width - lA))
    if len(tA) <= LB_STACKED_MAX:  # (np.stack costs several times a concatenate of the same rows)
        return _liang_barsky_rows(*(np.concatenate([b[c] for b in bounds]).reshape(4, -1) for c in (0, 1)))
    s0, s1 = np.zeros(len(tA)), np.ones(len(tA))
    inside = np.ones(len(tA), bool)
    for p, q in bounds:
        r = q / p
        s0 = np.where(p < 0, np.maximum(s0, r), s0)
        s1 = np.where(p > 0, np.minimum(s1, r), s1)
        inside &= ~((p == 0) & (q < 0))
    return s0, s1, inside & (s0 <= s1)


def _liang_barsky_rows(p: np.ndarray, q: np.ndarray):
    """Liang-Barsky on the four boundaries' p and q (4, n), all at once: s0, s1, inside. The entering
    parameter is the largest of the boundaries' q / p where p < 0 (and 0), the leaving one the smallest
    where p > 0 (and 1); a segment parallel to a boundary (p = 0) outside it (q < 0) is outside."""
    r = q / p
    s0 = np.maximum(np.where(p < 0, r, -np.inf).max(0), 0.0)
    s1 = np.minimum(np.where(p > 0, r, np.inf).min(0), 1.0)
    return s0, s1, ~((p == 0) & (q < 0)).any(0) & (s0 <= s1)
