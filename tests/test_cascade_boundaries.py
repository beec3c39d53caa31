"""The cascade's stages at and around each of their thresholds, on hand-built scenes and hand-picked pairs.

The benchmark checks that the cascade and the brute force keep the same pairs, but both run the same
exact stages: a wrong comparison, tolerance or sign in a stage would not show there. These tests give
each stage a pair just inside and just outside each of its limits (the stroke, the 2 mm reach margin,
the 20 degree normal cone, contact_tol along and across the axis, the pad's compliance and width,
the approach opening, the joint limits, obstacle heights against the grasp z and the palm) and assert
its verdict and, for the contacts stage, where it reports the contacts. They were written against
mutants of the stages (cell/grasp/cascade.py, bands.py, kinematics.py, pairs.py) that the other tests
let through.

The default cell: 80 mm stroke, 5 mm approach clearance each side, pads 12 mm wide and 10 mm thick,
palm 90 x 40 mm 40 mm above the finger tips, L1 + L2 = 325 + 275 mm, workspace x -50..560, y -450..450.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
import shapely

from cell.cellconfig import default_cell
from cell.grasp import cascade
from cell.grasp.cascade import STAGE_FUNCS, Context, Pairs
from cell.grasp.params import SynthesisParams
from cell.kinematics import inverse, reachable_mask
from cell.scene import parse_part

CELL = default_cell()
PARAMS = SynthesisParams()
SLANTED = {True: SynthesisParams(slanted_faces=True), False: SynthesisParams(slanted_faces=False)}
UP, DOWN, RIGHT, LEFT = (0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0)
GRASP_Z_MM = 1.0  # a 15 mm tall part on the tray: tips 1 mm above its bottom (cell.grasp.height)
PALM_Z_MM = GRASP_Z_MM + CELL.gripper.palm_offset_mm  # 41 mm


@pytest.fixture(autouse=True)
def _errstate_as_in_the_cascade():
    """The stages are called directly: nan and inf are ordinary values there (cascade.py)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        yield


def part(outline, pid="t", z_top_mm=15.0, holes=()):
    return parse_part({"id": pid, "outline": [[float(x), float(y)] for x, y in outline],
                       "holes": [[[float(x), float(y)] for x, y in h] for h in holes], "z_top": z_top_mm}, pid)


def box(x0, y0, x1, y1, pid="t", z_top_mm=15.0):
    return part([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], pid, z_top_mm)


def plate(top=(), bottom=(), half_h=15.0):
    """A plate x 320..380, y -half_h..half_h with bumps (x0, x1, height mm) standing out of its top and
    bottom faces."""
    pts = [(320, -half_h)]
    for x0, x1, h in sorted(bottom):
        pts += [(x0, -half_h), (x0, -half_h - h), (x1, -half_h - h), (x1, -half_h)]
    pts += [(380, -half_h), (380, half_h)]
    for x0, x1, h in sorted(top, reverse=True):
        pts += [(x1, half_h), (x1, half_h + h), (x0, half_h + h), (x0, half_h)]
    return part(pts + [(320, half_h)])


PLATE = plate()


def one_pair(target, pi, pj, ni=UP, nj=DOWN, obstacles=(), params=PARAMS, cell=CELL, grasp_z_mm=GRASP_Z_MM):
    """The scene and the one pair (p_i, p_j) with these normals (they set the closing axis u, the
    bisector of n_i and -n_j); no outline samples (the pre-check's outline test is off)."""
    ctx = Context.build(target, list(obstacles), cell, params, grasp_z_mm)
    return ctx, Pairs.of(np.array([pi, pj], float), np.array([ni, nj], float))


def kept(stage, ctx, P, pair=0):
    """The stage's verdict on one pair, asked as the cascade asks it: every pair at once."""
    return bool(STAGE_FUNCS[stage](ctx, P, np.arange(len(P)))[pair])


def contacts(target, pi=(350, 15), pj=(350, -15), ni=UP, nj=DOWN, params=PARAMS, cell=CELL):
    """The contacts stage's verdict on the pair and the contacts it reports (c_i, c_j, centre, half gap h)."""
    ctx, P = one_pair(target, pi, pj, ni, nj, params=params, cell=cell)
    return kept("contacts", ctx, P), P.ci[0], P.cj[0], P.center[0], P.h[0]


def after_contacts(target, obstacles):
    """Scene and the pair across the plate's 30 mm at x 350, with the contacts found (fingers and palm read
    them)."""
    ctx, P = one_pair(target, (350, 15), (350, -15), obstacles=obstacles)
    assert kept("contacts", ctx, P)
    return ctx, P


def turned(xy, angle_deg, about=(350.0, 0.0)):
    """Points (or directions, about=(0, 0)) turned by angle_deg about `about`."""
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return (np.asarray(xy, float) - about) @ rot.T + about


def with_gripper(**kw):
    return replace(CELL, gripper=replace(CELL.gripper, **kw))


def with_scara(**kw):
    return replace(CELL, scara=replace(CELL.scara, **kw))


# --- stroke: contact distance + 2 x approach clearance within the opening (and the real contacts' gap) ---

