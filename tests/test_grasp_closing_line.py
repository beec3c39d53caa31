"""`SynthesisParams.contacts_on_closing_line`: contacts on faces square to the closing axis are reported on
the line through the grasp centre (cell.grasp.closing_line)."""

import math

import numpy as np
import pytest
import shapely
from shapely.geometry import Point

from cell.cellconfig import default_cell
from cell.examples import load_examples
from cell.grasp.closing_line import onto_closing_line
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import GraspPlanner
from cell.physics import check_grasp
from cell.runtime.replay import planner_from_meta
from cell.scene import Scene, parse_part

CELL = default_cell()
# a T a checker drew (its stem's parallel faces 28 mm apart): sampled 2 mm apart along the outline, the chosen
# pair lay 0.5 mm either side of the closing line, the contacts' line 2.03 deg off the reported angle_deg
T_SHAPE = [[473.2265, 238.3554], [466.3111, 227.821], [460.9312, 231.3527], [478.2937, 257.8015],
           [483.6736, 254.2698], [476.7582, 243.7354], [494.7643, 231.9152], [491.2326, 226.5353]]


def line_off_axis_deg(g) -> float:
    c = g.contacts_mm
    line = math.degrees(math.atan2(c[1, 1] - c[0, 1], c[1, 0] - c[0, 0]))
    return abs((line - g.axis_deg + 90.0) % 180.0 - 90.0)


def test_contacts_on_parallel_faces_are_reported_on_the_closing_line():
    target = parse_part({"id": "t", "z_top": 20.0, "outline": T_SHAPE})
    # (sampled from its first vertex as listed: there the samples on the two faces lay off the closing line)
    grasps = {flag: GraspPlanner(CELL, load_examples(None), SynthesisParams(
        contacts_on_closing_line=flag, vertex_order_free=False)).plan(Scene((target,), "t")).grasp
        for flag in (False, True)}
    old, new = grasps[False], grasps[True]
    assert line_off_axis_deg(old) > 1.0
    assert line_off_axis_deg(new) < 1e-6
    # slid along their faces: the centre, the axis, the joints and the gap along the axis stay
    assert np.allclose(new.center_mm, old.center_mm, atol=1e-9) and new.axis_deg == old.axis_deg
    assert new.joints == old.joints
    u = np.array([math.cos(math.radians(old.axis_deg)), math.sin(math.radians(old.axis_deg))])
    assert abs((new.contacts_mm[1] - new.contacts_mm[0]) @ u) == pytest.approx(
        abs((old.contacts_mm[1] - old.contacts_mm[0]) @ u), abs=1e-9)
    assert new.opening_mm == np.linalg.norm(new.contacts_mm[1] - new.contacts_mm[0]) < old.opening_mm
    assert all(target.polygon.exterior.distance(Point(c)) < 1e-6 for c in new.contacts_mm)
    assert check_grasp(target, new.contacts_mm, new.axis_deg, new.grasp_z_mm, cell=CELL).ok
    assert not planner_from_meta({}, "old").contacts_on_closing_line


def test_a_contact_is_slid_only_along_a_straight_stretch_square_to_the_axis():
    boundary = shapely.Polygon([[0, 0], [40, 0], [40, 10], [0, 10]]).boundary
    centre = np.array([20.0, 5.0])
    on_faces = np.array([[19.5, 10.0], [20.5, 0.0]])  # 0.5 mm either side of the vertical closing line
    assert np.allclose(onto_closing_line(boundary, on_faces, centre, 90.0), [[20, 10], [20, 0]])
    # a notch between a contact and the line (0.2 mm wide; 0.23 mm between where four probes looked): the
    # outline does not run straight there, the contacts stay
    notched = shapely.Polygon([[0, 0], [40, 0], [40, 10], [19.9, 10], [19.9, 9], [19.7, 9], [19.7, 10],
                               [0, 10]]).boundary
    assert np.array_equal(onto_closing_line(notched, on_faces, centre, 90.0), on_faces)
    notched = shapely.Polygon([[0, 0], [40, 0], [40, 10], [19.49, 10], [19.49, 8], [19.26, 8], [19.26, 10],
                               [0, 10]]).boundary
    far = np.array([[19.0, 10.0], [21.0, 0.0]])
    assert np.array_equal(onto_closing_line(notched, far, centre, 90.0), far)
    # faces drawn with coordinates rounded to 0.01 mm (0.03 deg off square): slid, under a micrometre off the outline
    rounded = shapely.Polygon([[0, 0], [40, 0], [40, 10.01], [0, 9.99]]).boundary
    c = np.array([[19.5, 10.0 - 0.02 * 0.5 / 40], [20.5, 0.0]])
    moved = onto_closing_line(rounded, c, 0.5 * (c[0] + c[1]), 90.0)
    assert np.allclose(moved[:, 0], 20.0) and rounded.distance(shapely.Point(moved[0])) < 1e-3
    # NaN in, nothing slid
    assert np.isnan(onto_closing_line(boundary, np.full((2, 2), np.nan), centre, 90.0)).all()
    # a face slanted to the pads (the contact 0.5 mm across, the face 0.01 mm lower at the line): they stay
    slanted = shapely.Polygon([[0, 0], [40, 0], [40, 9.6], [0, 10.4]]).boundary
    c = np.array([[19.5, 10.01], [20.5, 0.0]])
    assert np.array_equal(onto_closing_line(slanted, c, 0.5 * (c[0] + c[1]), 90.0), c)
