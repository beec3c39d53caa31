"""Regions -> segments: each region's outline and holes traced at detection resolution (small holes
looked for again finer, holes.py), all rings refined at full resolution (subpixel.py, rings.py), and
what the refinement shows is no part left out (segmentation step 5)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.holes import hole_grazed, hole_holds, holes_fine, tray_dips
from cell.vision.rings import ring_area_centroid, tidy_rings
from cell.vision.subpixel import MIN_EDGE_SHARE, edge_share, refine_rings

if TYPE_CHECKING:
    from cell.vision.segment import Segment, SegmentParams


def regions_to_segments(pieces, frame: np.ndarray, det: np.ndarray, bg: np.ndarray, p: SegmentParams,
                        scale: int) -> list[Segment]:
    """Pieces (x0, y0, bool mask, merged) -> segments: outlines, holes (also the small ones seen
    only at finer resolution), all refined at full resolution in one pass."""
    from cell.vision.segment import DEFAULT_CAMERA_PX, Segment  # (segment.py imports this module)

    dh, dw = det.shape[:2]
    # small holes are looked for at the default camera's full resolution: 1 / k of a larger frame
    k = max(1, scale // DEFAULT_CAMERA_PX["scale"])
    found = []  # (outline, holes, merged, cut_off, mean colour) per region, before refinement
    for px0, py0, piece, merged in pieces:
        piece = piece.view(np.uint8)
        bx, by, bw, bh = cv2.boundingRect(piece)
        if bw == 0:
            continue
        # the piece's bounding box grown by a pixel
        y0, x0 = max(py0 + by - 1, 0), max(px0 + bx - 1, 0)
        y1, x1 = min(py0 + by + bh + 1, dh), min(px0 + bx + bw + 1, dw)
        sub = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cy0, cx0 = max(y0, py0), max(x0, px0)
        cy1, cx1 = min(y1, py0 + piece.shape[0]), min(x1, px0 + piece.shape[1])
        sub[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0] = piece[cy0 - py0:cy1 - py0, cx0 - px0:cx1 - px0]
        contours, hier = cv2.findContours(sub, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE, offset=(x0, y0))
        if hier is None:
            continue
        hier = hier[0]
        mean = cv2.mean(det[y0:y1, x0:x1], sub)[:3]
        outers = [i for i in range(len(contours)) if hier[i][3] < 0]
        for oi in outers:
            c = contours[oi].reshape(-1, 2)
            if cv2.contourArea(contours[oi]) < p.min_area_px / scale ** 2 * 0.5:
                continue
            ox, oy, ow, oh = cv2.boundingRect(contours[oi])
            cut = ox <= 0 or oy <= 0 or ox + ow >= dw or oy + oh >= dh  # touches the image border
            holes = [contours[j].reshape(-1, 2) for j in range(len(contours)) if hier[j][3] == oi
                     and cv2.contourArea(contours[j]) >= p.min_hole_area_px / scale ** 2]
            outline = _to_full(c, scale)
            hole_rings = [_to_full(hh, scale) for hh in holes]
            if scale > k and p.full_res_holes:
                # keep the holes seen at detection resolution; add the small ones only seen here
                dips = tray_dips(det, bg, sub, mean, (x0, y0, x1, y1), p)
                for ring in holes_fine(frame, k, bg, outline, mean, (x0, y0, x1, y1), p, scale, dips):
                    centre = ring.mean(axis=0)
                    if not any(cv2.pointPolygonTest(hh.astype(np.float32), (float(centre[0]), float(centre[1])),
                                                    False) >= 0 for hh in hole_rings):
                        hole_rings.append(ring)
            found.append((outline, hole_rings, merged, cut, mean))
    if p.refine and found:  # all rings of the frame in one pass
        rings = [r for o, hs, *_ in found for r in [o, *hs]]
        is_hole = [h for o, hs, *_ in found for h in [False] + [True] * len(hs)]
        edges: list = []
        refined = iter(tidy_rings(refine_rings(frame, rings, is_hole, p, edges), frame.shape))
        at = np.cumsum([0] + [1 + len(hs) for _, hs, *_ in found])[:-1]
        shares = [edge_share(rings[i], edges[i], frame.shape) for i in at]
        found = [(next(refined), [next(refined) for _ in hs], *rest) for _, hs, *rest in found]
        # a region with an edge along almost none of its outline is a lighting gradient the tray's
        # field does not follow (a vignetted corner, a bright patch at the border), not a part
        found = [f for f, share in zip(found, shares) if share >= MIN_EDGE_SHARE]
    segs = []
    for outline, hole_rings, merged, cut, mean in found:
        # each ring's area and centroid once: they give its orientation, the hole's size and the region's
        outer, cen = ring_area_centroid(outline)
        outline = outline if outer > 0 else outline[::-1].copy()  # counter-clockwise
        area, mom = abs(outer), abs(outer) * cen
        holes = []
        for hh in hole_rings:
            ha, hc = ring_area_centroid(hh)
            if not hole_holds(hh, outline, p, ha):
                hh = hole_grazed(hh, outline, p, ha)
                if hh is None:
                    continue
                ha, hc = ring_area_centroid(hh)
            holes.append(hh if ha < 0 else hh[::-1].copy())  # clockwise
            area, mom = area - abs(ha), mom - abs(ha) * hc
        area, cen = (area, mom / area) if area > 0 else (abs(outer), cen)  # (holes filling it: the outline's)
        if area < 0.5 * p.min_area_px:
            continue  # a sliver whose pixels passed the speck filter but whose outline did not
        segs.append(Segment(outline, holes, float(area), cen, bool(merged), cut, tuple(float(m) for m in mean)))
    return segs


def _to_full(c: np.ndarray, scale: int) -> np.ndarray:
    """Detection-resolution boundary pixel centres -> full-resolution CONTRACT coordinates."""
    return (c.astype(float) + 0.5) * scale
