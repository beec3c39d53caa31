"""Tests written in the sixth session's mutation pass over the friction check's pieces (cell/physics.py)
and the image reader (cell/vision/sources.py), for mutants the other tests let through."""

import math

import numpy as np
import pytest
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

from cell.physics import MU, PATCH_DEPTH_MM, _edge_reason, _pad_shares, _tip_in_patch, check_grasp
from cell.scene import Part

FRICTION_DEG = math.degrees(math.atan(MU))  # 16.699 deg
HALF_W = 6.0  # the default pads' half width: the band's border at y = +-6


def part(pid, geom, z_top, mass_g):
    return Part(pid, np.asarray(geom.exterior.coords)[:-1], (), 0.0, z_top, meta={"mass_g": mass_g})


# ------------------------------------------------------------------ _pad_shares: f1 - f0 = 2 W e / d
@pytest.mark.parametrize(("along_mm", "width_mm", "shares"), [
    (0.0, 20.0, (0.5, 0.5)),
    (5.0, 20.0, (0.25, 0.75)),  # towards the second pad: it carries more
    (-5.0, 20.0, (0.75, 0.25)),
    (0.1, 0.5, (0.3, 0.7)),  # a 0.5 mm thin part: divided by its own width, not by a floor of 1 mm
])
def test_each_pads_share_of_the_weight(along_mm, width_mm, shares):
    assert _pad_shares(along_mm, width_mm) == pytest.approx(shares)


def test_the_shares_are_worked_out_over_the_width_the_pads_stop_at_not_the_reported_contacts():
    """An H plate's web 20 mm wide, its centre of gravity 18 mm along the axis from the web's middle; the
    contacts reported 0.5 mm outside each face (within the 2 mm contact tolerance), 21 mm apart."""
    h = part("h", unary_union([box(0, -10, 20, 10), box(0, 10, 60, 40), box(0, -40, 60, -10)]), 10.0, 1.0)
    v = check_grasp(h, [[-0.5, 0.0], [20.5, 0.0]], 0.0, 2.0)
    assert v.jaw_width_mm == pytest.approx(20.0) and v.cog_along_mm == pytest.approx(18.0)
    assert v.extra["pad_shares"] == pytest.approx((0.5 - 18.0 / 20.0, 0.5 + 18.0 / 20.0))


# ------------------------------------------------------------------ the hold ratio exactly 1 holds
@pytest.mark.parametrize(("mass_g", "ok"), [(1223.2415902140672, True), (1223.2415902140674, False)])
def test_a_demand_exactly_at_the_capacity_holds(mass_g, ok):
    """A 20 mm cube held across its middle: slip and roll both at SAFETY x W / (2 mu N) = 1.0 exactly."""
    v = check_grasp(part("cube", box(0, -10, 20, 10), 20.0, mass_g), [[0.0, 0.0], [20.0, 0.0]], 0.0, 2.0)
    assert (v.torque_ratio == 1.0) == ok and v.ok == ok, v.reasons


# ------------------------------------------------------------------ _edge_reason: as many decimals as tell them apart
def test_a_slope_a_thousandth_of_a_degree_outside_the_cone_reads_with_three_decimals():
    reason = _edge_reason(1, 16.704, FRICTION_DEG, 1.2, False)
    assert "(16.704 deg > 16.699 deg)" in reason and reason.startswith("contact 1 is outside the friction cone")


def test_a_tip_reads_as_a_tip_with_its_width():
    reason = _edge_reason(0, 84.1, FRICTION_DEG, 0.05, True)
    assert reason.startswith("contact 0: only the pad's edge touches the part, on a tip reaching 0.05 mm")


# ------------------------------------------------------------------ _tip_in_patch: a tip turns back inside the patch
def _patch(*far_points):
    """A patch of material from the band's border (y = 6) down to `far_points`, the pad's face at x = 0."""
    return Polygon([(0.0, HALF_W), *far_points, (PATCH_DEPTH_MM, HALF_W)])


@pytest.mark.parametrize(("patch", "tip"), [
    (_patch((0.1, 5.0), (PATCH_DEPTH_MM, 5.0005)), True),  # the one farthest point is near the face: a tip
    (_patch((0.0, 5.0), (PATCH_DEPTH_MM, 5.0)), False),  # a face parallel to the axis, reaching the far side
    (_patch((PATCH_DEPTH_MM - 0.05, 5.0), (PATCH_DEPTH_MM, 5.5)), True),  # turns back 0.05 mm short of it
    (_patch((0.0, 5.5), (PATCH_DEPTH_MM - 5e-7, 5.0), (PATCH_DEPTH_MM, 5.5)), False),  # the far side, to float noise
])
def test_a_tip_is_told_from_a_slope_by_where_its_farthest_point_from_the_border_lies(patch, tip):
    assert _tip_in_patch(patch, 0.0, HALF_W) == tip


