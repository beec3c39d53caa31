import json

import numpy as np
import pytest
from shapely.geometry import Polygon

from cell.cellconfig import default_cell_path, load_cell, parse_cell
from cell.errors import BadInput
from cell.examples import GraspExample, append_examples, load_examples
from cell.fileio import append_lines_atomic, write_atomic
from cell.scene import load_assembly, load_scene, parse_assembly, parse_part, parse_scene

SQUARE = [[300, 0], [340, 0], [340, 40], [300, 40]]


def test_default_cell_matches_the_contract():
    c = load_cell(None)
    assert (c.scara.l1_mm, c.scara.l2_mm) == (325, 275)
    assert c.scara.j1_deg == (-132, 132) and c.scara.j2_deg == (-150, 150)
    assert c.scara.j3_mm == (0, 200) and c.scara.j4_deg == (-360, 360)
    assert c.gripper.opening_mm == (0, 80)
    assert (c.gripper.pad_width_mm, c.gripper.pad_thickness_mm, c.gripper.pad_height_mm) == (12, 10, 20)
    assert c.gripper.finger_length_mm == 40 and c.gripper.approach_clearance_mm == 5
    assert (c.gripper.palm_length_mm, c.gripper.palm_width_mm, c.gripper.palm_offset_mm) == (90, 40, 40)
    assert c.tray.x_mm == (200, 500) and c.tray.y_mm == (-250, 250)
    assert (c.camera.width_px, c.camera.height_px) == (1280, 1024)


@pytest.mark.parametrize("mutate,match", [
    (lambda d: d["scara"].pop("l1_mm"), "scara.l1_mm"),
    (lambda d: d["scara"].__setitem__("j1_deg", [10, -10]), "low < high"),
    (lambda d: d["gripper"].__setitem__("pad_width_mm", -1), "positive"),
    (lambda d: d.__setitem__("version", 7), "version"),
    (lambda d: d["can"]["nodes"]["j2"].__setitem__("node_id", 1), "duplicate"),
    (lambda d: d["tray"].__setitem__("x_mm", [-900, 500]), "inside the workspace"),
    (lambda d: d["can"]["nodes"]["j1"].__setitem__("node_id", 1.5), "can.nodes.j1.node_id must be a whole number"),
    (lambda d: d["camera"].__setitem__("width_px", 0.5), "camera.width_px must be a whole number"),
    (lambda d: d["can"].__setitem__("bitrate", 500000.5), "can.bitrate must be a whole number"),
    # units CONTRACT fixes: j1 in mm or j3 in deg was accepted, and `cell hw status` reported them so
    (lambda d: d["can"]["nodes"]["j1"].__setitem__("unit", "mm"), "can.nodes.j1.unit must be 'deg'"),
    (lambda d: d["can"]["nodes"]["j3"].__setitem__("unit", "deg"), "can.nodes.j3.unit must be 'mm'"),
    (lambda d: d["can"]["nodes"]["gripper"].__setitem__("unit", "deg"), "can.nodes.gripper.unit must be 'mm'"),
    # limits the drives get in whole counts/s, rounded down: under one count leaves none to send
    (lambda d: d["can"]["nodes"]["j2"].__setitem__("counts_per_unit", 0.001),
     r"scara.max_velocity.j2 = \S+ is under one count \(can.nodes.j2.counts_per_unit = 0.001\)"),
    (lambda d: d["scara"]["max_acceleration"].__setitem__("j3", 0.0005), "scara.max_acceleration.j3 = 0.0005 is under"),
    (lambda d: d["gripper"].__setitem__("speed_mm_s", 0.0009), "gripper.speed_mm_s = 0.0009 is under one count"),
])
def test_bad_cell_files_are_refused_with_the_key(mutate, match):
    d = json.loads(default_cell_path().read_text())
    mutate(d)
    with pytest.raises(BadInput, match=match):
        parse_cell(d, "x.json")


def test_cell_file_that_is_not_json(tmp_path):
    p = tmp_path / "cell.json"
    p.write_text("{ nope")
    with pytest.raises(BadInput, match="not valid JSON"):
        load_cell(p)


def test_scene_normalises_orientation_and_keeps_holes():
    cw = SQUARE[::-1]
    hole = [[310, 10], [320, 10], [320, 20], [310, 20]]
    s = parse_scene({"parts": [{"id": "a", "outline": cw, "holes": [hole], "z_top": 5}], "target": "a"})
    p = s.target_part
    x, y = p.outline_mm[:, 0], p.outline_mm[:, 1]
    signed = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    assert signed > 0  # counter-clockwise
    assert p.polygon.area == pytest.approx(1600 - 100)


