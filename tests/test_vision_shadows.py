"""Shadows on textured trays and lighting gradients at the border (docs/vision.md, steps 3 and 5):
a shadow-like region's sharp edge must stand above the tray's own grain, and a region with an edge
along almost none of its outline is lighting, not a part. Rendered scenes test the mechanisms; the
shared photographs (read in place from ../shared/external, skipped without them) the effect."""

import cv2
import numpy as np
import pytest
from conftest import EXTERNAL

from cell.vision import SegmentParams, read_image, segment_frame

OBJECTS = EXTERNAL / "opencv-objects"
PILLS = EXTERNAL / "simplecv-coins"


def cloth(seed: int, h: int = 240, w: int = 320, bgr=(130, 85, 55), grain: float = 0.18) -> np.ndarray:
    """A woven cloth: every pixel's brightness off by `grain` (sd), so its own gradient is sharp."""
    rng = np.random.default_rng(seed)
    weave = 1.0 + grain * rng.standard_normal((h, w)).astype(np.float32)
    return np.array(bgr, np.float32)[None, None, :] * weave[:, :, None]


def pill_on_cloth(seed: int, cx=160.0, cy=110.0, rad=14.0) -> np.ndarray:
    """A white disc on the cloth with a soft shadow below it (the cloth darkened to 0.6, fading over 6 px)."""
    img = cloth(seed)
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = np.hypot(xx - cx, yy - (cy + 7.0)) - rad
    img *= (1.0 - 0.4 * np.clip(1.0 - d / 6.0, 0.0, 1.0))[:, :, None]
    inside = np.clip(rad + 0.5 - np.hypot(xx - cx, yy - cy), 0.0, 1.0)[:, :, None]
    img = img * (1.0 - inside) + np.array([225, 232, 235], np.float32) * inside
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_shadow_on_cloth_is_not_taken_for_a_wall(seed):
    # before: the cloth's grain made the shadow's border 'sharp', the shadow was kept as a wall and the
    # outline ran 8.7 px into it; now the sharp edge must stand above the grain's own gradient
    cx, cy, rad = 160.0, 110.0, 14.0
    segs = segment_frame(pill_on_cloth(seed, cx, cy, rad), SegmentParams(min_area_px=60))
    assert len(segs) == 1
    off = np.hypot(segs[0].outline_px[:, 0] - cx, segs[0].outline_px[:, 1] - cy) - rad
    assert np.abs(off).max() < 2.0, off.max()
    assert abs(segs[0].area_px - np.pi * rad ** 2) < 0.1 * np.pi * rad ** 2


def test_a_plain_tray_keeps_its_sharp_edge():
    # the grain's bound is only raised on a grainy tray: on a quiet one a grey part's walls still count
    img = np.clip(cloth(3, grain=0.01), 0, 255).astype(np.uint8)
    cv2.rectangle(img, (120, 80), (200, 150), (96, 63, 41), -1)  # a plate darker than the tray (r 0.74)
    segs = segment_frame(img, SegmentParams(min_area_px=60))
    assert len(segs) == 1 and abs(segs[0].area_px - 81 * 71) < 0.05 * 81 * 71


def test_a_bright_patch_at_the_border_is_not_a_part():
    # a lamp's glow at one side that the tray's quadratic field does not follow: bright enough to be
    # evidence, but it has no edge anywhere; a part beside it keeps its outline
    img = cloth(4, bgr=(150, 160, 155), grain=0.03)
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img *= (1.0 + 0.3 * np.exp(-((xx / 60.0) ** 2 + ((yy - 120.0) / 60.0) ** 2)))[:, :, None]
    img = np.clip(img, 0, 255).astype(np.uint8)
    cv2.circle(img, (200, 120), 20, (40, 45, 50), -1)
    segs = segment_frame(img, SegmentParams(min_area_px=60))
    assert [s.cut_off for s in segs] == [False]
    assert abs(segs[0].centroid_px[0] - 200.5) < 1.0


