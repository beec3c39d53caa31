"""The part mask's regions: labelled per group of touching work boxes, specks dropped, touching
parts split (touching.py) (segmentation step 4)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.work_boxes import merged_boxes

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams


def split_regions(mask: np.ndarray, boxes, p: SegmentParams, scale: int, det_u8: np.ndarray | None = None
                  ) -> list[tuple[int, int, np.ndarray, bool]]:
    """The mask's parts as (x0, y0, piece bool mask in a box at (x0, y0), merged); specks
    dropped, touching parts split (`det_u8`: the 8-bit detection image, for colours and seams)."""
    min_area = p.min_area_px / scale ** 2
    regions = label_regions(mask, boxes, min_area, margin_px=2)
    if not p.split_touching:
        return [(x0, y0, sub.astype(bool), False) for x0, y0, sub in regions]
    from cell.vision.touching import split_necks

    return split_necks(regions, p, min_area, det_u8)


def label_regions(mask: np.ndarray, boxes, min_area: float, margin_px: int = 0
                  ) -> list[tuple[int, int, np.ndarray]]:
    """8-connected regions of `mask` (uint8 0/1, zero outside `boxes`) of at least `min_area`
    pixels, each as (x0, y0, uint8 0/1 mask of the region alone in its bounding box grown by
    `margin_px`, clipped to the frame), in the order of their first pixel within each group of
    touching boxes. Labelling box groups instead of the whole frame saves whole-frame passes."""
    h, w = mask.shape
    out = []
    for gx0, gy0, gx1, gy1 in _touching_groups(boxes):
        crop = mask[gy0:gy1, gx0:gx1]
        # (connectedComponentsWithStats is ten times slower than labelling and counting)
        n, lab = cv2.connectedComponents(crop, connectivity=8)
        if n <= 1:
            continue
        # the few large regions' boxes one by one (scipy's find_objects for every speck takes longer)
        for k in np.flatnonzero(np.bincount(lab.ravel(), minlength=n)[1:] >= min_area) + 1:
            region = cv2.compare(lab, float(k), cv2.CMP_EQ) & 1  # (0/1 bytes)
            bx, by, bw, bh = cv2.boundingRect(region)
            y0, x0 = max(by + gy0 - margin_px, 0), max(bx + gx0 - margin_px, 0)
            y1, x1 = min(by + bh + gy0 + margin_px, h), min(bx + bw + gx0 + margin_px, w)
            sub = np.zeros((y1 - y0, x1 - x0), np.uint8)
            # the region's pixels, copied from the group's (the margin may reach past the group)
            cy0, cx0 = max(y0, gy0), max(x0, gx0)
            cy1, cx1 = min(y1, gy1), min(x1, gx1)
            sub[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0] = region[cy0 - gy0:cy1 - gy0, cx0 - gx0:cx1 - gx0]
            out.append((x0, y0, sub))
    return out


def _touching_groups(boxes) -> list[tuple[int, int, int, int]]:
    """Bounding boxes of groups of boxes (x0, y0, x1, y1) that overlap or touch (also at a
    corner): 8-connected regions of a mask that is 0 outside the boxes never cross groups."""
    return [tuple(g) for g in merged_boxes(boxes, touching=True)]
