"""Outside checks of what `cell grasp` and `cell plan` print (CONTRACT.md), on scenes made here."""

import json
import math

from conftest import run_cli
from shapely import affinity
from shapely.geometry import Polygon


def box_scene(path, rotate_deg, w_mm=50.0, h_mm=30.0, z_top_mm=20.0, center=(350.0, 0.0)):
    p = Polygon([(-w_mm / 2, -h_mm / 2), (w_mm / 2, -h_mm / 2), (w_mm / 2, h_mm / 2), (-w_mm / 2, h_mm / 2)])
    p = affinity.translate(affinity.rotate(p, rotate_deg, origin=(0, 0)), *center)
    part = {"id": "box", "outline": [list(c) for c in p.exterior.coords[:-1]], "z_bottom": 0.0, "z_top": z_top_mm}
    path.write_text(json.dumps({"units": "mm", "parts": [part], "target": "box"}))
    return path


def test_angle_stays_in_the_contract_range_after_rounding(tmp_path, capsys):
    # the box's short faces turned by 4e-5 deg: the axis is -89.99996 deg, which 4 decimals made -90.0
    scenes = [box_scene(tmp_path / f"b{i}.json", r) for i, r in enumerate((0.00004, 0.00003, 90.00004))]
    code, out, err = run_cli("grasp", *scenes, "--json", capsys=capsys)
    assert code == 0, err
    for line in out.splitlines():
        d = json.loads(line)
        assert -90.0 < d["angle_deg"] <= 90.0, d["angle_deg"]
        j = d["joints"]
        axis = math.fmod(j["j1_deg"] + j["j2_deg"] + j["j4_deg"] - d["angle_deg"], 180.0)
        assert min(abs(axis), 180 - abs(axis)) < 1e-3


def test_grasp_z_of_a_thin_part_stays_below_its_top_minus_2_as_printed(tmp_path, capsys):
    # 2-3 mm tall parts are held at z_top - 2 exactly; 4 decimals rounded 0.324575 up to 0.3246
    tops = (2.32457466880464, 2.8803745629264927, 2.6147666761823043, 2.5)
    scenes = [box_scene(tmp_path / f"t{i}.json", 10.0, z_top_mm=t) for i, t in enumerate(tops)]
    code, out, err = run_cli("grasp", *scenes, "--json", capsys=capsys)
    assert code == 0, err
    for line, top in zip(out.splitlines(), tops, strict=True):
        d = json.loads(line)
        assert 0.0 <= d["grasp_z_mm"] <= top - 2.0, (d["grasp_z_mm"], top)
        assert d["joints"]["j3_mm"] == d["grasp_z_mm"]
        assert d["grasp_z_mm"] > top - 2.0 - 2e-4  # still at the limit, to the printed precision


# Stars an outside checker drew at random (7 and 5 points). The pads of the chosen pair closed on
# flat faces near the star's notches; the contacts, moved onto the material at the band's side, lay
# 6.4 mm across the axis from the pair's line, and the grasp centre (their midpoint) with them: the
# gripper standing there met a slanted arm 3.5 / 4.9 mm in front of both contacts
STAR7 = [[406.92, 39.78], [408.81, 29.69], [404.68, 20.3], [413.75, 15.49], [418.51, 6.4], [427.92, 10.49],
         [438.0, 8.55], [440.67, 18.46], [448.47, 25.13], [442.39, 33.39], [442.04, 43.65], [431.78, 44.05],
         [423.54, 50.17], [416.84, 42.4]]
STAR5 = [[282.02, -119.93], [264.57, -123.17], [249.48, -113.82], [247.16, -131.42], [233.61, -142.89],
         [249.63, -150.53], [256.35, -166.96], [268.57, -154.08], [286.27, -152.77], [277.8, -137.17]]