@pytest.mark.parametrize("opening_mm, width_mm, fits", [
    ((0.0, 80.0), 70.0, True),  # 70 + 2 x 5 = 80: at the limit
    ((0.0, 80.0), 70.0 + 5e-7, True),  # within EPS_MM (1e-6)
    ((0.0, 80.0), 70.0 + 2e-6, False),
    ((0.0, 80.0), 72.0, False),  # would fit with one clearance (77 mm)
    ((0.0, 80.0), 75.0, False),
    ((20.0, 80.0), 20.0, True),  # the jaws close to at least 20 mm
    ((20.0, 80.0), 20.0 - 5e-7, True),
    ((20.0, 80.0), 19.9, False),
], ids=["70mm", "70mm+5e-7", "70mm+2e-6", "72mm", "75mm", "20mm, min 20", "20mm-5e-7, min 20", "19.9mm, min 20"])
@pytest.mark.parametrize("stroke_at_pad_lines", [True, False], ids=["at pad lines", "at contacts"])
def test_a_box_fits_the_stroke_iff_its_width_plus_two_5mm_clearances_is_within_the_opening(
        opening_mm, width_mm, fits, stroke_at_pad_lines):
    cell = with_gripper(opening_mm=opening_mm)
    half = width_mm / 2
    ctx, P = one_pair(box(350 - half, -15, 350 + half, 15), (350 + half, 0), (350 - half, 0), RIGHT, LEFT,
                      params=SynthesisParams(stroke_at_pad_lines=stroke_at_pad_lines), cell=cell)
    assert kept("stroke", ctx, P) is fits  # on the candidates' distance
    assert kept("contacts", ctx, P) is fits  # on the real contacts' gap along the axis
    if fits:
        assert 2 * P.h[0] == pytest.approx(width_mm, abs=1e-9)


# --- reach: the pair's midpoint in the annulus 50..600 mm and the workspace, each with 2 mm to spare ---

def _at_radius(r_mm, angle_deg=45.0):
    a = math.radians(angle_deg)
    return r_mm * math.cos(a), r_mm * math.sin(a)


@pytest.mark.parametrize("pi, pj, reachable", [
    ((563, 0), (559, 0), True),  # midpoint x 561: 1 mm beyond the workspace, within the margin
    ((565, 0), (561, 0), False),  # x 563
    ((-49, 200), (-53, 200), True),  # x -51
    ((-51, 200), (-55, 200), False),  # x -53
    ((300, 453), (300, 449), True),  # y 451
    ((300, 455), (300, 451), False),  # y 453
    ((300, -449), (300, -453), True),  # y -451
    ((300, -451), (300, -455), False),  # y -453
    (_at_radius(603), _at_radius(599), True),  # r 601: within L1 + L2 + 2
    (_at_radius(605), _at_radius(601), False),  # r 603
    ((0, 51), (0, 47), True),  # r 49: within |L1 - L2| - 2
    ((0, 49), (0, 45), False),  # r 47
    # decided from the points' bounding box when it lies clear of every limit (the usual case)
    ((350, 15), (350, -15), True),
    ((429, 428), (429, 431), False),  # r 607: box's far corner 608 mm from the base
    ((-45, 20), (45, 20), False),  # box across the base: midpoint r 20
    ((500, -334.2), (500, -340), False),  # r 603, below the x axis (nearer end 601.5 mm away)
    ((10, 20), (10, 30), False),  # r 27
    ((-55, 200), (-55, 210), False),  # box beyond the workspace's x -52, inside the annulus
], ids=["x 561", "x 563", "x -51", "x -53", "y 451", "y 453", "y -451", "y -453", "r 601", "r 603", "r 49", "r 47",
        "box mid-tray", "box r 607", "box across the base", "box r 603 below y 0", "box r 27", "box x -55"])
def test_reach_keeps_midpoints_inside_annulus_and_workspace_with_a_2mm_margin(pi, pj, reachable):
    ctx, P = one_pair(PLATE, pi, pj, RIGHT, LEFT)
    assert kept("reach", ctx, P) is reachable


# --- antipodal: each normal within 20 deg of the line between the points; points <= 1 mm off the axis ---

def _normal(deg_from_up, down=False):
    a = math.radians(deg_from_up)
    return (math.sin(a), -math.cos(a) if down else math.cos(a))


@pytest.mark.parametrize("tilt_i_deg, tilt_j_deg, facing", [
    (19.9, 19.9, True),
    (20.0, 20.0, True),
    (20.0 + 1e-7, 20.0 + 1e-7, True),  # within the 1e-9 slack on the cosine
    (20.0 + 1e-5, 20.0 + 1e-5, False),
    (20.1, 19.9, False),  # n_i outside the cone
    (19.9, 20.1, False),  # n_j outside the cone
    (-19.9, -19.9, True),
], ids=["19.9deg", "20deg", "20deg+1e-7", "20deg+1e-5", "n_i 20.1deg", "n_j 20.1deg", "-19.9deg"])
def test_antipodal_keeps_normals_within_20_deg_of_the_line_between_the_points(tilt_i_deg, tilt_j_deg, facing):
    """A wedge: the normals lean away from each other by the same angle, so the axis (their
    bisector) stays on the line between the points."""
    ctx, P = one_pair(PLATE, (350, 15), (350, -15), _normal(tilt_i_deg), _normal(tilt_j_deg, down=True))
    assert kept("antipodal", ctx, P) is facing


@pytest.mark.parametrize("offset_mm, on_one_line", [
    (0.0, True), (1.5, True), (2.0, True),  # each point offset_mm / 2 from the line through the midpoint
    (2.0 + 1e-6, True),  # within EPS_MM
    (2.0 + 4e-6, False), (2.5, False),
], ids=["0mm", "1.5mm", "2mm", "2mm+1e-6", "2mm+4e-6", "2.5mm"])
def test_antipodal_keeps_points_at_most_contact_tol_across_the_axis_from_its_line(offset_mm, on_one_line):
    ctx, P = one_pair(PLATE, (350 + offset_mm / 2, 15), (350 - offset_mm / 2, -15))
    assert kept("antipodal", ctx, P) is on_one_line


