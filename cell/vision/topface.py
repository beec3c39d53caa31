"""The top face of a part inside its silhouette, for parts whose walls the camera sees.

From 800 mm a part of height h at distance r from the image of the vertical shows its walls
on the side facing that point, about r * h / (800 - h) wide: a 30 mm heatsink 200 mm off
the centre shows 8 mm of wall. The silhouette is then the top face swept down to the bottom,
and between fins, in deep holes and in tooth gaps the walls hide the tray, so the silhouette
alone cannot give the outline (a heatsink's fins come out as a solid block, a 45 mm housing's
bolt holes are not seen through). The top face can: under light from above it is brighter
than the walls. This module finds it (pixels of the silhouette not darker than the top's level
by a wall's shading) and accepts it only when it explains the silhouette: the top face swept
by the parallax between the top and the bottom plane must give back the silhouette, within
a band of a pixel or two along its boundary. A face that does not (walls as bright as the top,
dark markings wider than the walls' sweep, highlights) is refused and the caller maps the
silhouette instead. A dark marking no wider than the walls' sweep looks exactly like a hole too
deep to see through and is taken for one (one image cannot tell them apart).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

# (walls.py imports this module lazily)
from cell.vision.rings import signed_area
from cell.vision.segment import calibration_size_factor
from cell.vision.subpixel import refine_rings

MIN_WALL_PX = 1.0  # narrower walls: the two planes map the silhouette within half a pixel
WALL_SHADE = 0.81  # a wall pixel is darker than this x the top's level (walls: about 0.6 - 0.7)
TOP_LEVEL_PERCENTILE = 60  # the top face is most of the silhouette; highlights are a few per cent
# the face's opening and the sweep's test on the default camera (0.5 mm/px); a camera with f times its
# px per mm (`calibration_size_factor`) takes lengths x f and areas x f^2: the silhouette it checks
# comes from a detection of the default's pixel size in mm (segment.py), so its flaws are as large in
# mm, and so is the band of an edge's blur (a strip of it enclosed by the face is no hole). A close-up
# camera whose frames are no larger than the default's is detected finer than that (segment.py keeps 1/2
# there): its opening is then wider in pixels than its silhouette's flaws need; not tried on real frames
SWEEP_TOLERANCE = 1.5  # silhouette pixels the swept top face may miss or add, per pixel of perimeter
THICK_MISMATCH_PX = 40  # the largest region of the mismatch 3 px thick (corners and shading leave up to ~20)
THICK_PX = 3  # the face is opened by this, and the mismatch's regions this thick are looked at
_SUBPIX = 4  # fillPoly fractional bits


def top_face_px(seg, frame: np.ndarray, cal, z_top_mm: float, z_bottom_mm: float, params
                ) -> tuple[np.ndarray, list[np.ndarray]] | None:
    """The top face's outline and holes (CONTRACT-frame pixels, sub-pixel), or None.

    Parameters
    ----------
    seg : Segment
        One part's region (a merged one is accepted only when one face explains all of it).
    frame : ndarray (h, w, 3) uint8
        The frame the segment came from.
    cal : Calibration
        With a pose (the parallax between two planes needs one).
    z_top_mm, z_bottom_mm : float
        The part is a prism between these heights.
    params : SegmentParams
        For the sub-pixel refinement and the smallest hole.

    Returns None when the walls are too narrow to matter or the face found does not explain the
    silhouette; the caller then maps the silhouette.
    """
    outline = np.asarray(seg.outline_px, float)
    c = outline.mean(axis=0)
    # where the top's points at and next to c land on the bottom plane: the sweep from top to bottom
    # (it grows with the distance from the image of the vertical: affine over the part)
    probe = c + np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    shifts = cal.mm_to_px(cal.px_to_mm(probe, z_top_mm), z_bottom_mm) - probe
    d = shifts[0]
    gradient = np.column_stack([shifts[1] - d, shifts[2] - d]) / 10.0  # d(p) = d + gradient @ (p - c)
    w = float(np.hypot(*d))
    if not np.isfinite(w) or w < MIN_WALL_PX:
        return None
    h_img, w_img = frame.shape[:2]
    margin = int(np.ceil(w)) + 4
    u0, v0 = np.maximum(np.floor(outline.min(axis=0)).astype(int) - margin, 0)
    u1, v1 = np.minimum(np.ceil(outline.max(axis=0)).astype(int) + margin, [w_img, h_img])
    origin = np.array([u0 + 0.5, v0 + 0.5])  # fillPoly and contours count pixel centres at integers

    def raster(ring):
        return np.round((ring - origin) * (1 << _SUBPIX)).astype(np.int32)

    silhouette = np.zeros((v1 - v0, u1 - u0), np.uint8)
    cv2.fillPoly(silhouette, [raster(outline)], 1, cv2.LINE_8, shift=_SUBPIX)
    for hole in seg.holes_px:
        cv2.fillPoly(silhouette, [raster(np.asarray(hole, float))], 0, cv2.LINE_8, shift=_SUBPIX)
    inside = silhouette > 0
    if inside.sum() < 50:
        return None
    brightness = cv2.GaussianBlur(frame[v0:v1, u0:u1].astype(np.float32).sum(axis=2), (3, 3), 0.8)
    level = float(np.percentile(brightness[inside], TOP_LEVEL_PERCENTILE))
    face = (inside & (brightness >= WALL_SHADE * level)).astype(np.uint8)
    px_factor = calibration_size_factor(cal)  # the camera's px per mm over the default camera's
    k = _odd_px(THICK_PX, px_factor)  # 3 x 3 on the default camera: 1.5 mm
    face = cv2.morphologyEx(face, cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
    n, labels = cv2.connectedComponents(face, connectivity=8)
    if n < 2:
        return None
    face = (labels == 1 + int(np.argmax(np.bincount(labels.ravel())[1:]))).astype(np.uint8)
    perimeter = cv2.arcLength(raster(outline).astype(np.float32) / (1 << _SUBPIX), True)
    if not _explains(face, silhouette, d, gradient, c - origin, perimeter, px_factor):
        return None
    contours, hierarchy = cv2.findContours(face, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    outers, holes = [], []
    for k, cc in enumerate(contours):
        ring = cc[:, 0, :].astype(float) + origin
        if hierarchy[0][k][3] < 0:
            outers.append(ring)
        elif len(ring) >= 5 and cv2.contourArea(cc) >= params.min_hole_area_px:
            holes.append(ring)
    outer = max(outers, key=lambda r: abs(signed_area(r)))
    # refine like every outline, over a short range (a fin's top is a few pixels wide between two
    # walls). The contours run through the centres of the face's boundary pixels, half a pixel
    # inside its edge on average: a point where no edge is found is moved out by that much
    rings, is_hole = [outer, *holes], [False] + [True] * len(holes)
    refined = refine_rings(frame, rings, is_hole, replace(params, refine_range_px=2.0, scale=1))
    out = [np.where(np.all(f == r, axis=1)[:, None], _moved_out(r, 0.5, h), f)
           for r, f, h in zip(rings, refined, is_hole, strict=True)]
    return out[0], out[1:]


def _odd_px(px: int, px_factor: float) -> int:
    """The odd kernel size nearest `px` (odd) x px_factor: `px` on the default camera."""
    return 2 * round((px * px_factor - 1) / 2) + 1


def _moved_out(ring: np.ndarray, by_px: float, hole: bool) -> np.ndarray:
    """The ring moved by_px along its normal out of the face (into the hole for a hole)."""
    tang = np.roll(ring, -1, axis=0) - np.roll(ring, 1, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
    sign = (1.0 if signed_area(ring) > 0 else -1.0) * (-1.0 if hole else 1.0)
    return ring + by_px * sign * np.column_stack([tang[:, 1], -tang[:, 0]])


def _explains(face: np.ndarray, silhouette: np.ndarray, d: np.ndarray, gradient: np.ndarray, c: np.ndarray,
              perimeter_px: float, px_factor: float = 1.0) -> bool:
    """Does the top face swept from top to bottom (each pixel p by f * (d + gradient @ (p - c)),
    f from 0 to 1) give back the silhouette? Rasterising leaves a band of a pixel or two along
    the boundary; anything thicker (silhouette the swept face misses: a dark label taken for a
    hole, wider than the walls' sweep fills; swept face beyond the silhouette: walls as bright
    as the top taken for top) is refused, and so is a total over SWEEP_TOLERANCE pixels per
    pixel of perimeter. c: the point where the shift is d, in the masks' pixel indices. px_factor: the
    camera's px per mm over the default camera's (the thickness and both tolerances grow with it)."""
    steps = int(np.ceil(np.hypot(*d))) + 1
    swept = face.copy()
    size = (face.shape[1], face.shape[0])
    for s in range(1, steps + 1):
        f = s / steps
        a = np.eye(2) + f * gradient
        shift = np.column_stack([a, f * d - f * gradient @ c]).astype(np.float32)
        swept |= cv2.warpAffine(face, shift, size, flags=cv2.INTER_NEAREST)
    swept = cv2.morphologyEx(swept, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    mismatch = (swept != silhouette).astype(np.uint8)
    t = _odd_px(THICK_PX, px_factor)
    thick = cv2.erode(mismatch, np.ones((t, t), np.uint8))  # what is left of regions t px thick or more
    n, _, stats, _ = cv2.connectedComponentsWithStats(thick, connectivity=8)
    if n > 1 and stats[1:, cv2.CC_STAT_AREA].max() > THICK_MISMATCH_PX * px_factor ** 2:
        return False
    return int(np.count_nonzero(mismatch)) <= SWEEP_TOLERANCE * px_factor * perimeter_px
