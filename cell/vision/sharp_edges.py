"""Sharp edges: the gradient of the brightness ratio r, and the bounds above which an edge is
sharp (a material edge, not a shadow's soft one), raised over a textured tray's own grain."""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

from cell.vision.colour_change import quartile1

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams


def edge_bounds_sq(p: SegmentParams, scale: int, texture: float) -> tuple[np.float32, np.float32]:
    """The squared gradients of r (per detection px, float32) above which an edge is sharp: around any
    shadow-like region (`sharp_edge` per full-resolution px) and around one no part is near (`crisp_edge` per
    detection px, not above the first), each raised to `noise_k` x the tray's grain where that is higher (a
    cloth's own grain makes sharp edges).

    Why two: at 1 / scale the detection's own blur spreads every crisp edge over about a detection pixel,
    whatever the scale, so a crisp step of contrast c reads 0.31 - 0.36 c per detection px at 1 / 1 to 1 / 4;
    per full-resolution px that is c / scale of it. The sharp edge asks for 0.12 per detection px at 1 / 2 (a
    crisp step of 0.35) and 0.06 at 1 / 1 (0.19): flat grey parts at 0.65 - 0.75 of the tray were found at 640 px
    and had no sharp pixel at 1280 px. But at 1 / 2 a part's own short shadow (a penumbra of 1.5 - 3.5 px on
    the default camera) is hardly softer than a crisp edge (0.29 c against 0.35 c per detection px for a 5 mm
    plate's): only the step's height tells them apart, and the sharp edge's bound, which keeps the rendered
    shadows of 0.3 out, stays for the regions a part is near. A region no part is near is no part's own
    shadow, and the shadow of anything higher (an arm, a hand) has a penumbra many pixels wide."""
    grain = p.noise_k * texture

    def raised(sq: np.float32) -> np.float32:
        return np.float32(grain ** 2) if grain > np.sqrt(sq) else sq

    sharp_sq = raised(_sharp_bound_sq(p.sharp_edge, scale))
    if p.crisp_edge is None:
        return sharp_sq, sharp_sq
    return sharp_sq, min(sharp_sq, raised(_sharp_bound_sq(p.crisp_edge, 1)))


RAYLEIGH_Q1 = 0.7585  # the 25th percentile of the length of a 2-D N(0, s) vector, in s: sqrt(-2 ln 0.75)
TEXTURE_STEP = 8  # the tray's grain is measured on every this many-th detection pixel


def texture_gradient(sm: np.ndarray, bg: np.ndarray) -> float:
    """The spread (per detection px, of the brightness ratio r) of the tray's own gradient: its grain
    and noise, from the quietest quarter (the tray) like the noise spreads, on every 8th pixel (a
    tenth of a millisecond on the cell's frames; every 4th gives the same within 3 %), by central
    differences (the derivative `gradient_sq`'s Sobel x 1/8 measures)."""
    h, w = sm.shape[:2]
    st = TEXTURE_STEP
    if h < 3 or w < 3:
        return 0.0
    ny, nx = (h - 3) // st + 1, (w - 3) // st + 1  # centres at 1, 1 + st, ... with both neighbours inside

    def rsum(a, y, x):  # b + g + r on the strided view (no copies)
        v = a[y:y + st * (ny - 1) + 1:st, x:x + st * (nx - 1) + 1:st]
        return v[:, :, 0] + v[:, :, 1] + v[:, :, 2]

    sb = 2.0 * (rsum(bg, 1, 1) + 1.0)
    gx = (rsum(sm, 1, 2) - rsum(sm, 1, 0)) / sb
    gy = (rsum(sm, 2, 1) - rsum(sm, 0, 1)) / sb
    g2 = gx * gx
    g2 += gy * gy
    return float(np.sqrt(quartile1(g2))) / RAYLEIGH_Q1


def gradient_sq(r: np.ndarray) -> np.ndarray:
    """The squared gradient of r per detection px (Sobel x 1/8), float32."""
    gx = cv2.Sobel(r, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(r, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    return gx * gx + gy * gy


@lru_cache(maxsize=8)
def _sharp_bound_sq(edge: float, scale: int) -> np.float32:
    """The largest float32 g2 whose np.sqrt(g2) / scale is not above `edge` (in float32, as on
    the arrays): for float32 g2 >= 0, sqrt(g2) / scale > edge exactly when g2 > it (both roundings
    are monotonic, so the comparison flips once)."""
    def above(g2) -> bool:
        return bool((np.sqrt(np.array([g2], np.float32)) / scale > edge)[0])

    b = np.float32((edge * scale) ** 2)
    while above(b):
        b = np.nextafter(b, np.float32(0))
    while not above(np.nextafter(b, np.float32(np.inf))):
        b = np.nextafter(b, np.float32(np.inf))
    return b