@pytest.mark.parametrize("raw,match", [
    ({"parts": [{"id": "a", "outline": [[0, 0], [1, 1], [0, 1], [1, 0]], "z_top": 1}], "target": "a"},
     "not a valid polygon"),
    ({"parts": [{"id": "a", "outline": SQUARE, "z_top": 1}], "target": "b"}, "no part 'b'"),
    ({"parts": [{"id": "a", "outline": SQUARE, "z_top": 0, "z_bottom": 2}], "target": "a"}, "z_top"),
    ({"parts": [{"id": "a", "outline": [[0, 0], [1, 1]], "z_top": 1}], "target": "a"}, "at least 3"),
    ({"parts": [], "target": "a"}, "non-empty"),
    ({"parts": [{"id": "a", "outline": SQUARE, "z_bottom": -5, "z_top": 10}], "target": "a"}, "below the table"),
    ({"parts": [{"id": "a", "outline": SQUARE, "z_top": 1, "direction": [1, 0, 0]}], "target": "a"},
     "straight up"),
    ({"parts": [{"id": "a", "outline": SQUARE, "z_top": 1}, {"id": "a", "outline": SQUARE, "z_top": 1}],
      "target": "a"}, "duplicate"),
])
def test_bad_scenes(raw, match):
    with pytest.raises(BadInput, match=match):
        parse_scene(raw)


def test_float_noise_under_the_table_and_null_holes_are_read_as_meant():
    """Measured or converted data: a z_bottom of -1e-9 was "below the table" and "holes": null "must be a list"."""
    part = parse_scene({"parts": [{"id": "a", "outline": SQUARE, "z_bottom": -1e-9, "z_top": 5, "holes": None}],
                        "target": "a"}).target_part
    assert part.z_bottom_mm == 0.0 and part.holes_mm == ()
    with pytest.raises(BadInput, match="below the table"):  # a micrometre and more under it is still refused
        parse_scene({"parts": [{"id": "a", "outline": SQUARE, "z_bottom": -1e-3, "z_top": 5}], "target": "a"})
    with pytest.raises(BadInput, match="must be above z_bottom"):  # a top within the noise: no height at all
        parse_scene({"parts": [{"id": "a", "outline": SQUARE, "z_bottom": -5e-7, "z_top": -1e-7}], "target": "a"})


