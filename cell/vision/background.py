"""The empty tray's appearance under the current lighting, estimated from the frame itself.

Without a reference image of the empty tray, the tray is modelled as a smooth colour
field: a low-degree polynomial in (u, v) per colour channel, fitted robustly on every
other sample (a checkerboard) of a copy of the frame about 80 px wide. Parts are outliers of
that fit: the first inliers are the pixels near the frame's most frequent colour (counted
with more weight at the centre of the view, where the tray is), then the fit is repeated
with the pixels within 3 sigma of it. This follows lighting gradients and vignetting, needs no empty-tray
image, and works while the tray fills more of the frame than the parts do.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

FIT_WIDTH_PX = 80  # the fit runs on a copy about this wide (blocks small enough to be mostly pure tray)
FIT_DEGREE = 2
FIT_ITERATIONS = 4
MODE_BIN = 16  # DN per histogram bin when looking for the tray's colour
CENTRE_SIGMA = 0.4  # of the half-size: where the tray's colour is looked for
MODE_RADIUS = 40.0  # DN around the modal colour taken as the first inliers
# ... and is replaced only when its spread is this many times the other's and above ROUGH_MIN_DN:
# white packs taken for the tray 37 DN against the cloth's 10; a rendered tray 3.7 DN beside a plain
# table 1 DN (a tray filling 45 % of the view, as the default cell's does, must stay the tray)
ROUGH_TRAY = 2.0
ROUGH_MIN_DN = 15.0
TRAY_QUARTER = 0.25  # ... and one explaining less than this is replaced by the other when that explains more
TRAY_MIN_SHARE = 0.5  # a field that explains less of the view than this is checked against the other candidate


@lru_cache(maxsize=8)
def _design(h: int, w: int, degree: int) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    u = (u + 0.5) / w * 2 - 1
    v = (v + 0.5) / h * 2 - 1
    cols = [u ** i * v ** j for i in range(degree + 1) for j in range(degree + 1 - i)]
    return np.stack([c.ravel() for c in cols], axis=1)


@lru_cache(maxsize=8)
def _checkerboard(h: int, w: int) -> np.ndarray:
    """Flat indices of every other sample of an (h, w) grid, as the black squares of a
    checkerboard: half the samples, spread evenly over the grid. Read-only."""
    v, u = np.mgrid[0:h, 0:w]
    idx = np.flatnonzero(((u + v) % 2 == 0).ravel())
    idx.flags.writeable = False
    return idx


@lru_cache(maxsize=8)
def _centre_weights(h: int, w: int) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    un, vn = (u + 0.5) / w * 2 - 1, (v + 0.5) / h * 2 - 1
    return np.exp(-(un ** 2 + vn ** 2) / (2 * CENTRE_SIGMA ** 2)).ravel()


def estimate_background(image_bgr: np.ndarray, tray: str = "auto") -> tuple[np.ndarray, float]:
    """The tray's colour field at the image's size, and its noise (see `fit_tray_field`)."""
    h, w = image_bgr.shape[:2]
    field, sigma = fit_tray_field(image_bgr, tray)
    return field_at(field, (w, h)), sigma


def field_at(field: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The fitted colour field (from `fit_tray_field`) at another size (w, h), float32: resize maps
    pixel centres consistently, so the smooth field lands where it was fitted."""
    return cv2.resize(field, size, interpolation=cv2.INTER_LINEAR)


