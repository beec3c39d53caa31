"""Whether a reading of the frame took the tray for a part, and which of two readings explains it.

The tray's field is fitted on the assumption that the tray is the larger side of the view
(background.py). Where it is not (a back-lit panel in a dark surround, the panel cut by the border,
light parts on a dark panel), the tray comes out as one large region cut by the border, with the
parts as its holes, or the lit panel as one part: these checks see that, and compare the readings
made with the other side as the tray by what they show (whole parts, regions besides such a region,
the share of holes in it). segment.py makes the readings.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.background import fit_copy_of_whole_dn
from cell.vision.outside import split_outside
from cell.vision.rings import signed_area

if TYPE_CHECKING:
    from cell.vision.detection import Detection
    from cell.vision.segment import Segment, SegmentParams


TRAY_TAKEN_SHARE = 0.25  # a region cut by the border and this large a share of the frame may be the tray
# ... and the parts its holes when they are this share of it: then the region's own colour is tried as
# the tray's (pca_test1.jpg's panel, bright or dark: 0.46; the Festo frames' table: 0.01 - 0.05)
PARTS_AS_HOLES_SHARE = 0.15


def tray_taken_for_a_part(segs: list[Segment], shape) -> bool:
    """True when a region touching the border covers TRAY_TAKEN_SHARE of the frame and holds holes."""
    return any(s.cut_off and _large_with_holes(s, shape) for s in segs)


def _large_with_holes(s: Segment, shape) -> bool:
    """A region over TRAY_TAKEN_SHARE of the frame that holds holes: the tray (or a panel) taken for a part,
    with the parts as its holes."""
    return bool(s.holes_px) and s.area_px > TRAY_TAKEN_SHARE * shape[0] * shape[1]


def panel_taken_for_a_part(segs: list[Segment], shape, tray_field: np.ndarray, p: SegmentParams) -> bool:
    """True when no region is of the kind `tray_taken_for_a_part` looks for but one cut by the border on
    at least two sides of the frame, over TRAY_TAKEN_SHARE of it and without holes, is brighter than the
    tray by `brighter_min` (its mean brightness against the tray field's mean): a back-lit panel whose
    dark surround was taken for the tray, cut by the border through every part it holds."""
    if tray_taken_for_a_part(segs, shape):
        return False
    frame_px = shape[0] * shape[1]
    tray_sum = float(tray_field.reshape(-1, 3).mean(axis=0).sum())
    return any(s.cut_off and not s.holes_px and s.area_px > TRAY_TAKEN_SHARE * frame_px
               and _border_sides(s.outline_px, shape) >= 2
               and sum(s.mean_bgr) > (1.0 + p.brighter_min) * tray_sum for s in segs)


def _border_sides(ring: np.ndarray, shape, margin_px: float = 2.0) -> int:
    """On how many sides of the frame `ring` (CONTRACT px) comes within `margin_px` of the border."""
    h, w = shape[:2]
    u, v = ring[:, 0], ring[:, 1]
    return int(u.min() < margin_px) + int(u.max() > w - margin_px) + int(v.min() < margin_px) + int(
        v.max() > h - margin_px)


def panel_in_surround(segs: list[Segment], shape, p: SegmentParams, d: Detection) -> bool:
    """True when step 6 (outside.py) leaves out regions over TRAY_TAKEN_SHARE of the frame in all (the
    dark side, the first reading's tray, as the panel's surround) and keeps none that large on the tray."""
    on_tray, out = split_outside(segs, d.det.shape[:2], d.scale, p.min_area_px, max(p.refine_range_px, 2.0 * p.scale))
    frame_px = shape[0] * shape[1]
    return (sum(s.area_px for s in out) > TRAY_TAKEN_SHARE * frame_px
            and not any(s.area_px > TRAY_TAKEN_SHARE * frame_px for s in on_tray))


def holds_parts(segs: list[Segment], shape) -> bool:
    """True when a region, cut by the border or not, is `_large_with_holes`."""
    return any(_large_with_holes(s, shape) for s in segs)


def regions_besides(segs: list[Segment], shape) -> int:
    """How many regions are not `_large_with_holes`."""
    return sum(not _large_with_holes(s, shape) for s in segs)


def border_hole_share(segs: list[Segment], shape) -> float:
    """The largest share of holes (their area over the area inside the outline) among the regions cut
    by the border that cover TRAY_TAKEN_SHARE of the frame; 0 without such a region."""
    frame_px = shape[0] * shape[1]
    share = 0.0
    for s in segs:
        if s.cut_off and s.area_px > TRAY_TAKEN_SHARE * frame_px:
            holes = sum(abs(signed_area(h)) for h in s.holes_px)
            share = max(share, holes / (s.area_px + holes))
    return share


def region_seed(segs: list[Segment], shape, d: Detection) -> np.ndarray:
    """The regions `tray_taken_for_a_part` names (cut by the border, holes, TRAY_TAKEN_SHARE of the
    frame), their holes left out, drawn on the tray fit's small copy of the frame (sh, sw) uint8."""
    frame_px = shape[0] * shape[1]
    sh, sw = fit_copy_of_whole_dn(d.det_u8).shape[:2]  # (the copy's size; the copy itself is small)
    fy, fx = sh / shape[0], sw / shape[1]
    seed = np.zeros((sh, sw), np.uint8)
    def ring(r: np.ndarray) -> np.ndarray:
        return np.round(r * (fx, fy) - 0.5).astype(np.int32)

    for s in segs:
        if s.cut_off and s.holes_px and s.area_px > TRAY_TAKEN_SHARE * frame_px:
            cv2.fillPoly(seed, [ring(s.outline_px)], 1)
            cv2.fillPoly(seed, [ring(h) for h in s.holes_px], 0)
    inner = cv2.erode(seed, np.ones((3, 3), np.uint8))  # away from its edges, where samples mix colours
    return inner if cv2.countNonZero(inner) else seed


SAME_FIELD_DN = 6.0  # two tray fields closer than this (colour distance) on SAME_FIELD_SHARE of a region ...
SAME_FIELD_SHARE = 0.95  # ... read it alike


def same_on(a: np.ndarray, b: np.ndarray, where: np.ndarray) -> bool:
    """Whether two fields on the small copy (sh, sw, 3) agree within SAME_FIELD_DN on
    SAME_FIELD_SHARE of `where` (sh, sw)."""
    inside = where.astype(bool)
    if not inside.any():
        return False
    dist = np.sqrt(((a[inside] - b[inside]) ** 2).sum(axis=1))
    return float((dist < SAME_FIELD_DN).mean()) >= SAME_FIELD_SHARE


def whole_parts(segs: list[Segment]) -> int:
    """How many regions the border does not cut: what a right choice of tray shows more of."""
    return sum(not s.cut_off for s in segs)
