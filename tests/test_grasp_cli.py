"""`cell grasp`, `cell rules` and `cell bench grasp` from the command line (CONTRACT.md)."""

import json
import math

import numpy as np
import pytest
from conftest import run_cli

from cell.cellconfig import default_cell, default_cell_path
from cell.examples import append_examples
from cell.grasp import shapes
from cell.kinematics import Joints, forward, limit_violations, normalize_axis_deg
from cell.scene import Scene

CELL = default_cell()


@pytest.fixture
def examples(tmp_path):
    path = tmp_path / "examples.jsonl"
    append_examples(path, shapes.hand_made_examples())
    return path


def write_scene(path, parts, target, **extra):
    d = Scene(tuple(parts), target).to_json()
    d.update(extra)
    path.write_text(json.dumps(d))
    return path


@pytest.fixture
def scene(tmp_path):
    box = shapes.rectangle("box", 50, 30, (300, 100), 30)
    tall = shapes.rectangle("tall", 40, 40, (300, 150), 0, z_top_mm=40)
    return write_scene(tmp_path / "box.json", [box, tall], "box")


def test_grasp_json_has_the_contract_keys_and_they_agree(scene, examples, capsys):
    code, out, err = run_cli("grasp", scene, "--json", "--examples", examples, capsys=capsys)
    assert code == 0, err
    d = json.loads(out)
    for k in ("target", "contacts", "center", "angle_deg", "opening_mm", "grasp_z_mm", "joints", "counts", "time_ms"):
        assert k in d
    c = np.array(d["contacts"])
    assert d["target"] == "box" and c.shape == (2, 2)
    assert np.allclose(d["center"], c.mean(axis=0), atol=1e-3)
    assert d["opening_mm"] == pytest.approx(np.linalg.norm(c[0] - c[1]), abs=1e-3)
    assert -90 < d["angle_deg"] <= 90
    assert 0.0 <= d["grasp_z_mm"] <= 30 - 2
    j = Joints.from_dict(d["joints"])
    assert not limit_violations(j, CELL.scara)
    pose = forward(j, CELL.scara)
    assert math.hypot(pose.x_mm - d["center"][0], pose.y_mm - d["center"][1]) < 1e-2
    assert abs(normalize_axis_deg(pose.axis_deg - d["angle_deg"])) < 1e-3 and pose.z_mm == d["grasp_z_mm"]
    counts = d["counts"]
    z, z1, s, s1, s2 = (counts[k] for k in ("candidates", "valid_points", "pairs", "reachable", "valid_sets"))
    assert z >= z1 >= 2 and s == z1 * (z1 - 1) // 2 and s >= s1 >= s2 >= 1
    assert d["time_ms"] > 0


def test_several_scenes_one_line_each_and_bad_input_gives_exit_2(tmp_path, scene, examples, capsys):
    wide = write_scene(tmp_path / "wide.json", [shapes.rectangle("slab", 90, 75)], "slab")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    code, out, err = run_cli("grasp", scene, wide, scene, "--json", "--examples", examples, capsys=capsys)
    lines = [json.loads(x) for x in out.splitlines()]
    assert code == 0 and [x["scene"] for x in lines] == ["box.json", "wide.json", "box.json"]
    assert lines[1]["error"] == "no_feasible_grasp" and "stroke" in lines[1]["reason"]
    assert lines[0]["contacts"] == lines[2]["contacts"]
    code, out, err = run_cli("grasp", scene, bad, "--json", "--examples", examples, capsys=capsys)
    lines = [json.loads(x) for x in out.splitlines()]
    assert code == 2 and len(lines) == 2 and "contacts" in lines[0] and lines[1]["error"] == "bad_input"
    assert "not valid JSON" in err and "Traceback" not in err


def test_no_feasible_grasp_exits_3_with_the_reason(tmp_path, examples, capsys):
    wide = write_scene(tmp_path / "wide.json", [shapes.rectangle("slab", 90, 75)], "slab")
    code, out, err = run_cli("grasp", wide, "--json", "--examples", examples, capsys=capsys)
    d = json.loads(out)
    assert code == 3 and d["error"] == "no_feasible_grasp" and "wider than the gripper" in d["reason"]
    assert d["target"] == "slab" and d["counts"]["reachable"] == 0
    code, out, err = run_cli("grasp", wide, "--examples", examples, capsys=capsys)
    assert code == 3 and "no feasible grasp" in out