def fit_copy(image_bgr: np.ndarray) -> np.ndarray:
    """The copy about FIT_WIDTH_PX wide that the field is fitted on: `cv2.resize` of the image with
    INTER_AREA, as given (uint8 copies are rounded), (sh, sw, 3)."""
    h, w = image_bgr.shape[:2]
    f = max(1, w // FIT_WIDTH_PX)
    return cv2.resize(image_bgr, (max(4, w // f), max(4, h // f)), interpolation=cv2.INTER_AREA)


def fit_copy_of_whole_dn(image_u8: np.ndarray) -> np.ndarray:
    """`fit_copy(image_u8.astype(np.float32))`, bit for bit, in a third of the time when the copy
    tiles the image in blocks of f x f pixels with f a power of two (else computed so).

    Block means of whole numbers: the sums are exact in float32 whatever their order, and so are
    the divisions by f, so the column sums of f rows (whole numbers in uint16) averaged over f
    columns by the same resize and divided by f are the area average of the float32 image."""
    h, w = image_u8.shape[:2]
    f = max(1, w // FIT_WIDTH_PX)
    sw, sh = max(4, w // f), max(4, h // f)
    if (sw * f, sh * f) != (w, h) or f & (f - 1) or f > 256 or not image_u8.flags.c_contiguous:
        return fit_copy(image_u8.astype(np.float32))
    rows = np.add.reduce(image_u8.reshape(sh, f, w * 3), axis=1, dtype=np.uint16)  # (255 f fits)
    small = cv2.resize(rows.reshape(sh, w, 3).astype(np.float32), (sw, sh), interpolation=cv2.INTER_AREA)
    small *= np.float32(1.0 / f)
    return small


def fit_tray_field(image_bgr: np.ndarray, tray: str = "auto", small_bgr: np.ndarray | None = None,
                   seed: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The tray's colour field, on a copy about FIT_WIDTH_PX wide, and its noise.

    Parameters
    ----------
    image_bgr : ndarray of shape (h, w, 3), uint8 or float32
        The frame (usually the half-resolution detection copy).
    tray : {"auto", "bright"}
        "bright": the tray is the brighter side of the frame (a back-lit panel framed by a
        dark surround that would otherwise outnumber it).
    small_bgr : ndarray of shape (sh, sw, 3), optional
        `fit_copy(image_bgr)` if made already (e.g. by `fit_copy_of_whole_dn`).
    seed : ndarray of shape (sh, sw), optional
        Where on the small copy the tray is known to lie (e.g. a region first taken for a part):
        its colour is looked for there only, and no other candidate is tried.

    Returns
    -------
    field : ndarray of shape (sh, sw, 3) float32
        The field on the small copy (`field_at` brings it to any size).
    sigma_dn : float
        Robust spread (1.4826 MAD) of the tray's residual colour distance, DN.
    """
    small_bgr = fit_copy(image_bgr) if small_bgr is None else small_bgr
    sh, sw = small_bgr.shape[:2]
    # fitted on every other sample (a checkerboard): half the work, each sample still the mean of
    # a small block (mostly pure tray or pure part), and a smooth field needs no more
    sel = _checkerboard(sh, sw)
    small = small_bgr.reshape(-1, 3)[sel].astype(np.float64)
    nb = 256 // MODE_BIN
    q = (small * (1.0 / MODE_BIN)).astype(np.int64)  # (the bin size is a power of two: exact floor)
    # the camera looks at the tray: weigh the centre of the view up, the surroundings down
    weights = _centre_weights(sh, sw)[sel]
    if tray == "bright":
        grey = small.mean(axis=1).astype(np.uint8).reshape(-1, 1)
        otsu, _ = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        weights = weights * (grey.ravel() > otsu)
    elif tray != "auto":
        raise ValueError(f"tray must be 'auto' or 'bright', got {tray!r}")
    if seed is not None:
        weights = weights * np.asarray(seed, np.float64).ravel()[sel]
    codes = (q[:, 0] * nb + q[:, 1]) * nb + q[:, 2]
    a = _design(sh, sw, FIT_DEGREE)[sel]
    mode_bgr = _modal_bgr(codes, weights, nb)
    coef, sigma, res = _fit_around(mode_bgr, a, small)
    share = (res < max(3.0 * sigma, 6.0)).mean()  # the share of the view the field explains
    grown = _grown_inliers(small_bgr, mode_bgr) if share < GROW_BELOW_SHARE else None
    if grown is not None:
        # uneven light: the tray runs smoothly beyond MODE_RADIUS of its commonest colour (a lamp at
        # one side), and a field fitted around that colour alone covers only its part of the tray
        # and is extrapolated wrongly over the rest. Fitted to the tray's samples reached from that
        # colour's patch a ring at a time (`_grown_inliers`), the field is kept when it explains more
        # of the view and is not much rougher
        coef_g, sigma_g, res_g = _fit_around(mode_bgr, a, small, inliers=grown.ravel()[sel])
        limit = max(3.0 * min(sigma, sigma_g), 6.0)
        if sigma_g <= GROW_MAX_ROUGHER * sigma and (res_g < limit).sum() > (res < limit).sum():
            coef, sigma, res = coef_g, sigma_g, res_g
            share = (res < max(3.0 * sigma, 6.0)).mean()
    if tray == "auto" and seed is None and share < TRAY_MIN_SHARE:
        # the fit explains less than half the view: large or many parts may outnumber the tray near
        # the centre. The other candidate: the commonest colour of the whole view away from the
        # first one. It is the tray only if it explains more of the view (at the smoother one's
        # spread) and the first is rough (textured parts, not a plain surface): a smooth tray that
        # fills less than half the view beside a plain table stays the tray
        away = (res > MODE_RADIUS).astype(np.float64)  # off the first field
        if away.sum() >= 0.1 * len(small):
            coef2, sigma2, res2 = _fit_around(_modal_bgr(codes, away, nb), a, small)
            limit = max(3.0 * min(sigma, sigma2), 6.0)
            rough = sigma > max(ROUGH_TRAY * sigma2, ROUGH_MIN_DN)
            # a field explaining under a quarter of the view is no tray whether rough or smooth: the
            # noise is measured on the view's quietest quarter, taken for the tray (colour_change.py), and
            # the frame comes out empty (the black squares of a ChArUco board on paper, 11 %)
            if (rough or share < TRAY_QUARTER) and (res2 < limit).sum() > (res < limit).sum():
                coef, sigma = coef2, sigma2
    return (_design(sh, sw, FIT_DEGREE) @ coef).reshape(sh, sw, 3).astype(np.float32), sigma


def _modal_bgr(codes: np.ndarray, weights: np.ndarray, nb: int) -> np.ndarray:
    """The centre (b, g, r) of the most frequent colour bin, each bin counted with its neighbours."""
    hist = np.bincount(codes, weights=weights, minlength=nb ** 3).reshape(nb, nb, nb)
    # a lit tray spreads over neighbouring bins (gradients): count each bin with its neighbours
    hist = _box3(_box3(_box3(hist, 0), 1), 2)
    mode = int(np.argmax(hist))
    return (np.array([mode // (nb * nb), (mode // nb) % nb, mode % nb]) + 0.5) * MODE_BIN


GROW_RING = 2  # samples the tray's inliers grow by a round, the fit extrapolated no further
GROW_ROUNDS = 60
GROW_MAX_ROUGHER = 1.5  # ... and kept only when its spread is at most this many times the first fit's
GROW_BELOW_SHARE = 0.8  # the grown fit is tried when the first explains less of the view than this (an evenly
# lit tray is explained at 0.9 and more: the rendered frames of the cell, 0.91 - 0.94; photographs 0.77 - 0.88)


def _grown_inliers(small_bgr: np.ndarray, mode_bgr: np.ndarray, degree: int = FIT_DEGREE) -> np.ndarray | None:
    """The samples of the small copy (sh, sw, 3) that a smooth field reaches from the largest patch
    of samples near `mode_bgr` (within MODE_RADIUS), grown GROW_RING samples a round: each round the
    field is fitted to the samples reached so far and the ring around them joins where it lies within
    3 sigma of that field. The field is extrapolated only a ring at a time, so it follows a lighting
    gradient across the whole tray (whose far side may be far more than MODE_RADIUS from its
    commonest colour) while a part's edge, a step the field cannot follow, stops it. None when no
    patch is found. (sh, sw) bool."""
    sh, sw = small_bgr.shape[:2]
    flat = np.asarray(small_bgr, np.float64).reshape(-1, 3)
    near = (_row_norms(flat - mode_bgr) < MODE_RADIUS).reshape(sh, sw)
    if near.sum() < 8:
        return None
    n, lab = cv2.connectedComponents(near.view(np.uint8), connectivity=4)
    counts = np.bincount(lab.ravel())
    counts[0] = 0
    inl = lab == int(np.argmax(counts))
    a = _design(sh, sw, degree)
    ay = np.hstack([a, flat])
    nc = a.shape[1]
    ridge = 1e-9 * np.eye(nc)
    kernel = np.ones((2 * GROW_RING + 1, 2 * GROW_RING + 1), np.uint8)
    sigma0 = None
    for _ in range(GROW_ROUNDS):
        ayi = np.compress(inl.ravel(), ay, axis=0)
        normal = ayi.T @ ayi
        coef = np.linalg.solve(normal[:nc, :nc] + ridge, normal[:nc, nc:])
        res = _row_norms(flat - a @ coef).reshape(sh, sw)
        sigma = max(1.4826 * _median(res[inl]), 1.0)
        # the spread may grow with the tray reached (a quadratic follows a lamp's falloff only so
        # far) but to at most GROW_MAX_ROUGHER x the patch's own: a limit that grew with whatever
        # joined would run away into what lies next to the tray (dark parts on a dark surround)
        sigma0 = sigma if sigma0 is None else sigma0
        ring = cv2.dilate(inl.view(np.uint8), kernel).view(bool) & ~inl
        add = ring & (res < max(3.0 * min(sigma, GROW_MAX_ROUGHER * sigma0), 6.0))
        if not add.any():
            break
        inl = inl | add
    return inl


def _fit_around(mode_bgr: np.ndarray, a: np.ndarray, small: np.ndarray, inliers: np.ndarray | None = None
                ) -> tuple[np.ndarray, float, np.ndarray]:
    """The smooth field (coefficients (nc, 3)) fitted robustly from the samples near `mode_bgr`
    (or from `inliers`, (n,) bool, when given), its noise sigma (DN) and every sample's residual (n,)."""
    if inliers is None:
        dist = _row_norms(small - mode_bgr)
        inl = dist < MODE_RADIUS
        # a tray spread wider than MODE_RADIUS (a back-lit panel's glow with its contrast raised,
        # gamma 2: 9 % of the samples near its mode) is looked for in a wider ball before the whole
        # view is taken (which fits the mean of everything: every pixel a part or none)
        for radius in (2 * MODE_RADIUS, 4 * MODE_RADIUS):
            if inl.sum() >= 0.1 * len(small):
                break
            inl = dist < radius
    else:
        inl = inliers.copy()
    if inl.sum() < 0.1 * len(small):
        inl[:] = True
    nc = a.shape[1]
    ay = np.hstack([a, small])  # design and data side by side: one gather and one product a round
    ridge = 1e-9 * np.eye(nc)
    sigma = 1.0
    coef = res = None
    for _ in range(FIT_ITERATIONS):
        ayi = np.compress(inl, ay, axis=0)  # (ay[inl], four times faster)
        normal = ayi.T @ ayi  # [[A'A, A'y], [y'A, y'y]]
        coef = np.linalg.solve(normal[:nc, :nc] + ridge, normal[:nc, nc:])
        res = _row_norms(small - a @ coef)
        sigma = max(1.4826 * _median(res[inl]), 1.0)
        new = res < max(3.0 * sigma, 6.0)
        if new.sum() < 0.1 * len(small):
            break
        if np.array_equal(new, inl):
            break  # the same inliers again: the remaining rounds would repeat this fit
        inl = new
    return coef, sigma, res


def _box3(a: np.ndarray, axis: int) -> np.ndarray:
    """Sum of each element and its two neighbours along `axis` (zeros beyond the ends)."""
    p = np.moveaxis(a, axis, 0)
    out = p.copy()
    out[1:] += p[:-1]
    out[:-1] += p[1:]
    return np.moveaxis(out, 0, axis)


def _median(x: np.ndarray) -> float:
    """np.median of a 1-D array by one partial sort (without np.median's overhead)."""
    k = len(x) // 2
    if len(x) % 2:
        return float(np.partition(x, k)[k])
    part = np.partition(x, k)  # (one kth: numpy's multi-kth partition is ten times slower)
    return float((part[:k].max() + part[k]) * 0.5)


def _row_norms(d: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of an (n, 3) array (np.linalg.norm(d, axis=1), faster)."""
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])


def reference_background(reference_bgr: np.ndarray, out_size: tuple[int, int]) -> np.ndarray:
    """An image of the empty tray, smoothed and resized: the background field, float32."""
    ref = cv2.resize(reference_bgr, out_size, interpolation=cv2.INTER_AREA).astype(np.float32)
    return cv2.GaussianBlur(ref, (0, 0), 1.5)
