"""Shadow-like pixels (darker than the tray, its chroma) that are material: regions bounded by sharp
edges (walls, grey parts), not soft-edged shadows (segmentation step 3, docs/vision.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.touching import pick

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams


WALL_FACING_COS = 0.3
EDGE_BAND_PX = 1  # a shadow-like region meets the tray across up to this many sharp pixels beyond the 5 x 5
# neighbourhood of its border (a blurred step's band of sharp pixels, docs/vision.md step 3)
PART_REACH_PX = 3  # a part's own shadow lies within this of the part (detection px): beside it, or past the
# shadow's half of the part's edge band (up to 2 px wide at the crisp edge's bound, for the darkest parts)


def material_shadowlike(grad_sq, strong, darker, p: SegmentParams, scale: int, sharp_sq: np.float32,
                        origin=(0, 0), det_hw=None, lone: bool = False) -> np.ndarray:
    """Shadow-like regions bounded by sharp edges are material (walls, grey parts), not shadow.
    `grad_sq`: `gradient_sq(r)`; `sharp_sq`: the squared gradient above which an edge is sharp (`part_mask`);
    `lone`: only the regions no part is near (within PART_REACH_PX)."""
    # |grad| / scale > sharp_edge (per full-resolution pixel), compared on the squared gradient
    # against the exact float32 bound: no square root and division over the box
    sharp = grad_sq > sharp_sq
    # cut shadow-like regions at sharp edges, so a grey part and its own shadow come apart
    cand = (darker & ~sharp).view(np.uint8)  # (bool arrays viewed as 0/1 bytes for OpenCV: no copies)
    n, lab = cv2.connectedComponents(cand, connectivity=4)
    if n <= 1:
        return np.zeros_like(cand)
    apart = np.ones(n, bool)
    if lone:  # (a part's own shadow lies beside it, or past the shadow's half of the part's edge band)
        reach = cv2.dilate(strong.view(np.uint8), np.ones((2 * PART_REACH_PX + 1,) * 2, np.uint8))
        apart = np.bincount(pick(lab, reach.view(bool)), minlength=n) == 0
        if not apart[1:].any():
            return np.zeros_like(cand)
    # judge each region by its free border, where it meets the tray (not the part it hangs on):
    # a wall ends there in a sharp edge, a shadow fades out. Where it meets the tray is looked for
    # across the edge's own band: a flat grey part's blurred edge is a band of sharp pixels 2 - 3 px
    # wide, so its region's border pixels lie 3 px from the tray, beyond the 5 x 5 neighbourhood
    # (a grey patch at 0.65 of the tray, blurred by 0.8 px: no border pixel near the tray, sharp
    # share 0, thrown away as shadow). The tray grown by EDGE_BAND_PX through sharp pixels only
    # reaches those; a shadow's fading border meets the tray itself, as before
    tray = (~(strong | darker | sharp)).view(np.uint8)
    k3 = np.ones((3, 3), np.uint8)
    for _ in range(EDGE_BAND_PX):
        tray |= cv2.dilate(tray, k3) & sharp.view(np.uint8)
    near_tray = cv2.dilate(tray, np.ones((5, 5), np.uint8)) > 0
    near_part = cv2.dilate(strong.view(np.uint8), np.ones((3, 3), np.uint8)) > 0
    # (a region's border pixels: those with a neighbour outside it)
    border = cand.view(bool) & (cv2.erode(cand, np.ones((3, 3), np.uint8)) == 0)
    border &= near_tray & ~near_part
    near_sharp = cv2.dilate(sharp.view(np.uint8), np.ones((3, 3), np.uint8)) > 0
    total = np.bincount(pick(lab, border), minlength=n).astype(float)
    sharp_count = np.bincount(pick(lab, border & near_sharp), minlength=n).astype(float)
    frac = np.divide(sharp_count, total, out=np.zeros(n), where=total > 0)
    keep = (frac > p.sharp_fraction) & apart
    keep[0] = False
    if keep.any() and strong.any() and not lone:
        ns, parts_lab = cv2.connectedComponents(strong.view(np.uint8), connectivity=8)
        inside = np.take(keep, lab)  # only the regions still in question (take: twice as fast as keep[lab])
        bx0, by0, bw, bh = cv2.boundingRect(inside.view(np.uint8))  # (they are small: look only there)
        ys, xs = np.nonzero(inside[by0:by0 + bh, bx0:bx0 + bw])
        ys += by0
        xs += bx0
        hi, lo = _labels_around(parts_lab, ys, xs, (bx0, by0, bx0 + bw, by0 + bh))
        li = lab[ys, xs]
        touch = hi > 0  # pixels next to a part (only they see a part's label)
        lt, hit, lot = li[touch], hi[touch], lo[touch]
        hi_c = np.zeros(n)
        np.maximum.at(hi_c, lt, hit)
        lo_c = np.full(n, 1e9)
        np.minimum.at(lo_c, lt, lot)
        # a shadow-like nook between two separate parts is the crevice where they meet, not a wall
        keep &= ~((hi_c > 0) & (lo_c < 1e9) & (hi_c != lo_c))
        # walls are seen only on a part's side that faces the image of the vertical; a sharp
        # strip on the other side is the part's own short shadow
        cnt = np.maximum(np.bincount(li, minlength=n), 1)
        cx, cy = np.bincount(li, xs, n) / cnt, np.bincount(li, ys, n) / cnt
        owner = hi_c.astype(int)
        h_det, w_det = det_hw or grad_sq.shape
        vp = ((np.array(p.vertical_px) / scale) if p.vertical_px is not None
              else np.array([w_det, h_det]) / 2.0) - np.asarray(origin)  # in the box's pixels
        centres = np.zeros((ns, 2))  # of the parts that own a region still kept
        for o in np.unique(owner[keep & (owner > 0)]):
            m = cv2.moments((parts_lab == o).view(np.uint8), binaryImage=True)
            centres[o] = m["m10"] / m["m00"], m["m01"] / m["m00"]
        pc = centres[owner]
        ax, ay = cx - pc[:, 0], cy - pc[:, 1]
        bx, by = vp[0] - pc[:, 0], vp[1] - pc[:, 1]
        cos = (ax * bx + ay * by) / np.maximum(np.hypot(ax, ay) * np.hypot(bx, by), 1e-9)
        facing = cos > WALL_FACING_COS  # walls on sides turned away from the vertical are thin anyway
        if p.walls_beyond:
            # ... and the vertical must lie beyond the region, seen from the part: a part that holds the image
            # of the vertical (near the image centre) shows no wall at all, whatever side its strip lies on
            facing &= ax * (vp[0] - cx) + ay * (vp[1] - cy) > 0
        keep &= (owner == 0) | facing
    out = np.take(keep, lab).view(np.uint8)
    # the sharp edge pixels around kept regions (a wall's outer edge) belong to the part
    grown = cv2.dilate(out, np.ones((3, 3), np.uint8))
    out |= (darker & sharp & (grown > 0)).view(np.uint8)
    return out


def _labels_around(parts_lab: np.ndarray, ys: np.ndarray, xs: np.ndarray, box) -> tuple[np.ndarray, np.ndarray]:
    """The highest and the lowest part label (the tray, 0, counted as 1e9) in the 3 x 3
    neighbourhood of each pixel (ys, xs), all in `box` (x0, y0, x1, y1); float32 (k,) each. The
    dilation and erosion run on the box and a pixel around it only: the same values there as
    over the whole image (outside the image they ignore the border, as there)."""
    x0, y0, x1, y1 = box
    cy0, cx0 = max(y0 - 1, 0), max(x0 - 1, 0)
    pl = parts_lab[cy0:y1 + 1, cx0:x1 + 1].astype(np.float32)
    k3 = np.ones((3, 3), np.uint8)
    hi = cv2.dilate(pl, k3)
    lo = cv2.erode(cv2.add(pl, cv2.threshold(pl, 0.5, 1e9, cv2.THRESH_BINARY_INV)[1]), k3)  # (pl + 1e9 where 0)
    yc, xc = ys - cy0, xs - cx0
    return hi[yc, xc], lo[yc, xc]
