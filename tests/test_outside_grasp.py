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
