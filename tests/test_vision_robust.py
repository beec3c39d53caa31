"""Segmentation of real photographs made harder at run time: uneven light, inverted contrast,
rotation, rescaling, noise, JPEG, tiling, crops at the border, blank frames. The photographs are
read in place from ../shared/external (SOURCE.md there gives their published figures); nothing is
copied into the project."""


import json

import cv2
import numpy as np
import pytest
from conftest import EXTERNAL, run_cli

from cell.vision import read_image, segment_frame

OBJECTS = EXTERNAL / "opencv-objects"
PILLS = EXTERNAL / "simplecv-coins"
FESTO = EXTERNAL / "p5binpicking-festo-table"

pytestmark = pytest.mark.skipif(not (OBJECTS / "pca_test1.jpg").is_file() or not (PILLS / "pills.png").is_file(),
                                reason=f"the shared photographs are not in {EXTERNAL} (../shared/external)")


def whole(segs, min_area):
    return [s for s in segs if not s.cut_off and s.area_px >= min_area]


def lit(img, gain):
    """`img` under a lighting field `gain` (h, w), clipped as a camera clips."""
    return np.clip(img.astype(np.float32) * gain[:, :, None], 0, 255).astype(np.uint8)


def ramp(shape, lo, hi, axis):
    h, w = shape[:2]
    if axis == "u":
        return np.broadcast_to(np.linspace(lo, hi, w, dtype=np.float32)[None, :], (h, w))
    return np.broadcast_to(np.linspace(lo, hi, h, dtype=np.float32)[:, None], (h, w))


@pytest.fixture(scope="module")
def pca():
    return read_image(OBJECTS / "pca_test1.jpg")


@pytest.mark.parametrize("lo, hi, axis", [(0.5, 1.2, "u"), (0.35, 1.0, "v"), (1.0, 0.4, "u")])
def test_backlit_parts_under_a_lighting_gradient(pca, lo, hi, axis):
    """The back-lit panel of pca_test1.jpg lit unevenly (a lamp at one side: the panel's far side
    2.5 - 3 x as bright as its near side). The tray field fitted around the panel's commonest colour
    covered only the stretch of panel within 40 DN of it and was extrapolated wrongly over the rest:
    0 of the 6 parts. Grown a ring at a time from there it follows the gradient."""
    segs = segment_frame(lit(pca, ramp(pca.shape, lo, hi, axis)))
    parts = whole(segs, 5000)
    assert len(parts) == 6
    areas = sorted(s.area_px for s in parts)
    plain = sorted(s.area_px for s in whole(segment_frame(pca), 5000))
    assert np.allclose(areas, plain, rtol=0.04)  # the same bars, the same size


@pytest.mark.parametrize("name", ["pca_test1.jpg", "pills.png", "stuff.jpg"])
def test_inverted_contrast_keeps_the_parts(name):
    """Light parts on a dark ground: each photograph with its contrast inverted. pca_test1.jpg's
    panel then is dark in a light surround, and the bright side (what `--backlit` and the back-lit
    check took for the tray) is the surround: the panel came out as one part with the 6 bars as its
    holes, no part whole. The panel's own colour, looked for in that region, is now tried too."""
    path = (OBJECTS if name != "pills.png" else PILLS) / name
    img = read_image(path)
    counts = {"pca_test1.jpg": (6, 5000), "pills.png": (2, 20000), "stuff.jpg": (5, 900)}
    n, min_area = counts[name]
    plain = whole(segment_frame(img), min_area)
    inverted = whole(segment_frame(255 - img), min_area)
    assert len(plain) == len(inverted) == n
    if name == "stuff.jpg":
        return  # its shadows turn into bright halos: the same objects, other outlines
    for s in inverted:  # the same parts where they were
        d = min(np.hypot(*(s.centroid_px - t.centroid_px)) for t in plain)
        assert d < 3.0
    if name == "pca_test1.jpg":  # a back-lit silhouette: the same outline either way
        assert np.allclose(sorted(s.area_px for s in inverted), sorted(s.area_px for s in plain), rtol=0.01)