# --- precheck: certain collisions on the fingers' paths, the palm's centre and the outline ahead ---

TALL_MM = 40.0  # an obstacle taller than the grasp z (1 mm) and lower than the palm (41 mm)


@pytest.mark.parametrize("obstacle, precheck, fingers", [
    (box(340, 20, 360, 26, "o", TALL_MM), False, False),  # across p_i's path (+u side)
    (box(340, -26, 360, -20, "o", TALL_MM), False, False),  # across p_j's path (-u side)
    (box(340, 27, 360, 40, "o", TALL_MM), False, False),  # 12 mm out: within the approach opening
    (box(340, 29.99, 360, 40, "o", TALL_MM), True, False),  # 14.99 mm: the finger's outer face reaches it
    (box(340, 30.0, 360, 40, "o", TALL_MM), True, False),  # 15 mm: touching counts
    (box(340, 30.01, 360, 40, "o", TALL_MM), True, True),  # 15.01 mm: clear
    (box(353, 16, 370, 25, "o", TALL_MM), False, False),  # beside the closing line, under the finger's side
    (box(356.0, 16, 370, 25, "o", TALL_MM), True, False),  # beside, touching the finger's side (6 mm)
    (box(356.01, 16, 370, 25, "o", TALL_MM), True, True),  # 0.01 mm clear of its side
    (box(340, 20, 360, 26, "o", GRASP_Z_MM), True, True),  # level with the grasp z: passed over
    (box(340, 20, 360, 26, "o", GRASP_Z_MM + 1e-7), True, True),  # within Z_EPS_MM
    (box(340, 20, 360, 26, "o", GRASP_Z_MM + 0.01), False, False),
    (box(340, 20, 360, 26, "o", GRASP_Z_MM + 0.5), False, False),
], ids=["+u path", "-u path", "12mm out", "14.99mm out", "15mm out", "15.01mm out", "3mm beside", "6mm beside",
        "6.01mm beside", "z=grasp z", "z=grasp z+1e-7", "z=grasp z+0.01", "z=grasp z+0.5"])
def test_a_finger_hits_obstacles_taller_than_the_grasp_z_on_its_path_from_the_opening(obstacle, precheck, fingers):
    """Pair across the plate's 30 mm; each finger's footprint runs from the contact 15 mm out
    (5 mm approach clearance + 10 mm pad), 12 mm wide. The pre-check rejects only what the
    fingers' check would."""
    ctx, P = after_contacts(PLATE, [obstacle])
    assert kept("precheck", ctx, P) is precheck
    assert kept("fingers_obstacles", ctx, P) is fingers


def test_a_finger_passes_a_neighbour_beside_a_narrow_tongue_below_the_contact_line():
    """A 4 mm tongue under a 12 mm pad: the pad overhangs it, but stops on the tongue's top; a tall
    neighbour beside the tongue 0.5 mm below that line is clear of the finger (and 0.5 mm above it
    is not)."""
    tongue = part([[320, -15], [380, -15], [380, 10], [352, 10], [352, 15], [348, 15], [348, 10], [320, 10]])
    for top_mm, clear in ((14.5, True), (15.5, False)):
        ctx, P = after_contacts(tongue, [box(353, 11, 360, top_mm, "o", TALL_MM)])
        assert kept("fingers_obstacles", ctx, P) is clear


# an L: an arm x 320..380, y -15..0 and a leg x 320..335, y 0..25 (not convex: the pre-check also
# looks for the target's own material on the fingers' paths)
L_PART = part([[320, -15], [380, -15], [380, 0], [335, 0], [335, 25], [320, 25]])
# a C open to the right: jaws y -20..-10 and 0..10, back x 320..330
C_PART = part([[320, -20], [380, -20], [380, -10], [330, -10], [330, 0], [380, 0], [380, 10], [320, 10]])


def test_precheck_on_a_non_convex_target_still_looks_for_obstacles_on_the_fingers_paths():
    ctx, P = one_pair(L_PART, (365, 0), (365, -15), obstacles=[box(355, -26, 375, -20, "o", TALL_MM)])
    assert not kept("precheck", ctx, P)
    ctx, P = one_pair(L_PART, (365, 0), (365, -15))
    assert kept("precheck", ctx, P)


def test_precheck_rejects_a_finger_path_through_the_targets_own_material():
    """Across the C's lower jaw: p_i's finger, 15 mm long, would enter the upper jaw 10 mm above."""
    ctx, P = one_pair(C_PART, (360, -10), (360, -20))
    assert not kept("precheck", ctx, P)
    assert not kept("contacts", ctx, P)


def test_precheck_and_palm_reject_a_pair_centred_on_a_palm_high_pin():
    """A ring (r 30, hole r 12) on a 60 mm tall pin: across the ring the pair's centre is on the pin."""
    ring = part([[350 + 30 * math.cos(a), 30 * math.sin(a)] for a in np.linspace(0, 2 * math.pi, 96, endpoint=False)],
                holes=[[[350 + 12 * math.cos(a), -12 * math.sin(a)] for a in np.linspace(0, 2 * math.pi, 96,
                                                                                      endpoint=False)]])
    pin = box(344, -6, 356, 6, "pin", 60.0)
    ctx, P = one_pair(ring, (380, 0), (320, 0), RIGHT, LEFT, obstacles=[pin])
    assert not kept("precheck", ctx, P)
    assert kept("contacts", ctx, P) and kept("fingers_obstacles", ctx, P) and not kept("palm", ctx, P)
    ctx, P = one_pair(ring, (380, 0), (320, 0), RIGHT, LEFT)
    assert kept("precheck", ctx, P)