@pytest.mark.parametrize("strip_top_mm, code", [(0.5, 0), (30.0, 3)])
def test_strips_lower_than_the_grasp_z_touching_the_long_sides_leave_them_free(tmp_path, capsys, strip_top_mm, code):
    """A 40 x 70 box between two strips 1 mm away: 0.5 mm strips are passed over by pads and fingers (the
    box held across its 40 mm, from the long sides); 30 mm strips leave no free long side and the box is
    wider than the stroke the other way. Shipped examples."""
    box = shapes.rectangle("box", 40, 70, (320, 35), 0, z_top_mm=12)
    strips = [shapes.rectangle(f"s{i}", 20, 110, (320 + i * 31, 35), 0, z_top_mm=strip_top_mm) for i in (-1, 1)]
    path = write_scene(tmp_path / "strips.json", [box, *strips], "box")
    got, out, _ = run_cli("grasp", path, "--json", capsys=capsys)
    d = json.loads(out)
    assert got == code
    if code == 0:
        assert d["opening_mm"] == pytest.approx(40.0, abs=0.5)
        assert d["grasp_z_mm"] > strip_top_mm


@pytest.mark.parametrize("z_bottom,z_top,code", [(0.0, 1.5, 3), (20.0, 21.9, 3), (0.0, 2.0, 0), (20.0, 22.0, 0)])
def test_a_target_thinner_than_the_pads_need_has_no_grasp(tmp_path, examples, capsys, z_bottom, z_top, code):
    """CONTRACT: grasp z within [z_bottom, z_top - 2]. A part less than 2 mm tall has no such z: it
    was planned at z_bottom, outside the promised range; it is now 'no feasible grasp'."""
    part = shapes.rectangle("sheet", 50, 30, (320, 40), 10, z_bottom_mm=z_bottom, z_top_mm=z_top)
    path = write_scene(tmp_path / "sheet.json", [part], "sheet")
    got, out, err = run_cli("grasp", path, "--json", "--examples", examples, capsys=capsys)
    d = json.loads(out)
    assert got == code, d
    if code == 3:
        assert d["error"] == "no_feasible_grasp" and "2 mm" in d["reason"] and "tall" in d["reason"]
    else:
        assert z_bottom <= d["grasp_z_mm"] <= z_top - 2



@pytest.mark.parametrize("j3_mm,z_top,expected", [
    ((5.0, 200.0), 15.0, 5.0),  # usual z 1: up to J3's lowest, within [z_bottom, z_top - 2]
    ((5.0, 200.0), 30.0, 12.0),  # usual z 12 is reachable: unchanged
    ((5.0, 200.0), 6.0, "J3 reaches down to 5 mm"),  # z_top - 2 = 4 is below J3's lowest
    ((0.0, 10.0), 45.0, 10.0),  # usual z 27: down to J3's top, the palm (40 mm up) above the part
    ((0.0, 10.0), 100.0, "the palm (40 mm above the tips) would be inside the part, whose top is at z 100 mm"),
])
def test_the_grasp_z_moves_into_j3s_range_where_it_may(tmp_path, examples, capsys, j3_mm, z_top, expected):
    raw = json.loads(default_cell_path().read_text())
    raw["scara"]["j3_mm"] = list(j3_mm)
    if j3_mm[1] < raw["motion"]["safe_z_mm"]:  # the cell's own heights within J3, or it is refused
        raw["motion"].update(safe_z_mm=j3_mm[1], dropoff_mm=[330.0, 380.0, j3_mm[1]])
        raw["motion"]["home_joints"]["j3_mm"] = j3_mm[1]
    cell = tmp_path / "cell.json"
    cell.write_text(json.dumps(raw))
    part = shapes.rectangle("box", 50, 30, (320, 40), 10, z_top_mm=z_top)
    path = write_scene(tmp_path / "box.json", [part], "box")
    code, out, _ = run_cli("grasp", path, "--json", "--examples", examples, "--cell", cell, capsys=capsys)
    d = json.loads(out)
    if isinstance(expected, str):
        assert code == 3 and expected in d["reason"], d
    else:
        assert code == 0 and d["grasp_z_mm"] == expected and d["joints"]["j3_mm"] == expected, d


