"""`SynthesisParams.slanted_faces`: a pad on a face slanted to it by a few degrees (a tapered web)."""

import numpy as np
import pytest
from shapely.geometry import Point

from cell.cellconfig import default_cell
from cell.grasp import shapes
from cell.grasp.candidates import candidate_points
from cell.grasp.cascade import STAGES, Context, Pairs, run_brute_force, run_cascade
from cell.grasp.height import grasp_z_mm
from cell.grasp.params import SynthesisParams
from cell.physics import check_grasp
from cell.scene import parse_part

CELL = default_cell()
ON = SynthesisParams(slanted_faces=True)
OFF = SynthesisParams(slanted_faces=False)
# a tapered web 100 mm long, 28 mm wide at one end and 12 at the other: each long side slants by
# 4.6 deg, like a connecting rod's web (a 12 mm pad touches it first at its side, 0.5 mm proud)
WEB = parse_part({"id": "web", "z_top": 8,
                  "outline": (np.array([[-50, -14], [50, -6], [50, 6], [-50, 14]]) + [350, 0]).tolist()})


def cascade_for(target, params):
    op, free = candidate_points(target, (), params)
    idx = np.flatnonzero(free)
    vp = op.subset(idx)
    gz = grasp_z_mm(target.z_bottom_mm, target.z_top_mm, CELL.gripper)
    ctx = Context.build(target, [], CELL, params, gz, op.points, op.ring)
    P = Pairs.of(vp.points, vp.normals, idx)
    return P, run_cascade(ctx, P), ctx


def across_the_web(P):
    return (np.abs(P.pi[:, 0] - P.pj[:, 0]) < 1.5) & (np.abs(P.m[:, 0] - 350) < 15) & (np.abs(P.u[:, 1]) > 0.99)


def test_by_default_a_slanted_face_is_refused_at_the_contacts_stage():
    P, cr, _ = cascade_for(WEB, OFF)
    across = across_the_web(P)
    assert across.any()
    assert not np.isin(np.flatnonzero(across), cr.survivors).any()
    assert STAGES.index("contacts") in set(cr.rejected_by[across].tolist())


def test_with_slanted_faces_the_pads_press_on_the_candidates_and_the_grasp_is_stable():
    P, cr, ctx = cascade_for(WEB, ON)
    kept = np.intersect1d(np.flatnonzero(across_the_web(P)), cr.survivors)
    assert len(kept) >= 3
    gz = grasp_z_mm(WEB.z_bottom_mm, WEB.z_top_mm, CELL.gripper)
    for k in kept:
        ci, cj = P.ci[k], P.cj[k]
        # the reported contacts are where the pads press: within 0.5 mm along and tol across of the candidates
        assert np.linalg.norm(ci - P.pi[k]) <= 1.5 and np.linalg.norm(cj - P.pj[k]) <= 1.5
        for c in (ci, cj):
            assert WEB.polygon.boundary.distance(Point(c)) < 0.6
        v = check_grasp(WEB, np.array([ci, cj]), P.axis_deg(k), gz, (), CELL)
        assert v.ok, v.reasons
    # the cheap stages still reject only what the exact ones would: the same pairs as the brute force
    P2, _, _ = cascade_for(WEB, ON)
    br = run_brute_force(ctx, P2)
    assert np.array_equal(np.sort(cr.survivors), np.sort(br.survivors))


def test_slanted_faces_only_add_pressed_pairs_and_still_stop_at_a_bump():
    box = shapes.rectangle("box", 50, 30, (300, 100), 30)
    Pa, ca, _ = cascade_for(box, OFF)
    Pb, cb, ctx = cascade_for(box, ON)
    assert np.isin(ca.survivors, cb.survivors).all()  # what was kept is kept, with the same contacts
    assert np.allclose(Pa.ci[ca.survivors], Pb.ci[ca.survivors]) and np.allclose(Pa.cj[ca.survivors],
                                                                                Pb.cj[ca.survivors])
    # the added pairs: pads overhanging a face's end (the touching stretch's middle is off the
    # candidate, the candidate is pressed): the contacts are the candidates and the grasp holds
    added = np.setdiff1d(cb.survivors, ca.survivors)
    gz = grasp_z_mm(box.z_bottom_mm, box.z_top_mm, CELL.gripper)
    for k in added:
        assert np.linalg.norm(Pb.ci[k] - Pb.pi[k]) <= 1.5 and np.linalg.norm(Pb.cj[k] - Pb.pj[k]) <= 1.5
        assert check_grasp(box, np.array([Pb.ci[k], Pb.cj[k]]), Pb.axis_deg(k), gz, (), CELL).ok
    # a 3 mm bump on the top face: a pad beside it still stops on the bump, not on the candidate
    c = np.array([350.0, 0.0])
    outline = np.array([[-30, -15], [30, -15], [30, 15], [2, 15], [2, 18], [-2, 18], [-2, 15], [-30, 15]]) + c
    bump = parse_part({"id": "bump", "outline": outline.tolist(), "z_top": 15})
    P, cr, _ = cascade_for(bump, ON)
    beside = ((np.abs(P.u[:, 0]) < 1e-6) & (np.abs(P.pi[:, 0] - P.pj[:, 0]) < 0.5)
              & (np.abs(P.m[:, 0] - 350) > 3) & (np.abs(P.m[:, 0] - 350) < 8)
              & (np.maximum(P.pi[:, 1], P.pj[:, 1]) < 15.5))
    assert beside.any() and not np.isin(np.flatnonzero(beside), cr.survivors).any()