needs_photos = pytest.mark.skipif(not (OBJECTS / "stuff.jpg").is_file() or not (PILLS / "wshed.jpg").is_file(),
                                  reason=f"the shared photographs are not in {EXTERNAL} (../shared/external)")


@needs_photos
def test_stuff_no_part_for_the_light_at_the_left_border():
    img = read_image(OBJECTS / "stuff.jpg")
    segs = segment_frame(img)
    # before: a 3,212 px patch where the table brightens toward the left border, cut off there
    assert not any(s.outline_px[:, 0].min() < 2.0 for s in segs)
    # the pen, the cap, the coin, the lid and the lighter (its metal head and pink body split by colour)
    assert len(segs) == 6
    assert sum(s.merged for s in segs) >= 2


@needs_photos
def test_wshed_pill_outlines_do_not_take_in_their_shadows():
    img = read_image(PILLS / "wshed.jpg")
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float32)
    cloth_grey = float(np.median(grey))
    segs = segment_frame(img, SegmentParams(min_area_px=60))
    assert len(segs) >= 4
    for s in segs:
        m = np.zeros(grey.shape, np.uint8)
        cv2.fillPoly(m, [np.round(s.outline_px * 16).astype(np.int32)], 1, shift=4)
        # the pills are brighter than the cloth; what is darker is their shaded rim and their shadow
        # (before: 0.49 and 0.44 on two regions that had taken in the shadows below them; now 0.20 - 0.30)
        assert (grey[m > 0] < cloth_grey - 10).mean() < 0.35, s.area_px
    lone = [s for s in segs if s.area_px < 400]
    assert len(lone) >= 3  # the three lone pills
    # the heap of touching pills is one region and flagged (it was not before)
    assert max(segs, key=lambda s: s.area_px).merged


