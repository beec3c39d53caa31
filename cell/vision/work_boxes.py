"""Where to look closely: boxes around everything that differs from the tray, found on a coarse copy
(the part mask is worked out only inside them; outside them it is 0)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.colour_change import colour_change, evidence, noise_spreads

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams


BOX_MARGIN_PX = 12  # detection px around what differs: room for weak edges, shadows' tails, walls
COARSE_EVIDENCE = 0.8  # x the weak-evidence thresholds
BOX_FULL_FRAME = 0.6  # when the boxes cover more of the frame than this, one box for all


def work_boxes(coarse, bg_coarse, p: SegmentParams, det_hw: tuple[int, int]) -> list[tuple[int, int, int, int]]:
    """Disjoint boxes (detection px) that hold everything that differs from the tray, with a
    margin: found on a coarse copy with the weak-evidence thresholds lowered (averaging keeps a
    part's change and lowers the noise; thin parts lose contrast). Each box holds whole clusters
    of changed pixels. `coarse`, `bg_coarse`: the blurred detection image and the tray at
    1 / COARSE size; `det_hw` the detection image's size."""
    h, w = det_hw
    ch, cw = coarse.shape[:2]
    r, chroma, chroma_dn, bright_dn = colour_change(coarse, bg_coarse)
    # the coarse copy's own noise (averaging lowers it), measured like the frame's
    noise_c, noise_b = noise_spreads(chroma_dn, bright_dn)
    changed = (evidence(r, chroma, chroma_dn, bright_dn, p, COARSE_EVIDENCE * p.hysteresis, noise_c, noise_b)
               | (r < 1.0 - COARSE_EVIDENCE * p.brighter_min))
    n, lab = cv2.connectedComponents(changed.view(np.uint8), connectivity=8)
    if n <= 1:
        return []
    from scipy import ndimage

    m = BOX_MARGIN_PX
    boxes = [[max(sl[1].start * w // cw - m, 0), max(sl[0].start * h // ch - m, 0),
              min(sl[1].stop * w // cw + m, w), min(sl[0].stop * h // ch + m, h)]
             for sl in ndimage.find_objects(lab) if sl is not None]
    boxes = merged_boxes(boxes)  # overlapping boxes become one, so that no box cuts through a cluster
    if sum((b[2] - b[0]) * (b[3] - b[1]) for b in boxes) > BOX_FULL_FRAME * w * h:
        return [(0, 0, w, h)]
    return [tuple(b) for b in boxes]


def merged_boxes(boxes, touching: bool = False) -> list[list[int]]:
    """Boxes (x0, y0, x1, y1) that overlap merged into their bounding box until none overlaps; with `touching`,
    boxes that only touch (also at a corner) too."""
    groups = [list(b) for b in boxes]
    merged = True
    while merged:
        merged = False
        out: list[list[int]] = []
        for bx in groups:
            for o in out:
                if touching:
                    meet = bx[0] <= o[2] and o[0] <= bx[2] and bx[1] <= o[3] and o[1] <= bx[3]
                else:
                    meet = bx[0] < o[2] and o[0] < bx[2] and bx[1] < o[3] and o[1] < bx[3]
                if meet:
                    o[:] = [min(o[0], bx[0]), min(o[1], bx[1]), max(o[2], bx[2]), max(o[3], bx[3])]
                    merged = True
                    break
            else:
                out.append(bx)
        groups = out
    return groups
