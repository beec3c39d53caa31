"""The top face of tall parts: fins, deep holes and tooth gaps hidden by walls (cell/vision/topface.py)."""

from dataclasses import replace

import numpy as np
import pytest

from calibration import load_calibration
from cell import parts_library as lib
from cell.vision import SegmentParams, SimCamera, SimCameraOptions, segment_frame, segment_to_mm
from cell.vision.bench import _ring_errors
from cell.vision.topface import top_face_px

CAL = load_calibration()
PARAMS = SegmentParams.for_calibration(CAL)


def render(part, **opts):
    return SimCamera(CAL, replace(SimCameraOptions(seed=3), **opts)).render([part])


def rms_mm(outline, holes, part) -> float:
    d1, d2 = _ring_errors([outline] + holes, part.polygon)
    return float(np.sqrt(np.mean(np.concatenate([d1, d2]) ** 2)))


def silhouette_only(seg):
    """The same region mapped point by point (what segment_to_mm does when no top face is accepted)."""
    return replace(seg, cut_off=True)  # cut-off regions never take the top-face path


@pytest.mark.parametrize("name, x, y, th", [("heatsink_s", 430, 160, 30), ("heatsink_m", 260, -150, -70)])
def test_fins_hidden_by_their_walls_come_back_from_the_top_face(name, x, y, th):
    part = lib.place(lib.part(name), x, y, th)
    frame = render(part)
    seg = segment_frame(frame, PARAMS)[0]
    assert top_face_px(seg, frame, CAL, part.z_top_mm, part.z_bottom_mm, PARAMS) is not None
    rms = rms_mm(*segment_to_mm(seg, CAL, part.z_top_mm, part.z_bottom_mm, frame), part)
    rms_silhouette = rms_mm(*segment_to_mm(silhouette_only(seg), CAL, part.z_top_mm, part.z_bottom_mm, frame), part)
    assert rms < 0.35 and rms_silhouette > 2.0  # the silhouette fills the gaps between the fins


def test_bolt_holes_of_a_tall_housing_are_found_on_its_top():
    part = lib.place(lib.part("motor_housing_s"), 420, 150, 30)  # 45 mm tall: the holes are not seen through
    frame = render(part)
    seg = segment_frame(frame, PARAMS)[0]
    assert len(seg.holes_px) < len(part.holes_mm)
    outline, holes = segment_to_mm(seg, CAL, part.z_top_mm, part.z_bottom_mm, frame)
    assert len(holes) == len(part.holes_mm)
    assert rms_mm(outline, holes, part) < 0.35


def test_walls_as_bright_as_the_top_are_not_taken_for_a_face():
    # the light does not make walls darker: no face explains the silhouette, it is mapped point by point
    part = lib.place(lib.part("heatsink_s"), 430, 160, 30)
    frame = render(part, wall_shade=1.0)
    seg = segment_frame(frame, PARAMS)[0]
    assert top_face_px(seg, frame, CAL, part.z_top_mm, part.z_bottom_mm, PARAMS) is None


def test_a_dark_marking_wider_than_the_walls_is_not_taken_for_a_hole():
    part = lib.place(lib.part("enclosure_m"), 420, 150, 30)  # 30 mm tall, no holes
    frame = render(part).copy()
    seg = segment_frame(frame, PARAMS)[0]
    assert top_face_px(seg, frame, CAL, part.z_top_mm, part.z_bottom_mm, PARAMS) is not None
    c = np.round(seg.centroid_px).astype(int)
    frame[c[1] - 25:c[1] + 25, c[0] - 25:c[0] + 25] //= 2  # a label printed on the top, 25 mm wide
    assert top_face_px(seg, frame, CAL, part.z_top_mm, part.z_bottom_mm, PARAMS) is None
    outline, holes = segment_to_mm(seg, CAL, part.z_top_mm, part.z_bottom_mm, frame)
    assert holes == [] and rms_mm(outline, holes, part) < 1.0


def test_low_parts_and_parts_near_the_image_centre_keep_the_silhouette():
    part = lib.place(lib.part("cover_rect_m"), 350, 0, 30)  # under the camera: walls under 2 px
    frame = render(part)
    seg = segment_frame(frame, PARAMS)[0]
    assert top_face_px(seg, frame, CAL, part.z_top_mm, part.z_bottom_mm, PARAMS) is None


def test_two_touching_parts_of_different_heights_are_not_one_face():
    # a merged region takes the top-face path only when one face explains all of it
    tall = lib.place(lib.part("box_housing_m"), 420, 150, 0)
    low = lib.place(lib.part("cover_rect_m"), 0, 0, 0)
    gap = tall.polygon.bounds[2] - low.polygon.bounds[0] - 0.5
    low = low.moved(gap, 150 + 0.0)
    assert tall.polygon.distance(low.polygon) < 1.0 and not tall.polygon.intersects(low.polygon.buffer(-0.2))
    frame = SimCamera(CAL, SimCameraOptions(seed=3)).render([tall, low])
    region = max(segment_frame(frame, PARAMS), key=lambda s: s.area_px)
    assert region.area_px > 1.2 * segment_frame(render(tall), PARAMS)[0].area_px  # the two came out as one
    assert top_face_px(region, frame, CAL, tall.z_top_mm, tall.z_bottom_mm, PARAMS) is None
