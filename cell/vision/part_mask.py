"""The part mask at detection resolution (segmentation steps 2 and 3): in each work box, the pixels
whose colour change marks a part, with the weaker evidence connected to them, and the shadow-like
pixels that are material."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.colour_change import colour_change, evidence, noise_spreads
from cell.vision.detection import smoothed_copies
from cell.vision.shadowlike import material_shadowlike
from cell.vision.sharp_edges import edge_bounds_sq, gradient_sq, texture_gradient
from cell.vision.touching import pick
from cell.vision.work_boxes import work_boxes

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams


def part_mask(det: np.ndarray, bg: np.ndarray, p: SegmentParams, scale: int, smoothed=None,
              bg_coarse: np.ndarray | None = None) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
    """uint8 mask (0/1) of part pixels at detection resolution (steps 2 and 3), and the boxes
    (x0, y0, x1, y1) outside which it is 0. Only those boxes around what differs from the tray
    are looked at closely. `smoothed`: `smoothed_copies(det)` if made already; `bg_coarse`: the
    tray at 1 / COARSE size if known (else `bg` averaged down)."""
    sm, sparse, coarse = smoothed or smoothed_copies(det)
    # spread from the quietest quarter of the frame (the tray), valid while the tray covers a
    # quarter of the view: the 25th percentile of |N(0, s)| is 0.32 s
    _, _, chroma_dn, bright_dn = colour_change(sparse, np.ascontiguousarray(bg[::4, ::4]))
    noise_c, noise_b = noise_spreads(chroma_dn, bright_dn)
    bounds_sq = edge_bounds_sq(p, scale, texture_gradient(sm, bg))
    h, w = det.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    if bg_coarse is None:
        bg_coarse = cv2.resize(bg, coarse.shape[1::-1], interpolation=cv2.INTER_AREA)
    boxes = work_boxes(coarse, bg_coarse, p, (h, w))
    for x0, y0, x1, y1 in boxes:
        mask[y0:y1, x0:x1] = _mask_in_box(sm[y0:y1, x0:x1], bg[y0:y1, x0:x1], p, scale, noise_c, noise_b,
                                          bounds_sq, (x0, y0), (h, w))
    return mask, boxes


def _mask_in_box(sm, bg, p: SegmentParams, scale: int, noise_c: float, noise_b: float, bounds_sq, origin=(0, 0),
                 det_hw=None):
    """Part mask (uint8 0/1) in one box (steps 2 and 3). `bounds_sq`: the squared gradients of r above
    which an edge is sharp, around any shadow-like region and around one no part is near (`edge_bounds_sq`)."""
    r, chroma, chroma_dn, bright_dn = colour_change(sm, bg)
    strong = evidence(r, chroma, chroma_dn, bright_dn, p, 1.0, noise_c, noise_b)
    if p.hysteresis < 1.0:  # weaker evidence counts where it is connected to strong evidence,
        # but not in shadow (a shadow next to a part mixes with the part's colour at its edge)
        weak = (evidence(r, chroma, chroma_dn, bright_dn, p, p.hysteresis, noise_c, noise_b)
                & ~(r < 1.0 - p.brighter_min)) | strong
        n, lab = cv2.connectedComponents(weak.view(np.uint8), connectivity=8)
        seeded = np.zeros(n, bool)
        seeded[pick(lab, strong)] = True
        seeded[0] = False
        strong = np.take(seeded, lab)
    darker = (r < 1.0 - p.brighter_min) & ~strong
    if not p.shadow_aware:
        strong |= darker
        darker[:] = False
    mask = strong.astype(np.uint8)
    if darker.any():
        # shadow-like pixels enclosed by a part are its holes (the tray in the part's shadow)
        from cell.vision.touching import fill_holes

        enclosed = fill_holes(strong.view(np.uint8)).view(bool) & ~strong
        shadowlike = darker & ~enclosed
        grad_sq = gradient_sq(r)
        sharp_sq, crisp_sq = bounds_sq
        mask |= material_shadowlike(grad_sq, strong, shadowlike, p, scale, sharp_sq, origin, det_hw)
        if crisp_sq < sharp_sq:  # (detected at 1 / 2 or coarser) grey parts no part is near, by a crisp edge
            mask |= material_shadowlike(grad_sq, strong, shadowlike, p, scale, crisp_sq, origin, det_hw, lone=True)
    k = np.ones((3, 3), np.uint8)
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, k)