# ------------------------------------------------------------------ read_image: bit depths and channels
def _read(tmp_path, img, name="frame.png", grey=False):
    import cv2

    from cell.vision.sources import read_image

    path = tmp_path / name
    assert cv2.imwrite(str(path), img)
    return read_image(path, grey=grey)


@pytest.mark.parametrize(("top", "depth"), [(255, 8), (256, 10), (1023, 10), (1024, 12), (4095, 12), (16383, 14),
                                            (16384, 16), (65535, 16)])
def test_a_16_bit_frame_is_scaled_by_the_smallest_bit_depth_holding_its_maximum(tmp_path, top, depth):
    ramp = np.linspace(0, top, 64 * 64).round().astype(np.uint16).reshape(64, 64)
    got = _read(tmp_path, ramp, grey=True)
    want = np.round(ramp.astype(float) * 255.0 / (2**depth - 1))
    assert got.dtype == np.uint8 and np.abs(got.astype(float) - want).max() <= 0.5 + 1e-6
    if depth == 8:
        assert np.array_equal(got, ramp)


def test_a_full_range_16_bit_copy_of_an_8_bit_frame_gives_back_that_frame(tmp_path):
    frame = np.arange(256, dtype=np.uint8).repeat(3).reshape(16, 16, 3)
    assert np.array_equal(_read(tmp_path, frame.astype(np.uint16) * 257), frame)


@pytest.mark.parametrize(("top", "alpha"), [(0.5, 255.0), (1.0, 255.0), (4.0, 255.0 / 4.0), (4000.0, 255.0 / 4000.0)])
def test_a_float_frame_in_0_1_is_times_255_and_a_brighter_one_scaled_to_its_maximum(tmp_path, top, alpha):
    ramp = np.linspace(0.0, top, 64 * 64, dtype=np.float32).reshape(64, 64)
    got = _read(tmp_path, ramp, "frame.tiff", grey=True)
    assert np.abs(got.astype(float) - np.minimum(ramp.astype(float) * alpha, 255.0)).max() <= 0.5 + 1e-3


def test_a_colour_float_frame_read_grey_weighs_blue_green_red_as_an_8_bit_frame_does(tmp_path):
    bgr = np.zeros((8, 24, 3), np.float32)
    bgr[:, :8, 0], bgr[:, 8:16, 1], bgr[:, 16:, 2] = 1.0, 1.0, 1.0  # blue, green, red
    want = _read(tmp_path, (bgr * 255).astype(np.uint8), "frame8.png", grey=True)
    got = _read(tmp_path, bgr, "frame.tiff", grey=True)
    assert np.abs(got.astype(int) - want).max() <= 1 and list(got[0, [0, 16]]) == [29, 76]  # blue is darker than red


@pytest.mark.parametrize("grey", [False, True])
def test_a_float_frame_with_alpha_keeps_its_colours(tmp_path, grey):
    bgra = np.zeros((8, 16, 4), np.float32)
    bgra[:, :8, 0], bgra[:, 8:, 2], bgra[..., 3] = 1.0, 1.0, 1.0  # blue, then red; opaque
    got = _read(tmp_path, bgra, "frame.tiff", grey=grey)
    if grey:
        assert got.shape == (8, 16) and list(got[0, [0, 8]]) == [29, 76]
    else:
        assert got.shape == (8, 16, 3) and got[0, 0].tolist() == [255, 0, 0] and got[0, 8].tolist() == [0, 0, 255]


def test_a_frame_decoded_with_two_channels_is_refused():
    from pathlib import Path

    from cell.errors import BadInput
    from cell.vision.sources import _with_channels

    for grey in (False, True):
        with pytest.raises(BadInput, match="has 2 channels; grey, colour or colour with alpha images are read"):
            _with_channels(np.zeros((8, 8, 2), np.uint8), grey, Path("frame.tiff"))


def test_an_empty_file_is_said_to_be_empty(tmp_path):
    from cell.errors import BadInput
    from cell.vision.sources import read_image

    path = tmp_path / "frame.png"
    path.write_bytes(b"")
    with pytest.raises(BadInput, match=r"frame.png is empty \(0 bytes\)"):
        read_image(path)
