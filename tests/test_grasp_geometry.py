"""Geometry of the grasp pipeline: resampling, normals, centroid, attributes and their invariance."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from cell.grasp import shapes
from cell.grasp.attributes import describe_points, global_attributes, local_attributes
from cell.grasp.candidates import candidate_points, free_mask, side_neighbours
from cell.grasp.outline import Ring, centre_of_gravity, part_rings, project_to_outline, resample
from cell.grasp.params import SynthesisParams
from cell.scene import parse_part

PARAMS = SynthesisParams()


def test_resampling_is_even_along_the_outline_and_on_it():
    part = shapes.rectangle("r", 60, 30)
    rings = part_rings(part)
    ring_idx, arc = resample(rings, 2.0)
    assert len(arc) == round(180 / 2.0)
    pts = rings[0].at(arc)
    gaps = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
    # straight runs are exactly one step apart; across a corner the chord is shorter
    assert np.isclose(np.median(gaps), 2.0)
    assert np.all(gaps <= 2.0 + 1e-9)
    assert max(part.polygon.boundary.distance(Point(p)) for p in pts) < 1e-9


def test_resampling_a_ring_with_a_hole_covers_both_and_keeps_the_step():
    part = shapes.disc("d", 30, hole_r_mm=10, n=180)
    ring_idx, arc = resample(part_rings(part), 3.0)
    assert set(ring_idx.tolist()) == {0, 1}
    assert abs((ring_idx == 0).sum() - 2 * math.pi * 30 / 3.0) < 2
    assert abs((ring_idx == 1).sum() - 2 * math.pi * 10 / 3.0) < 2


def test_normals_point_away_from_the_material_on_outline_and_holes():
    part = shapes.disc("d", 30, hole_r_mm=10)
    op, _ = candidate_points(part, [], PARAMS)
    poly = part.polygon
    for p, n in zip(op.points, op.normals, strict=True):
        assert not poly.contains(Point(p + 0.5 * n))
        assert poly.contains(Point(p - 0.5 * n))


def test_centre_of_gravity_takes_the_holes_out():
    # 100 x 100 square with a 20 x 20 hole whose centre is 30 mm right of the square's centre
    sq = [[0, 0], [100, 0], [100, 100], [0, 100]]
    hole = [[70, 40], [90, 40], [90, 60], [70, 60]]
    part = parse_part({"id": "p", "outline": sq, "holes": [hole], "z_top": 5})
    cx = (100 * 100 * 50 - 400 * 80) / (10000 - 400)
    assert np.allclose(centre_of_gravity(part), [cx, 50.0])


def test_convexity_is_positive_at_corners_negative_in_notches_zero_on_flats():
    ell = shapes.l_shape("l", 60, 40, 15, center=(0, 0))
    rings = part_rings(ell)
    verts = ell.outline_mm
    cog = centre_of_gravity(ell)
    # the inner (reflex) corner is the vertex nearest to the centre of gravity
    inner = verts[np.argmin(np.linalg.norm(verts - cog, axis=1))]
    outer = verts[np.argmax(np.linalg.norm(verts - cog, axis=1))]
    arcs = [project_to_outline(rings, p)[1] for p in (inner, outer)]
    r_flat, s_flat, _ = project_to_outline(rings, 0.5 * (verts[0] + verts[1]))
    op = describe_points(rings, [0, 0, 0], [*arcs, s_flat], (3.0, 6.0, 12.0))
    assert np.all(op.convexity[0] < -0.3)
    assert np.all(op.convexity[1] > 0.3)
    assert np.allclose(op.convexity[2, :2], 0.0, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(dx=st.floats(-150, 150), dy=st.floats(-200, 200), angle=st.floats(-180, 180),
       which=st.sampled_from(["l", "gear", "ring", "split ring"]))
def test_local_and_global_attributes_do_not_change_when_the_part_moves(dx, dy, angle, which):
    from test_grasp_learning import _split_ring

    part = {"l": shapes.l_shape("p", 70, 45, 15), "gear": shapes.gear("p", 28, 9, 3),
            "ring": shapes.disc("p", 25, hole_r_mm=9), "split ring": _split_ring(60.0, 5.0, 3.0)}[which]
    moved = part.moved(dx, dy, angle)
    a = [part_rings(p) for p in (part, moved)]
    ring_idx, arc = resample(a[0], PARAMS.step_mm)
    ops = [describe_points(r, ring_idx, arc, PARAMS.scales_mm) for r in a]
    La, Lb = (local_attributes(op, p, True, PARAMS.closed_slit_mm) for op, p in zip(ops, (part, moved), strict=True))
    assert np.allclose(La, Lb, atol=1e-6)
    # the moved points are the original points moved
    t = math.radians(angle)
    rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    c = centre_of_gravity(part)
    assert np.allclose((ops[0].points - c) @ rot.T + c + (dx, dy), ops[1].points, atol=1e-6)
    pairs = np.array([[0, len(arc) // 2], [3, len(arc) // 3], [5, len(arc) - 7]])
    Ga, Gb = (global_attributes(op.points[pairs], op.chord_normals[pairs], p, True, PARAMS.closed_slit_mm)
              for op, p in zip(ops, (part, moved), strict=True))
    assert np.allclose(Ga, Gb, atol=1e-6)


def test_global_attributes_ignore_the_order_of_the_contacts_and_see_centring():
    part = shapes.rectangle("r", 60, 30, center=(0, 0))
    rings = part_rings(part)
    arcs = [project_to_outline(rings, p)[1] for p in ([0, 15], [0, -15], [20, 15], [20, -15], [30, 0], [0, 15])]
    op = describe_points(rings, [0] * 6, arcs, PARAMS.scales_mm)
    sets = np.array([[0, 1], [1, 0], [2, 3], [4, 5]])
    G = global_attributes(op.points[sets], op.chord_normals[sets], part)
    assert np.allclose(G[0], G[1])
    assert G[0, 0] == pytest.approx(0.0, abs=1e-9) and G[2, 0] == pytest.approx(20.0)
    assert np.allclose(G[0, 2:], 0.0, atol=1e-6)  # facing straight at each other at every scale
    assert G[3, 2] > 30  # an end and a side: the worst contact is far from pushing at the centre


def test_relative_distance_is_size_free_and_mm_distance_is_not():
    small, big = shapes.l_shape("s", 60, 40, 15), shapes.l_shape("b", 120, 80, 30)
    Ls = []
    for p in (small, big):
        rings = part_rings(p)
        op = describe_points(rings, [0], [rings[0].length_mm * 0.1], PARAMS.scales_mm)
        Ls.append(local_attributes(op, p))
    assert Ls[0][0, 1] == pytest.approx(Ls[1][0, 1], rel=1e-6)
    assert Ls[1][0, 0] == pytest.approx(2 * Ls[0][0, 0], rel=1e-6)


def test_contact_with_a_neighbour_is_not_free_area_but_a_part_underneath_is():
    target = shapes.rectangle("t", 60, 30, center=(350, 0), z_top_mm=20, z_bottom_mm=5)  # on the plate
    touching = shapes.rectangle("n", 20, 30, center=(350 + 30 + 10 + 1.0, 0), z_top_mm=10)  # 1 mm gap
    apart = shapes.rectangle("far", 20, 30, center=(350 + 30 + 10 + 3.0, 0), z_top_mm=10)  # 3 mm gap
    below = parse_part({"id": "plate", "outline": [[250, -100], [450, -100], [450, 100], [250, 100]],
                        "z_bottom": 0, "z_top": 5})
    assert [p.id for p in side_neighbours(target, [touching, apart, below])] == ["n", "far"]
    op, free = candidate_points(target, [touching, below], PARAMS)
    blocked = op.points[~free]
    assert len(blocked) == 15 and np.allclose(blocked[:, 0], 380.0)
    _, free2 = candidate_points(target, [apart], PARAMS)
    assert free2.all()
    assert free_mask(op.points, [], 1.5).all()


def test_a_neighbour_no_higher_than_the_grasp_z_leaves_the_outline_free():
    # the pads hold the target above the grasp z and pass over a lower part beside it, as the fingers do
    target = shapes.rectangle("t", 60, 30, center=(350, 0), z_top_mm=20, z_bottom_mm=0)
    low = shapes.rectangle("low", 20, 30, center=(350 + 30 + 10 + 1.0, 0), z_top_mm=10)  # 1 mm gap
    assert [p.id for p in side_neighbours(target, [low], grasp_z_mm=10.0)] == []  # its top at the grasp z
    assert [p.id for p in side_neighbours(target, [low], grasp_z_mm=9.9)] == ["low"]
    _, free = candidate_points(target, [low], PARAMS, grasp_z_mm=12.0)
    assert free.all()
    op, free = candidate_points(target, [low], PARAMS, grasp_z_mm=8.0)
    assert len(op.points[~free]) == 15 and np.allclose(op.points[~free][:, 0], 380.0)


def test_ring_project_and_at_are_inverse():
    ring = Ring.of(shapes.gear("g", 30).outline_mm)
    for s in np.linspace(0, ring.length_mm, 17, endpoint=False):
        p = ring.at(s)
        s2, d = ring.project(p)
        assert d < 1e-9 and np.allclose(ring.at(s2), p, atol=1e-9)