# a plate with a notch 0.75 mm deep in each face, x 343.5..356.9: a pad across it (12 mm + contact_tol
# each side) rests on both rims, and the contact moves onto the nearer rim, 6.5 mm from the closing line
NOTCHED = part([[320, -15], [343.5, -15], [343.5, -14.25], [356.9, -14.25], [356.9, -15], [380, -15], [380, 15],
                [356.9, 15], [356.9, 14.25], [343.5, 14.25], [343.5, 15], [320, 15]])


def test_precheck_keeps_a_pair_whose_fingers_sit_beside_the_closing_line_in_a_notch():
    """Across the notches' floors at x 350 the contacts lie on the rims at x 343.5: the fingers (x
    337.5..349.5) clear a tall post at x 349.6..352.6 that stands on the pair's closing line, 7.25 mm
    beyond the candidate, and the palm (x 323.5..363.5) a palm-high tower 14-22 mm across from that line.
    The pre-check must not reject what the exact stages keep."""
    post = box(349.6, 20, 352.6, 26, "post", TALL_MM)
    tower = box(364, 40, 372, 48, "tower", 80.0)
    ctx, P = one_pair(NOTCHED, (350, 14.25), (350, -14.25), obstacles=[post, tower])
    assert kept("contacts", ctx, P) and abs(P.center[0, 0] - 343.5) < 1e-9
    assert kept("ik", ctx, P) and kept("fingers_obstacles", ctx, P) and kept("palm", ctx, P)
    assert kept("precheck", ctx, P)


def test_precheck_asks_nothing_of_a_palm_narrower_than_the_contacts_play_across():
    """A 12 mm palm over the notch's pair (contacts' centre at x 343.5: palm x 337.5..349.5) clears a
    palm-high post at x 349.8..352 on the pair's closing line: with contacts that may lie 7 mm across, no
    point of a 12 mm palm is surely covered, and the pre-check must not ask any."""
    cell = with_gripper(palm_width_mm=12.0)
    post = box(349.8, 40, 352, 48, "post", 80.0)
    ctx, P = one_pair(NOTCHED, (350, 14.25), (350, -14.25), obstacles=[post], cell=cell)
    assert kept("contacts", ctx, P) and kept("palm", ctx, P)
    assert kept("precheck", ctx, P)


def _samples_along(ring, step_mm=2.0):
    """Outline samples every step_mm from each vertex (the last one on each edge nearer)."""
    out = []
    ring = np.asarray(ring, float)
    for a, b in zip(ring, np.roll(ring, -1, 0), strict=True):
        n = int(np.ceil(np.hypot(*(b - a)) / step_mm - 1e-9))
        out += [a + (b - a) * min(k * step_mm / np.hypot(*(b - a)), 1.0) for k in range(n)]
    return np.array(out)


def outline_pairs(ring, points, normals, cell=CELL):
    """Scene with outline samples and the pairs of `points` (each a sample of the ring)."""
    samples = _samples_along(ring)
    ctx = Context.build(part(ring), [], cell, PARAMS, GRASP_Z_MM, samples, np.zeros(len(samples), int))
    idx = [int(np.argmin(np.hypot(*(samples - p).T))) for p in points]
    assert np.allclose(samples[idx], points)
    return ctx, Pairs.of(samples[idx], np.array(normals, float), np.array(idx))


def _top_bump_ring(x_near, h, width=2.0):
    """The plate with a bump `width` wide and h high on its top face, its nearer side at x_near (left of
    the candidate (350, 15))."""
    return [[320, -15], [380, -15], [380, 15], [x_near, 15], [x_near, 15 + h], [x_near - width, 15 + h],
            [x_near - width, 15], [320, 15]]


def _bottom_bump_ring(x_near, h, width=2.0):
    return [[320, -15], [x_near, -15], [x_near, -15 - h], [x_near + width, -15 - h], [x_near + width, -15],
            [380, -15], [380, 15], [320, 15]]


@pytest.mark.parametrize("ring, no_outline_ahead", [
    (_top_bump_ring(343.5, 1.5), False),  # 6.5 mm beside p_i (band: 6 + 1 mm), 1.5 mm ahead of it
    (_top_bump_ring(344.5, 1.5), False),  # 5.5 mm beside
    (_top_bump_ring(342.5, 1.5), True),  # 7.5 mm beside: outside the band
    (_top_bump_ring(343.5, 1.0), True),  # ahead by contact_tol: the pad stops within tol
    (_top_bump_ring(343.5, 0.5), True),
    (_bottom_bump_ring(356.5, 1.5), False),  # beside p_j, ahead along -u
], ids=["6.5mm beside, 1.5mm high", "5.5mm beside", "7.5mm beside", "1mm high", "0.5mm high", "beside p_j"])
@pytest.mark.parametrize("rows", ["every row", "rows the bound picks"])
def test_precheck_rejects_outline_next_to_a_point_ahead_of_it_in_its_pads_band(ring, no_outline_ahead, rows):
    """The plate's samples, 2 mm apart, with a bump beside p_i or p_j; the pre-check agrees with the
    contacts stage. With a third point (more pad rows than points) the per-point bound picks the
    rows to look at."""
    points = [(350, 15), (350, -15)] + ([(380, 1)] if rows == "rows the bound picks" else [])
    ctx, P = outline_pairs(ring, points, [UP, DOWN, RIGHT][:len(points)])
    assert kept("precheck", ctx, P) is no_outline_ahead
    assert kept("contacts", ctx, P) is no_outline_ahead


