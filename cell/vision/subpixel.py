"""Sub-pixel outlines: every point of a region's rings moved along its normal to where the full-resolution
colour profile crosses half-way between the part and what lies beside it (segmentation step 5)."""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams

MIN_EDGE_SHARE = 0.25  # the share of a region's outline (off the image border) where refinement must find an edge


def edge_share(ring: np.ndarray, found: np.ndarray | None, shape) -> float:
    """The share of the ring's points off the image border (a region cut there has no edge there)
    where an edge was found; 1 when too few points to tell."""
    if found is None:
        return 1.0
    h, w = shape[:2]
    off = (ring[:, 0] > 1.0) & (ring[:, 0] < w - 1.0) & (ring[:, 1] > 1.0) & (ring[:, 1] < h - 1.0)
    n = int(off.sum())
    if n < 5:
        return 1.0
    return float(np.count_nonzero(found & off)) / n


def refine_rings(frame: np.ndarray, rings: list[np.ndarray], is_hole: list[bool], p: SegmentParams,
                 edges: list | None = None) -> list[np.ndarray]:
    """Move each ring point along its normal to the half-way crossing of the colour profile.

    The profile across the edge is projected on the colour difference between the part side
    and the other side, so it runs from 1 (part) to 0 (tray, shadow or hole) whatever the
    colours; 0.5 is the edge of an optically blurred step. All rings are sampled in one pass.
    `edges`, a list: filled with each ring's bool array, per point, of whether an edge was found
    there (a crossing with the sides `min_edge_contrast_dn` apart; None for rings too short).
    """
    todo = [i for i, r in enumerate(rings) if len(r) >= 5]
    if edges is not None:
        edges[:] = [None] * len(rings)
    if not todo:
        return list(rings)
    p = p.for_frame(frame.shape)
    # all rings' points in one array; each point's neighbours k steps along its own ring
    lens = np.array([len(rings[i]) for i in todo])
    starts = np.concatenate(([0], np.cumsum(lens)[:-1]))
    pts0 = np.concatenate([rings[i] for i in todo])
    n = len(pts0)
    ring_of = np.repeat(np.arange(len(todo)), lens)
    first, size = starts[ring_of], lens[ring_of]
    local = np.arange(n) - first
    tang = pts0[first + (local + 2) % size] - pts0[first + (local - 2) % size]
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
    nxt = pts0[first + (local + 1) % size]
    area2 = np.add.reduceat(pts0[:, 0] * nxt[:, 1] - nxt[:, 0] * pts0[:, 1], starts)  # twice each ring's signed area
    sign = np.where(area2 > 0, 1.0, -1.0) * np.where(np.array([is_hole[i] for i in todo]), -1.0, 1.0)
    normal = sign[ring_of, None] * np.column_stack([tang[:, 1], -tang[:, 0]])  # out of the material
    rng_px = max(p.refine_range_px, 2.0 * p.scale)  # the coarse outline is up to a detection pixel off
    ts, basis, nearest_first = _profile_steps(rng_px)
    nt = len(ts)
    # sample positions p + t normal + k tangent for every (t, k), per axis (n, nt * 3), as one
    # product of (n, 3) coefficients and the (3, nt * 3) basis, in float32 (pixel centres at integers)
    mapx = np.column_stack([pts0[:, 0] - 0.5, normal[:, 0], tang[:, 0]]).astype(np.float32) @ basis
    mapy = np.column_stack([pts0[:, 1] - 0.5, normal[:, 1], tang[:, 1]]).astype(np.float32) @ basis
    samp = cv2.remap(frame, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)  # (n, nt * 3, 3) uint8
    # the three samples of each step are neighbours in a row: an area resize averages them
    prof = cv2.resize(samp.astype(np.float32), (nt, n), interpolation=cv2.INTER_AREA).reshape(n, nt, 3)
    q = 3  # samples at each end that stand for "inside" and "outside"
    inside = _median3(prof[:, :q])
    outside = _median3(prof[:, -q:])
    d = inside - outside
    dd = np.einsum("nc,nc->n", d, d)
    ok = dd > p.min_edge_contrast_dn ** 2
    f = (np.matmul(prof, d[:, :, None])[:, :, 0] - np.einsum("nc,nc->n", outside, d)[:, None]) / np.maximum(
        dd, 1e-9)[:, None]
    cross = (f[:, :-1] >= 0.5) & (f[:, 1:] < 0.5)
    # the crossing nearest the coarse point (of two as near, the one further in): the first one in
    # the steps ordered by distance (argmax finds the first True)
    j = nearest_first[np.argmax(cross[:, nearest_first], axis=1)]
    rows = np.arange(n)
    found = cross[rows, j] & ok
    f0, f1 = f[rows, j], f[rows, j + 1]
    frac = np.clip((f0 - 0.5) / np.maximum(f0 - f1, 1e-9), 0.0, 1.0)
    t = np.where(found, ts[j] + frac * (ts[1] - ts[0]), 0.0)
    moved = pts0 + t[:, None] * normal
    out = list(rings)
    start = 0
    for i in todo:
        out[i] = moved[start:start + len(rings[i])]
        if edges is not None:
            edges[i] = found[start:start + len(rings[i])]
        start += len(rings[i])
    return out


@lru_cache(maxsize=4)
def _profile_steps(rng_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps t (px) along the normal, the (3, nt * 3) float32 basis of the sample positions
    (1, t, k) for the three samples k = -1, 0, 1 across the profile at each step, and the
    intervals between steps ordered by the distance of their middle from 0 (ties: the lower
    first). Read-only: shared by every call."""
    ts = np.arange(-rng_px, rng_px + 1e-9, 0.5)
    nt = len(ts)
    ks = np.array([-1.0, 0.0, 1.0])  # three samples across the profile, averaged (noise)
    basis = np.stack([np.ones(nt * 3), np.repeat(ts, 3), np.tile(ks, nt)]).astype(np.float32)
    nearest_first = np.argsort(np.abs(0.5 * (ts[:-1] + ts[1:])), kind="stable")
    for a in (ts, basis, nearest_first):
        a.flags.writeable = False
    return ts, basis, nearest_first


def _median3(a: np.ndarray) -> np.ndarray:
    """Median over axis 1 of length 3 (np.median is slow for this)."""
    x, y, z = a[:, 0], a[:, 1], a[:, 2]
    return np.maximum(np.minimum(x, y), np.minimum(np.maximum(x, y), z))
