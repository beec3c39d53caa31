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
about a pixel along its boundary. A face that does not (walls as bright as the top, dark
markings wider than a wall, highlights) is refused and the caller maps the silhouette instead.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

MIN_WALL_PX = 1.0  # narrower walls: the two planes map the silhouette within half a pixel
WALL_SHADE = 0.81  # a wall pixel is darker than this x the top's level (walls: about 0.6 - 0.7)
TOP_LEVEL_PERCENTILE = 60  # the top face is most of the silhouette; highlights are a few per cent
SWEEP_TOLERANCE = 1.5  # silhouette pixels the swept top face may miss or add, per pixel of perimeter
_SUBPIX = 4  # fillPoly fractional bits


def top_face_px(seg, frame: np.ndarray, cal, z_top_mm: float, z_bottom_mm: float, params
                ) -> tuple[np.ndarray, list[np.ndarray]] | None:
    """The top face's outline and holes (CONTRACT-frame pixels, sub-pixel), or None.

    Parameters
    ----------
    seg : Segment
        One part's region (not a merged one).
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
    from cell.vision.segment import _signed_area, refine_rings

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
    face = cv2.morphologyEx(face, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels = cv2.connectedComponents(face, connectivity=8)
    if n < 2:
        return None
    face = (labels == 1 + int(np.argmax(np.bincount(labels.ravel())[1:]))).astype(np.uint8)
    perimeter = cv2.arcLength(raster(outline).astype(np.float32) / (1 << _SUBPIX), True)
    if not _explains(face, silhouette, d, gradient, c - origin, perimeter):
        return None
    contours, hierarchy = cv2.findContours(face, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    outers, holes = [], []
    for k, cc in enumerate(contours):
        ring = cc[:, 0, :].astype(float) + origin
        if hierarchy[0][k][3] < 0:
            outers.append(ring)
        elif len(ring) >= 5 and cv2.contourArea(cc) >= params.min_hole_area_px:
            holes.append(ring)
    outer = max(outers, key=lambda r: abs(_signed_area(r)))
    # the face's boundary is pixel-exact; refine it like every outline, over a short range (a fin's
    # top is a few pixels wide between two walls)
    rings = refine_rings(frame, [outer, *holes], [False] + [True] * len(holes),
                         replace(params, refine_range_px=2.0, scale=1))
    return rings[0], rings[1:]


def _explains(face: np.ndarray, silhouette: np.ndarray, d: np.ndarray, gradient: np.ndarray, c: np.ndarray,
              perimeter_px: float) -> bool:
    """Does the top face swept from top to bottom (each pixel p by f * (d + gradient @ (p - c)),
    f from 0 to 1) give back the silhouette, within SWEEP_TOLERANCE pixels per pixel of its
    perimeter? c: the point where the shift is d, in the masks' pixel indices."""
    steps = int(np.ceil(np.hypot(*d))) + 1
    swept = face.copy()
    size = (face.shape[1], face.shape[0])
    for s in range(1, steps + 1):
        f = s / steps
        a = np.eye(2) + f * gradient
        shift = np.column_stack([a, f * d - f * gradient @ c]).astype(np.float32)
        swept |= cv2.warpAffine(face, shift, size, flags=cv2.INTER_NEAREST)
    swept = cv2.morphologyEx(swept, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    return int(np.count_nonzero(swept != silhouette)) <= SWEEP_TOLERANCE * perimeter_px
