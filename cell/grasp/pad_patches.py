"""Where the pads stop and what they touch there, for many grasps at once: the planner's own reading of the
quantities `cell.physics.check_grasp` weighs a grasp with (numpy and exact clipping, no code shared with it).

In each grasp's frame (origin at the contacts' midpoint, x along the closing axis from the first contact to
the second, y across) the pads close along x inside a band as wide as the pad. They stop at the first material
of the part inside the approach opening: its least and greatest x there (`x_left`, `x_right`). Each pad's
patch is the material within PATCH_DEPTH_MM of where it stops; the judge takes its width across the pad and
its middle. The extent of the part's material in an axis-aligned box is attained at a vertex of their
intersection: an edge of the part clipped to the box (Liang-Barsky), or a corner of the box inside the part
(which, for the boxes here, only happens where the set is not kept: `pad_patches`). That is exact, so the only
differences from the judge's shapely are of float rounding: every quantity is given as an interval (the box
taken EPS_MM smaller and larger), and what the rounding could decide (material on the band's side, a step just
at the patch depth) shows as a wide interval, not a wrong value.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from cell.physics import PATCH_DEPTH_MM
from cell.scene import Part

EPS_MM = 1e-6  # far above the judge's float rounding (1e-12 mm), far below anything that matters to a grasp
WINDOW_MM = 2 * PATCH_DEPTH_MM  # each pad is looked at up to this far past its contact


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
    n = len(c)
    # Both pads at once, each in a frame of its own where it closes towards +x: the first pad's is the grasp's,
    # the second's the grasp's turned half a turn (its x is minus the grasp's)
    sides_u = np.concatenate([u, -u])
    sides_v = np.stack([-sides_u[:, 1], sides_u[:, 0]], axis=1)
    sides_c = np.concatenate([centre, centre])
    # the approach opening: the judge's is the reported contacts' distance, which lies between the distance
    # along the axis (contacts moved onto the closing line) and the contacts' own
    half_w = pad_width_mm / 2
    s_in = np.tile(along / 2 + approach_clearance_mm - EPS_MM, 2)
    s_out = np.tile(np.linalg.norm(gap, axis=1) / 2 + approach_clearance_mm + EPS_MM, 2)
    # Each pad only from the opening to WINDOW_MM past its contact: where material lies in there, the pad stops
    # in there and its patch is in there too (checked below); the rest of the band (a ring's far side, a hole)
    # is not looked at
    w_lo, w_hi = -s_out, np.tile(-along / 2 + WINDOW_MM, 2)
    pieces = _Pieces.clip(part, sides_c, sides_u, sides_v, w_lo, w_hi, half_w + EPS_MM)
    # Where the pad stops: the least x of the material in the band, which lies on an edge clipped to the box or
    # on a corner of the box inside the part. On the far corners only where nothing in the window is nearer
    # (not known then: the window check below); on the near ones, at the opening, only where the finger lands
    # on the part there, which an edge across the opening or the opening's middle inside the part tells.
    f0, _, _, _ = pieces.extent(w_lo, w_hi, half_w + EPS_MM, clipped=True)
    f1, _, _, _ = pieces.extent(-s_in, np.minimum(w_hi, s_in), half_w - EPS_MM)
    opening = sides_c - s_out[:, None] * sides_u
    lands = (f0 <= w_lo + EPS_MM) | shapely.contains_xy(part.polygon, opening[:, 0], opening[:, 1])
    # (f1, from the edges only, is at least the least x in the narrower band: [f0, f1] holds the judge's face)
    # The judge's face lies in [f0, f1]; its patch box runs from it PATCH_DEPTH_MM into the part. The material of
    # a box from f0 (no material in the band before the judge's face) to f0 + PATCH_DEPTH_MM, in the narrower
    # band, is in the judge's patch whichever the face; a box to f1 + PATCH_DEPTH_MM in the wider band holds
    # the judge's. Their corners at the face are not inside the part (no material nearer in the band), so their
    # material's extent across the pad is their edges'.
    small = (f0 - EPS_MM, f0 + PATCH_DEPTH_MM - EPS_MM)
    large = (f0 - EPS_MM, f1 + PATCH_DEPTH_MM + EPS_MM)
    # (a face further in than the window, or none: not known here, and the set is not kept)
    known = (large[1] <= w_hi) & ~lands
    near = pieces.within(*large, half_w + EPS_MM)  # (the few pieces there: the small box lies in the large)
    _, _, ys_lo, ys_hi = near.extent(*small, half_w - EPS_MM)
    _, _, yl_lo, yl_hi = near.extent(*large, half_w + EPS_MM, clipped=True)
    width = np.where(ys_hi >= ys_lo, ys_hi - ys_lo, 0.0)
    # the middle lies between these (its ends each between the small box's and the large one's)
    m_lo = 0.5 * (yl_lo + np.where(np.isfinite(ys_hi), ys_hi, yl_lo))
    m_hi = 0.5 * (np.where(np.isfinite(ys_lo), ys_lo, yl_hi) + yl_hi)
    none = ~np.isfinite(ys_lo)  # the judge's patch may be empty: it takes the middle of the pad then
    m_lo, m_hi = np.where(none, np.minimum(m_lo, 0.0), m_lo), np.where(none, np.maximum(m_hi, 0.0), m_hi)
    y_mid, x_mid = 0.5 * (m_lo + m_hi), 0.5 * (f0 + f1)
    with np.errstate(invalid="ignore"):  # (no face: nan, and not kept)
        middle = sides_c + x_mid[:, None] * sides_u + y_mid[:, None] * sides_v
        slack = 0.5 * (m_hi - m_lo) + 0.5 * (f1 - f0) + EPS_MM
        reach = np.where(known, near.distance(x_mid, y_mid) + 2.0 * slack, np.inf)
    f0, f1 = np.where(known, f0, np.inf), np.where(known, f1, np.inf)
    x_left, x_right = (f0[:n], f1[:n]), (-f1[n:], -f0[n:])  # (the second pad's, in the grasp's frame)
    width, reach = np.stack([width[:n], width[n:]], axis=1), np.stack([reach[:n], reach[n:]], axis=1)
    middle = np.stack([middle[:n], middle[n:]], axis=1)
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
    """The part's edges clipped to one box per grasp (its frame's [x_lo, x_hi] x [-hw, hw]): piece i is the
    stretch [s0, s1] of the edge starting at (x, y) and running (dx, dy) in grasp `of[i]`'s frame, pieces in
    grasp order. A smaller box's edges are these clipped again (`within`)."""

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
    def clip(cls, part: Part, centre, u, v, x_lo, x_hi, hw) -> _Pieces:
        """The part's edges clipped to each grasp's box [x_lo, x_hi] x [-hw, hw] (x_lo, x_hi (k,))."""
        starts, steps = _edges(part)
        ends = starts + steps
        # only the (grasp, edge) pairs whose bounding boxes overlap, in the base frame
        mid, half = centre + (0.5 * (x_lo + x_hi))[:, None] * u, 0.5 * (x_hi - x_lo)
        rx, ry = np.abs(u[:, 0]) * half + np.abs(v[:, 0]) * hw, np.abs(u[:, 1]) * half + np.abs(v[:, 1]) * hw
        of, e = np.nonzero((np.minimum(starts[:, 0], ends[:, 0])[None] <= (mid[:, 0] + rx)[:, None])
                           & (np.maximum(starts[:, 0], ends[:, 0])[None] >= (mid[:, 0] - rx)[:, None])
                           & (np.minimum(starts[:, 1], ends[:, 1])[None] <= (mid[:, 1] + ry)[:, None])
                           & (np.maximum(starts[:, 1], ends[:, 1])[None] >= (mid[:, 1] - ry)[:, None]))
        rel = starts[e] - centre[of]
        uo, vo = u[of], v[of]
        x, y = np.einsum("ij,ij->i", rel, uo), np.einsum("ij,ij->i", rel, vo)
        dx, dy = np.einsum("ij,ij->i", steps[e], uo), np.einsum("ij,ij->i", steps[e], vo)
        p = cls(part, centre, u, v, of, x, y, dx, dy, np.zeros(len(e)), np.ones(len(e)))
        return p.within(x_lo, x_hi, hw)

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
        return _per_grasp(np.hypot(qx - t * self.dx, qy - t * self.dy), self.of, len(self.centre), np.minimum, np.inf)

    def extent(self, x_lo, x_hi, hw, clipped: bool = False):
        """(least x, greatest x, least y, greatest y), each (k,), of these pieces in each grasp's box
        [x_lo, x_hi] x [-hw, hw] (x_lo, x_hi (k,)): inf, -inf where there are none. `clipped`: they are clipped
        to that box already. The material's extent is this but where a corner of the box lies inside the part
        (`pad_patches` says where that cannot matter)."""
        k = len(self.centre)
        p = self if clipped else self.within(x_lo, x_hi, hw)
        xa, xb = p.x + p.s0 * p.dx, p.x + p.s1 * p.dx
        ya, yb = p.y + p.s0 * p.dy, p.y + p.s1 * p.dy
        out = [_per_grasp(np.minimum(xa, xb), p.of, k, np.minimum, np.inf),
               _per_grasp(np.maximum(xa, xb), p.of, k, np.maximum, -np.inf),
               _per_grasp(np.minimum(ya, yb), p.of, k, np.minimum, np.inf),
               _per_grasp(np.maximum(ya, yb), p.of, k, np.maximum, -np.inf)]
        return tuple(out)


def _per_grasp(values: np.ndarray, of: np.ndarray, k: int, ufunc, empty: float) -> np.ndarray:
    """(k,) `values` of pieces in grasp order (`of`, sorted) reduced per grasp by `ufunc` (`empty` for none)."""
    out = np.full(k, empty)
    if len(of):
        starts = np.flatnonzero(np.concatenate([[True], of[1:] != of[:-1]]))
        out[of[starts]] = ufunc.reduceat(values, starts)
    return out
