"""The noise spreads the segmentation measures on the tray (docs/vision.md, step 2 and Limits).

The brightness change is a channel mean (a normal: its 25th percentile's |.| is 0.32 sd) and the
tray's grain a 2-D gradient (Rayleigh: 0.7585 sd), read right. The chroma change is an L1 over three
channels: under channel noise of sd s its 25th percentile is 1.18 s, not 0.32 s, so the spread
reads 3.7 x s. Kept for now (docs: read right it lets shadows' colour casts through on the
photographs); these tests pin what is measured and state the statistic a correction would use."""

import cv2
import numpy as np
import pytest
from conftest import EXTERNAL
from scipy.optimize import brentq
from scipy.stats import norm

from cell.vision import read_image, segment_frame
from cell.vision.colour_change import colour_change, noise_spreads
from cell.vision.detection import smoothed_copies
from cell.vision.sharp_edges import RAYLEIGH_Q1, texture_gradient

GREY = (1 / 3, 1 / 3, 1 / 3)
CELL_TRAY = (140 / 345, 115 / 345, 90 / 345)  # the simulated camera's blue tray (BGR 140, 115, 90)
CHROMA_Q1 = 1.180  # the L1 chroma change's 25th percentile under channel noise, in sd (grey tray)
CHROMA_BOUND_SD = 8.50  # the L1 that channel noise exceeds as rarely as |N(0, 1)| exceeds 5 (grey tray)
READ_AS = CHROMA_Q1 / 0.32  # what the segmentation's chroma spread reads, in channel sd (3.69)


def l1_chroma(n: np.ndarray, shares) -> np.ndarray:
    """The chroma change (L1 of the normalised colour's change, x the brightness sum) that channel
    noise n (m, 3) makes on a tray whose channels hold `shares` of its brightness."""
    w = np.asarray(shares)
    return np.abs(n - w * n.sum(axis=1, keepdims=True)).sum(axis=1)


def l1_tail(t: float, shares, steps: int = 20000) -> float:
    """P(L1 chroma change > t) for N(0, 1) channel noise, by quadrature: the change lies in the plane
    sum = 0 as A z with z ~ N(0, I_2); along the direction phi its L1 is |z| g(phi)."""
    w = np.asarray(shares)
    m = np.eye(3) - np.outer(w, np.ones(3))
    val, vec = np.linalg.eigh(m @ m.T)
    a = vec[:, 1:] * np.sqrt(np.clip(val[1:], 0, None))
    phi = (np.arange(steps) + 0.5) / steps * 2 * np.pi
    g = np.abs(a @ np.stack([np.cos(phi), np.sin(phi)])).sum(axis=0)
    return float(np.mean(np.exp(-0.5 * (t / g) ** 2)))


@pytest.mark.parametrize("shares, q1", [(GREY, CHROMA_Q1), (CELL_TRAY, 1.189), ((0.5, 0.3, 0.2), 1.220)])
def test_the_chroma_change_of_channel_noise_has_the_stated_quartile(shares, q1):
    n = np.random.default_rng(0).standard_normal((2_000_000, 3))
    assert np.percentile(l1_chroma(n, shares), 25) == pytest.approx(q1, abs=0.004)
    # the brightness change, a channel mean, is a normal: 0.32 of its sd is right (0.3186)
    assert np.percentile(np.abs(n.mean(axis=1)), 25) / np.sqrt(1 / 3) == pytest.approx(0.32, abs=0.003)
    # the quadrature agrees with the simulation where the simulation sees the tail
    t3 = 1.80 * 3
    assert l1_tail(t3, shares) == pytest.approx(float(np.mean(l1_chroma(n, shares) > t3)), rel=0.05)


def test_the_chroma_bound_as_rare_as_five_brightness_spreads():
    """At 5 spreads the brightness is exceeded by noise 5.7e-7 of the time; channel noise exceeds an
    L1 chroma change of 8.50 sd as rarely on a grey tray (8.57 on the cell's blue one): over the 25th
    percentile 7.2 x it, whatever the tray's colour. The segmentation's bound is 5 x 3.69 = 18.4 sd."""
    def bound(shares):
        return brentq(lambda t: l1_tail(t, shares) - 2 * norm.sf(5), 1.0, 20.0)

    assert bound(GREY) == pytest.approx(CHROMA_BOUND_SD, abs=0.02)
    for shares, q1 in ((GREY, CHROMA_Q1), (CELL_TRAY, 1.189)):
        assert bound(shares) / q1 == pytest.approx(7.21, abs=0.02)


