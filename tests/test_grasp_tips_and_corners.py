"""Pads resting on tips and on corners: gears are held across their teeth (the operator seats a pad on
the tips a part's convex hull runs over), and no pair is kept whose pads both rest on a point each
(the contacts stage's pivot check)."""

import numpy as np
import pytest
from shapely.geometry import Point
from test_grasp_cascade import cascade_for

from cell import parts_library as L
from cell.cellconfig import default_cell
from cell.errors import NoFeasibleGrasp
from cell.examples import GraspExample, load_examples
from cell.grasp import shapes
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import GraspPlanner
from cell.operator import Operator
from cell.physics import check_grasp
from cell.scene import Part, Scene
from cell.study.stability import gear_shapes

CELL = default_cell()


@pytest.fixture(autouse=True)
def _errstate_as_in_the_cascade():
    with np.errstate(divide="ignore", invalid="ignore"):
        yield


def gear(name: str, x: float = 360.0, y: float = -20.0, theta: float = 17.0) -> Part:
    part = next(g for g in gear_shapes() if g.id == name)
    return L.place(part, x, y, theta, "gear")


@pytest.mark.parametrize("name", ["spur_gear_m0.8z30", "spur_gear_m1z40", "spur_gear_m1.25z20", "spur_gear_m1.5z30",
                                  "spur_gear_m2z20"])
def test_gears_not_in_the_library_are_held_across_their_tips(name):
    """Fine teeth (modules 0.8-2, none in the library): with the examples before 2026-12-04 tree 1 took
    each tip for a corner and every one of these had no grasp."""
    part = gear(name)
    g = GraspPlanner(CELL, load_examples()).plan(Scene((part,), "gear")).grasp
    v = check_grasp(part, g.contacts_mm, g.axis_deg, g.grasp_z_mm, cell=CELL)
    assert v.ok, v.reasons
    hull = part.polygon.convex_hull.exterior
    assert all(hull.distance(Point(*c)) < 0.3 for c in g.contacts_mm)  # on the tips, not in a root
    assert min(v.patch_width_mm) >= 2.0  # each pad rests on more than one tip's corner


def test_the_operator_seats_a_pad_across_gear_tips_but_not_on_a_corner_or_a_lone_spike():
    op = Operator()
    part = gear("spur_gear_m1z40", 0.0, 0.0, 0.0)
    tip = max(np.asarray(part.outline_mm), key=lambda q: np.hypot(*q))  # a tip's corner: the outline turns 70 deg
    assert op.judge_point(part, tip).valid
    square = Part("sq", np.array([[300, -20], [340, -20], [340, 20], [300, 20]], float), z_top_mm=10)
    assert "sharp corner" in op.judge_point(square, [300, -20]).reason
    # a spike 1 mm wide on a bar: on the hull, which runs on gently there, but the pad would rest on 1 mm
    spiked = Part("spk", np.array([[300, 0], [340, 0], [340, 10], [320.5, 10], [320.5, 15], [319.5, 15],
                                   [319.5, 10], [300, 10]], float), z_top_mm=10)
    assert not op.judge_point(spiked, [320.0, 15.0]).valid
    # a fork's body, 0.5 mm from its top corner: the hull runs on to a prong's tip, slanted 9.5 degrees, and a
    # pad on that line would rest on the corner alone (one piece of material 3 mm across: no seat)
    fork = Part("fork", np.array([[340, -15], [360, -15], [360, 5], [357, 5], [357, 15], [354.5, 15], [354.5, 5],
                                  [345.5, 5], [345.5, 15], [343, 15], [343, 5], [340, 5]], float), z_top_mm=8)
    assert not op.judge_point(fork, [359.5, 5.0]).valid


@pytest.mark.parametrize("n_sides", [4, 6])  # a square's corners touch 1 mm of material, a hexagon's 1.7
def test_no_pair_is_kept_whose_pads_both_rest_on_a_corner(n_sides):
    side = 21.0 if n_sides == 4 else 15.0
    r = side / 2 / np.sin(np.pi / n_sides)
    ang = np.arange(n_sides) * 2 * np.pi / n_sides
    corners = np.column_stack([350 + r * np.cos(ang), r * np.sin(ang)])
    # the outline starts in the middle of a side: the samples (half a step, then every 1 mm) fall on every corner
    outline = np.vstack([0.5 * (corners[-1] + corners[0]), corners])
    target = Part("poly", outline, z_top_mm=10)

    def corner_pairs(params):
        P, cr, _ = cascade_for(target, params=params)
        at = [np.min(np.linalg.norm(c[:, None] - corners[None], axis=2), axis=1) < 0.01 for c in (P.pi, P.pj)]
        both = at[0] & at[1]
        return int((cr.rejected_by[both] < 0).sum()), int(both.sum()), P

    # (sampled from the first vertex as listed, the middle of a side: vertex_order_free off)
    kept, facing, P = corner_pairs(SynthesisParams(step_mm=1.0, vertex_order_free=False))
    assert facing >= n_sides // 2 and kept == 0 and P.pivot_refused >= n_sides // 2
    kept_before, _, _ = corner_pairs(SynthesisParams(step_mm=1.0, min_touch_width_mm=0.0, vertex_order_free=False))
    assert kept_before >= n_sides // 2  # (the check is what takes them)


