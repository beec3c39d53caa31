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

COVER_MIN = 0.9
MAX_SPLIT_DEPTH = 6
MIN_PIECE_HALF_WIDTH = 4.0  # detection px: a colour piece narrower than this is a wall, not a part
# 8-bit Lab -> CIE Lab units, lightness counted half: a highlight on metal or a shaded face is the
# same part, brighter
LAB_U8_WEIGHT = np.array([0.5 * 100.0 / 255.0, 1.0, 1.0], np.float32)
KMEANS_SAMPLES = 500  # pixels a colour split's k-means looks at (about; every n-th of the region)
CONVEX_SOLIDITY = 0.97  # touching blobs leave notches: two tangent discs have a solidity of about 0.9
UNEQUAL_LOBES = 0.85  # a lobe's peak under this x the largest's: the parts meet beside the neck's middle


def pick(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """a[mask] for a boolean mask of a's leading shape (the same values in the same order), by
    np.compress on the flattened arrays: several times faster than boolean indexing in 2-D."""
    return np.compress(mask.ravel(), a.reshape(mask.size, *a.shape[mask.ndim:]), axis=0)


def split_necks(regions, p, min_area_det: float, bgr: np.ndarray | None = None
                ) -> list[tuple[int, int, np.ndarray, bool]]:
    """Split touching parts.

    Parameters
    ----------
    regions : list of (x0, y0, ndarray of shape (h, w) uint8 0/1)
        Each region alone in a box at (x0, y0) of the detection image (with a margin).
    bgr : ndarray of shape (H, W, 3) uint8, optional
        The detection image: colours for the colour split, brightness for the seams.

    Returns
    -------
    list of (x0, y0, bool mask of shape (h, w), merged) : the parts, in their region's box.
    """
    r_min = p.min_lobe_radius_px / max(1, int(p.scale))  # (p set for the frame: `SegmentParams.for_frame`)
    out = []
    for x0, y0, sub in regions:
        bgr_box = None if bgr is None else bgr[y0:y0 + sub.shape[0], x0:x0 + sub.shape[1]]
        for piece, is_merged in _region_pieces(sub, bgr_box, p, r_min, min_area_det):
            out.append((x0, y0, piece, is_merged))
    return out


def _region_pieces(sub, bgr, p, r_min: float, min_area_det: float) -> list[tuple[np.ndarray, bool]]:
    """One region -> its parts as (bool mask in the region's box, merged flag)."""
    pieces = None
    if bgr is not None:
        # 8-bit Lab (L x 255 / 100, a and b + 128): a third of the float conversion's time, and
        # its rounding (under 1 unit) is far below the colour differences that split (30)
        pieces = split_by_colour(sub, cv2.cvtColor(bgr, cv2.COLOR_BGR2LAB), min_area_det, p.colour_split)
    # each colour piece may still hold touching parts; each split lobe is looked at again
    work = [(sub, 0)] if pieces is None else [((pieces == c).view(np.uint8), 0)
                                              for c in range(1, int(pieces.max()) + 1)]
    found = []
    while work:
        piece, depth = work.pop()
        if not piece.any():
            continue
        decision, parts = _analyse(piece, p, r_min, min_area_det, bgr)
        if decision == "split" and depth < MAX_SPLIT_DEPTH:
            work.extend(((parts == k).view(np.uint8), depth + 1) for k in range(1, int(parts.max()) + 1))
            continue
        found.append((piece.view(bool), decision == "merged"))  # (0/1 bytes: a bool view)
    return found


KMEANS_SEED = 0x5EED


def split_by_colour(sub: np.ndarray, lab_img: np.ndarray, min_area: float, min_delta_e: float):
    """Split a region into parts of clearly different colour that each own part of its outline.

    `lab_img`: the region's box in OpenCV's 8-bit CIE Lab (uint8 (h, w, 3): L x 255 / 100, a + 128,
    b + 128); `min_delta_e` in CIE Lab units.

    Two colour clusters (k-means in CIE Lab) count as two touching parts only when both form a
    large connected piece that reaches the region's outline: pills in a blister pack or a
    highlight on metal lie inside their part and do not split it. Returns a label image
    (1..k inside the region) or None.
    """
    area = cv2.countNonZero(sub)
    if area < 2 * min_area:
        return None
    _, std = cv2.meanStdDev(lab_img, mask=sub)
    if float((std.ravel() * LAB_U8_WEIGHT).max()) < 0.25 * min_delta_e:
        return None  # one colour: nothing to split
    mask = sub.view(bool)
    px = pick(lab_img, mask) * LAB_U8_WEIGHT  # (float32; the offsets of a and b do not matter to k-means)
    # the two colours from an even sample of the pixels (k-means' time grows with their number),
    # then every pixel to the nearer of them
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 10, 0.5)
    # k-means++ draws its first centres from OpenCV's process-wide generator: seeded here, a region splits
    # the same whatever was segmented before it (the same frame gave other outlines on a second call)
    cv2.setRNGSeed(KMEANS_SEED)
    _, _, centres = cv2.kmeans(px[::max(1, len(px) // KMEANS_SAMPLES)], 2, None, crit, 1, cv2.KMEANS_PP_CENTERS)
    c0, c1 = centres.astype(np.float64)
    if np.linalg.norm(c0 - c1) < min_delta_e:
        return None
    # |x - c1| < |x - c0| exactly when x . (c1 - c0) > (|c1|^2 - |c0|^2) / 2
    nearer_c1 = px @ (c1 - c0).astype(np.float32) > np.float32(0.5 * (c1 @ c1 - c0 @ c0))
    cl = np.zeros(sub.shape, np.uint8)
    cl[mask] = nearer_c1.view(np.uint8) + 1
    outline = mask & (cv2.erode(sub, np.ones((3, 3), np.uint8)) == 0)
    n_out = int(outline.sum())
    seeds = np.zeros(sub.shape, np.int32)
    k = 0
    for c in (1, 2):
        piece = cv2.morphologyEx((cl == c).view(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        # (connectedComponentsWithStats is ten times slower than labelling and counting)
        n, comp = cv2.connectedComponents(piece, connectivity=8)
        areas = np.bincount(comp.ravel(), minlength=n)
        for j in range(1, n):
            if areas[j] < min_area:
                continue  # a speck of colour
            sel = comp == j
            # edge pixels mix with the tray's colour: a piece owns the outline it comes near
            reach = cv2.dilate(sel.view(np.uint8), np.ones((7, 7), np.uint8)) > 0
            # and is a body, not a band: a part's own wall seen from the side is a thin strip
            thick = float(cv2.distanceTransform(sel.view(np.uint8), cv2.DIST_L2, 3).max()) >= MIN_PIECE_HALF_WIDTH
            if (outline & reach).sum() >= 0.15 * n_out and thick:
                k += 1
                seeds[sel] = k
    if k < 2:
        return None
    return _nearest_label(seeds, sub)  # every pixel of the region goes to the nearest seed


def _nearest_label(parts: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Extend labels (1..k) to every pixel of `region` by nearest labelled pixel."""
    seeds = parts > 0
    _, nearest = cv2.distanceTransformWithLabels((~seeds).astype(np.uint8), cv2.DIST_L2, 5,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(nearest.max()) + 1, np.int32)
    lut[nearest[seeds]] = parts[seeds]
    return np.where(region > 0, lut[nearest], 0)


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """The mask (0/1 uint8) with every region not reachable from the border filled."""
    flood = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    cv2.floodFill(flood, None, (0, 0), 1)
    # reached from the border: 1 in `flood` and not in the mask; everything else is filled
    return cv2.bitwise_or(mask, 1 - flood[1:-1, 1:-1])


def _analyse(sub: np.ndarray, p, r_min: float, min_area: float, bgr: np.ndarray | None):
    # (outer contours are the same with the holes filled or not)
    contours, _ = cv2.findContours(sub, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if len(contours) == 1:
        hull_area = cv2.contourArea(cv2.convexHull(contours[0]))
        if hull_area > 0 and cv2.contourArea(contours[0]) / hull_area > CONVEX_SOLIDITY:
            return "one", None  # (nearly) convex: no neck, nothing to split
    with_holes, sub = sub, fill_holes(sub)  # holes would put false saddles into the distance transform
    dt = cv2.distanceTransform(sub, cv2.DIST_L2, 5)
    peak = float(dt.max())
    if peak < 2 * r_min:
        return "one", None
    levels = np.arange(1.0, peak, max(1.0, peak / 12))
    for level in levels[_levels_that_fall_apart(dt, levels)]:  # (at the others n <= 2: nothing to look at)
        n, cores = cv2.connectedComponents(cv2.compare(dt, _below_f32(level), cv2.CMP_GT), connectivity=8)
        if n <= 2:
            continue
        idx = np.arange(1, n)
        inside = cores > 0
        peak_of = np.zeros(n)
        np.maximum.at(peak_of, pick(cores, inside), pick(dt, inside))
        peaks = peak_of[1:]
        areas = np.bincount(cores.ravel(), minlength=n)[1:]
        big = idx[(peaks >= np.maximum(r_min, level / p.neck_flag)) & (areas >= 3)]
        if len(big) < 2:
            continue
        lobe_peaks = peak_of[big]
        is_big = np.zeros(n, np.uint8)
        is_big[big] = 1
        grown = dilate_ellipse(is_big[cores], 2 * int(level) + 3)
        cover = float((grown.view(bool) & sub.view(bool)).sum()) / float(sub.sum())
        if cover < COVER_MIN:
            # lobes joined by bars or arms: one part with a shape of its own; but three or more
            # separate lobes in one region are a heap of parts
            return ("merged" if len(big) >= 3 else "one"), None
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
                           markers.copy())
        parts = _lobes(ws, len(big), sub, with_holes, min_area, _fill_lines)
        if parts is None:
            return "merged", None
        grey = None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)  # (only needed here)
        if _seam_visible(parts, ws, grey, p.seam_contrast_dn):
            return "split", parts
        # lobes of other sizes (discs of two sizes) meet beside the neck's middle, where the distance
        # transform cuts: cut again from the same lobes along the image's own edges. Parts that touch at
        # a neck meet along a line no longer than it is wide; a longer cut found some other edge. Equal
        # lobes meet in the middle: there a cut along the image found a highlight's edge on one part with
        # a waist (rendered metal twin discs: 13 of 100 split, none flagged) and is not tried
        if lobe_peaks.min() < UNEQUAL_LOBES * lobe_peaks.max():
            ws = cv2.watershed(np.ascontiguousarray(bgr), markers)
            inner = cv2.erode(sub, np.ones((5, 5), np.uint8)) > 0  # (as `_seam_visible`: the cut's ends left out)
            if np.count_nonzero((ws == -1) & inner) <= 2 * level * (len(big) - 1):
                parts = _lobes(ws, len(big), sub, with_holes, min_area, _nearest_label)
                if parts is not None and _seam_visible(parts, ws, grey, p.seam_contrast_dn):
                    return "split", parts
        # a neck but no seam in the image: one part with a waist, or two parts that touch so
        # closely that nothing shows. Flag it: a false alarm costs a look, a wrong outline a part.
        return "merged", None
    return "one", None


def _lobes(ws: np.ndarray, n: int, sub: np.ndarray, with_holes: np.ndarray, min_area: float, fill
           ) -> np.ndarray | None:
    """The watershed's lobes 1..n over the region, or None if one is a speck. `fill` gives the region's
    unlabelled pixels to a lobe: the watershed lines (-1) on the distance transform (`_fill_lines`); on the
    image also what the flood from outside reached along a dark gap or a blurred rim (`_nearest_label`)."""
    parts = fill(np.where((ws >= 1) & (ws <= n) & (sub > 0), ws, 0), sub)
    parts[with_holes == 0] = 0  # the parts keep their holes (a washer split off its neighbour)
    if min(int((parts == k).sum()) for k in range(1, n + 1)) < min_area:
        return None
    return parts


DIRECT_ELLIPSE_MAX_PX = 51  # larger elliptic kernels: dilated row by row (OpenCV's time grows with the kernel's area)


def dilate_ellipse(mask: np.ndarray, size_px: int) -> np.ndarray:
    """cv2.dilate(mask, the MORPH_ELLIPSE kernel of size_px x size_px (odd)) of a 0/1 uint8 mask,
    0/1 uint8, bit for bit. Above DIRECT_ELLIPSE_MAX_PX the kernel is taken row by row: each of its
    rows is a run of half-width w centred on the anchor, so a pixel is reached from the row dy away
    when that row has a set pixel within w along it (the rows' distances to their nearest set pixel
    are computed once). A 235 px kernel on a 540 x 513 region: 114 -> 8 ms (tested against OpenCV)."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size_px, size_px))
    if size_px <= DIRECT_ELLIPSE_MAX_PX or size_px > 2 * 254 + 1:  # (the rows' distances saturate at 255)
        return cv2.dilate(mask, kernel)
    half_widths = kernel.sum(axis=1) // 2
    r = size_px // 2
    h = mask.shape[0]
    dist = _row_distance_u8(mask)
    out = np.zeros_like(mask)
    for i, w in enumerate(half_widths):
        dy = i - r  # the kernel's row dy below the anchor reaches pixels dy rows above its set pixels
        if abs(dy) >= h:
            continue
        src, dst = dist[max(dy, 0):h + min(dy, 0)], out[max(-dy, 0):h + min(-dy, 0)]
        # (row slices of contiguous arrays: OpenCV works on them in place)
        cv2.bitwise_or(dst, cv2.threshold(src, float(w), 1, cv2.THRESH_BINARY_INV)[1], dst=dst)
    return out


def _row_distance_u8(mask: np.ndarray) -> np.ndarray:
    """Per pixel, the distance (px) along its row to the nearest set pixel of the 0/1 mask, at most
    255 (rows without one: 255), uint8."""
    w = mask.shape[1]
    x = np.arange(w, dtype=np.int32)
    on = mask.view(bool)
    left = np.maximum.accumulate(np.where(on, x, -256), axis=1)  # (-256, w + 255: beyond 255 either way)
    right = np.minimum.accumulate(np.where(on, x, w + 255)[:, ::-1], axis=1)[:, ::-1]
    return np.minimum(np.minimum(x - left, right - x), 255).astype(np.uint8)


def _levels_that_fall_apart(dt: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """For each level L, does {dt > L} have two or more 8-connected pieces? bool (len(levels),).

    All levels are labelled in one call (most regions never fall apart, and one call over a
    stack is half the time of one per level): the thresholded images are stacked with a blank
    row between them, so no piece crosses from one level to the next, and labels are numbered
    in raster order, so each level's labels follow the previous level's: a level has as many
    pieces as its largest label exceeds the largest label above it (tested against labelling
    each level alone).
    """
    h, w = dt.shape
    thr = levels.astype(np.float32)  # `_below_f32` of every level at once
    thr = np.where(thr > levels, np.nextafter(thr, np.float32(-np.inf)), thr)
    stack = np.zeros((len(levels), h + 1, w), np.uint8)
    np.greater(dt, thr[:, None, None], out=stack[:, :h].view(bool))  # (the same as cv2.compare: exact bounds)
    _, lab = cv2.connectedComponents(stack.reshape(-1, w), connectivity=8)
    top = np.maximum.accumulate(lab.reshape(len(levels), -1).max(axis=1))
    return np.diff(top, prepend=0) >= 2


def _below_f32(x: float) -> float:
    """The largest float32 at most x: for float32 values v, v > it exactly when v > x."""
    t = np.float32(x)
    return float(np.nextafter(t, np.float32(-np.inf)) if t > x else t)


def _seam_visible(parts: np.ndarray, ws: np.ndarray, grey: np.ndarray | None, contrast_dn: float) -> bool:
    """Does the image show where the lobes meet: a thin dark or bright line along the cut (the
    gap, walls, a crease) or a change of brightness across it (different parts)?"""
    if grey is None:
        return True
    inner = cv2.erode((parts > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # away from the outline
    cut = (ws == -1) & inner
    if cut.sum() < 2:
        return True
    near = (cv2.dilate(cut.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0) & ~(
        cv2.dilate(cut.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & inner
    if not near.any():
        return True
    g = grey.astype(np.float32)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    line = np.maximum(cv2.morphologyEx(g, cv2.MORPH_BLACKHAT, k), cv2.morphologyEx(g, cv2.MORPH_TOPHAT, k))
    on_cut = cv2.dilate(cut.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    valley = float(np.median(np.max([line[on_cut]], axis=0))) - float(np.median(line[near]))
    sides = [float(np.median(g[near & (parts == k)])) for k in np.unique(parts[near]) if k > 0]
    step = max(sides) - min(sides) if len(sides) > 1 else 0.0
    return valley > 0.5 * contrast_dn or step > contrast_dn


def _fill_lines(parts: np.ndarray, sub: np.ndarray) -> np.ndarray:
    holes = (sub > 0) & (parts == 0)
    if not holes.any():
        return parts
    grown = cv2.dilate(parts.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)
    parts = parts.copy()
    parts[holes] = grown[holes]
    return parts