BOWTIE = [[300, 0], [340, 40], [340, 0], [300, 40]]


@pytest.mark.parametrize("case, message", [
    ("bowtie", "not a valid polygon"),
    ("no-target", "no part 'ghost'"),
    ("empty-examples", "holds no examples"),
    ("missing-file", "does not exist"),
])
def test_bad_inputs_give_a_clear_message_and_exit_2(tmp_path, examples, case, message, capsys):
    ex = examples
    if case == "bowtie":
        path = tmp_path / "s.json"
        path.write_text(json.dumps({"parts": [{"id": "b", "outline": BOWTIE, "z_top": 5}], "target": "b"}))
    elif case == "no-target":
        path = write_scene(tmp_path / "s.json", [shapes.rectangle("r", 60, 30)], "r")
        d = json.loads(path.read_text())
        d["target"] = "ghost"
        path.write_text(json.dumps(d))
    elif case == "empty-examples":
        path = write_scene(tmp_path / "s.json", [shapes.rectangle("r", 60, 30)], "r")
        ex = tmp_path / "empty.jsonl"
        ex.write_text("")
    else:
        path = tmp_path / "nowhere.json"
    code, out, err = run_cli("grasp", path, "--json", "--examples", ex, capsys=capsys)
    assert code == 2 and message in err and "Traceback" not in err and out == ""


def test_missing_default_examples_is_a_clear_error(tmp_path, monkeypatch, scene, capsys):
    import cell.examples

    monkeypatch.setattr(cell.examples, "default_examples_path", lambda: tmp_path / "gone.jsonl")
    code, out, err = run_cli("grasp", scene, "--json", capsys=capsys)
    assert code == 2 and "default example file" in err and "--examples" in err


def narrow_cell(tmp_path, opening_max):
    d = json.loads(default_cell_path().read_text())
    d["gripper"]["opening_mm"] = [0.0, opening_max]
    p = tmp_path / f"cell-{opening_max:g}.json"
    p.write_text(json.dumps(d))
    return p


def test_the_cell_comes_from_the_option_or_the_scene(tmp_path, examples, capsys):
    part = shapes.rectangle("r", 60, 30)
    narrow = narrow_cell(tmp_path, 35)  # 30 mm + 2 x 5 clearance does not fit
    plain = write_scene(tmp_path / "plain.json", [part], "r")
    own = write_scene(tmp_path / "own.json", [part], "r", cell=narrow.name)  # relative to the scene file
    assert run_cli("grasp", plain, "--json", "--examples", examples, capsys=capsys)[0] == 0
    code, out, _ = run_cli("grasp", plain, "--json", "--examples", examples, "--cell", narrow, capsys=capsys)
    assert code == 3 and "stroke" in json.loads(out)["reason"]
    assert run_cli("grasp", own, "--json", "--examples", examples, capsys=capsys)[0] == 3
    wide = narrow_cell(tmp_path, 80)
    assert run_cli("grasp", own, "--json", "--examples", examples, "--cell", wide, capsys=capsys)[0] == 0


def test_human_summary_and_explain(scene, examples, capsys):
    code, out, err = run_cli("grasp", scene, "--examples", examples, "--explain", capsys=capsys)
    assert code == 0
    assert "grasp 'box'" in out and "candidates" in out and "valid sets" in out
    assert "tree 1" in out and "tree 2" in out and "stage" in out and "nearest accepted example" in out
    code, out, err = run_cli("grasp", scene, "--examples", examples, "--explain", "--json", capsys=capsys)
    assert any("tree 1" in line for line in json.loads(out)["explain"])


def test_rules_prints_both_trees(examples, capsys):
    code, out, err = run_cli("rules", "--examples", examples, capsys=capsys)
    assert code == 0 and "Tree 1" in out and "Tree 2" in out and " THEN " in out
    code, out, err = run_cli("rules", "--examples", examples, "--json", capsys=capsys)
    d = json.loads(out)
    assert d["points"] and d["sets"] and d["training"]["examples"] == len(shapes.hand_made_examples())