def _on_outline_mm(target, P, kept):
    return np.array([[target.polygon.boundary.distance(Point(c)) for c in (P.ci[k], P.cj[k])] for k in kept])


def test_the_reported_contacts_are_on_the_material_the_pads_touch():
    # on the web the pad stops at its side, 0.5 mm proud of the face under the candidate: the pad's
    # line runs in front of the outline there, the material it touches does not
    on = SynthesisParams(slanted_faces=True, contacts_on_material=True)
    off = SynthesisParams(slanted_faces=True, contacts_on_material=False)
    P_on, cr_on, _ = cascade_for(WEB, on)
    P_off, cr_off, _ = cascade_for(WEB, off)
    assert np.array_equal(cr_on.survivors, cr_off.survivors)  # the same verdicts, only what is reported moves
    kept = np.intersect1d(np.flatnonzero(across_the_web(P_on)), cr_on.survivors)
    assert len(kept) >= 3
    assert _on_outline_mm(WEB, P_off, kept).max() > 0.1  # the pad's line: up to 0.5 mm off the web's face
    assert _on_outline_mm(WEB, P_on, kept).max() < 1e-6  # on the face
    moved = np.linalg.norm(P_on.ci[kept] - P_off.ci[kept], axis=1)
    assert moved.max() <= 0.5 + 1e-9  # no further than the pad's compliance
    gz = grasp_z_mm(WEB.z_bottom_mm, WEB.z_top_mm, CELL.gripper)
    for k in kept:
        assert np.allclose(P_on.center[k], 0.5 * (P_on.ci[k] + P_on.cj[k]))
        assert check_grasp(WEB, np.array([P_on.ci[k], P_on.cj[k]]), P_on.axis_deg(k), gz, (), CELL).ok


def test_a_pad_across_a_notch_reports_a_point_of_the_part_not_the_gap():
    # a concave 11-gon (a segmented outline) whose chosen pad lies across a notch: the middle of the
    # touching material is over the gap, 0.97 mm from the outline; the contact is on the nearer side
    target = parse_part({"id": "t", "z_top": 35.485, "outline": [
        [425.7222, -174.3889], [469.7793, -183.2455], [488.5585, -189.2691], [493.5194, -211.0794],
        [470.6206, -203.74], [473.493, -227.1121], [452.2384, -216.1085], [437.7714, -218.8563],
        [425.4525, -207.366], [428.3968, -202.4424], [428.9516, -190.5188]]})
    far = {}
    for flag in (False, True):  # (sampled from its first vertex as listed, where the pad lay across the notch)
        P, cr, _ = cascade_for(target, SynthesisParams(contacts_on_material=flag, vertex_order_free=False))
        far[flag] = _on_outline_mm(target, P, cr.survivors).max()
    assert far[False] > 0.5 and far[True] < 1e-6


# an irregular star a checker drew at random: a pad closing on its slanted tips touched them at its edge
STAR = [[362.4138, 0.7098], [366.4774, 1.7445], [367.2337, 4.6443], [364.9594, 7.7373], [361.2435, 7.1311],
        [363.5024, 10.8328], [354.8574, 9.6865], [351.6202, 13.1429], [350.7642, 12.1913], [350.5743, 15.7018],
        [332.1922, -2.8916], [335.0347, -5.5871], [335.1787, -5.7235], [335.2146, -5.7577], [335.9343, -6.44],
        [335.9702, -6.4742], [339.2023, -7.2129], [340.3814, -7.6065], [338.6266, -12.2859], [339.7014, -12.9203],
        [346.3446, -14.9487], [348.3922, -13.5217], [352.4282, -16.1634], [353.2943, -16.7289], [354.9013, -17.7778],
        [357.0136, -14.9777], [361.5709, -9.8848], [365.3732, -7.8646], [365.4338, -7.7281], [367.3906, -3.3122]]


