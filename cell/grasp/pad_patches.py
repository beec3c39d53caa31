"""Where the pads stop and what they touch there, for many grasps at once: the planner's own reading of the
quantities `cell.physics.check_grasp` weighs a grasp with (numpy and exact clipping, no code shared with it).

In each grasp's frame (origin at the contacts' midpoint, x along the closing axis from the first contact to
the second, y across) the pads close along x inside a band as wide as the pad. They stop at the first material
of the part inside the approach opening: its least and greatest x there (`x_left`, `x_right`). Each pad's
patch is the material within PATCH_DEPTH_MM of where it stops; the judge takes its width across the pad and
its middle. The extent of the part's material in an axis-aligned box is attained at a vertex of their
intersection: an edge of the part clipped to the box (Liang-Barsky), or a corner of the box inside the part.
That is exact, so the only differences from the judge's shapely are of float rounding: every quantity is
given as an interval (the box taken EPS_MM smaller and larger), and what the rounding could decide
(material on the band's side, a step just at the patch depth) shows as a wide interval, not a wrong value.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from cell.physics import PATCH_DEPTH_MM
from cell.scene import Part

EPS_MM = 1e-6  # far above the judge's float rounding (1e-12 mm), far below anything that matters to a grasp


@dataclass
class PadPatches:
    """(k,) arrays for k grasps; each value as an interval (lo, hi) where rounding could move it."""

    centre: np.ndarray  # (k, 2) base frame
    u: np.ndarray  # (k, 2) unit closing axis, from the first contact to the second
    x_left: tuple[np.ndarray, np.ndarray]  # where the first pad stops (inf: no material between the pads)
    x_right: tuple[np.ndarray, np.ndarray]  # where the second stops
    width_least: np.ndarray  # (k, 2) each patch's width across the pad, at the least (0: none)
    middle: np.ndarray  # (k, 2, 2) base frame: the point on each pad's face at its patch's middle
    # (k, 2) how far from `middle` the judge's point of the outline nearest its patch's middle lies at most: the
    # middle's distance from the patch's own edges (the nearest of all is no further), and twice its rounding
    reach: np.ndarray


def pad_patches(part: Part, contacts_mm: np.ndarray, axes: np.ndarray, pad_width_mm: float,
                approach_clearance_mm: float) -> PadPatches:
    """Where pads `pad_width_mm` wide, closing along `axes` (k, 2) on the contacts (k, 2, 2) from the
    approach opening (the contacts' distance plus 2 x `approach_clearance_mm`), stop and touch `part`."""
    c = np.asarray(contacts_mm, float).reshape(-1, 2, 2)
    u = np.asarray(axes, float).reshape(-1, 2)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    gap = c[:, 1] - c[:, 0]
    along = np.einsum("ij,ij->i", gap, u)
    u = np.where(along[:, None] < 0, -u, u)  # as the judge turns it: the first contact's pad at -x
    along = np.abs(along)
    centre = 0.5 * (c[:, 0] + c[:, 1])
    v = np.stack([-u[:, 1], u[:, 0]], axis=1)
    # the approach opening: the judge's is the reported contacts' distance, which lies between the distance
    # along the axis (contacts moved onto the closing line) and the contacts' own
    half_w = pad_width_mm / 2
    s_in = along / 2 + approach_clearance_mm - EPS_MM
    s_out = np.linalg.norm(gap, axis=1) / 2 + approach_clearance_mm + EPS_MM
    pieces = _Pieces.clip(part, centre, u, v, s_out, half_w + EPS_MM)  # every box below lies in this one
    lo_in, hi_in, _, _ = pieces.extent(-s_in, s_in, half_w - EPS_MM)
    lo_out, hi_out, _, _ = pieces.extent(-s_out, s_out, half_w + EPS_MM)
    x_left, x_right = (lo_out, lo_in), (hi_in, hi_out)
    width = np.zeros((len(c), 2))
    middle = np.zeros((len(c), 2, 2))
    reach = np.zeros((len(c), 2))
    for k, (face, deeper) in enumerate(((x_left, 1.0), (x_right, -1.0))):
        f0, f1 = face  # the judge's face lies in [f0, f1]; its box runs from it PATCH_DEPTH_MM into the part
        # a box inside the judge's whichever the face, and one holding it (empty, x_lo > x_hi, where rounding
        # could move the face by more than the depth)
        if deeper > 0:
            small, large = (f1 + EPS_MM, f0 + PATCH_DEPTH_MM - EPS_MM), (f0 - EPS_MM, f1 + PATCH_DEPTH_MM + EPS_MM)
        else:
            small, large = (f1 - PATCH_DEPTH_MM + EPS_MM, f0 - EPS_MM), (f0 - PATCH_DEPTH_MM - EPS_MM, f1 + EPS_MM)
        near = pieces.within(*large, half_w + EPS_MM)  # (the few pieces there: the small box lies in the large)
        _, _, ys_lo, ys_hi = near.extent(*small, half_w - EPS_MM)
        _, _, yl_lo, yl_hi = near.extent(*large, half_w + EPS_MM)
        width[:, k] = np.where(ys_hi >= ys_lo, ys_hi - ys_lo, 0.0)
        # the middle lies between these (its ends each between the small box's and the large one's)
        m_lo = 0.5 * (yl_lo + np.where(np.isfinite(ys_hi), ys_hi, yl_lo))
        m_hi = 0.5 * (np.where(np.isfinite(ys_lo), ys_lo, yl_hi) + yl_hi)
        none = ~np.isfinite(ys_lo)  # the judge's patch may be empty: it takes the middle of the pad then
        m_lo, m_hi = np.where(none, np.minimum(m_lo, 0.0), m_lo), np.where(none, np.maximum(m_hi, 0.0), m_hi)
        y_mid, x_mid = 0.5 * (m_lo + m_hi), 0.5 * (f0 + f1)
        middle[:, k] = centre + x_mid[:, None] * u + y_mid[:, None] * v
        slack = 0.5 * (m_hi - m_lo) + 0.5 * (f1 - f0) + EPS_MM
        reach[:, k] = near.distance(x_mid, y_mid) + 2.0 * slack
    return PadPatches(centre, u, x_left, x_right, width, middle, reach)


def _edges(part: Part) -> tuple[np.ndarray, np.ndarray]:
    """The part's edges, holes' included: starts (n, 2) and their vectors to the ends (n, 2)."""
    starts, steps = [], []
    for ring in (part.polygon.exterior, *part.polygon.interiors):
        xy = np.asarray(ring.coords, float)
        starts.append(xy[:-1])
        steps.append(np.diff(xy, axis=0))
    return np.concatenate(starts), np.concatenate(steps)


@dataclass
class _Pieces:
    """The part's edges clipped to one box per grasp (its frame's [-s, s] x [-hw, hw]): piece i is the stretch
    [s0, s1] of the edge starting at (x, y) and running (dx, dy) in grasp `of[i]`'s frame, pieces in grasp order.
    Every smaller box's material is found from them (a box's edges inside a larger box are the larger box's
    pieces clipped again) and its corners inside the part."""

    part: Part
    centre: np.ndarray
    u: np.ndarray
    v: np.ndarray
    of: np.ndarray
    x: np.ndarray
    y: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    s0: np.ndarray
    s1: np.ndarray

    @classmethod
    def clip(cls, part: Part, centre, u, v, s, hw) -> _Pieces:
        starts, steps = _edges(part)
        # across the axis first (matrix products): of a band across the part, few edges reach it
        y0 = starts @ v.T - np.einsum("kj,kj->k", centre, v)[None]  # (n, k)
        y1 = y0 + steps @ v.T
        e, of = np.nonzero((np.minimum(y0, y1) <= hw) & (np.maximum(y0, y1) >= -hw))
        order = np.argsort(of, kind="stable")  # in grasp order
        e, of = e[order], of[order]
        uo = u[of]
        x = np.einsum("ij,ij->i", starts[e] - centre[of], uo)
        dx = np.einsum("ij,ij->i", steps[e], uo)
        y = y0[e, of]
        p = cls(part, centre, u, v, of, x, y, dx, y1[e, of] - y, np.zeros(len(e)), np.ones(len(e)))
        return p.within(-s, s, hw)

    def within(self, x_lo, x_hi, hw) -> _Pieces:
        """These pieces clipped to each grasp's box [x_lo, x_hi] x [-hw, hw] (x_lo, x_hi (k,)), the empty left out."""
        s0, s1 = self._clipped(x_lo[self.of], x_hi[self.of], hw)
        k = np.flatnonzero(s0 <= s1)
        return _Pieces(self.part, self.centre, self.u, self.v, self.of[k], self.x[k], self.y[k], self.dx[k],
                       self.dy[k], s0[k], s1[k])

    def _clipped(self, x_lo, x_hi, hw):
        """Each piece's stretch inside [x_lo, x_hi] x [-hw, hw] (per piece): s0 > s1 where it has none
        (Liang-Barsky)."""
        s0, s1 = self.s0, self.s1
        with np.errstate(divide="ignore", invalid="ignore"):  # (a face at inf: the pads close on nothing)
            for p, q in ((-self.dx, self.x - x_lo), (self.dx, x_hi - self.x), (-self.dy, self.y + hw),
                         (self.dy, hw - self.y)):
                r = q / p
                s0 = np.where(p < 0, np.maximum(s0, r), s0)
                s1 = np.where(p > 0, np.minimum(s1, r), s1)
                s1 = np.where((p == 0) & (q < 0), -np.inf, s1)
        return s0, np.where(x_lo <= x_hi, s1, -np.inf)

    def distance(self, px, py) -> np.ndarray:
        """(k,) the distance from each grasp's point (px, py) (its frame) to its nearest piece (inf: none)."""
        qx, qy = px[self.of] - self.x, py[self.of] - self.y
        ll = self.dx * self.dx + self.dy * self.dy
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.where(ll > 0, (qx * self.dx + qy * self.dy) / ll, self.s0), self.s0, self.s1)
        out = np.full(len(self.centre), np.inf)
        np.minimum.at(out, self.of, np.hypot(qx - t * self.dx, qy - t * self.dy))
        return out

    def extent(self, x_lo, x_hi, hw):
        """(least x, greatest x, least y, greatest y), each (k,), of the part's material in each grasp's box
        [x_lo, x_hi] x [-hw, hw] (x_lo, x_hi (k,)): inf, -inf where there is none."""
        k = len(self.centre)
        p = self.within(x_lo, x_hi, hw)
        ends_x = np.concatenate([p.x + p.s0 * p.dx, p.x + p.s1 * p.dx])
        ends_y = np.concatenate([p.y + p.s0 * p.dy, p.y + p.s1 * p.dy])
        of2 = np.concatenate([p.of, p.of])
        out = [np.full(k, np.inf), np.full(k, -np.inf), np.full(k, np.inf), np.full(k, -np.inf)]
        np.minimum.at(out[0], of2, ends_x)
        np.maximum.at(out[1], of2, ends_x)
        np.minimum.at(out[2], of2, ends_y)
        np.maximum.at(out[3], of2, ends_y)
        # the box's corners inside the part
        cx = np.stack([x_lo, x_lo, x_hi, x_hi], axis=1)
        cy = np.broadcast_to(np.array([-hw, hw, -hw, hw]), cx.shape)
        base = self.centre[:, None] + cx[..., None] * self.u[:, None] + cy[..., None] * self.v[:, None]
        inside = shapely.contains_xy(self.part.polygon, base[..., 0], base[..., 1]) & (x_lo <= x_hi)[:, None]
        out[0] = np.minimum(out[0], np.where(inside, cx, np.inf).min(axis=1))
        out[1] = np.maximum(out[1], np.where(inside, cx, -np.inf).max(axis=1))
        out[2] = np.minimum(out[2], np.where(inside, cy, np.inf).min(axis=1))
        out[3] = np.maximum(out[3], np.where(inside, cy, -np.inf).max(axis=1))
        return tuple(out)