def test_the_outline_test_counts_only_outline_within_the_pads_reach():
    """Pads 1 mm thick with no approach clearance reach 1 mm (= contact_tol) past the contact: a bump
    1.5 mm high beside p_i is beyond them, and the contacts stage (slanted faces) keeps the pair."""
    cell = with_gripper(approach_clearance_mm=0.0, pad_thickness_mm=1.0)
    ring = _top_bump_ring(343.5, 1.5)
    ctx, P = outline_pairs(ring, [(350, 15), (350, -15)], [UP, DOWN], cell=cell)
    assert not cascade._outline_ahead(ctx, P, np.arange(1))[0]
    assert kept("contacts", ctx, P)
    ctx, P = outline_pairs(ring, [(350, 15), (350, -15)], [UP, DOWN])
    assert cascade._outline_ahead(ctx, P, np.arange(1))[0]  # the default pads reach it


# an overhang 2.25 mm above the plate's top face (a hook: post x 375..380)
HOOK_2MM = part([[320, -15], [380, -15], [380, 22], [330, 22], [330, 17.25], [375, 17.25], [375, 15], [320, 15]])
# a plate with a tab on its top face x 345..355 (not convex)
TAB = part([[320, -15], [380, -15], [380, 15], [355, 15], [355, 25], [345, 25], [345, 15], [320, 15]])


@pytest.mark.parametrize("target, pi, thickness_mm", [(HOOK_2MM, (350, 15), 2.0), (TAB, (330, 15), 1.0)],
                         ids=["2mm pads under a 2.25mm overhang", "1mm pads beside a tab"])
def test_precheck_keeps_what_the_exact_stages_keep_with_thin_pads_and_no_approach_clearance(target, pi, thickness_mm):
    """Pads 2 mm thick clear an overhang 2.25 mm above the contact, and 1 mm pads a flat face; the
    pre-check looked 2.5 mm out, inside the overhang, and 0.5 mm behind the contact, inside the part,
    and rejected pairs the exact stages keep (cascade != brute force)."""
    cell = with_gripper(approach_clearance_mm=0.0, pad_thickness_mm=thickness_mm)
    ctx, P = one_pair(target, pi, (pi[0], -15), cell=cell)
    assert kept("contacts", ctx, P) and kept("fingers_obstacles", ctx, P) and kept("palm", ctx, P)
    assert kept("precheck", ctx, P)


# --- contacts: where each pad first meets material in its band (pad width + tol each side) ---

@pytest.mark.parametrize("top, bottom, stops, ci", [
    ((), (), True, (350, 15)),
    (((349, 351, 0.5),), (), True, (350, 15.5)),  # a bump on the axis: the pad stops on its top
    (((349, 351, 1.0),), (), True, (350, 16.0)),  # contact_tol ahead of the candidate
    (((349, 351, 1.0 + 5e-7),), (), True, (350, 16.0 + 5e-7)),  # within EPS_MM
    (((349, 351, 1.0 + 2e-6),), (), False, None),
    (((349, 351, 1.5),), (), False, None),
    ((), ((349, 351, 1.5),), False, None),  # under p_j
    (((353, 355, 0.8),), (), False, None),  # 3-5 mm beside: the pad rests on it, 0.8 mm above the candidate
    (((350.6, 353, 0.5),), (), True, (350, 15)),  # 0.5 mm high: within the pad's compliance, touches too
    (((350.6, 353, 0.501),), (), False, None),
], ids=["flat", "0.5mm on axis", "1mm on axis", "1mm+5e-7", "1mm+2e-6", "1.5mm on axis", "1.5mm under p_j",
        "0.8mm beside", "0.5mm beside", "0.501mm beside"])
@pytest.mark.parametrize("slanted", [True, False], ids=["slanted faces", "plain"])
def test_a_pad_stops_at_the_first_material_in_its_band_within_contact_tol_of_the_candidate(
        top, bottom, stops, ci, slanted):
    ok, c_i, c_j, _, _ = contacts(plate(top, bottom), params=SLANTED[slanted])
    assert ok is stops
    if stops:
        assert np.allclose(c_i, ci, atol=1e-9) and np.allclose(c_j, (350, -15), atol=1e-9)


@pytest.mark.parametrize("beside_mm, stops", [(6.5, False), (6.9, False), (7.0, True), (7.1, True)],
                         ids=["6.5mm", "6.9mm", "7mm", "7.1mm"])
@pytest.mark.parametrize("angle_deg", [0.0, 33.0], ids=["axis-aligned", "turned 33deg"])
def test_a_wall_beside_the_pad_counts_within_contact_tol_of_its_side_and_not_on_that_line(beside_mm, angle_deg, stops):
    """A wall 10 mm high rising from the top face beside_mm from the closing line (an L's inner corner):
    the band is the pad's 6 mm + contact_tol (1 mm), material exactly on its side is outside at any
    angle (turned 33 deg, the band's bounding box takes in edges outside it)."""
    x = 350 - beside_mm
    outline = turned([[320, -15], [380, -15], [380, 15], [x, 15], [x, 25], [320, 25]], angle_deg)
    (pi, pj), (ni, nj) = turned([(350, 15), (350, -15)], angle_deg), turned([UP, DOWN], angle_deg, (0, 0))
    ok, c_i, _, _, _ = contacts(part(outline), tuple(pi), tuple(pj), tuple(ni), tuple(nj))
    assert ok is stops
    if stops:
        assert np.allclose(c_i, pi)


