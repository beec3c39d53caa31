"""Segments -> mm on the part's top plane (`segment_to_mm`): where the camera sees a part's walls, the
silhouette's edge is the part's bottom edge, mapped at the bottom's height; the top face, when found
(topface.py), is mapped at the top."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.detection import as_bgr
from cell.vision.rings import signed_area

if TYPE_CHECKING:
    from cell.vision.segment import Segment, SegmentParams


def segment_to_mm(seg: Segment, cal, z_mm: float, z_bottom_mm: float | None = None,
                  frame: np.ndarray | None = None, params: SegmentParams | None = None):
    """Map a segment to the base frame on the plane of the part's top.

    The camera sees a part's walls on the side facing the image of the vertical (the point
    vertical lines run to, near the image centre). With `z_bottom_mm` (the part is a prism from
    z_bottom to z_mm) and the `frame`, the top face is looked for inside the silhouette
    (topface.py: brighter than the walls, and swept down to the bottom it gives back the
    silhouette); when found, its outline and holes are mapped at the top. Else the silhouette
    is mapped point by point: on the wall side the outline is the part's bottom edge when the
    wall shows, its top edge when the wall looks like the tray; with `z_bottom_mm` those
    boundary points are mapped at the bottom, and with the `frame` each point is checked in
    the image: if the band where a wall would be has the top face's colour, the point is the
    top edge after all. Cut-off regions are always mapped point by point; a merged region takes
    the top-face path only when one face explains all of it (one prism after all).

    Returns
    -------
    (outline_mm ndarray of shape (n, 2), list of hole rings (m, 2)), base frame, mm.
    """
    if z_bottom_mm is None or abs(z_bottom_mm - z_mm) < 1e-9:
        return cal.px_to_mm(seg.outline_px, z_mm), [cal.px_to_mm(hh, z_mm) for hh in seg.holes_px]
    img = None if frame is None else as_bgr(frame)
    if img is not None and not seg.cut_off and cal.has_pose:
        from cell.vision.segment import SegmentParams  # (segment.py imports this module)
        from cell.vision.topface import top_face_px

        p = (params or SegmentParams.for_calibration(cal, z_mm=z_mm)).for_frame(img.shape)
        face = top_face_px(seg, img, cal, z_mm, z_bottom_mm, p)
        if face is not None:
            return cal.px_to_mm(face[0], z_mm), [cal.px_to_mm(h, z_mm) for h in face[1]]
    vp = cal.vertical_vanishing_px()

    def ring(r: np.ndarray, hole: bool) -> np.ndarray:
        top = cal.px_to_mm(r, z_mm)
        if len(r) < 5:
            return top
        tang = np.roll(r, -2, axis=0) - np.roll(r, 2, axis=0)
        normal = np.column_stack([tang[:, 1], -tang[:, 0]]) * (1.0 if signed_area(r) > 0 else -1.0)
        if hole:
            normal = -normal
        wall_side = (normal * (r - vp)).sum(axis=1) < 0
        bottom = cal.px_to_mm(r, z_bottom_mm)
        if img is None or not wall_side.any():
            return np.where(wall_side[:, None], bottom, top)
        seen = _wall_visible(img, r, cal.mm_to_px(bottom, z_mm))
        return np.where((wall_side & seen)[:, None], bottom, top)

    return ring(seg.outline_px, False), [ring(hh, True) for hh in seg.holes_px]


WALL_MIN_PX = 1.0  # narrower walls: the two hypotheses differ by less than half a pixel's mapping
WALL_CONTRAST = 0.15  # relative colour change that shows a wall
WALL_DARK_DN = 20.0
WALL_VOTE_WINDOW = 9


def _wall_visible(img: np.ndarray, b: np.ndarray, b_top: np.ndarray) -> np.ndarray:
    """For boundary points `b` (n, 2) taken as bottom edges, with their top edges at `b_top`:
    does the band between them differ from the top face beyond it (a wall is seen)?"""
    d = b_top - b
    w = np.linalg.norm(d, axis=1)
    u = d / np.maximum(w, 1e-9)[:, None]
    t = np.column_stack([-u[:, 1], u[:, 0]])

    def sample(pts):
        offs = np.array([-1.0, 0.0, 1.0])
        q = pts[:, None, :] + offs[None, :, None] * t[:, None, :]
        mx = (q[..., 0] - 0.5).astype(np.float32)
        my = (q[..., 1] - 0.5).astype(np.float32)
        return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float32).mean(
            axis=1)

    top = sample(b_top + 2.0 * u)
    # relative to the top face's brightness: a dark part's wall is only a few DN darker than its
    # top, but brushed metal varies by as many DN from row to row
    norm = np.linalg.norm(top, axis=1) / np.sqrt(3) + WALL_DARK_DN
    diff = np.max([np.linalg.norm(sample(b + f * d) - top, axis=1) for f in (0.6, 0.8)], axis=0) / norm
    vote = (diff > WALL_CONTRAST).astype(float)
    # a wall's look changes slowly along the part: a running majority removes single misreadings
    k = WALL_VOTE_WINDOW // 2
    vote = np.mean([np.roll(vote, s) for s in range(-k, k + 1)], axis=0) > 0.5
    return (w >= WALL_MIN_PX) & vote
