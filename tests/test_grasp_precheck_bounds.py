"""The pre-check's footprints rest on bounds on where the contacts stage puts a pair's contacts
(cascade.py, "Where the contacts stage puts a pair's contacts"): along the closing axis within
[t - shift - compliance, t + tol] of the pair's midpoint, across it anywhere in the pad's band, and
within tol + `_onto_material_move_mm` where the material near the candidate is convex (`convex_near`).
Here every contact the stage reports, on the parts library and on parts made to strain the bounds, is
checked against them."""

from dataclasses import replace

import numpy as np
import pytest

from cell import parts_library as lib
from cell.cellconfig import default_cell
from cell.grasp import cascade, shapes
from cell.grasp.candidates import candidate_points
from cell.grasp.cascade import STAGE_FUNCS, Context, Pairs
from cell.grasp.height import grasp_z_mm
from cell.grasp.pairs import EPS_MM, convex_near
from cell.grasp.params import SynthesisParams
from cell.scene import parse_part

CELL = default_cell()
RULES = {"today": SynthesisParams(),
         "oldest": SynthesisParams(slanted_faces=False, contacts_on_material=False, max_contact_skew_deg=90,
                                   stroke_at_pad_lines=False)}


@pytest.fixture(autouse=True)
def _errstate_as_in_the_cascade():
    with np.errstate(divide="ignore", invalid="ignore"):
        yield


def notched_plate(left_mm, right_mm, depth_mm, both_faces=True):
    """A plate x 320..380, y -15..15 with a notch depth_mm deep in its top face (and its bottom face) from
    x 350 - left_mm to 350 + right_mm."""
    a, b = 350 - left_mm, 350 + right_mm
    top = [[380, 15], [b, 15], [b, 15 - depth_mm], [a, 15 - depth_mm], [a, 15], [320, 15]]
    bottom = ([[320, -15], [a, -15], [a, -15 + depth_mm], [b, -15 + depth_mm], [b, -15], [380, -15]]
              if both_faces else [[320, -15], [380, -15]])
    return parse_part({"id": "notched", "outline": bottom + top, "z_top": 15})


def trident(half_mm=3.0, gaps_mm=(0.5, 0.6), drop_mm=0.75):
    """A base x 320..380, y -15..5 with three prongs 15 mm long: the middle one x 350 -+ half_mm, drop_mm
    shorter than those beside it, gaps_mm (left, right) away, each 5.5 mm wide. Pads across the middle
    prong's tip rest on the outer prongs; within 8 mm of the tip there is no concave corner, only
    three separate stretches of outline."""
    a, b = 350 - half_mm, 350 + half_mm
    l0, l1 = a - gaps_mm[0] - 5.5, a - gaps_mm[0]
    r0, r1 = b + gaps_mm[1], b + gaps_mm[1] + 5.5
    top, tip = 20.0, 20.0 - drop_mm
    outline = [[320, -15], [380, -15], [380, 5], [r1, 5], [r1, top], [r0, top], [r0, 5], [b, 5], [b, tip],
               [a, tip], [a, 5], [l1, 5], [l1, top], [l0, top], [l0, 5], [320, 5]]
    return parse_part({"id": "trident", "outline": outline, "z_top": 15})


def wobbly_disc(n=3000, r_mm=25.0, wobble_mm=0.03):
    """A disc drawn every 0.05 mm with a wobble: the exact stages see it thinned (outline_shift_mm > 0)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = r_mm + wobble_mm * np.random.default_rng(1).normal(size=n)
    return replace(shapes.rectangle("d", 10, 10), outline_mm=np.column_stack([350 + r * np.cos(a), r * np.sin(a)]),
                   holes_mm=[])


def contacts_of_every_pair(target, params):
    """The scene (every free outline point a candidate), its pairs, those through the cheap stages up to
    antipodal and the contacts stage's verdict on them."""
    op, free = candidate_points(target, [], params)
    idx = np.flatnonzero(free)
    vp = op.subset(idx)
    gz = grasp_z_mm(target.z_bottom_mm, target.z_top_mm, CELL.gripper)
    ctx = Context.build(target, [], CELL, params, gz, op.points, op.ring, op.normals)
    P = Pairs.of(vp.points, vp.normals, idx)
    alive = np.arange(len(P))
    for stage in ("stroke", "reach", "antipodal"):
        alive = alive[STAGE_FUNCS[stage](ctx, P, alive)]
    ok = STAGE_FUNCS["contacts"](ctx, P, alive)
    return ctx, P, alive[ok]


def placed(k, P):
    """The contacts' offsets from the pairs' midpoints along the closing axis (each from its own side:
    p_i's along u, p_j's along -u) and across it, each (k, 2)."""
    m, u = P.m[k], P.u[k]
    rel = np.stack([P.ci[k] - m, P.cj[k] - m], axis=1)  # (k, 2, 2)
    along = np.stack([(rel[:, 0] * u).sum(1), -(rel[:, 1] * u).sum(1)], axis=1)
    across = np.abs(np.stack([rel[:, s, 0] * u[:, 1] - rel[:, s, 1] * u[:, 0] for s in (0, 1)], axis=1))
    return along, across