def test_contacts_offset_across_the_axis_are_refused_so_the_grasp_passes_the_physical_check():
    """Pads on slanted tips touch at their edges: the contacts' line ran 11.8 deg off the closing axis
    and the physical check refused the grasp the planner chose. Within max_contact_skew_deg (3, the
    check's own limit) the planner picks one it accepts. (The pads held to stop within their compliance of
    the contacts refuse that grasp too: left off here, to see the skew limit alone.)"""
    from dataclasses import replace

    from cell.examples import load_examples
    from cell.grasp.synthesis import GraspPlanner
    from cell.scene import Scene

    part = replace(shapes.rectangle("t", 10, 10, z_top_mm=33.7), outline_mm=np.array(STAR), holes_mm=[])
    examples = load_examples(None)
    verdicts = {}
    for skew in (90.0, SynthesisParams().max_contact_skew_deg):
        # (sampled from its first vertex as the checker listed it: there the pads met the tips at their edges)
        params = SynthesisParams(max_contact_skew_deg=skew, touch_within_compliance=False, vertex_order_free=False,
                                 part_shape_weight=0.0)  # (the choice then: with the part's shape it picks another)
        g = GraspPlanner(CELL, examples, params).plan(Scene((part,), "t")).grasp
        verdicts[skew] = check_grasp(part, g.contacts_mm, g.axis_deg, g.grasp_z_mm)
        line = np.degrees(np.arctan2(*(g.contacts_mm[1] - g.contacts_mm[0])[::-1]))
        skew_deg = abs((line - g.axis_deg + 90.0) % 180.0 - 90.0)
        assert (skew_deg <= skew + 1e-6) if skew < 90 else skew_deg > 10
    assert not verdicts[90.0].ok and "off the line through the contacts" in verdicts[90.0].reasons[0]
    assert verdicts[3.0].ok, verdicts[3.0].reasons


# a random hexagon 3 mm tall beside a 15 mm block (a checker's scene): the grasp chosen with the pads allowed to
# stop further out on a slanted face had a contact 0.53 mm behind where the pads stop (the README says 0.5)
HEXAGON = [[524.3474, -102.4449], [497.9625, -135.5311], [467.1663, -127.9228], [461.4529, -95.9068],
           [469.0332, -73.7729], [494.807, -75.0469]]
BLOCK = [[509.0425, -147.6064], [509.1748, -134.5944], [488.4511, -140.1529], [493.0951, -147.9547],
         [495.535, -158.0021]]


def test_the_pads_at_the_grasp_centre_stop_within_their_compliance_of_the_contacts():
    from cell.examples import load_examples
    from cell.grasp.bands import PAD_COMPLIANCE_MM
    from cell.grasp.synthesis import GraspPlanner
    from cell.runtime.replay import planner_from_meta
    from cell.scene import Scene

    target = parse_part({"id": "t", "z_top": 3.0, "outline": HEXAGON})
    block = parse_part({"id": "n0", "z_top": 15.0, "outline": BLOCK})
    behind = {}
    for strict in (False, True):
        # (sampled from its first vertex as the checker listed it, where the grasp showed it)
        g = GraspPlanner(CELL, load_examples(None), SynthesisParams(touch_within_compliance=strict,
                                                                    vertex_order_free=False)).plan(
            Scene((target, block), "t")).grasp
        chk = check_grasp(target, g.contacts_mm, g.axis_deg, g.grasp_z_mm, (block,), CELL)
        assert chk.ok, chk.reasons
        behind[strict] = chk.contact_error_mm  # along the axis, from where rigid pads stop
    assert behind[False] > PAD_COMPLIANCE_MM + 0.02
    assert behind[True] <= PAD_COMPLIANCE_MM + 1e-6
    assert SynthesisParams().touch_within_compliance and not planner_from_meta({}, "old").touch_within_compliance


def test_the_contact_skew_limit_must_be_an_angle_in_0_to_90():
    from cell.errors import BadInput

    for bad in (0.0, -1.0, 91.0):
        with pytest.raises(BadInput, match="max_contact_skew_deg"):
            SynthesisParams(max_contact_skew_deg=bad)