def test_bench_grasp_reports_the_cascade_against_the_brute_force(examples, capsys):
    code, out, err = run_cli("bench", "grasp", "--repeat", "1", "--examples", examples, "--json",
                             "--scenes", "neighbours", capsys=capsys)
    rows = [json.loads(x) for x in out.splitlines()]
    assert code == 0
    summary = rows[-1]
    assert summary["all_same_pairs"] is True
    done = [r for r in rows[:-1] if "speedup" in r]
    assert [r["scene"] for r in rows[:-1]] == ["box-among-neighbours", "bar-among-neighbours"]
    assert done and all(r["exact_checks_cascade"] < r["exact_checks_brute"] for r in done)


@pytest.mark.parametrize("opt", [["--step-mm", "0"], ["--step-mm", "nan"], ["--step-mm", "1e18"], ["--step-mm", "21"],
                                 ["--gap-mm", "-1"]])
def test_bad_synthesis_options_are_bad_input(scene, examples, opt, capsys):
    code, out, err = run_cli("grasp", scene, "--json", "--examples", examples, *opt, capsys=capsys)
    assert code == 2 and "synthesis parameter" in err and out == ""


def test_explain_names_the_outline_that_touches_a_neighbour(tmp_path, examples, capsys):
    box = shapes.rectangle("box", 50, 30, (300, 100), 0)
    touching = shapes.rectangle("n", 20, 30, (300 + 25 + 10 + 0.5, 100), 0, z_top_mm=10)
    path = write_scene(tmp_path / "touch.json", [box, touching], "box")
    code, out, err = run_cli("grasp", path, "--examples", examples, "--explain", capsys=capsys)
    assert code == 0 and "not a candidate: 17 outline points within 1.5 mm" in out  # face + 1 past each corner


def test_bench_grasp_library_sweep_reports_the_bound_of_any_cascade(capsys):
    # the shipped examples (the bench's default) plan the hex nuts; the hand-made ones plan none
    code, out, err = run_cli("bench", "grasp", "--repeat", "1", "--json", "--library", "--scenes", "hex_nut",
                             capsys=capsys)
    rows = [json.loads(x) for x in out.splitlines()]
    assert code == 0 and all(r["scene"].startswith("library:hex_nut") for r in rows[:-1]) and len(rows) > 2
    done = [r for r in rows[:-1] if "speedup" in r]
    assert len(done) >= 2
    for r in done:  # s/s': the exact stages see at least the s' pairs they keep
        assert r["bound"] == round(r["counts"]["pairs"] / r["counts"]["reachable"], 1)
        assert r["exact_checks_cascade"] >= 4 * r["counts"]["reachable"]
    assert rows[-1]["planned"] == len(done) and 0 <= rows[-1]["speedup_at_least_20x"] <= len(done)
    total = sum(r["brute_ms"] for r in done) / sum(r["cascade_ms"] for r in done)
    assert rows[-1]["total_speedup"] == round(total, 1)  # the summed times' ratio, not a scene's


def test_a_noisy_self_crossing_camera_contour_is_planned(tmp_path, examples, capsys):
    """2000 vertices, collinear runs, 0.05 mm noise: the outline crosses itself in tiny loops. It
    is repaired on reading (docs/grasp.md) and planned like the clean rectangle."""
    from shapely.geometry import Point, Polygon

    corners = np.array([[300.0, 0.0], [360.0, 0.0], [360.0, 35.0], [300.0, 35.0], [300.0, 0.0]])
    cum = np.r_[0, np.cumsum(np.linalg.norm(np.diff(corners, axis=0), axis=1))]
    s = np.linspace(0, cum[-1], 2000, endpoint=False)
    pts = np.c_[np.interp(s, cum, corners[:, 0]), np.interp(s, cum, corners[:, 1])]
    pts = (pts + np.random.default_rng(3).normal(0, 0.05, pts.shape)).round(3)
    assert not Polygon(pts).is_valid
    path = tmp_path / "contour.json"
    path.write_text(json.dumps({"units": "mm", "target": "a",
                                "parts": [{"id": "a", "outline": pts.tolist(), "z_top": 10}]}))
    code, out, err = run_cli("grasp", path, "--json", "--examples", examples, capsys=capsys)
    assert code == 0, err
    d = json.loads(out)
    c = np.array(d["contacts"])
    # the pad rests on the outermost noise: the contact is on the pad's line, within its compliance
    assert all(Polygon(pts).buffer(0).exterior.distance(Point(p)) < 0.5 for p in c)
    assert d["opening_mm"] == pytest.approx(np.linalg.norm(c[0] - c[1]), abs=1e-3)
    assert 34 < d["opening_mm"] < 36.5 or 59 < d["opening_mm"] < 61.5


