"""Local (per point, paper 4.1) and global (per contact set, paper 6.1) attributes.

Every attribute is built from distances and angles measured on the part itself (to its
centre of gravity, along its outline), so it does not change when the part is moved or
rotated on the tray. Sizes: the same part comes in several sizes, so the distance to the
centre of gravity is given twice, in mm and relative to the part's equivalent-disc radius
sqrt(area / pi) (size-free); the convexities are measured at fixed scales in mm, because
what matters for a 12 mm jaw pad is the shape at the pad's scale: a larger part of the
same family looks flatter to the same pad, and should. The trees pick what separates
the examples; `cell rules` shows which.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from cell.grasp.outline import Ring, centre_of_gravity, reference_radius_mm
from cell.scene import Part

NORMAL_CHORD_MM = 0.25  # half-length of the chord that gives a point's normal


def local_names(scales_mm) -> list[str]:
    return ["dist_cog_mm", "dist_cog_rel"] + [f"convexity_{s:g}mm" for s in scales_mm]


def global_names(scales_mm) -> list[str]:
    out = ["centre_offset_mm", "centre_offset_rel"]
    for s in scales_mm:
        out += [f"angle_max_{s:g}mm_deg", f"angle_mean_{s:g}mm_deg"]
    return out


@dataclass(frozen=True, eq=False)
class OutlinePoints:
    """Points on a part's outline with what the attributes need.

    points (z, 2) mm; normals (z, 2) outward unit normals of the outline at each point;
    chord_normals (z, S, 2) outward unit normals of the chord from arc - s to arc + s, one
    per scale s (a smoothed normal at that scale); convexity (z, S); ring (z,) int; arc_mm (z,).
    """

    points: np.ndarray
    normals: np.ndarray
    chord_normals: np.ndarray
    convexity: np.ndarray
    ring: np.ndarray
    arc_mm: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, mask_or_idx) -> OutlinePoints:
        return OutlinePoints(*(a[mask_or_idx] for a in (self.points, self.normals, self.chord_normals,
                                                        self.convexity, self.ring, self.arc_mm)))


def describe_points(rings: list[Ring], ring_idx, arc_mm, scales_mm) -> OutlinePoints:
    """Points, normals and multiresolution convexity at the given arc positions."""
    ring_idx = np.asarray(ring_idx, int)
    arc_mm = np.asarray(arc_mm, float)
    z, S = len(arc_mm), len(scales_mm)
    pts, nrm = np.zeros((z, 2)), np.zeros((z, 2))
    cn, cx = np.zeros((z, S, 2)), np.zeros((z, S))
    scales = np.asarray(scales_mm, float)
    for r, ring in enumerate(rings):
        m = ring_idx == r
        if not m.any():
            continue
        s = arc_mm[m]
        p = ring.at(s)
        # the normal of a short chord: the edge's normal, and the mean of both edges' normals at a vertex
        # (a sample may fall on a vertex; which edge holds it would then be float noise)
        e = min(NORMAL_CHORD_MM, ring.length_mm / 4)
        d = ring.at(s + e) - ring.at(s - e)
        n = np.stack([d[:, 1], -d[:, 0]], -1)
        pts[m], nrm[m] = p, n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        # A scale longer than half the ring would wrap round: cap it (small holes).
        sc = np.minimum(scales, ring.length_mm / 2.0 * 0.999)
        a = ring.at(s[:, None] - sc[None, :])  # (k, S, 2)
        b = ring.at(s[:, None] + sc[None, :])
        d = b - a
        n = np.stack([d[..., 1], -d[..., 0]], -1)
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        cn[m] = n
        # Signed bulge of the point beyond its chord, per unit of scale: > 0 convex, < 0 concave.
        cx[m] = ((p[:, None, :] - 0.5 * (a + b)) * n).sum(-1) / sc[None, :]
    return OutlinePoints(pts, nrm, cn, cx, ring_idx, arc_mm)


def local_attributes(op: OutlinePoints, part: Part, outer_disc: bool = True, slit_mm: float = 0.0) -> np.ndarray:
    """(z, 2 + S): distance to the centre of gravity (mm, relative to `reference_radius_mm`), convexity per scale."""
    d = np.linalg.norm(op.points - centre_of_gravity(part), axis=1)
    return np.column_stack([d, d / reference_radius_mm(part, outer_disc, slit_mm), op.convexity])


def global_attributes(contacts, chord_normals, part: Part, outer_disc: bool = True, slit_mm: float = 0.0,
                      stable_angles: bool = True) -> np.ndarray:
    """Attributes of contact sets.

    contacts (k, n, 2) mm, chord_normals (k, n, S, 2). The reference point is the centroid of
    the contacts (for two contacts the midpoint; the paper's convex-hull centre of gravity).
    Returns (k, 2 + 2 S): reference-to-centre-of-gravity distance (mm, relative), then per
    scale the largest and the mean angle (deg) between a contact's inward normal and the line
    from the contact to the reference point (0 = pushing straight at it, force-closure-like).
    The per-contact angles are reduced by max and mean, so the contacts' order does not matter.
    stable_angles: from atan2 of the cross and dot products (off: arccos of the dot, as recordings made before
    2026-12-05 have it; near 0 it turned float noise of 1e-13 into 1e-6 deg).
    """
    contacts = np.asarray(contacts, float)
    ref = contacts.mean(axis=1)  # (k, 2)
    off = np.linalg.norm(ref - centre_of_gravity(part), axis=1)
    to_ref = ref[:, None, :] - contacts  # (k, n, 2)
    to_ref /= np.maximum(np.linalg.norm(to_ref, axis=-1, keepdims=True), 1e-12)
    inward, line = -chord_normals, to_ref[:, :, None, :]
    dot = (inward * line).sum(-1)  # (k, n, S)
    if stable_angles:
        cross = inward[..., 0] * line[..., 1] - inward[..., 1] * line[..., 0]
        ang = np.degrees(np.arctan2(np.abs(cross), dot))
    else:
        ang = np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))
    per_scale = np.stack([ang.max(axis=1), ang.mean(axis=1)], -1).reshape(len(contacts), -1)
    return np.column_stack([off, off / reference_radius_mm(part, outer_disc, slit_mm), per_scale])


PART_NAMES = ["part_log_elongation", "part_solidity"]


def part_attributes(part: Part) -> np.ndarray:
    """(2,) what kind of part it is, whatever its pose and size: ln of its elongation (the square root of the
    ratio of its principal second moments of area, holes out: 0 for a disc, a square or a hexagon; a bar 6
    times as long as wide ln 6), and its solidity (area / convex hull area: 1 for a convex plate, about 0.2
    for an open clip). Both are integrals over the area, so an outline's noise (a segmented edge) barely moves
    them, unlike the perimeter. The choice of a grasp compares them with the examples' parts
    (learning.nearest_example): a part is grasped as the operator grasped parts of its kind."""
    poly = shapely.geometry.polygon.orient(part.polygon, 1.0)  # outer CCW, holes CW: the sums add up signed
    c = np.asarray(poly.centroid.coords[0], float)
    m = np.zeros(3)  # integrals of x^2, y^2, x y over the area, about the centroid
    for ring in (poly.exterior, *poly.interiors):
        xy = np.asarray(ring.coords, float)[:-1] - c
        x, y = xy[:, 0], xy[:, 1]
        x1, y1 = np.roll(x, -1), np.roll(y, -1)
        cr = x * y1 - x1 * y
        m += [(cr * (x * x + x * x1 + x1 * x1)).sum() / 12, (cr * (y * y + y * y1 + y1 * y1)).sum() / 12,
              (cr * (x * y1 + 2 * x * y + 2 * x1 * y1 + x1 * y)).sum() / 24]
    low, high = np.linalg.eigvalsh(np.array([[m[0], m[2]], [m[2], m[1]]]))
    elongation = np.sqrt(high / max(low, 1e-12 * high, 1e-300))
    return np.array([np.log(elongation), poly.area / poly.convex_hull.area])
