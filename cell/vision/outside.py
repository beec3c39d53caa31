"""Regions outside the tray: the surround of a tray (or back-lit panel) that does not fill the view.

The camera looks down on the tray. Whatever lies beyond the tray's edge (the table, the panel's frame,
the dark room around a light box) differs from the tray's colour and comes out of the segmentation as
regions, most of them cut by the image border because the surround runs on out of the view. They are
not parts on the tray. A region is left out as lying outside the tray when it is cut by the image
border and at least OUTSIDE_SHARE of its area (outline less holes) lies outside the tray's extent,
measured the outlines' refinement range in from the extent's edge (a region's edge may lie that far
from where the tray's pixels end, and a thin sliver of surround along the tray's edge would otherwise
count as half in).

Only regions cut by the border: the surround runs on out of the view. A whole region outside the
tray's extent lies on something that is not tray-coloured either (a speck on the panel's frame, or a
part on a sheet, or on a stretch of the tray in deep shadow, which the tray's colour does not
explain): what it lies on cannot be told, and it is kept.

The tray's extent is the convex hull of the tray-coloured area: the frame outside every region's
outline (holes are the tray seen through a part, or a tray-coloured patch on something else: they do
not say where the tray runs), opened by a square as wide as the speck (the square root of the smallest
part's area) so that strips between neighbouring regions do not join pieces of it, and of its pieces
(each measured inside its outer contour, the parts on it included) those at least PIECE_SHARE of the
largest (a tray cut in two by a long part keeps both halves; a stray tray-coloured patch in the
surround is left out). Where the tray reaches the image border, its hull runs along the
border and a part cut there lies inside it. A corner of the view where the tray reaches both borders
that meet there is taken into the hull too: a tray that fills the view runs on beyond the corner, and
a part cut off in the corner would otherwise lie beyond the chord the hull draws across it. So when
the tray fills the view the hull is the whole frame and nothing is left out.

Nothing is left out when the extent covers less than MIN_TRAY_SHARE of the view: the tray's colour is
fitted on the assumption that the tray is at least a quarter of it (background.py), and a smaller
extent says the reading of the tray is in doubt, not that the parts lie beyond it.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

OUTSIDE_SHARE = 0.9  # a region at least this much outside the tray's extent lies beyond the tray
PIECE_SHARE = 0.1  # pieces of the tray-coloured area at least this share of the largest make the tray
MIN_TRAY_SHARE = 0.25  # an extent covering less of the view than this leaves everything in
SHIFT = 4  # fractional bits of the points drawn at detection resolution


def tray_extent(segs, det_hw: tuple[int, int], scale: int, min_area_px: float) -> np.ndarray | None:
    """The tray's extent at detection resolution: (dh, dw) uint8, 1 inside the convex hull of the
    tray-coloured area's pieces (see the module's docstring); None when no tray is in view. `segs`:
    every region of the frame, outlines in frame pixels; the frame is detected at 1 / `scale`;
    `min_area_px`: the speck area (frame pixels), whose side is the width under which a tray-coloured
    strip is no tray."""
    dh, dw = det_hw
    filled = np.zeros((dh, dw), np.uint8)
    for s in segs:  # one at a time: polygons filled in one call cancel where they overlap (even-odd)
        cv2.fillPoly(filled, [_det_points(s.outline_px, scale)], 1, lineType=cv2.LINE_8, shift=SHIFT)
    tray = 1 - filled
    side = max(3, 2 * int(math.sqrt(max(min_area_px, 1.0)) / scale / 2) + 1)  # odd, detection px
    opened = cv2.morphologyEx(tray, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (side, side)))
    # the pieces by their outer contours (each piece's extent, the parts on it included; 8-connected):
    # labelling and counting the pixels took five times as long
    contours, _ = cv2.findContours(opened, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    areas = np.array([cv2.contourArea(c) for c in contours])
    pieces = [c for c, a in zip(contours, areas, strict=True) if a >= PIECE_SHARE * areas.max()]
    points = [c.reshape(-1, 2) for c in pieces] + _border_reaches(tray, pieces)
    xy = np.concatenate(points)
    top, bottom = (xy[:, 1] == 0).any(), (xy[:, 1] == dh - 1).any()
    left, right = (xy[:, 0] == 0).any(), (xy[:, 0] == dw - 1).any()
    for (x, y), a, b in (((0, 0), top, left), ((dw - 1, 0), top, right), ((0, dh - 1), bottom, left),
                         ((dw - 1, dh - 1), bottom, right)):
        if a and b:
            points.append(np.array([[x, y]], np.int32))
    hull = np.zeros((dh, dw), np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.concatenate(points)), 1)
    return hull


def _border_reaches(tray: np.ndarray, pieces: list) -> list[np.ndarray]:
    """The border pixels the tray reaches through gaps narrower than the opening (between parts lined up
    along the border, or where a part nearly meets it): tray-coloured pixels on the frame's border whose
    connected tray area (unopened, 8-connected) holds one of the kept `pieces`. Without them a row of
    parts cut by the border, a few pixels apart, was taken for a wall of surround and left out."""
    dh, dw = tray.shape
    _, labels = cv2.connectedComponents(tray, connectivity=8)
    kept = {int(labels[c[0, 0, 1], c[0, 0, 0]]) for c in pieces} - {0}
    rows = np.r_[np.zeros(dw, int), np.full(dw, dh - 1), np.arange(dh), np.arange(dh)]
    cols = np.r_[np.arange(dw), np.arange(dw), np.zeros(dh, int), np.full(dh, dw - 1)]
    on = np.isin(labels[rows, cols], list(kept))
    return [np.stack([cols[on], rows[on]], 1).astype(np.int32)] if on.any() else []


def _det_points(ring: np.ndarray, scale: int) -> np.ndarray:
    """A ring in frame pixels (CONTRACT: pixel centres at + 0.5) as fixed-point detection pixel indices."""
    return np.round((np.asarray(ring, np.float64) / scale - 0.5) * (1 << SHIFT)).astype(np.int32)


def inner(hull: np.ndarray, margin: int) -> np.ndarray:
    """`hull` taken `margin` pixels in from its edge; the frame's border is no edge of it (eroded as
    if the hull ran on beyond the frame)."""
    if margin <= 0:
        return hull
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
    return cv2.erode(hull, k, borderType=cv2.BORDER_REPLICATE)


def outside_share(seg, hull: np.ndarray, scale: int) -> float:
    """The share of `seg`'s area (outline less holes, drawn at detection resolution) outside `hull`."""
    region = np.zeros(hull.shape, np.uint8)
    cv2.fillPoly(region, [_det_points(seg.outline_px, scale)], 1, lineType=cv2.LINE_8, shift=SHIFT)
    if seg.holes_px:
        cv2.fillPoly(region, [_det_points(h, scale) for h in seg.holes_px], 0, lineType=cv2.LINE_8, shift=SHIFT)
    total = cv2.countNonZero(region)
    return 1.0 - cv2.countNonZero(region & hull) / total if total else 0.0


def split_outside(segs, det_hw: tuple[int, int], scale: int, min_area_px: float, edge_px: float
                  ) -> tuple[list, list]:
    """`segs` (largest first) as (the regions on the tray, the regions outside it), each in order.
    `edge_px`: how far (frame px) a region's edge may lie from where the tray's pixels end (the
    outlines' refinement range): the extent is measured that far in from its edge."""
    if not any(s.cut_off for s in segs):
        # no region reaches the border: the tray-coloured area runs all round it, and its hull is the
        # whole frame (a surround that runs out of the view is cut by the border). Every frame of the
        # cell whose parts all lie in view stops here
        return list(segs), []
    hull = tray_extent(segs, det_hw, scale, min_area_px)
    if hull is None or cv2.countNonZero(hull) < MIN_TRAY_SHARE * hull.size:
        return list(segs), []
    hull = inner(hull, max(1, math.ceil(edge_px / scale)))
    kept, out = [], []
    for s in segs:
        (out if s.cut_off and outside_share(s, hull, scale) >= OUTSIDE_SHARE else kept).append(s)
    return kept, out