CHARUCO = EXTERNAL / "opencv-charuco" / "choriginal.jpg"


@pytest.mark.skipif(not CHARUCO.is_file(), reason=f"{CHARUCO} is not there (../shared/external)")
@pytest.mark.parametrize("factor", [1, 2])
def test_a_minority_colour_is_not_taken_for_the_tray(factor):
    """OpenCV's ChArUco photograph: a printed board on a wooden table, no part in the usual sense,
    but plainly not an empty view. The commonest colour near the centre was the board's black
    squares, 11 % of the view, smooth, so no other candidate was tried; the noise, measured on the
    view's quietest quarter (then the wood and the paper), hid everything: no region at all. A field
    that explains under a quarter of the view now gives way to the other candidate (the wood, 53 %),
    and the back-lit check then takes the paper for the tray: the board's black squares come out."""
    img = read_image(CHARUCO)
    if factor != 1:
        img = cv2.resize(img, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC)
    segs = segment_frame(img)
    squares = [s for s in whole(segs, 0) if 2000 < s.area_px / factor ** 2 < 4500]
    assert len(squares) >= 10  # 17 black squares, some touching others at their corners


def test_a_tray_spread_wider_than_the_mode_radius_is_not_fitted_as_the_mean_of_everything(pca):
    """pca_test1.jpg with gamma 2: the lit panel's glow spreads its colours, and only 9 % of the
    samples lay within 40 DN of its commonest colour; the fit then started from every sample and
    ended as the mean of panel, bars and surround (spread 161 DN). It now looks in a wider ball
    first. (The segmentation of that frame is still poor: the panel's dim centre is taken for
    part of the bars; docs/vision.md, limits.)"""
    from cell.vision.background import fit_copy_of_whole_dn, fit_tray_field

    img = (255 * (pca / 255.0) ** 2).astype(np.uint8)
    field, sigma = fit_tray_field(img.astype(np.float32), "bright", fit_copy_of_whole_dn(img))
    assert sigma < 40
    assert field[field.shape[0] // 2, field.shape[1] // 2].mean() > 60  # the panel, not its dark surround


@pytest.mark.skipif(not (FESTO / "aruco_img.png").is_file(), reason=f"{FESTO} is not there (../shared/external)")
@pytest.mark.parametrize("exposure", [0.35, 0.15])
def test_an_underexposed_cell_frame_gives_the_parts_of_the_frame(exposure):
    """The Festo cell frame at a third and a seventh of its exposure (low light). Every colour then
    lay within the tray colour's 40 DN ball, the tray was fitted as the mean of everything and
    nothing was found. Brought to a normal exposure first, it gives the frame's own parts: the
    four covers and the three marker cards not cut by the border (60 x 115 and 59 x 59 mm at
    0.56 mm/px) where they were; at a seventh, two patches of the table's noise besides."""
    img = read_image(FESTO / "aruco_img.png")
    dark = (img * exposure).astype(np.uint8)
    plain = whole(segment_frame(img), 9000)
    found = whole(segment_frame(dark), 9000)
    assert len(plain) == 7
    assert 0 <= len(found) - len(plain) <= (0 if exposure > 0.3 else 2)
    for s in plain:
        t = min(found, key=lambda t: np.hypot(*(t.centroid_px - s.centroid_px)))
        assert np.hypot(*(t.centroid_px - s.centroid_px)) < 3.0
        assert t.area_px == pytest.approx(s.area_px, rel=0.05)
        assert np.allclose(t.mean_bgr, np.array(s.mean_bgr) * exposure, atol=6)  # the dark frame's colours


def test_a_dark_or_blank_frame_of_any_size_has_no_parts():
    rng = np.random.default_rng(3)
    for frame in (np.zeros((480, 640, 3), np.uint8), np.full((480, 640, 3), 255, np.uint8),
                  rng.integers(0, 6, (960, 1280, 3), dtype=np.uint8),  # a covered lens: only noise
                  np.clip(128 + rng.normal(0, 12, (600, 800, 3)), 0, 255).astype(np.uint8),
                  np.full((3000, 4000, 3), 90, np.uint8), np.full((1, 1, 3), 7, np.uint8)):
        assert segment_frame(frame) == []


@pytest.mark.skipif(not (FESTO / "aruco_img2.png").is_file(), reason=f"{FESTO} is not there (../shared/external)")
def test_outlines_are_simple_polygons_inside_the_frame():
    """Every ring `cell segment` gives is a simple polygon (but for pinches at a vertex) within
    [0, w] x [0, h] whose area is the segment's: the refinement moved points past the border
    (Festo frame 2 upscaled 2 x: 2.7 px out) and made rings cross themselves (there 4 of 49 holes;
    with noise added 6 of 23 outlines and 3 of 67 holes)."""
    from shapely.geometry import LinearRing, Polygon

    img = read_image(FESTO / "aruco_img2.png")
    rng = np.random.default_rng(0)
    for frame in (cv2.resize(img, None, fx=2, fy=2, interpolation=cv2.INTER_LINEAR),
                  np.clip(img + rng.normal(0, 10, img.shape), 0, 255).astype(np.uint8)):
        h, w = frame.shape[:2]
        segs = segment_frame(frame)
        assert len(segs) > 10
        for s in segs:
            for r in [s.outline_px, *s.holes_px]:
                # simple, or touching itself at a vertex it visits twice (two blobs meeting at a
                # pixel, as OpenCV's contour of the mask has them: kept)
                assert LinearRing(r).is_simple or len(np.unique(r, axis=0)) < len(r)
                assert r.min() >= 0 and r[:, 0].max() <= w and r[:, 1].max() <= h
            poly = Polygon(s.outline_px, s.holes_px)
            assert poly.area == pytest.approx(s.area_px, rel=0.01)


def test_a_strip_of_a_frame_is_segmented_not_refused_with_a_traceback():
    """A 3 x 5000 px frame was reduced to a detection copy of no rows (OpenCV's resize asserted);
    a 60 px strip of pills.png stretched to 4000 px keeps its two packs."""
    assert segment_frame(np.full((3, 5000, 3), 120, np.uint8)) == []
    assert segment_frame(np.full((5000, 3, 3), 120, np.uint8)) == []
    strip = cv2.resize(read_image(PILLS / "pills.png"), (4000, 60), interpolation=cv2.INTER_AREA)
    assert len([s for s in segment_frame(strip) if s.area_px > 5000]) == 2


def test_cli_strip_and_blank_frames(tmp_path, capsys):
    for name, img in (("strip.png", np.full((3, 5000, 3), 120, np.uint8)),
                      ("blank.jpg", np.full((3000, 4000, 3), 200, np.uint8))):
        cv2.imwrite(str(tmp_path / name), img)
        code, out, err = run_cli("segment", tmp_path / name, "--json", capsys=capsys)
        assert code == 0 and json.loads(out)["parts"] == [] and "Traceback" not in err


@pytest.mark.parametrize("name, count, min_area", [("pca_test1.jpg", 6, 5000), ("pills.png", 2, 20000)])
def test_counts_and_areas_follow_rotation_flip_and_scale(name, count, min_area):
    """The published counts (6 bars, SOURCE.md's PCA tutorial figure; 2 blister packs) under
    rotation, mirroring and rescaling, with the areas x the scale squared (within 3 %)."""
    img = read_image((OBJECTS if name == "pca_test1.jpg" else PILLS) / name)
    plain = sorted(s.area_px for s in whole(segment_frame(img), min_area))
    assert len(plain) == count
    variants = [(cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE), 1.0), (cv2.rotate(img, cv2.ROTATE_180), 1.0),
                (np.ascontiguousarray(img[:, ::-1]), 1.0),
                (cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA), 0.5),
                (cv2.resize(img, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC), 2.0)]
    for frame, f in variants:
        areas = sorted(s.area_px / f ** 2 for s in whole(segment_frame(frame), min_area * f ** 2))
        assert len(areas) == count
        assert np.allclose(areas, plain, rtol=0.03)