def grey_plate(seed: int, k: float, sigma: float = 0.8) -> np.ndarray:
    """A flat grey plate (k x the tray's colour, crisp edges blurred by `sigma` px) on a quiet tray."""
    img = cloth(seed, grain=0.01)
    m = np.zeros(img.shape[:2], np.float32)
    m[80:150, 120:200] = 1.0
    m = cv2.GaussianBlur(m, (0, 0), sigma)[:, :, None]
    return np.clip(img * (1.0 - m) + img * k * m, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("k", [0.62, 0.65, 0.68])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_flat_grey_plate_with_a_blurred_crisp_edge_is_material(seed, k):
    # the plate's edge, blurred by the optics and the detection's own blur, is a band of sharp pixels
    # 2 - 3 px wide: the plate's border pixels lay 3 px from the tray, outside the 5 x 5 neighbourhood
    # where the free border was looked for, so none counted, its sharp share was 0 and the plate was
    # thrown away as a shadow (no region at all for k 0.6 - 0.65; found from 0.7 on, where the band
    # is narrower). Now the tray is looked for across the edge's band
    segs = segment_frame(grey_plate(seed, k), SegmentParams(min_area_px=60))
    assert len(segs) == 1
    assert abs(segs[0].area_px - 80 * 70) < 0.03 * 80 * 70
    assert np.allclose(segs[0].centroid_px, (160.0, 115.0), atol=1.0)


def grey_rectangle(k: float, shape=(1024, 1280), box=(400, 300, 200, 150), seed: int = 0) -> np.ndarray:
    """A flat neutral-grey rectangle (x, y, w, h) at k x a grey tray (170 DN), crisp edges blurred by 0.8 px,
    pixel noise of 1 DN: a grey part on the contract camera's 1280 x 1024 frame."""
    img = np.full((*shape, 3), 170.0, np.float32)
    x, y, w, h = box
    img[y:y + h, x:x + w] *= k
    img = cv2.GaussianBlur(img, (0, 0), 0.8) + np.random.default_rng(seed).normal(0.0, 1.0, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("shape, ks", [((1024, 1280), [0.6, 0.65, 0.7, 0.75, 0.8]),
                                       ((512, 640), [0.6, 0.65, 0.7, 0.75])])
def test_a_flat_grey_part_is_found_at_every_frame_size(shape, ks):
    # detected at 1 / 2 (1280 px), the edge's bound per full-resolution px is 0.12 per detection px, where any
    # crisp step reads about a third of its height: the rectangle needed to be darker than 0.65 of the tray
    # (found at 0.6, none of 0.65 - 0.8); at 640 px (detected at 1 / 1) 0.19 of a step sufficed. A region no part
    # is near is now judged by a crisp edge at the detection's own resolution, whatever the frame's size
    for k in ks:
        segs = segment_frame(grey_rectangle(k, shape))
        assert len(segs) == 1, (k, len(segs))
        assert abs(segs[0].area_px - 200 * 150) < 0.02 * 200 * 150, k
        assert np.allclose(segs[0].centroid_px, (500.0, 375.0), atol=1.0), k


def test_grey_parts_at_1280_px_are_judged_as_before_where_recorded_so():
    # `crisp_edge` None: the sharp edge's bound per full-resolution px everywhere, as recordings made before replay
    assert segment_frame(grey_rectangle(0.7), SegmentParams(crisp_edge=None)) == []


@pytest.mark.parametrize("shape", [(1024, 1280), (512, 640)])
def test_a_soft_shadow_of_something_above_the_tray_is_no_part_at_any_frame_size(shape):
    # no part near it, so judged by the crisp edge's bound: an arm's shadow, its penumbra 6 px (sd)
    img = np.full((*shape, 3), (140.0, 115.0, 90.0), np.float32)
    m = np.zeros(shape, np.float32)
    m[300:450, 400:600] = 1.0
    img *= 1.0 - 0.4 * cv2.GaussianBlur(m, (0, 0), 6.0)[:, :, None]
    img += np.random.default_rng(1).normal(0.0, 1.0, img.shape)
    assert segment_frame(np.clip(np.round(img), 0, 255).astype(np.uint8)) == []


def part_with_strip(seed: int = 0) -> np.ndarray:
    """A red plate (80 x 70 px, centre (140, 115)) on a quiet tray with a crisp shadow-like strip 6 px wide along
    its right side (the tray darkened to 0.6, its colour kept): a wall or the plate's own short shadow."""
    img = cloth(seed, grain=0.01)
    plate, strip = np.zeros(img.shape[:2], np.float32), np.zeros(img.shape[:2], np.float32)
    plate[80:150, 100:180] = 1.0
    strip[80:150, 180:186] = 1.0
    plate, strip = (cv2.GaussianBlur(m, (0, 0), 0.8)[:, :, None] for m in (plate, strip))
    img = img * (1.0 - 0.4 * strip)
    img = img * (1.0 - plate) + np.array([40, 40, 200], np.float32) * plate
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("vertical_px, wall", [((300, 115), True), ((165, 115), False), ((20, 115), False)])
def test_a_strip_beside_a_part_is_its_wall_only_where_the_vertical_lies_beyond_it(vertical_px, wall):
    # walls show on the side of a part that faces the image of the vertical. With the vertical inside the plate
    # (165, 115), right of its centre, no wall shows anywhere; the strip on the right was kept as a wall all the
    # same (within 72 degrees of the vertical's direction from the plate's centre). It still is with
    # `walls_beyond` off, as recordings made before replay
    plate, with_strip = 80 * 70, 86 * 70
    segs = segment_frame(part_with_strip(), SegmentParams(min_area_px=60, vertical_px=vertical_px))
    assert len(segs) == 1 and abs(segs[0].area_px - (with_strip if wall else plate)) < 0.02 * plate
    before = segment_frame(part_with_strip(), SegmentParams(min_area_px=60, vertical_px=vertical_px,
                                                            walls_beyond=False))
    assert abs(before[0].area_px - (plate if vertical_px[0] < 100 else with_strip)) < 0.02 * plate


# flat rectangles pasted on stuff.jpg's empty table (x, y, w, h), away from the objects and their shadows
PATCHES = [(520, 100, 60, 40), (120, 250, 60, 40), (470, 330, 60, 40), (80, 400, 60, 40), (560, 400, 60, 40)]


def patched(img: np.ndarray, k: float, sigma: float = 0.8) -> np.ndarray:
    """stuff.jpg with PATCHES pasted, each k x the table's local colour (its median there), edges blurred."""
    out = img.astype(np.float32)
    for x, y, w, h in PATCHES:
        colour = np.median(img[y:y + h, x:x + w].reshape(-1, 3), axis=0) * k
        m = np.zeros(img.shape[:2], np.float32)
        m[y:y + h, x:x + w] = 1.0
        m = cv2.GaussianBlur(m, (0, 0), sigma)[:, :, None]
        out = out * (1.0 - m) + colour * m
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


@needs_photos
@pytest.mark.parametrize("k", [0.65, 0.75])
def test_stuff_flat_grey_patches_are_found(k):
    # before: 2 of the 5 at 0.65 and at 0.75 (the others thrown away as shadows: their free border's
    # sharp share came out 0 - 0.3, the border pixels being beyond the 5 x 5 reach of the tray). The
    # fifth, (80, 400), lies where the table is darker than its fitted field: part of it reads darker
    # than any shadow (r < 0.55), the rest hangs on that as on a part, on the side turned from the
    # vertical: still lost (docs/vision.md, Limits)
    img = read_image(OBJECTS / "stuff.jpg")
    segs = segment_frame(patched(img, k))
    found = [any(abs(s.centroid_px[0] - (x + w / 2)) < 2 and abs(s.centroid_px[1] - (y + h / 2)) < 2
                 and abs(s.area_px - w * h) < 0.05 * w * h for s in segs) for x, y, w, h in PATCHES]
    assert sum(found) >= 4, found
    # the five objects are still there, with nothing taken from their shadows
    # (the patches move the tray's fitted field a little: the lighter's small grey head is 454 px, 580 plain)
    for o in [o for o in segment_frame(img) if o.area_px > 900]:
        assert any(np.hypot(*(s.centroid_px - o.centroid_px)) < 3 and abs(s.area_px - o.area_px) < 0.05 * o.area_px
                   for s in segs), o.area_px
    assert len(segs) == 6 + sum(found)


@needs_photos
def test_stuff_flat_grey_patches_are_found_on_the_photograph_upscaled_to_1280_px():
    # the patches at 0.7 (5 of 5 at 640 px) and the photograph upscaled 2 x (bicubic): detected at 1 / 2, the
    # sharp edge per full-resolution px took them all for shadows (0 of 5). The fifth is the one of the darker
    # left (Limits), lost at 640 px too at 0.65 and 0.75
    img = read_image(OBJECTS / "stuff.jpg")
    segs = segment_frame(cv2.resize(patched(img, 0.7), None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC))
    found = [any(np.hypot(*(s.centroid_px - (2 * x + w, 2 * y + h))) < 4
                 and abs(s.area_px - 4 * w * h) < 0.05 * 4 * w * h for s in segs) for x, y, w, h in PATCHES]
    assert sum(found) >= 4, found
    plain = segment_frame(cv2.resize(img, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC))
    for o in [o for o in plain if o.area_px > 4 * 900]:  # the objects, nothing taken from their shadows
        assert any(np.hypot(*(s.centroid_px - o.centroid_px)) < 6 and abs(s.area_px - o.area_px) < 0.05 * o.area_px
                   for s in segs), o.area_px
    assert len(segs) == len(plain) + sum(found)
