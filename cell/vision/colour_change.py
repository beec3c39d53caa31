"""Per pixel, how the frame differs from the tray: the colour change, the noise it must stand
above, and the evidence that marks a part (segmentation step 2)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.holes import SUM_PLUS_1

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams


def colour_change(sm: np.ndarray, bg: np.ndarray):
    """Per pixel: brightness ratio r, chroma change (L1 of normalised colour), both in DN too."""
    si = cv2.transform(sm, SUM_PLUS_1)
    sb = cv2.transform(bg, SUM_PLUS_1)
    r = si / sb
    db = sm[:, :, 0] / si  # (channel views: no copies; then in place: fewer passes and allocations)
    db -= bg[:, :, 0] / sb
    dg = sm[:, :, 1] / si
    dg -= bg[:, :, 1] / sb
    dr = np.abs(db + dg)  # |b + g| = |r| of the normalised colour change (it sums to 0)
    chroma = np.abs(db)  # the L1 over b, g, r, summed in the order |b| + |g| + |r|
    chroma += np.abs(dg)
    chroma += dr
    # the same changes in DN, to be compared with the frame's noise (dark trays have noisy chroma)
    return r, chroma, chroma * si, (si - sb) / 3.0


def noise_spreads(chroma_dn: np.ndarray, bright_dn: np.ndarray) -> tuple[float, float]:
    """Noise spreads (DN) of chroma and brightness from their 25th percentiles: the quietest
    quarter is the tray, and the 25th percentile of |N(0, s)| is 0.32 s.

    Right for the brightness (a channel mean: its spread is the channels' sd / sqrt(3)). The chroma
    change is an L1 over three channels, whose 25th percentile is 1.18 x the channels' sd, so this
    reads 3.7 x that sd (tests/test_vision_noise.py). Kept: read right (and the bound matched to the
    brightness's tail, 8.5 sd), the rendered frames keep all their parts under noise, but on the
    photographs shadows' colour casts, JPEG chroma bled round dark objects and surround touching
    parts pass as parts (docs/vision.md, Limits)."""
    return quartile1(chroma_dn) / 0.32 + 1e-3, quartile1(np.abs(bright_dn)) / 0.32 + 1e-3


def quartile1(a: np.ndarray) -> float:
    """np.percentile(a, 25) (linear interpolation) by one partial sort, without its overhead."""
    flat = a.ravel()
    idx = 0.25 * (flat.size - 1)
    lo = int(idx)
    part = np.partition(flat, lo)  # (one kth: numpy's multi-kth partition is ten times slower)
    nxt = part[lo + 1:].min() if lo + 1 < flat.size else part[lo]
    return float(part[lo] + (nxt - part[lo]) * (idx - lo))


def evidence(r, chroma, chroma_dn, bright_dn, p: SegmentParams, f: float, noise_c: float, noise_b: float):
    """Pixels that changed their chroma, or are brighter, or darker than any shadow makes the
    tray, by f x the thresholds, each change standing f x noise_k noise spreads above the tray's."""
    k = f * p.noise_k
    out = chroma > f * p.chroma_min  # (in place: fewer passes over the box)
    out &= chroma_dn > k * noise_c
    brighter = r > 1.0 + f * p.brighter_min
    brighter &= bright_dn > k * noise_b
    out |= brighter
    dark = r < 1.0 - p.darker_min
    dark &= bright_dn < -(k * noise_b)
    out |= dark
    return out
