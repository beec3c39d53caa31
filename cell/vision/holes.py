"""A region's holes: small holes looked for again at full resolution where the region's pixels lean towards the
tray's colour (they blur into their part at detection resolution), and refined holes kept only where they
still lie inside their outline (a sliver along the edge is no hole; a large hole the outline grazes is clipped)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.rings import ahead, signed_area

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams

SUM_PLUS_1 = np.ones((1, 4), np.float32)  # cv2.transform: b + g + r + 1 in one pass (the same sums)
_ONES_1x3 = np.ones((1, 3), np.float32)


def hole_holds(hole: np.ndarray, outline: np.ndarray, p: SegmentParams, area: float | None = None) -> bool:
    """A refined hole keeps its minimum area and lies inside its outline (a sliver along the
    edge that refinement squeezed or pushed onto the outline is no hole). `area`: the hole's
    signed area if known."""
    if abs(signed_area(hole) if area is None else area) < 0.5 * p.min_hole_area_px:
        return False
    ring = outline.astype(np.float32)
    (u0, v0), (u1, v1) = hole.min(axis=0) - 1.0, hole.max(axis=0) + 1.0
    a, b = outline, ahead(outline, 1)
    near = ((np.minimum(a[:, 0], b[:, 0]) <= u1) & (np.maximum(a[:, 0], b[:, 0]) >= u0)
            & (np.minimum(a[:, 1], b[:, 1]) <= v1) & (np.maximum(a[:, 1], b[:, 1]) >= v0))
    if not near.any():  # no edge of the outline comes near: the hole lies wholly inside or outside
        return cv2.pointPolygonTest(ring, (float(hole[0, 0]), float(hole[0, 1])), False) > 0
    return bool(_clear_inside(hole, ring).all())


def _clear_inside(hole: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """(m,) True where the hole's vertex lies more than 0.5 px inside the outline `ring` (float32)."""
    return np.array([cv2.pointPolygonTest(ring, (float(u), float(v)), True) > 0.5 for u, v in hole])


GRAZED_HOLE_MIN = 4.0  # x min_hole_area_px: a hole this large that the outline grazes is kept, clipped
GRAZED_KEEPS = 0.8  # ... when clipping keeps this share of it (else it was a sliver along the edge)
GRAZED_MAX_SHARE = 0.2  # ... and at most this share of its ring is within 0.5 px of the outline
# (measured: the washer's hole 0.12; slivers of strong shadow along a plate's edge 0.29 - 0.41)


def hole_grazed(hole: np.ndarray, outline: np.ndarray, p: SegmentParams, area: float) -> np.ndarray | None:
    """A large hole whose refined ring touches or crosses the outline where the outline runs close
    (a washer's hole next to the jagged line that split the washer from its neighbour): the hole
    clipped to the outline (0.5 px inside), or None when it was no more than a sliver."""
    if abs(area) < GRAZED_HOLE_MIN * p.min_hole_area_px:
        return None
    close = np.count_nonzero(~_clear_inside(hole, outline.astype(np.float32)))
    if close > GRAZED_MAX_SHARE * len(hole):
        return None  # a stretch of it runs along the edge: a sliver of shadow, not a hole
    from shapely.geometry import Polygon

    inside = Polygon(hole).buffer(0).intersection(Polygon(outline).buffer(0).buffer(-0.5))
    pieces = [g for g in getattr(inside, "geoms", [inside]) if g.geom_type == "Polygon" and not g.is_empty]
    if not pieces:
        return None
    best = max(pieces, key=lambda g: g.area)
    if best.area < GRAZED_KEEPS * abs(area):
        return None
    return np.asarray(best.exterior.coords, float)[:-1]


def tray_dips(det, bg, region, part_bgr, box, p: SegmentParams) -> tuple[int, int, int, int] | None:
    """Bounding box (detection px, within `box`) of the region's pixels that lean towards the
    tray's colour and keep its chroma: where a small hole may hide. None: nowhere."""
    x0, y0, x1, y1 = box
    img, b = det[y0:y1, x0:x1], bg[y0:y1, x0:x1]
    inner = cv2.erode(region, np.ones((3, 3), np.uint8))
    if not inner.any():
        return None
    # the tray's colour varies slowly: the box is compared with its mean colour
    tray = cv2.mean(b)[:3]
    f = _towards_part(img, part_bgr, tray)
    ch = _ratio_chroma(img, tray, ratio=False)[1]
    dips = (((f < 0.8) & (ch < 2.0 * p.chroma_min)) | (ch < 0.5 * _chroma_of(part_bgr, tray))) & inner.view(bool)
    bx, by, bw, bh = cv2.boundingRect(dips.view(np.uint8))
    return None if bw == 0 else (bx, by, bx + bw, by + bh)


def _towards_part(img: np.ndarray, part_bgr, tray_bgr) -> np.ndarray:
    """Per pixel, how far its colour lies from the tray's towards the part's (0 at the tray's
    colour, 1 at the part's, projected on their difference); float32 (h, w)."""
    d = np.asarray(part_bgr, np.float64) - np.asarray(tray_bgr, np.float64)
    wt = d / max(float(d @ d), 1.0)
    # (one affine cv2.transform: the offset is the tray's projection)
    return cv2.transform(img, np.array([[*wt, -float(wt @ np.asarray(tray_bgr, np.float64))]], np.float32))