def test_a_scenes_cell_path_is_its_folders_only(tmp_path, monkeypatch):
    """Not the working directory's where the path names nothing beside the scene (tried: a misspelt cell file took
    an unrelated one's limits and tray without a word)."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "mycell.json").write_text(default_cell_path().read_text())
    scene = {"parts": [{"id": "a", "outline": SQUARE, "z_top": 5}], "target": "a", "cell": "mycell.json"}
    (tmp_path / "sub" / "scene.json").write_text(json.dumps(scene))
    monkeypatch.chdir(tmp_path)
    assert load_scene(tmp_path / "sub" / "scene.json").cell_path == str(tmp_path / "sub" / "mycell.json")


def test_a_scene_refuses_only_its_target_moving_other_than_up():
    # the obstacles stay where they are in this step: their own directions do not matter here
    parts = [{"id": "a", "outline": SQUARE, "z_top": 1},
             {"id": "b", "outline": [[20, 0], [30, 0], [30, 10], [20, 10]], "z_top": 1, "direction": [1, 0, 0]}]
    assert parse_scene({"parts": parts, "target": "a"}).target == "a"
    with pytest.raises(BadInput, match="'b' has disassembly direction"):
        parse_scene({"parts": parts, "target": "b"})


def test_assembly_refuses_other_directions_and_bad_sequences():
    parts = [{"id": "a", "outline": SQUARE, "z_top": 1}, {"id": "b", "outline": SQUARE, "z_bottom": 1, "z_top": 2,
                                                          "direction": [1, 0, 0]}]  # b lies on a
    with pytest.raises(BadInput, match="straight up"):
        parse_assembly({"parts": parts, "sequence": ["a", "b"]})
    parts[1].pop("direction")
    with pytest.raises(BadInput, match="exactly once"):
        parse_assembly({"parts": parts, "sequence": ["a", "a"]})
    a = parse_assembly({"parts": parts, "sequence": ["b", "a"]})
    assert a.scene_at(1).ids == ["a"] and a.scene_at(1).target == "a"


def _moved(ring, dx, dy=0.0):
    return [[x + dx, y + dy] for x, y in ring]


@pytest.mark.parametrize("b, overlap", [
    ({"outline": SQUARE}, "1600.0 mm2 and their heights by 10 mm"),  # the same place
    ({"outline": _moved(SQUARE, 5, 3)}, "1295.0 mm2 and their heights by 10 mm"),
    ({"outline": _moved(SQUARE, 35), "z_bottom": 9, "z_top": 20}, "200.0 mm2 and their heights by 1 mm"),
], ids=["same-place", "shifted", "sunk-1mm-into-it"])
def test_an_assembly_with_two_parts_in_one_place_is_refused_naming_them(b, overlap):
    parts = [{"id": "a", "outline": SQUARE, "z_top": 10}, {"id": "b", "z_top": 10, **b}]
    with pytest.raises(BadInput, match=rf"^<assembly>: parts 'a' and 'b' are in one place: their outlines overlap "
                                       rf"by {overlap}$"):
        parse_assembly({"parts": parts, "sequence": ["a", "b"]})


RING = {"outline": [[280, -20], [360, -20], [360, 60], [280, 60]], "holes": [SQUARE]}  # SQUARE is its hole


@pytest.mark.parametrize("b", [
    {"outline": _moved(SQUARE, 40)},  # touching: a shared edge
    {"outline": _moved(SQUARE, 39.98)},  # overlapping by 0.8 mm2: within the tolerance
    {"outline": SQUARE, "z_bottom": 10, "z_top": 20},  # lying on it
    {"outline": _moved(SQUARE, 10), "z_bottom": 9.6, "z_top": 20},  # on it, heights rounded (0.4 mm)
    {"outline": SQUARE, "z_bottom": 20, "z_top": 30},  # above it
], ids=["touching", "within-tolerance", "lying-on-it", "resting-0.4mm-low", "above"])
def test_parts_that_touch_or_lie_on_one_another_are_an_assembly(b):
    parts = [{"id": "a", "outline": SQUARE, "z_top": 10}, {"id": "b", "z_top": 10, **b}]
    assert parse_assembly({"parts": parts, "sequence": ["b", "a"]}).sequence == ("b", "a")
    # a part in another's hole
    parts = [{"id": "ring", **RING, "z_top": 10}, {"id": "pin", "outline": SQUARE, "z_top": 30}]
    assert parse_assembly({"parts": parts, "sequence": ["pin", "ring"]}).sequence == ("pin", "ring")


def test_run_and_plan_refuse_two_parts_in_one_place_before_anything_moves(tmp_path, capsys):
    """`cell run` ran such an assembly and stopped half way (exit 1): the camera saw one part, not two."""
    from conftest import ROOT, run_cli

    asm = json.loads((ROOT / "cell" / "data" / "assemblies" / "default.json").read_text())
    nut = next(p for p in asm["parts"] if p["id"] == "nut")
    asm["parts"].append({**nut, "id": "nut2", "outline": _moved(nut["outline"], 5, 3),
                         "holes": [_moved(h, 5, 3) for h in nut["holes"]]})
    asm["sequence"].append("nut2")
    path = tmp_path / "a.json"
    path.write_text(json.dumps(asm))
    for command in (["run", path, "--record", tmp_path / "rec"], ["plan", path]):
        code, out, err = run_cli(*command, capsys=capsys)
        assert code == 2 and out == "" and err.startswith(f"cell: error: {path}: parts 'nut' and 'nut2' are in one "
                                                         "place: their outlines overlap by "), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]  # no recording begun


@pytest.mark.parametrize("direction,ok", [([0, 0, 1], True), ([0, 0, 2.5], True), ([0, 0, 1e-3], True),
                                          ([0, 0, 1e308], True), ([0, 0, 1e-300], True),  # (refused: squared)
                                          ([0, 0, -1], False), ([0, 0, 0], False), ([0, 1, 1], False),
                                          ([1e-300, 0, 1e-300], False)])
def test_an_upward_direction_of_any_length_is_straight_up(direction, ok):
    parts = [{"id": "a", "outline": SQUARE, "z_top": 1, "direction": direction}]
    if ok:
        assert parse_assembly({"parts": parts, "sequence": ["a"]}).sequence == ("a",)
    else:
        with pytest.raises(BadInput, match="straight up"):
            parse_assembly({"parts": parts, "sequence": ["a"]})


def _example(eid, valid=True):
    part = parse_part({"id": "sq", "outline": SQUARE, "z_top": 10})
    return GraspExample(eid, part, np.array([[300.0, 20.0], [340.0, 20.0]]), valid,
                        {"kind": "manual", "by": "test"})


def test_examples_round_trip_and_append_atomically(tmp_path):
    p = tmp_path / "ex.jsonl"
    append_examples(p, [_example("a"), _example("b", valid=False)])
    append_examples(p, [_example("c")])
    got = load_examples(p)
    assert [e.id for e in got] == ["a", "b", "c"] and [e.valid for e in got] == [True, False, True]
    assert np.allclose(got[0].contacts_mm, [[300, 20], [340, 20]])
    with pytest.raises(BadInput, match="already"):
        append_examples(p, [_example("a")])
    assert len(load_examples(p)) == 3  # the refused append lost nothing


def test_bad_example_lines_name_the_line(tmp_path):
    p = tmp_path / "ex.jsonl"
    good = json.dumps(_example("a").to_json())
    far = _example("b").to_json()
    far["contacts"][0] = [100, 100]
    p.write_text(good + "\n" + json.dumps(far) + "\n")
    with pytest.raises(BadInput, match="line 2.*from the part's outline"):
        load_examples(p)
    p.write_text(good + "\n{broken\n")
    with pytest.raises(BadInput, match="line 2: not valid JSON"):
        load_examples(p)
    p.write_text("\n")
    with pytest.raises(BadInput, match="holds no examples"):
        load_examples(p)
    # numbers as strings: numpy read "300" as 300.0 and the example was taken
    for key, value in (("contacts", [["300", "20"], [340, 20]]),
                       ("joints", {"j1_deg": "10", "j2_deg": 20, "j3_mm": 5, "j4_deg": 0})):
        bad = _example("s").to_json()
        bad[key] = value
        p.write_text(json.dumps(bad) + "\n")
        with pytest.raises(BadInput, match=f"line 1.*'{key}'.*strings are not numbers"):
            load_examples(p)


def test_atomic_write_leaves_no_temp_files(tmp_path):
    p = tmp_path / "a.txt"
    write_atomic(p, "one")
    append_lines_atomic(p, ["two", "three"])
    assert p.read_text() == "one\ntwo\nthree\n"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]  # nor the appenders' lock file


BIG_INT = 10 ** 400  # valid JSON, and Python's json reads it as an int that no float holds


@pytest.mark.parametrize("edit,match", [
    (lambda p: p.__setitem__("z_top", BIG_INT), "z_top"),
    (lambda p: p.__setitem__("z_bottom", -BIG_INT), "z_bottom"),
    (lambda p: p["outline"].__setitem__(0, [BIG_INT, 0]), "outline"),
    (lambda p: p.__setitem__("direction", [0, 0, BIG_INT]), "direction"),
    (lambda p: p["outline"].__setitem__(2, [1e300, 1e300]), "outline"),
    (lambda p: p.__setitem__("holes", [[[310, 10], [320, 10], [-1e200, 20]]]), "hole #0"),
])
def test_numbers_too_large_for_a_scene_are_bad_input_not_a_crash(tmp_path, edit, match):
    part = {"id": "a", "outline": [list(p) for p in SQUARE], "z_top": 5}
    edit(part)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"parts": [part], "target": "a"}))
    with pytest.raises(BadInput, match=match):
        load_scene(path)


def test_a_cell_number_too_large_for_a_float_is_bad_input(tmp_path):
    d = json.loads(default_cell_path().read_text())
    d["scara"]["l1_mm"] = BIG_INT
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(d))
    with pytest.raises(BadInput, match="scara.l1_mm"):
        load_cell(path)


def _camera_contour(n=2000, noise_mm=0.05, seed=3):
    """A 60 x 35 mm rectangle as a camera gives it: n vertices, every edge a collinear run, a few
    hundredths of a mm of noise; at this density the noise crosses the outline over itself."""
    corners = np.array([[300.0, 0.0], [360.0, 0.0], [360.0, 35.0], [300.0, 35.0], [300.0, 0.0]])
    cum = np.r_[0, np.cumsum(np.linalg.norm(np.diff(corners, axis=0), axis=1))]
    s = np.linspace(0, cum[-1], n, endpoint=False)
    pts = np.c_[np.interp(s, cum, corners[:, 0]), np.interp(s, cum, corners[:, 1])]
    return (pts + np.random.default_rng(seed).normal(0, noise_mm, pts.shape)).round(3)


def test_a_noisy_camera_contour_that_crosses_itself_in_tiny_loops_is_repaired(tmp_path):
    from shapely.geometry import Polygon

    pts = _camera_contour()
    assert not Polygon(pts).is_valid  # the case: it was refused as "not a valid polygon"
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"parts": [{"id": "a", "outline": pts.tolist(), "z_top": 10}], "target": "a"}))
    part = load_scene(path).target_part
    assert part.polygon.is_valid and not part.holes_mm  # no pinholes left by loops turning inward
    assert part.polygon.area == pytest.approx(60 * 35, rel=0.01)
    assert part.polygon.symmetric_difference(Polygon(pts).buffer(0)).area < 2.0
    assert len(part.outline_mm) > 0.9 * len(pts)  # the outline as given, not a simplification


@pytest.mark.parametrize("outline", [
    [[300, 0], [340, 40], [340, 0], [300, 40]],  # bow tie: two halves of one size
    [[300, 0], [340, 0], [340, 40], [300, 40], [300, 20], [290, 22], [290, 18], [300, 20.5]],  # a 20 mm2 loop
])
def test_an_outline_that_really_crosses_itself_is_still_refused(outline):
    with pytest.raises(BadInput, match="not a valid polygon"):
        parse_part({"id": "a", "outline": outline, "z_top": 5})


@pytest.mark.parametrize("holes", [
    [[[330, 10], [350, 10], [350, 20], [330, 20]]],  # half outside the outline
    [[[310, 10], [320, 10], [320, 20], [310, 20]], [[315, 15], [325, 15], [325, 25], [315, 25]]],  # overlapping
    [[[280, 10], [290, 10], [290, 20], [280, 20]]],  # wholly outside
])
def test_holes_that_are_not_inside_the_outline_are_still_refused(holes):
    # a hole out of the outline is named as such, and so are overlapping holes
    with pytest.raises(BadInput, match="lies outside the outline|holes #0 and #1 overlap"):
        parse_part({"id": "a", "outline": SQUARE, "holes": holes, "z_top": 5})


@pytest.mark.parametrize("angle_deg", [0.0, 1.7, 30.0])
@pytest.mark.parametrize("second", [
    [[345, -5], [355, -5], [355, 5], [345, 5]],  # overlapping the first, edges on one line when not turned
    [[342, -3], [348, -3], [348, 3], [342, 3]],  # inside the first
])
def test_overlapping_holes_are_refused_at_any_turn(angle_deg, second):
    """Before, two overlapping axis-aligned holes were repaired into one and planned, the same
    turned by 1.7 deg refused: the material between them was read differently."""
    from shapely import affinity

    def turned(ring):
        return [list(c) for c in affinity.rotate(Polygon(ring), angle_deg, origin=(350, 0)).exterior.coords[:-1]]

    outline = [[320, -25], [380, -25], [380, 25], [320, 25]]
    first = [[340, -5], [350, -5], [350, 5], [340, 5]]
    raw = {"id": "t", "outline": turned(outline), "holes": [turned(first), turned(second)], "z_top": 12}
    with pytest.raises(BadInput, match="holes #0 and #1 overlap"):
        parse_part(raw)
    apart = {**raw, "holes": [turned(first), turned([[360, -5], [370, -5], [370, 5], [360, 5]])]}
    assert len(parse_part(apart).holes_mm) == 2


def test_holes_sharing_an_edge_are_not_refused_as_overlapping_when_turned():
    """Two holes sharing half an edge overlap by float noise (1e-14 mm2) once the part is turned:
    that is no overlap (a review found 709 of 1800 turns refused)."""
    from shapely import affinity

    outline = [[320, -25], [380, -25], [380, 25], [320, 25]]
    holes = [[[340, -5], [350, -5], [350, 5], [340, 5]], [[350, 0], [360, 0], [360, 10], [350, 10]]]
    for angle in np.arange(0.0, 180.0, 0.7):
        def turned(ring, a=angle):
            return [list(c) for c in affinity.rotate(Polygon(ring), a, origin=(350, 0)).exterior.coords[:-1]]
        part = parse_part({"id": "t", "outline": turned(outline), "holes": [turned(h) for h in holes], "z_top": 12})
        assert part.polygon.area == pytest.approx(60 * 50 - 200, abs=1e-6)


def test_a_hole_touching_the_outline_at_a_point_is_read_at_every_turn():
    """A hole's vertex on the outline, written with 4 decimals, lies up to 5e-5 mm out of it once
    turned: it was refused as "outside the outline" at one turn of three."""
    from shapely import affinity

    outline = [[320, -20], [380, -20], [380, 20], [320, 20]]
    hole = [[340, -20], [350, -10], [340, -10]]  # a vertex on the outline's lower edge
    for angle in (0.0, 17.3, 61.1, 133.7, 250.9):
        def turned(ring, a=angle):
            pts = affinity.rotate(Polygon(ring), a, origin=(300, 0)).exterior.coords[:-1]
            return [[round(x, 4), round(y, 4)] for x, y in pts]
        part = parse_part({"id": "t", "outline": turned(outline), "holes": [turned(hole)], "z_top": 12})
        assert part.polygon.area == pytest.approx(60 * 40 - 50, abs=0.01)


def test_json_nested_too_deeply_is_bad_input_not_a_recursion_error(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    from calibration import load_calibration

    for load in (load_scene, load_assembly, load_cell, load_calibration):  # every file read by read_json
        with pytest.raises(BadInput, match="nested too deeply"):
            load(path)


def test_json_integer_of_too_many_digits_is_bad_input_not_a_value_error(tmp_path):
    """json.loads raised a plain ValueError (int()'s limit of 4300 digits): an internal error, exit 1."""
    path = tmp_path / "big.json"
    path.write_text('{"units": "mm",\n "parts": [[' + "9" * 5000 + ", -20]]}")
    from calibration import load_calibration

    for load in (load_scene, load_assembly, load_cell, load_calibration):  # every file read by read_json
        with pytest.raises(BadInput, match=r"big.json is not valid JSON: a number too large: 5000 digits, "
                                           r"at most 4300 at line 2 column 13"):
            load(path)


def test_files_starting_with_a_utf8_bom_are_read(tmp_path):
    # editors on Windows start UTF-8 files with a byte order mark; it is not content
    bom = "\ufeff"
    scene = tmp_path / "scene.json"
    scene.write_text(bom + json.dumps({"units": "mm", "parts": [{"id": "sq", "outline": SQUARE, "z_top": 10}],
                                       "target": "sq"}), encoding="utf-8")
    assert load_scene(scene).target == "sq"
    cell = tmp_path / "cell.json"
    cell.write_text(bom + default_cell_path().read_text(encoding="utf-8"), encoding="utf-8")
    assert load_cell(cell) == load_cell(default_cell_path())
    ex = tmp_path / "ex.jsonl"
    append_examples(ex, [_example("a")])
    ex.write_text(bom + ex.read_text(encoding="utf-8"), encoding="utf-8")
    assert [e.id for e in load_examples(ex)] == ["a"]
    append_examples(ex, [_example("b")])  # and appended to
    assert [e.id for e in load_examples(ex)] == ["a", "b"]


def test_a_key_given_twice_in_one_object_is_bad_input(tmp_path, capsys):
    # json keeps the last one silently: a cell file with two l1_mm would run with whichever came last
    from conftest import run_cli

    text = default_cell_path().read_text(encoding="utf-8")
    cell = tmp_path / "cell.json"
    cell.write_text(text.replace('"l1_mm": 325', '"l1_mm": 325, "l1_mm": 100', 1), encoding="utf-8")
    assert '"l1_mm": 100' in cell.read_text()
    with pytest.raises(BadInput, match="key 'l1_mm' appears twice"):
        load_cell(cell)
    scene = tmp_path / "scene.json"
    scene.write_text('{"units": "mm", "target": "sq", "target": "sq", "parts": []}')
    code, out, err = run_cli("grasp", scene, "--json", capsys=capsys)
    assert code == 2 and "key 'target' appears twice" in err
    ex = tmp_path / "ex.jsonl"
    append_examples(ex, [_example("a")])
    ex.write_text(ex.read_text().replace('"valid":true', '"valid":true,"valid":false', 1))
    with pytest.raises(BadInput, match="line 1: key 'valid' appears twice"):
        load_examples(ex)
    from calibration import default_calibration_path

    for command, path, text in [("plan", tmp_path / "a.json", '{"units": "mm", "units": "mm", "parts": []}'),
                                ("map", tmp_path / "cal.json", default_calibration_path().read_text().replace(
                                    '"version": 1,', '"version": 1, "units": "mm", "units": "mm",', 1))]:
        path.write_text(text)
        code, out, err = run_cli(command, path, *(["--px", "1,2"] if command == "map" else []), capsys=capsys)
        assert code == 2 and err.endswith(f"file {path}: key 'units' appears twice in one object\n"), err
    # the same key in two different objects is fine
    assert load_cell(default_cell_path()).scara.l1_mm == 325