def _slanted_top(slope):
    """The plate with its top face through (350, 15) rising by `slope` towards +x."""
    return part([[320, -15], [380, -15], [380, 15 + 30 * slope], [320, 15 - 30 * slope]])


@pytest.mark.parametrize("slope, x_i, pressed, contact_x, held", [
    (0.075, 350.0, True, 350.034, True),  # the pad's side 0.45 mm above the candidate: it presses on it
    (0.0917, 350.0, False, None, False),  # 0.55 mm: the pad stops on the face's higher end only
    (0.075, 350.6, True, 350.034, True),  # candidates 0.6 mm either side of the axis: the contact on the closing line
    (0.0917, 350.6, True, 350.645, False),  # the face under the closing line 0.55 mm low: across from the candidate
], ids=["4.3deg", "5.2deg", "4.3deg offset", "5.2deg offset"])
def test_with_slanted_faces_a_pad_presses_on_a_candidate_within_its_05mm_compliance(slope, x_i, pressed, contact_x,
                                                                                    held):
    """The axis is vertical (normals chosen so); on the slanted face the pad first touches at its side. The
    contact across from the candidate moves the grasp centre 0.32 mm along the face; the pad centred there
    stops on the face's higher end 0.52 mm above the contact: kept only with `touch_within_compliance` off."""
    target = _slanted_top(slope)
    pi, pj = (x_i, 15 + slope * (x_i - 350)), (700 - x_i, -15)
    assert contacts(target, pi, pj, params=SLANTED[True])[0] is held
    ok, c_i, c_j, _, _ = contacts(target, pi, pj, params=replace(SLANTED[True], touch_within_compliance=False))
    assert ok is pressed
    assert not contacts(target, pi, pj, params=SLANTED[False])[0]  # plain: the touch is off the candidate
    if pressed:
        assert c_i[0] == pytest.approx(contact_x, abs=2e-3)
        assert target.polygon.exterior.distance(shapely.Point(c_i)) < 1e-9  # on the face
        assert np.allclose(c_j, (350, -15))


def test_a_pad_pressing_on_a_step_reports_the_contact_across_from_the_candidate():
    """The top face steps down 1 mm at x 350.3, between the candidate (350.8, 15) and the closing line
    (x 350): the pad presses on the candidate and the contact is across from it, not over the step."""
    target = part([[320, -15], [380, -15], [380, 15], [350.3, 15], [350.3, 14], [320, 14]])
    ok, c_i, c_j, _, _ = contacts(target, (350.8, 15), (349.2, -15), params=SLANTED[True])
    assert ok and np.allclose(c_i, (350.8, 15)) and np.allclose(c_j, (350, -15))
    assert not contacts(target, (350.8, 15), (349.2, -15), params=SLANTED[False])[0]


@pytest.mark.parametrize("x_mm, pressed", [(343.5, True), (356.5, True), (344.5, False), (355.5, False)],
                         ids=["6.5mm left", "6.5mm right", "5.5mm left", "5.5mm right"])
def test_a_spike_beside_the_pad_within_contact_tol_does_not_stop_a_pressing_pad(x_mm, pressed):
    """A spike 0.2 mm wide and 0.8 mm high beside the closing line. 6.5 mm beside: inside the band (6 +
    1 mm), outside the pad (6 mm); with slanted faces the pad, stopped on the face, presses on the
    candidate. 5.5 mm beside: under the pad, which stops on the spike 0.8 mm above the candidate."""
    target = plate(top=((x_mm - 0.1, x_mm + 0.1, 0.8),))
    ok, c_i, _, _, _ = contacts(target, params=SLANTED[True])
    assert ok is pressed
    if pressed:
        assert np.allclose(c_i, (350, 15))
    assert not contacts(target, params=SLANTED[False])[0]


def _hook(gap_mm, tip=False):
    """A plate x 320..380, y -10..0 with an overhang gap_mm above its top face (post x 375..380); with
    tip, the overhang's underside is a V whose lowest point, at x 350, is gap_mm above."""
    g = gap_mm
    under = [[340, g + 2], [350, g], [360, g + 2]] if tip else []
    return part([[320, -10], [380, -10], [380, g + 6], [330, g + 6], [330, g + 3], *under, [375, g + 3],
                 [375, 0], [320, 0]] if tip else
                [[320, -10], [380, -10], [380, g + 3], [330, g + 3], [330, g], [375, g], [375, 0], [320, 0]])


@pytest.mark.parametrize("gap_mm, stops", [(12.0, False), (14.5, False), (14.99, False), (15.0, False), (15.01, True),
                                           (15.5, True)],
                         ids=["12mm", "14.5mm", "14.99mm", "15mm", "15.01mm", "15.5mm"])
@pytest.mark.parametrize("tip", [False, True], ids=["flat underside", "V underside"])
def test_a_pad_closing_from_the_approach_opening_meets_an_overhang_up_to_15mm_above_the_contact(gap_mm, tip, stops):
    """The pad sweeps from the approach opening (5 mm + its 10 mm thickness out) to the contact:
    material of the target up to 15 mm above the contact, touching at 15 mm, is in its way."""
    ok, c_i, _, _, _ = contacts(_hook(gap_mm, tip), (350, 0), (350, -10))
    assert ok is stops
    if stops:
        assert np.allclose(c_i, (350, 0))