def test_a_star_held_only_tip_to_tip_has_no_grasp_and_is_told_why():
    a = np.arange(8) * np.pi / 4
    rad = np.where(np.arange(8) % 2 == 0, 20.0, 4.0)
    star = Part("star", np.column_stack([350 + rad * np.cos(a), rad * np.sin(a)]), z_top_mm=8)
    ex = GraspExample("ok", shapes.rectangle("r", 60, 30), np.array([[350, 15], [350, -15]]), True, {"kind": "manual"})
    with pytest.raises(NoFeasibleGrasp) as e:
        GraspPlanner(CELL, [ex]).plan(Scene((star,), "star"))
    assert "both rest on material narrower than 2 mm" in e.value.reason and "pivot" in e.value.reason
    g = GraspPlanner(CELL, [ex], SynthesisParams(min_touch_width_mm=0.0)).plan(Scene((star,), "star")).grasp
    v = check_grasp(star, g.contacts_mm, g.axis_deg, g.grasp_z_mm, cell=CELL)
    assert not v.ok and "both pads sit on sharp corners" in v.reasons  # what the check refuses is not planned


def test_sprockets_with_narrow_teeth_are_never_held_by_one_tooth_tip_a_pad():
    """The pivot check measures the touching material under the pad only: in the contacts stage's band, a
    pad's width plus contact_tol each side, the next tooth's flank 6.8-7 mm across counted, and 4 of 60
    random sprockets were held by one tip a pad ('both pads sit on sharp corners')."""
    from shapely.geometry import Point as P
    from shapely.geometry.polygon import orient

    from cell.operator import random_pose

    rng = np.random.default_rng(1)
    planner = GraspPlanner(CELL, load_examples())
    planned = 0
    for _ in range(60):
        teeth, tip_d = int(rng.integers(9, 40)), float(rng.uniform(20, 68))
        g = L._gear(teeth, tip_d / 2, tip_d / 2 - float(rng.uniform(1.5, 5)), float(rng.uniform(0.05, 0.4)),
                    float(rng.uniform(0.2, 0.5)))
        g = orient(g.difference(P(0, 0).buffer(tip_d * 0.15)), 1.0)
        c = np.array(g.centroid.coords[0])
        holes = tuple(np.asarray(r.coords)[:-1] - c for r in g.interiors)
        p0 = Part("s", np.asarray(g.exterior.coords)[:-1] - c, holes, 0, 8, meta={"material": "steel"})
        p = L.place(p0, *random_pose(p0, CELL, rng))
        p = Part("s", p.outline_mm, p.holes_mm, 0, 8, meta={"material": "steel"})
        try:
            gr = planner.plan(Scene((p,), "s")).grasp
        except NoFeasibleGrasp:
            continue
        planned += 1
        v = check_grasp(p, gr.contacts_mm, gr.axis_deg, gr.grasp_z_mm, cell=CELL)
        assert v.ok, (teeth, tip_d, v.reasons)
    assert planned >= 40


def test_a_pad_whose_band_first_touches_beside_it_is_judged_on_what_it_rests_on():
    """A spike 1.2 mm wide between ribs 0.7 mm taller, 6.3-6.8 mm to the side: inside the contacts stage's band
    (the pad plus contact_tol each side) but beside the 12 mm pad. The band's first touch is a rib's, nothing
    under the pad lies within the compliance of it, and the pivot check took the width for none: pairs with
    both pads on the two spikes were kept (the physical check: 'both pads sit on sharp corners')."""
    top = [(-15, 10), (-0.6, 10), (-0.6, 14), (0.6, 14), (0.6, 10), (6.3, 10), (6.3, 14.7), (6.8, 14.7),
           (6.8, 10), (15, 10)]
    outline = np.array(top + [(-x, -y) for x, y in top], float)[::-1] + (350, 0)  # counter-clockwise
    target = Part("spk", outline, z_top_mm=10)

    def kept_spike_pairs(params):
        P, cr, _ = cascade_for(target, params=params)
        on_spike = [(np.abs(c[:, 0] - 350) <= 0.61) & (np.abs(np.abs(c[:, 1]) - 14) < 0.01) for c in (P.pi, P.pj)]
        both = np.flatnonzero(on_spike[0] & on_spike[1])
        return len(both), int((cr.rejected_by[both] < 0).sum())

    facing, kept = kept_spike_pairs(SynthesisParams(step_mm=0.5))
    assert facing > 0 and kept == 0
    assert kept_spike_pairs(SynthesisParams(step_mm=0.5, min_touch_width_mm=0.0))[1] > 0
