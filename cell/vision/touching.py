"""Touching parts: split a region at a narrow neck, or flag it as merged.

Two convex-ish parts that touch form one region whose distance transform (DT) has two
lobes joined by a low saddle. Thresholding the DT at rising levels L finds the first level
where the region falls apart into two or more cores (each with a peak well above L). If
those cores, grown back by L, cover the region (nothing but the lobes: the signature of
touching blobs, unlike a lever whose bosses are joined by a long bar), the region is split
by a watershed from the cores when the neck is narrow (L / smaller peak < `neck_split`),
and flagged merged when it is only moderately narrow (< `neck_flag`). Touching parts with
no neck at all (two plates side by side) cannot be told from one part by shape alone.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

MIN_LOBE_RADIUS_PX = 6.0  # full-resolution px: teeth and tabs are not lobes
COVER_MIN = 0.9


def split_necks(labels: np.ndarray, p, min_area_det: float, grey: np.ndarray | None = None
                ) -> tuple[np.ndarray, set[int]]:
    """Return a label image where touching regions are split, and the labels flagged merged."""
    out = np.zeros_like(labels)
    merged: set[int] = set()
    next_id = 1
    scale = max(1, int(p.scale))
    r_min = MIN_LOBE_RADIUS_PX / scale
    hh, ww = labels.shape
    for lid, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        y0, x0 = max(sl[0].start - 2, 0), max(sl[1].start - 2, 0)
        y1, x1 = min(sl[0].stop + 2, hh), min(sl[1].stop + 2, ww)
        sub = (labels[y0:y1, x0:x1] == lid).astype(np.uint8)
        decision, parts = _analyse(sub, p, r_min, min_area_det,
                                   None if grey is None else grey[y0:y1, x0:x1])
        view = out[y0:y1, x0:x1]
        if decision == "split":
            for k in range(1, parts.max() + 1):
                sel = parts == k
                if sel.any():
                    view[sel] = next_id
                    next_id += 1
        else:
            view[sub.astype(bool)] = next_id
            if decision == "merged":
                merged.add(next_id)
            next_id += 1
    return out, merged


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """The mask (0/1 uint8) with every region not reachable from the border filled."""
    pad = np.pad(mask, 1)
    flood = pad.copy()
    cv2.floodFill(flood, None, (0, 0), 1)
    return (pad | (1 - flood))[1:-1, 1:-1]


def _analyse(sub: np.ndarray, p, r_min: float, min_area: float, grey: np.ndarray | None):
    sub = fill_holes(sub)  # holes would put false saddles into the distance transform
    dt = cv2.distanceTransform(sub, cv2.DIST_L2, 5)
    peak = float(dt.max())
    if peak < 2 * r_min:
        return "one", None
    for level in np.arange(1.0, peak, max(1.0, peak / 12)):
        n, cores = cv2.connectedComponents((dt > level).astype(np.uint8), connectivity=8)
        if n <= 2:
            continue
        idx = np.arange(1, n)
        peaks = np.asarray(ndimage.maximum(dt, cores, idx), float)
        areas = np.bincount(cores.ravel(), minlength=n)[1:]
        big = idx[(peaks >= np.maximum(r_min, level / p.neck_flag)) & (areas >= 3)]
        if len(big) < 2:
            continue
        lobe_peaks = np.asarray(ndimage.maximum(dt, cores, big), float)
        grown = cv2.dilate(np.isin(cores, big).astype(np.uint8),
                           cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * int(level) + 3,) * 2))
        cover = float((grown.astype(bool) & sub.astype(bool)).sum()) / float(sub.sum())
        if cover < COVER_MIN:
            return "one", None  # lobes joined by bars or arms: one part with a shape of its own
        ratio = level / float(np.sort(lobe_peaks)[-2])
        if ratio >= p.neck_flag:
            return "one", None
        if ratio >= p.neck_split:
            return "merged", None
        markers = np.zeros(sub.shape, np.int32)
        for k, c in enumerate(big, start=1):
            markers[cores == c] = k
        markers[sub == 0] = len(big) + 1
        ws = cv2.watershed(cv2.cvtColor((255 - np.clip(dt * 8, 0, 255)).astype(np.uint8), cv2.COLOR_GRAY2BGR),
                           markers)
        parts = np.where((ws >= 1) & (ws <= len(big)) & (sub > 0), ws, 0)
        # the watershed lines (-1) inside the region go to the neighbouring lobe
        parts = _fill_lines(parts, sub)
        if min(int((parts == k).sum()) for k in range(1, len(big) + 1)) < min_area:
            return "merged", None
        if not _seam_visible(parts, ws, grey, p.seam_contrast_dn):
            # a neck but no seam in the image: one part with a waist, or parts that touch
            # so closely nothing shows; only a pinch-thin neck is reported as merged
            return ("merged" if ratio < p.neck_pinch else "one"), None
        return "split", parts
    return "one", None


def _seam_visible(parts: np.ndarray, ws: np.ndarray, grey: np.ndarray | None, contrast_dn: float) -> bool:
    """Is there a line of other brightness along the cut (walls, crease, different colours)?"""
    if grey is None:
        return True
    inner = cv2.erode((parts > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # away from the outline
    cut = (ws == -1) & inner
    if cut.sum() < 2:
        return True
    near = (cv2.dilate(cut.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0) & ~(
        cv2.dilate(cut.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0) & inner
    if not near.any():
        return True
    valley = abs(float(np.median(grey[cut])) - float(np.median(grey[near])))
    sides = [float(np.median(grey[near & (parts == k)])) for k in np.unique(parts[near]) if k > 0]
    step = max(sides) - min(sides) if len(sides) > 1 else 0.0
    return max(valley, step) > contrast_dn


def _fill_lines(parts: np.ndarray, sub: np.ndarray) -> np.ndarray:
    holes = (sub > 0) & (parts == 0)
    if not holes.any():
        return parts
    grown = cv2.dilate(parts.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)
    parts = parts.copy()
    parts[holes] = grown[holes]
    return parts