def _ratio_chroma(img: np.ndarray, tray_bgr, ratio: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
    """Brightness ratio (None unless `ratio`) and chroma change (L1 over the three channels of the
    colour divided by its sum) of an unblurred image against the tray's colour (3 floats: it
    varies slowly, one colour serves a part's box); float32 (h, w) each."""
    si = cv2.transform(img, SUM_PLUS_1)
    st = float(tray_bgr[0]) + float(tray_bgr[1]) + float(tray_bgr[2]) + 1.0
    # (cv2.multiply by a merged reciprocal: the same products as numpy's broadcast, faster)
    diff = cv2.absdiff(cv2.multiply(img, cv2.merge([1.0 / si] * 3)), tuple(float(t) / st for t in tray_bgr) + (0.0,))
    return (si * np.float32(1.0 / st) if ratio else None), cv2.transform(diff, _ONES_1x3)


def _chroma_of(part_bgr, tray_mean_bgr) -> float:
    """Chroma change (L1 of normalised colour) of a part's mean colour against the tray's mean."""
    # (in Python floats: the same double operations in the same order as on numpy arrays, faster for 3 values)
    p0, p1, p2 = (float(v) for v in part_bgr)
    t0, t1, t2 = (float(v) for v in tray_mean_bgr)
    sp, st = p0 + p1 + p2 + 1.0, t0 + t1 + t2 + 1.0
    return abs(p0 / sp - t0 / st) + abs(p1 / sp - t1 / st) + abs(p2 / sp - t2 / st)


def _reduced(frame: np.ndarray, k: int, box) -> np.ndarray:
    """The frame at 1 / k in `box` (x0, y0, x1, y1 in reduced px, within w // k, h // k): each pixel
    the mean of k x k (pixel i spans frame pixels i k .. (i + 1) k). Only the box is reduced: most
    of a 12 MP frame is tray no hole search looks at (the whole frame took 24 ms)."""
    x0, y0, x1, y1 = box
    crop = frame[y0 * k:y1 * k, x0 * k:x1 * k]
    return crop if k == 1 else cv2.resize(crop, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)


def holes_fine(frame, k: int, bg, outline, part_bgr, box, p: SegmentParams, scale: int, dips=None
                ) -> list[np.ndarray]:
    """Holes found inside a region's outline on the frame at 1 / k (full resolution on the
    default camera, k = 1): pixels that look like the tray (its chroma, at most shadow-dark) and
    lie nearer the tray's colour than the part's. Small holes blur into their part at detection
    resolution; here they keep their pixels. With `dips` (from `tray_dips`) only that part of
    the region is looked at. Rings in full-resolution CONTRACT coordinates."""
    if dips is None:
        return []
    bx0, by0 = box[0], box[1]
    m = 3  # detection px of margin around the dips
    box = (max(bx0 + dips[0] - m, box[0]), max(by0 + dips[1] - m, box[1]), min(bx0 + dips[2] + m, box[2]),
           min(by0 + dips[3] + m, box[3]))
    r_fine = scale / k  # fine px per detection px (whole unless an odd scale was given)
    h, w = frame.shape[0] // k, frame.shape[1] // k
    x0, y0 = math.floor(box[0] * r_fine), math.floor(box[1] * r_fine)
    x1, y1 = min(math.ceil(box[2] * r_fine), w), min(math.ceil(box[3] * r_fine), h)
    img = _reduced(frame, k, (x0, y0, x1, y1)).astype(np.float32)
    inside = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(inside, [np.round((outline / k - (x0, y0) - 0.5) * 4).astype(np.int32)], 1, cv2.LINE_8, 2)
    inside = cv2.erode(inside, np.ones((5, 5), np.uint8))  # away from the outline's blur
    if not inside.any():
        return []
    tray = cv2.mean(bg[box[1]:box[3], box[0]:box[2]])[:3]  # (the tray varies slowly: its mean over the box)
    f = _towards_part(img, part_bgr, tray)
    r, chroma = _ratio_chroma(img, tray)
    # nearer the tray's colour than the part's; for a coloured part the chroma alone decides, as
    # the tray seen through a hole lies in the part's shadow (darker, towards a dark part's colour)
    half_chroma = 0.5 * _chroma_of(part_bgr, tray)
    tray_like = (chroma < max(p.chroma_min, half_chroma)) & (r > 1.0 - p.darker_min) & (r < 1.0 + p.brighter_min)
    holes = (((f < 0.5) | (chroma < half_chroma)) & tray_like & inside.view(bool)).view(np.uint8)
    holes = cv2.morphologyEx(holes, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    contours, _ = cv2.findContours(holes, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    rings = []
    for c in contours:
        if cv2.contourArea(c) < p.min_hole_area_px / k ** 2:
            continue
        # fine pixel centres -> CONTRACT frame (a fine pixel spans k frame pixels)
        rings.append((c.reshape(-1, 2).astype(float) + (x0 + 0.5, y0 + 0.5)) * k)
    return rings
