"""Matching on a full tray maps each region at a part's heights only where the part may be, once per pair of
heights, and decides exactly as mapping every region at every part's heights did: rendered frames of a
dense layout from the parts library -> the real segmentation -> segment_to_mm as the loop calls it."""

import numpy as np
import pytest
from shapely.geometry import Polygon

from cell.commands import bench_perception as bench
from cell.commands.bench_perception import LAYOUTS, grid_layout
from cell.runtime.matching import MAX_SHIFT_MM, Region, RegionOutline, box_gap_mm, locate, unexplained


@pytest.fixture(scope="module")
def tray():
    """(calibration, frame, segments, parts) of the rendered grid layout."""
    from calibration import load_calibration
    from cell.vision import SegmentParams, SimCamera, SimCameraOptions, segment_frame

    cal = load_calibration()
    parts = grid_layout(*LAYOUTS[28])
    frame = SimCamera(cal, SimCameraOptions(seed=3)).render(parts)
    return cal, frame, segment_frame(frame, SegmentParams.for_calibration(cal)), parts


def loop_mapping(seg, cal, frame, calls=None):
    """The region's outline in mm as the loop maps it; `calls` counts the mappings."""
    at = bench.loop_mapping(seg, cal, frame)

    def polygon_at(z_top, z_bottom):
        if calls is not None:
            calls.append((id(seg), z_top, z_bottom))
        return at(z_top, z_bottom)
    return polygon_at


def test_a_pixel_at_any_height_is_its_point_at_another_scaled_about_the_camera_foot():
    # the lemma box_mm rests on: one scale about (t_x, t_y) for every pixel, lens distortion or not
    from calibration import load_calibration

    cal = load_calibration()
    rng = np.random.default_rng(0)
    px = np.vstack([rng.uniform([0, 0], [cal.width_px, cal.height_px], (200, 2)),
                    [[0, 0], [cal.width_px, 0], [0, cal.height_px], [cal.width_px, cal.height_px]]])
    foot, cam_z = cal.cam2base[:2, 3], cal.cam2base[2, 3]
    at_ref = cal.px_to_mm(px, 0.0)
    for z in (-5.0, 12.5, 45.0, 120.0):
        k = (z - cam_z) / (0.0 - cam_z)
        assert np.allclose(cal.px_to_mm(px, z), foot + k * (at_ref - foot), rtol=0, atol=1e-9)


def test_the_box_holds_every_outline_the_region_maps_to_at_every_part_height(tray, monkeypatch):
    import cell.vision.topface as topface

    cal, frame, segments, parts = tray
    faces = []
    real_face = topface.top_face_px

    def face(*args, **kw):
        found = real_face(*args, **kw)
        faces.append(found is not None)
        return found
    monkeypatch.setattr(topface, "top_face_px", face)
    heights = sorted({(p.z_top_mm, p.z_bottom_mm) for p in parts}) + [(0.0, 0.0), (80.0, 10.0)]
    slack = []  # at the parts' heights
    for seg in segments:
        outline = RegionOutline(loop_mapping(seg, cal, frame), [seg.outline_px, *seg.holes_px], cal)
        for z_top, z_bottom in heights:
            x0, y0, x1, y1 = outline(z_top, z_bottom).bounds
            bx0, by0, bx1, by1 = outline.box_mm(z_top, z_bottom)
            assert bx0 <= x0 and by0 <= y0 and x1 <= bx1 and y1 <= by1, (z_top, z_bottom)
            if z_top < 80.0:
                slack.append(max(x0 - bx0, y0 - by0, bx1 - x1, by1 - y1))
    assert any(faces), "no outline took the top-face path: the margin for a face's rings went untried"
    # a few mm (the face margin, the heights: a region mapped at both of a tall part's holds both scales)
    assert np.median(slack) < 6.0 and max(slack) < 20.0, (np.median(slack), max(slack))


def test_without_a_pose_nothing_is_ruled_out_and_each_height_is_still_mapped_once():
    calls = []
    square = Polygon([(0, 0), (10, 0), (10, 10), (0, 10)])
    outline = RegionOutline(lambda zt, zb: calls.append((zt, zb)) or square, [np.zeros((4, 2))], object())
    region = Region(0, outline)
    assert outline(5.0, 0.0) is outline(5.0, 0.0) and calls == [(5.0, 0.0)]
    far = type("P", (), {"z_top_mm": 5.0, "z_bottom_mm": 0.0, "polygon": Polygon([(900, 0), (910, 0), (910, 9)])})
    assert outline.box_mm(5.0, 0.0) is None and not region.surely_farther(far, MAX_SHIFT_MM)


def test_box_gap_is_the_distance_between_boxes():
    assert box_gap_mm((0, 0, 10, 10), (13, 14, 20, 20)) == 5.0
    assert box_gap_mm((0, 0, 10, 10), (5, 5, 20, 20)) == 0.0
    assert box_gap_mm((13, 0, 20, 1), (0, 0, 10, 10)) == 3.0


def test_locate_on_a_full_tray_maps_only_near_regions_once_and_decides_the_same(tray):
    cal, frame, segments, parts = tray
    every = [Region(i, loop_mapping(s, cal, frame), s.merged, s.cut_off) for i, s in enumerate(segments)]
    calls = []
    outlines = [RegionOutline(loop_mapping(s, cal, frame, calls), [s.outline_px, *s.holes_px], cal)
                for s in segments]
    scaled = [Region(i, o, s.merged, s.cut_off) for i, (o, s) in enumerate(zip(outlines, segments))]
    assert len(parts) >= 24 and len(segments) >= len(parts)
    found_every, strangers_every = locate(parts, every)
    found, strangers = locate(parts, scaled)
    assert found == found_every and strangers == strangers_every  # every pose to the last bit
    assert len(found) == len(parts)
    assert len(calls) == len(set(calls)), "a region was mapped twice at the same heights"
    all_pairs = len(parts) * len(segments)
    assert len(calls) < 0.3 * all_pairs, (len(calls), all_pairs)  # was all of them: n (n + 1) a frame
    seen = {pid: loc.apply(next(p for p in parts if p.id == pid)) for pid, loc in found.items()}
    before = len(calls)
    assert unexplained(scaled, seen, found, 60.0) == unexplained(every, seen, found, 60.0)
    assert len(calls) - before < len(segments)  # at the located parts' heights: already mapped