@pytest.mark.parametrize("slit_mm", [0.5, 1.0, 1.5], ids=["0.5mm", "1mm", "1.5mm"])
def test_a_pad_cannot_enter_a_slit_narrower_than_itself(slit_mm):
    """A slit slit_mm high cut into a 60 x 40 block from its left side (y 5..5 + slit_mm, x 320..370): a
    candidate on the slit's floor is under material that fills the pad's band up to the opening."""
    target = part([[320, -15], [380, -15], [380, 25], [320, 25], [320, 5 + slit_mm], [370, 5 + slit_mm], [370, 5],
                   [320, 5]])
    assert not contacts(target, (345, 5), (345, -15))[0]


@pytest.mark.parametrize("boss_x_mm, aligned", [(350.75, True), (350.9, False)], ids=["0.75mm across", "0.9mm across"])
def test_the_contacts_line_must_be_within_3_deg_of_the_closing_axis(boss_x_mm, aligned):
    """A plate 15 mm thick with a boss 0.4 mm wide and 0.8 mm high on its top face: the pad stops on the
    boss, boss_x_mm - 350 across the axis from the other contact, 15.8 mm away along it (tan 3 deg x 15.8
    = 0.828 mm)."""
    x = boss_x_mm
    ok, c_i, c_j, centre, h = contacts(plate(top=((x - 0.2, x + 0.2, 0.8),), half_h=7.5), (350, 7.5), (350, -7.5))
    assert ok is aligned
    assert np.allclose(c_i, (x, 8.3)) and np.allclose(c_j, (350, -7.5))
    assert h == pytest.approx(7.9)  # half the gap along the axis, not half the contacts' distance
    assert np.allclose(centre, (0.5 * (x + 350), 0.4))  # the grasp centre between the contacts


def _bumped_box_69_9(lateral_mm, side):
    """A box 69.9 mm wide (x 315.05..384.95) with a bump 0.4 mm proud on its +x (side 1) or -x face, lateral_mm
    (lo, hi) along y."""
    lo, hi = lateral_mm
    x0, x1 = 315.05, 384.95
    if side == 1:
        return part([[x0, -15], [x1, -15], [x1, lo], [x1 + 0.4, lo], [x1 + 0.4, hi], [x1, hi], [x1, 15], [x0, 15]])
    return part([[x0, -15], [x1, -15], [x1, 15], [x0, 15], [x0, hi], [x0 - 0.4, hi], [x0 - 0.4, lo], [x0, lo]])


@pytest.mark.parametrize("lateral_mm, side, fits", [
    ((3, 5), 1, False), ((3, 5), -1, False),  # under a pad: the pads stop 70.3 mm apart, + 2 x 5 > 80
    ((6.3, 6.7), 1, True), ((6.3, 6.7), -1, True),  # beside the pads (6 mm): they stop 69.9 mm apart
], ids=["under p_i's pad", "under p_j's pad", "beside p_i's pad", "beside p_j's pad"])
def test_the_stroke_is_checked_where_the_pads_stop_not_at_the_contacts(lateral_mm, side, fits):
    """The contacts are on the faces 69.9 mm apart (the bump is within the pad's compliance in front of
    them); the pads stop on the bump."""
    target = _bumped_box_69_9(lateral_mm, side)
    for at_pad_lines in (True, False):
        ok, c_i, c_j, _, h = contacts(target, (384.95, 0), (315.05, 0), RIGHT, LEFT,
                                      params=SynthesisParams(stroke_at_pad_lines=at_pad_lines))
        assert ok is (fits or not at_pad_lines)
        assert np.allclose([c_i, c_j], [(384.95, 0), (315.05, 0)]) and 2 * h == pytest.approx(69.9)


# --- ik: the contacts' centre in the workspace and some solution within the joint limits ---

def _ik(centre, axis_deg, cell=CELL, grasp_z_mm=GRASP_Z_MM):
    a = math.radians(axis_deg)
    u = np.array([math.cos(a), math.sin(a)])
    c = np.asarray(centre, float)
    ctx, P = one_pair(PLATE, c + 5 * u, c - 5 * u, tuple(u), tuple(-u), cell=cell, grasp_z_mm=grasp_z_mm)
    P.center[0] = c  # as the contacts stage leaves it
    return kept("ik", ctx, P)


@pytest.mark.parametrize("centre, inside", [((-55, 300), False), ((-45, 300), True), ((565, 0), False),
                                            ((555, 0), True), ((300, -455), False), ((300, -445), True),
                                            ((300, 455), False), ((300, 445), True)],
                         ids=["x -55", "x -45", "x 565", "x 555", "y -455", "y -445", "y 455", "y 445"])
def test_ik_keeps_only_centres_inside_the_workspace_even_where_the_arm_reaches(centre, inside):
    assert inverse(*centre, GRASP_Z_MM, 0.0, CELL.scara)  # the arm reaches all of them
    assert _ik(centre, 0.0) is inside


# at (350, 0) the elbows are J1 = -+47.91, J2 = +-109.19 deg: the tool axis J1 + J2 = +-61.28 deg
_SOLS = inverse(350.0, 0.0, GRASP_Z_MM, 0.0, CELL.scara, within_limits=False)
J1_AT_350, J2_AT_350 = abs(_SOLS[0].j1_deg), abs(_SOLS[0].j2_deg)
J12_AT_350 = abs(_SOLS[0].j1_deg + _SOLS[0].j2_deg)


@pytest.mark.parametrize("axis_deg, reachable", [(0.0, False), (30.0, False), (90.0, False), (J12_AT_350, True),
                                                 (120.0, True), (J12_AT_350 + 20 + 1e-10, True),
                                                 (J12_AT_350 + 20 + 1e-6, False)],
                         ids=["0", "30", "90", "J1+J2", "120", "J4 20+1e-10", "J4 20+1e-6"])