@pytest.mark.parametrize("smallest_mm, part", [
    # jaws that close to 20 mm at the least, a part 8 x 6 mm: the reason named only the largest
    # opening ("contact distance at most 70 mm"), which the part is well within
    (20.0, shapes.rectangle("p", 8, 6, (320, 40))),
    # 25 mm at the least, a 20 mm square: its diagonal pairs fit the stroke, its facing ones do not,
    # and the reason called the part wider than the stroke
    (25.0, shapes.rectangle("p", 20, 20, (350, 0))),
])
def test_a_part_narrower_than_the_smallest_opening_says_so(tmp_path, examples, smallest_mm, part, capsys):
    d = json.loads(default_cell_path().read_text())
    d["gripper"]["opening_mm"] = [smallest_mm, 80.0]
    cell = tmp_path / "cell.json"
    cell.write_text(json.dumps(d))
    path = write_scene(tmp_path / "pin.json", [part], "p")
    code, out, err = run_cli("grasp", path, "--json", "--examples", examples, "--cell", cell, capsys=capsys)
    r = json.loads(out)
    assert code == 3 and r["error"] == "no_feasible_grasp", r
    assert "narrower than the gripper's smallest opening" in r["reason"] and f"{smallest_mm:g} mm" in r["reason"]
    assert "wider" not in r["reason"]


def test_explain_says_why_there_is_no_grasp(tmp_path, examples, capsys):
    # a box boxed in by a wall taller than the palm's bottom on each long side: the pairs across
    # it get through the cheap stages and stop where the fingers meet the walls (46 mm long: the ends'
    # points are valid for the hand-made examples' tree 1)
    box = shapes.rectangle("box", 46, 30, (330, 0), 0)
    walls = [shapes.rectangle(f"w{k}", 70, 6, (330, s * 19.0), 0, z_top_mm=80) for k, s in enumerate((-1, 1))]
    path = write_scene(tmp_path / "boxed.json", [box, *walls], "box")
    code, out, err = run_cli("grasp", path, "--examples", examples, "--explain", "--json", capsys=capsys)
    d = json.loads(out)
    assert code == 3 and d["error"] == "no_feasible_grasp"
    stopped = [line for line in d["explain"] if line.startswith("rejected pair")]
    assert stopped and all("stage (" in line and "pairs stopped here" in line for line in stopped)
    # one line per stage that stopped pairs, with how many: together every pair of valid points
    total = sum(int(line.rsplit("; ", 1)[1].split()[0]) for line in stopped)
    assert total == d["counts"]["pairs"]
    code, text, _ = run_cli("grasp", path, "--examples", examples, "--explain", capsys=capsys)
    assert code == 3 and "  rejected pair" in text


@pytest.mark.parametrize("part, message", [
    # a hole around the outline used to be planned as a frame 62 mm wide around a 60 mm part
    ({"outline": [[320, -20], [380, -20], [380, 20], [320, 20]],
      "holes": [[[319, -21], [381, -21], [381, 21], [319, 21]]]}, "hole #0: lies outside the outline"),
    ({"outline": [[320, -20], [380, -20], [380, 20], [320, 20]],
      "holes": [[[370, -5], [400, -5], [400, 5], [370, 5]]]}, "hole #0: lies outside the outline"),
    ({"outline": [[True, -20], [380, -20], [380, 20], [320, 20]]}, "every point must be [x, y] with numbers"),
    ({"outline": [["320", "-20"], [380, -20], [380, 20], [320, 20]]}, "every point must be [x, y] with numbers"),
    # 40 m of outline: all pairs of its 16568 points would take 2 GB and more
    ({"outline": [[-4650, -5000], [5350, -5000], [5350, 5000], [-4650, 5000]]}, "more than the planner takes"),
    # 4 km of outline: refused before its 2 million points are sampled (it took 9 s and 1.2 GB)
    ({"outline": [[-5e5, -5e5], [5e5, -5e5], [5e5, 5e5], [-5e5, 5e5]]}, "2000000 points at the 2 mm step"),
    # a hole equal to the outline was planned as a solid part
    ({"outline": [[320, -20], [380, -20], [380, 20], [320, 20]],
      "holes": [[[320, -20], [380, -20], [380, 20], [320, 20]]]}, "hole #0: covers the whole outline"),
])
def test_scenes_a_checker_found_planned_or_crashing_are_bad_input(tmp_path, examples, part, message, capsys):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"units": "mm", "target": "t", "parts": [{"id": "t", "z_top": 12, **part}]}))
    code, out, err = run_cli("grasp", path, "--examples", examples, capsys=capsys)
    assert code == 2 and message in err and "Traceback" not in err, err


