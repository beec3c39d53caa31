"""Footprints of the gripper seen from above (pure geometry, base frame, mm).

A footprint is a rectangle along the closing axis u: from t0 to t1 along u measured from a
centre point, `half_width` on each side across it. Vectorised builders make (k, 4, 2)
corner arrays for the cascade; the per-grasp functions return shapely polygons for the
figures and the visualisation.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import Polygon

from cell.cellconfig import Cell


def axis_rects(center, u, t0, t1, half_width) -> np.ndarray:
    """Corners (k, 4, 2) of rectangles spanning [t0, t1] along u (k, 2) from center (k, 2): corner
    c + u t + v w for (t0, -half_width), (t1, -half_width), (t1, half_width), (t0, half_width), v = u
    turned by +90 degrees."""
    center, u = np.atleast_2d(center), np.atleast_2d(u)
    k = len(center)
    t0, t1 = np.broadcast_to(t0, k), np.broadcast_to(t1, k)
    hw = np.broadcast_to(half_width, k)
    out = np.empty((k, 4, 2))
    for axis, (c, uc, vc) in enumerate(((center[:, 0], u[:, 0], -u[:, 1]), (center[:, 1], u[:, 1], u[:, 0]))):
        a0, a1, w = c + uc * t0, c + uc * t1, vc * hw  # (c + u t) + v (-w) is (c + u t) - v w, exactly
        out[:, 0, axis], out[:, 1, axis], out[:, 2, axis], out[:, 3, axis] = a0 - w, a1 - w, a1 + w, a0 + w
    return out


def axis_rect_bounds(cx, cy, ux, uy, t0, t1, half_width):
    """Bounding boxes of the rectangles of `axis_rects` (centre and u given by component, each (k,)):
    lo x, lo y, hi x, hi y, each (k,), bit for bit the extremes of axis_rects' corners (rounding is
    monotonic, so the extreme of the rounded corners is the rounded extreme) without building them."""
    ax0, ax1 = cx + ux * t0, cx + ux * t1
    ay0, ay1 = cy + uy * t0, cy + uy * t1
    bx, by = np.abs(-uy * half_width), np.abs(ux * half_width)  # |v * half_width|, v = u turned by +90 degrees
    return np.minimum(ax0, ax1) - bx, np.minimum(ay0, ay1) - by, np.maximum(ax0, ax1) + bx, np.maximum(ay0, ay1) + by


def rect_polygons(corners: np.ndarray) -> np.ndarray:
    """shapely polygons (k,) from corner arrays (k, 4, 2)."""
    # one ragged-array call: shapely.polygons (or linearrings, then polygons) on the coordinates costs more
    k = len(corners)
    ring = np.concatenate([corners, corners[:, :1]], axis=1).reshape(-1, 2)
    return shapely.from_ragged_array(shapely.GeometryType.POLYGON, ring, (np.arange(0, 5 * k + 1, 5), np.arange(k + 1)))


def _axis(grasp) -> np.ndarray:
    a = math.radians(grasp.axis_deg)
    u = np.array([math.cos(a), math.sin(a)])
    # Contact 0 lies on the +u side when it is ahead of the centre along u.
    if np.dot(np.asarray(grasp.contacts_mm[0]) - grasp.center_mm, u) < 0:
        u = -u
    return u


def finger_footprints(grasp, cell: Cell, opening_mm: float | None = None) -> list[Polygon]:
    """The two fingers' footprints (12 x 10 pads outside the contacts) with the jaws opened to
    `opening_mm` (default: at the contacts). Contact 0's finger first."""
    g = cell.gripper
    h = (grasp.opening_mm if opening_mm is None else opening_mm) / 2.0
    u = _axis(grasp)
    c = np.asarray(grasp.center_mm, float)
    corners = axis_rects(np.vstack([c, c]), np.vstack([u, -u]), h, h + g.pad_thickness_mm, g.pad_width_mm / 2)
    return list(rect_polygons(corners))


def swept_finger_footprints(grasp, cell: Cell) -> list[Polygon]:
    """Each finger's footprint swept from the approach opening to the contact."""
    g = cell.gripper
    h = grasp.opening_mm / 2.0
    u = _axis(grasp)
    c = np.asarray(grasp.center_mm, float)
    corners = axis_rects(np.vstack([c, c]), np.vstack([u, -u]), h,
                         h + g.approach_clearance_mm + g.pad_thickness_mm, g.pad_width_mm / 2)
    return list(rect_polygons(corners))


def palm_footprint(grasp, cell: Cell) -> Polygon:
    """The palm: palm_length along the closing axis, palm_width across, centred on the grasp."""
    g = cell.gripper
    u = _axis(grasp)
    corners = axis_rects(np.asarray(grasp.center_mm, float)[None], u[None], -g.palm_length_mm / 2,
                         g.palm_length_mm / 2, g.palm_width_mm / 2)
    return rect_polygons(corners)[0]