def noisy_flat(tray_bgr, sd: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A flat detection image (512 x 640) with N(0, sd) noise per channel, and its tray."""
    tray = np.empty((512, 640, 3), np.float32)
    tray[:] = tray_bgr
    return tray + np.random.default_rng(seed).normal(0.0, sd, tray.shape).astype(np.float32), tray


@pytest.mark.parametrize("sd", [2.0, 6.0, 12.0])
@pytest.mark.parametrize("tray_bgr", [(128, 128, 128), (140, 115, 90)])
def test_the_spreads_measured_on_a_flat_frame_against_the_known_sd_of_its_noise(sd, tray_bgr):
    """A flat tray with noise of a known sd per channel, blurred as detection blurs it (within 5 %):
    the brightness spread is the channels' sd / sqrt(3) after the blur, as it should be; the chroma
    spread reads 3.69 x the channels' sd (docs/vision.md, Limits: 1.0 x read right)."""
    det, tray = noisy_flat(tray_bgr, sd, int(sd))
    _, sparse, _ = smoothed_copies(det)  # what the spreads are measured on (every 4th blurred pixel)
    bg = np.ascontiguousarray(tray[::4, ::4])
    noise_c, noise_b = noise_spreads(*colour_change(sparse, bg)[2:])
    blurred_sd = float((sparse - bg).std())  # the noise as detection sees it (the blur lowers it)
    assert noise_b == pytest.approx(blurred_sd / np.sqrt(3), rel=0.05)
    assert noise_c == pytest.approx(READ_AS * blurred_sd, rel=0.05)


@pytest.mark.parametrize("sd", [2.0, 12.0])
def test_the_tray_grain_measured_on_a_flat_frame_is_the_sd_of_its_gradient(sd):
    """The grain (step 3) is the spread of each component of r's central-difference gradient, read
    from the 25th percentile of its length (a 2-D normal's: RAYLEIGH_Q1), within 6 %."""
    det, tray = noisy_flat((140, 115, 90), sd, 7)
    sm = cv2.GaussianBlur(det, (5, 5), 0.8)
    s = sm.sum(axis=2) / (tray.sum(axis=2) + 1.0)
    gx = (s[1:-1, 2:] - s[1:-1, :-2]) / 2
    gy = (s[2:, 1:-1] - s[:-2, 1:-1]) / 2
    assert RAYLEIGH_Q1 == pytest.approx(np.sqrt(-2 * np.log(0.75)), abs=1e-4)
    assert texture_gradient(sm, tray) == pytest.approx(float(np.hypot(gx.std(), gy.std()) / np.sqrt(2)), rel=0.06)


STUFF = EXTERNAL / "opencv-objects" / "stuff.jpg"


@pytest.mark.skipif(not STUFF.is_file(), reason=f"the shared photographs are not in {EXTERNAL} (../shared/external)")
@pytest.mark.xfail(strict=True, reason="docs/vision.md, Limits: the chroma's noise spread reads 3.7 x the noise's sd")
def test_the_pink_lighter_of_stuff_jpg_is_found_under_noise_and_jpeg():
    """The lighter's pink body (chroma 45 DN against the table) under noise of sd 6 and at JPEG quality
    30: one region covers it (0.07 - 0.08 of it with the spread as read; all of it read right)."""
    img = read_image(STUFF)
    rng = np.random.default_rng(0)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 30])
    for frame in (np.clip(img + rng.normal(0.0, 6.0, img.shape), 0, 255).astype(np.uint8), cv2.imdecode(buf, 1)):
        cover = 0.0
        for s in segment_frame(frame):
            m = np.zeros(frame.shape[:2], np.uint8)
            cv2.fillPoly(m, [np.round(s.outline_px * 16).astype(np.int32)], 1, shift=4)
            cover = max(cover, float(m[355:445, 322:348].mean()))  # the body, within its outline
        assert cover > 0.9