def test_a_scene_file_that_is_no_regular_file_is_bad_input(tmp_path, examples, capsys):
    import os

    fifo = tmp_path / "scene.fifo"
    os.mkfifo(fifo)  # reading it would block for ever
    for path in (fifo, "/dev/zero"):  # /dev/zero would fill the memory
        code, _, err = run_cli("grasp", path, "--examples", examples, capsys=capsys)
        assert code == 2 and "is not a regular file" in err




@pytest.mark.parametrize("diameter_mm", [71.0, 75.0])
def test_a_disc_wider_than_the_stroke_is_told_so(tmp_path, examples, capsys, diameter_mm):
    """Chords of it fit the stroke, so the stroke stage keeps pairs; the pads then meet the disc
    further out. The reason was "a protrusion in its band" or "puts a finger on material"."""
    disc = shapes.disc("d", diameter_mm / 2, (330, 20), n=90)
    path = write_scene(tmp_path / "disc.json", [disc], "d")
    code, out, _ = run_cli("grasp", path, "--json", "--examples", examples, capsys=capsys)
    reason = json.loads(out)["reason"]
    # ("at least 70.5 mm across", or "facing contact points are at least 70.5 mm apart", as the samples lie)
    assert code == 3 and reason.startswith("the part is wider than the gripper's stroke: "), reason
    assert "protrusion" not in reason and "finger on material" not in reason


def test_explain_shows_each_rejected_set_once(tmp_path, examples):
    # pairs of other candidates can end on the same contacts (the pads seat on one stretch): the sample
    # of rejected sets shows distinct contacts, up to three of them
    from cell.examples import load_examples
    from cell.grasp.explain import rejections
    from cell.grasp.synthesis import GraspPlanner

    planner = GraspPlanner(CELL, load_examples(examples))
    result = planner.plan(Scene((shapes.rectangle("bar", 80, 60, (340, 0), 0),), "bar"))
    contacts = np.array(result.reachable_pairs, float)
    assert len(contacts) >= 4
    contacts[1:-2] = contacts[0]  # every set but the last two has the first one's contacts
    made = {"reachable_pairs": contacts, "reachable_attributes": result.reachable_attributes,
            "set_valid": np.zeros(len(contacts), bool)}
    shown = [line.split(":")[0] for line in rejections(made, planner) if line.startswith("rejected set")]
    assert len(shown) == 3 and len(set(shown)) == 3
    made["set_valid"][-2:] = True  # only the copies are rejected: one line
    shown = [line for line in rejections(made, planner) if line.startswith("rejected set")]
    assert len(shown) == 1


def test_the_shipped_example_scene_is_the_default_assemblys_first_step_and_plans(capsys):
    """README's first `cell grasp` runs on cell/data/scenes/default_step0.json: the default assembly's
    first step, as `cell plan` sees it (kept in step with the assembly), planned with the shipped examples."""
    from importlib import resources

    from cell.scene import load_assembly, load_scene

    data = resources.files("cell") / "data"
    shipped = load_scene(str(data / "scenes" / "default_step0.json"))
    step0 = load_assembly(str(data / "assemblies" / "default.json")).scene_at(0)
    assert shipped.target == step0.target
    assert {p.id: p.to_json() for p in shipped.parts} == {p.id: p.to_json() for p in step0.parts}
    code, out, err = run_cli("grasp", data / "scenes" / "default_step0.json", "--json", capsys=capsys)
    assert code == 0, err
    out = json.loads(out)
    assert out["target"] == step0.target and out["counts"]["valid_sets"] > 0