def check_bounds(target, params):
    """Asserts the bounds on every pair the contacts stage keeps; returns how far across the contacts lay
    and whether their candidates were in convex material, (k, 2) each."""
    ctx, P, k = contacts_of_every_pair(target, params)
    g, tol = CELL.gripper, params.contact_tol_mm
    along, across = placed(k, P)
    behind, ahead = cascade._contact_along_bounds_mm(ctx)
    t = P.t[k][:, None]
    assert (along >= t - behind - 1e-9).all() and (along <= t + ahead + 1e-9).all()
    assert (across <= g.pad_width_mm / 2 + tol + 1e-9).all()
    convex = convex_near(ctx, P.points, P.normals)[P.ij[k]]
    near = tol + EPS_MM + cascade._onto_material_move_mm(ctx)
    assert (across[convex] <= near + 1e-9).all()
    centre = P.center[k] - P.m[k]
    centre_across = np.abs(centre[:, 0] * P.u[k, 1] - centre[:, 1] * P.u[k, 0])
    assert (centre_across <= cascade._centre_across_bound_mm(ctx, P, k) + 1e-9).all()
    return across, convex


@pytest.mark.parametrize("rules", RULES)
@pytest.mark.parametrize("turn_deg", [20.0, -55.0])
def test_every_library_parts_contacts_lie_within_the_bounds(rules, turn_deg):
    for part in lib.parts():
        check_bounds(lib.place(part, 350, 0, turn_deg), RULES[rules])


NOTCHED_AND_FORKED = [notched_plate(6.5, 6.9, 0.75), notched_plate(6.9, 6.5, 0.95), notched_plate(3.5, 3.6, 0.6),
                      notched_plate(5.0, 9.0, 0.8, both_faces=False), trident(), trident(2.0, (0.6, 0.4), 0.9)]


@pytest.mark.parametrize("rules", RULES)
@pytest.mark.parametrize("turn_deg", [0.0, 17.0])
def test_contacts_on_notched_and_forked_parts_lie_within_the_bounds_and_off_the_line_only_outside_convex_material(
        rules, turn_deg):
    """Notches 0.6-0.95 mm deep (under contact_tol, over the compliance) and 7-14 mm wide, and a middle
    prong as much shorter than those beside it: the pads rest on the rims (the outer prongs) and
    (contacts on the material) the contacts move onto them, more than half a pad across; the candidates
    there are not in convex material."""
    far = []
    for target in NOTCHED_AND_FORKED:
        if turn_deg:
            target = target.moved(0.0, 0.0, turn_deg, about=(350.0, 0.0))
        across, convex = check_bounds(target, RULES[rules])
        far.append(across[~convex].max(initial=0.0))
    if RULES[rules].contacts_on_material:
        assert max(far) > CELL.gripper.pad_width_mm / 2
    else:  # the contact stays on the touch's line, within tol of the closing line
        assert max(far) <= RULES[rules].contact_tol_mm + 1e-6


def test_contacts_on_a_thinned_outline_lie_within_the_bounds():
    target = wobbly_disc()
    ctx, _, k = contacts_of_every_pair(target, RULES["today"])
    assert ctx.outline_shift_mm > 0 and len(k)
    check_bounds(target, RULES["today"])


@pytest.mark.parametrize("target, convex_everywhere", [
    (shapes.rectangle("r", 60, 30, angle_deg=20), True),
    (shapes.disc("d", 20), True),
    (shapes.disc("ring", 30, hole_r_mm=24), True),  # the hole lies 6 mm behind every point
    (notched_plate(6.5, 6.9, 0.75), False),
    (shapes.l_shape("l"), False),
    (trident(), False),
])
def test_convex_near_tells_convex_neighbourhoods(target, convex_everywhere):
    """On a convex part every sample's neighbourhood is convex, and a hole far enough behind the outline
    does not count; near a notch or an L's inner corner some are not."""
    op, _ = candidate_points(target, [], RULES["today"])
    ctx = Context.build(target, [], CELL, RULES["today"], 1.0, op.points, op.ring, op.normals)
    convex = convex_near(ctx, op.points, op.normals)
    outer = op.ring == 0
    assert bool(convex[outer].all()) is convex_everywhere
    if not convex_everywhere:
        assert convex[outer].any()  # away from the notch or the corner they are


@pytest.mark.parametrize("target", [wobbly_disc(), notched_plate(6.5, 6.9, 0.75), trident(), shapes.l_shape("l"),
                                    *lib.parts()[::9]], ids=lambda p: p.id)
def test_convex_near_is_the_same_with_and_without_the_edge_tree(target, monkeypatch):
    """Which edges meet each sample's region is found by comparing every (sample, edge) pair on small
    outlines and through the STRtree on large ones (a camera's outline: 5x faster there); the two
    must agree sample for sample."""
    import cell.grasp.pairs as pairs

    op, _ = candidate_points(target, [], RULES["today"])
    ctx = Context.build(target, [], CELL, RULES["today"], 1.0, op.points, op.ring, op.normals)
    by_path = {}
    for path, limit in (("broadcast", 10**12), ("tree", 0)):
        monkeypatch.setattr(pairs, "NEAR_EDGES_BROADCAST_MAX", limit)
        by_path[path] = convex_near(ctx, op.points, op.normals)
    assert np.array_equal(by_path["broadcast"], by_path["tree"])