def pads_first_touch_mm(outline, d):
    """For the printed grasp d: how far in front of each contact the 12 mm pads, centred on the line
    through `center` along `angle_deg` and closing from the approach opening, first meet the part
    (worked out here with shapely from the contract's words, not with the planner's bands)."""
    from shapely.geometry import box

    th = math.radians(d["angle_deg"])
    u = (math.cos(th), math.sin(th))
    cx, cy = d["center"]
    local = affinity.affine_transform(Polygon(outline), [u[0], u[1], -u[1], u[0], -(cx * u[0] + cy * u[1]),
                                                         cx * u[1] - cy * u[0]])
    out = []
    for x, y in d["contacts"]:
        t = (x - cx) * u[0] + (y - cy) * u[1]
        side = 1.0 if t > 0 else -1.0
        sweep = box(abs(t) - 2.0, -6.0, abs(t) + 15.0, 6.0)  # the pad's band, from the contact to its open face
        hit = affine_side(local, side).intersection(sweep)
        far = max((p[0] for g in getattr(hit, "geoms", [hit]) if g.geom_type == "Polygon"
                   for p in g.exterior.coords), default=-math.inf)
        out.append(far - abs(t))
    return out


def affine_side(poly, side):
    return poly if side > 0 else affinity.scale(poly, -1.0, 1.0, origin=(0, 0))


def test_the_pads_where_the_gripper_stands_stop_at_the_printed_contacts(tmp_path, capsys):
    scenes = []
    for i, (outline, top) in enumerate(((STAR7, 16.03), (STAR5, 43.06))):
        for turn in (0.0, 90.0, 211.0):
            p = affinity.rotate(Polygon(outline), turn, origin=(350.0, 0.0))
            part = {"id": "star", "outline": [list(c) for c in p.exterior.coords[:-1]], "z_bottom": 0.0, "z_top": top}
            path = tmp_path / f"star{i}_{turn:g}.json"
            path.write_text(json.dumps({"units": "mm", "parts": [part], "target": "star"}))
            scenes.append((path, part["outline"]))
    code, out, err = run_cli("grasp", *[s for s, _ in scenes], "--json", capsys=capsys)
    assert code == 0, err
    planned = 0
    for (path, outline), line in zip(scenes, out.splitlines(), strict=True):
        d = json.loads(line)
        if "error" in d:
            continue
        planned += 1
        # within the pads' compliance (0.5 mm) and the slant of the face as the centre moved: not 3.5 mm
        assert max(pads_first_touch_mm(outline, d)) <= 1.0, (path.name, pads_first_touch_mm(outline, d))
    assert planned >= 2


def test_every_pair_the_cascade_keeps_has_its_pads_stop_at_its_contacts():
    # not only the chosen grasp: every reachable pair's contacts, centre and axis, as a grasp would print them
    import numpy as np

    from cell.cellconfig import default_cell
    from cell.grasp.candidates import candidate_points
    from cell.grasp.cascade import Context, Pairs, run_cascade
    from cell.grasp.height import grasp_z_mm
    from cell.grasp.params import SynthesisParams
    from cell.scene import parse_part

    cell, params = default_cell(), SynthesisParams()
    kept = 0
    for outline, top in ((STAR7, 16.03), (STAR5, 43.06)):
        part = parse_part({"id": "star", "outline": outline, "z_top": top})
        op, free = candidate_points(part, (), params)
        vp = op.subset(np.flatnonzero(free))
        ctx = Context.build(part, [], cell, params, grasp_z_mm(0.0, top, cell.gripper), op.points, op.ring)
        P = Pairs.of(vp.points, vp.normals, np.flatnonzero(free))
        for k in run_cascade(ctx, P).survivors:
            d = {"contacts": [P.ci[k].tolist(), P.cj[k].tolist()], "center": P.center[k].tolist(),
                 "angle_deg": P.axis_deg(k)}
            assert max(pads_first_touch_mm(outline, d)) <= 1.0, (k, pads_first_touch_mm(outline, d))
            kept += 1
    assert kept >= 10