def test_ik_needs_a_j4_turn_within_its_limits_for_the_closing_axis(axis_deg, reachable):
    """J4 limited to +-20 deg: the axis must be within 20 deg (mod 180) of one elbow's J1 + J2."""
    cell = with_scara(j4_deg=(-20.0, 20.0))
    assert _ik((350, 0), axis_deg, cell) is reachable
    assert bool(reachable_mask([350.0], [0.0], GRASP_Z_MM, [axis_deg], cell.scara)[0]) is reachable
    assert bool(inverse(350.0, 0.0, GRASP_Z_MM, axis_deg, cell.scara)) is reachable


def test_the_ik_stage_keeps_only_pairs_with_joint_solutions_just_beyond_a_j4_limit():
    # reachable_mask allowed J4 1e-9 of a half turn (1.8e-7 deg) past its limits, inverse 1e-9 deg: the
    # ik stage kept a pair whose joint solutions (joints_of) were empty
    cell = with_scara(j4_deg=(-20.0, 20.0))
    axis_deg = J12_AT_350 + 20 + 1e-8  # J4 1e-8 deg beyond its limit
    assert not inverse(350.0, 0.0, GRASP_Z_MM, axis_deg, cell.scara)
    assert not _ik((350, 0), axis_deg, cell)


@pytest.mark.parametrize("joint, needed_deg", [("j1_deg", J1_AT_350), ("j2_deg", J2_AT_350)], ids=["J1", "J2"])
@pytest.mark.parametrize("spare_deg, reachable", [(1e-6, True), (-1e-10, True), (-1e-6, False), (-1.0, False)],
                         ids=["1e-6 to spare", "1e-10 short", "1e-6 short", "1 short"])
def test_ik_keeps_a_centre_only_within_the_j1_and_j2_limits(joint, needed_deg, spare_deg, reachable):
    """Both elbows at (350, 0) need |J1| = 47.91 and |J2| = 109.19 deg; limits set that much +- spare_deg."""
    cell = with_scara(**{joint: (-needed_deg - spare_deg, needed_deg + spare_deg)})
    assert _ik((350, 0), 0.0, cell) is reachable
    assert bool(reachable_mask([350.0], [0.0], GRASP_Z_MM, [0.0], cell.scara)[0]) is reachable


@pytest.mark.parametrize("grasp_z_mm, reachable", [(5.0, True), (5.0 - 1e-10, True), (4.99, False), (200.0, True),
                                                   (200.01, False)], ids=["5", "5-1e-10", "4.99", "200", "200.01"])
def test_ik_keeps_a_grasp_z_only_within_j3(grasp_z_mm, reachable):
    cell = with_scara(j3_mm=(5.0, 200.0))
    assert _ik((350, 0), 0.0, cell, grasp_z_mm) is reachable


# --- palm: 90 mm along the axis, 40 across, centred on the grasp; obstacles above its bottom (41 mm) ---

@pytest.mark.parametrize("obstacle, clear", [
    (box(340, -50, 360, -45.01, "o", 60.0), True),  # 45.01 mm on the -u side
    (box(340, -50, 360, -45.0, "o", 60.0), False),  # touching the palm's end
    (box(340, -50, 360, -44.99, "o", 60.0), False),
    (box(345, 40, 355, 44, "o", 60.0), False),  # 40-44 mm on the +u side, clear of the fingers
    (box(365, 20, 375, 30, "o", 60.0), False),  # 15-25 mm beside the axis: under the palm's 20 mm half width
    (box(370.01, 20, 380, 30, "o", 60.0), True),
    (box(345, 40, 355, 44, "o", PALM_Z_MM), True),  # level with the palm's bottom: passed over
    (box(345, 40, 355, 44, "o", PALM_Z_MM + 1e-7), True),
    (box(345, 40, 355, 44, "o", PALM_Z_MM + 0.01), False),
    (box(345, 40, 355, 44, "o", 30.0), True),  # taller than the fingers' z, lower than the palm
], ids=["-u 45.01mm", "-u 45mm", "-u 44.99mm", "+u 40mm", "beside 15mm", "beside 20.01mm", "z=palm",
        "z=palm+1e-7", "z=palm+0.01", "z=30"])
def test_the_palm_hits_obstacles_taller_than_its_bottom_under_its_90x40mm_footprint(obstacle, clear):
    ctx, P = after_contacts(PLATE, [obstacle])
    assert kept("palm", ctx, P) is clear
    assert kept("fingers_obstacles", ctx, P)
    assert kept("precheck", ctx, P) or not clear  # it rejects only what the palm's check rejects


@pytest.mark.parametrize("obstacle", [box(345, 40, 355, 50, "o", 60.0), box(365, 40, 375, 50, "o", 60.0),
                                      box(365, -5, 375, 5, "o", 60.0)],
                         ids=["+u end", "+u end, beside", "beside the middle"])
def test_precheck_rejects_a_palm_high_obstacle_under_the_palm_away_from_the_pairs_midpoint(obstacle):
    """Across a flat plate the contacts lie within 1.55 mm of the pair's closing line and 0.75 mm of its
    midpoint along it: the palm surely covers 44.25 mm along and 18.45 mm across from the midpoint, and the
    pre-check asks its corners and sides' middles."""
    ctx, P = after_contacts(PLATE, [obstacle])
    assert not kept("palm", ctx, P)
    ctx, P = one_pair(PLATE, (350, 15), (350, -15), obstacles=[obstacle])
    assert not kept("precheck", ctx, P)
