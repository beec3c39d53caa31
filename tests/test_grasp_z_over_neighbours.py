"""Where the usual grasp z gives no grasp, the planner tries the grasp z 1 mm above each lower neighbour's top
(SynthesisParams.grasp_z_over_neighbours): the fingers pass over that neighbour (CONTRACT: only obstacles
taller than the grasp z are collision regions)."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import run_cli

from cell.cellconfig import default_cell
from cell.errors import BadInput, NoFeasibleGrasp
from cell.examples import load_examples
from cell.grasp.height import TIP_ABOVE_NEIGHBOUR_MM, TIP_BELOW_TOP_MM, raised_grasp_z_mm
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import GraspPlanner
from cell.physics import check_grasp, lift_clear
from cell.runtime.replay import planner_from_meta
from cell.scene import Part, Scene

CELL = default_cell()
OFF = SynthesisParams(grasp_z_over_neighbours=False)


@pytest.fixture(scope="module")
def shipped():
    return load_examples(None)


@pytest.fixture(scope="module")
def planner(shipped):
    return GraspPlanner(CELL, shipped)


@pytest.fixture(scope="module")
def usual(shipped):
    return GraspPlanner(CELL, shipped, OFF)


def hexagon(across_flats_mm, at=(350.0, 0.0), turn_deg=0.0) -> np.ndarray:
    r = across_flats_mm / math.sqrt(3)
    a = np.radians(turn_deg + 60.0 * np.arange(6))
    return np.column_stack([at[0] + r * np.cos(a), at[1] + r * np.sin(a)])


def circle(r_mm, at=(350.0, 0.0), n=64) -> np.ndarray:
    a = 2 * np.pi * np.arange(n) / n
    return np.column_stack([at[0] + r_mm * np.cos(a), at[1] + r_mm * np.sin(a)])[::-1]


def rect(x0, y0, x1, y1) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


def nut_in_gasket(gasket_top_mm=4.0, at=(350.0, 0.0), turn_deg=0.0) -> Scene:
    """An AF24 hex nut 13 mm tall in the r = 15 mm hole of a 120 x 120 gasket: the hole leaves 1.1-3 mm
    around the nut, no room for a 10 mm finger below the gasket's top."""
    nut = Part("nut", hexagon(24.0, at, turn_deg), (), 0.0, 13.0)
    x, y = at
    gasket = Part("gasket", rect(x - 60, y - 60, x + 60, y + 60), (circle(15.0, at),), 0.0, gasket_top_mm)
    return Scene((nut, gasket), "nut")


def box_beside_low_parts() -> Scene:
    """A box 20 mm tall with a part 2.1-5 mm tall 1 mm from each side: no free outline at the usual z (2 mm)."""
    return Scene((Part("box", rect(330, -15, 370, 15), (), 0.0, 20.0),
                  Part("low_w", rect(300, -30, 329, 30), (), 0.0, 2.1),
                  Part("low_e", rect(371, -30, 400, 30), (), 0.0, 5.0),
                  Part("low_s", rect(330, -40, 370, -16), (), 0.0, 3.0),
                  Part("low_n", rect(330, 16, 370, 40), (), 0.0, 4.0)), "box")


def held_over_neighbours(result, scene: Scene) -> None:
    """The grasp at a raised z: reported, reached by its joints, within CONTRACT's [z_bottom, z_top - 2], and
    physically sound with the obstacles present (and lifted clear of them)."""
    g, t = result.grasp, scene.target_part
    assert t.z_bottom_mm <= g.grasp_z_mm <= t.z_top_mm - TIP_BELOW_TOP_MM
    assert result.to_json()["grasp_z_mm"] == g.grasp_z_mm
    assert g.joints.j3_mm == pytest.approx(g.grasp_z_mm, abs=1e-9)
    assert all(j.j3_mm == pytest.approx(g.grasp_z_mm, abs=1e-9) for j in g.joint_options)
    check = check_grasp(t, g.contacts_mm, g.axis_deg, g.grasp_z_mm, scene.obstacles, CELL)
    assert check.ok, check.reasons
    assert lift_clear(t, scene.obstacles, g.contacts_mm, g.grasp_z_mm, CELL).ok


@pytest.mark.parametrize("turn_deg", [0.0, 17.0, 45.0])
def test_a_nut_in_a_gasket_hole_is_held_over_the_gasket(planner, usual, turn_deg):
    scene = nut_in_gasket(turn_deg=turn_deg)
    with pytest.raises(NoFeasibleGrasp, match="precheck"):
        usual.plan(scene)
    result = planner.plan(scene)
    assert result.grasp.grasp_z_mm == 4.0 + TIP_ABOVE_NEIGHBOUR_MM
    held_over_neighbours(result, scene)
    # at the usual z (1 mm) the same contacts put a finger on the gasket
    g = result.grasp
    assert not check_grasp(scene.target_part, g.contacts_mm, g.axis_deg, 1.0, scene.obstacles, CELL).ok


def test_cell_grasp_says_the_raised_z_and_its_joints(tmp_path, capsys):
    scene = nut_in_gasket()
    path = tmp_path / "nut.json"
    path.write_text(json.dumps({"units": "mm", "target": "nut", "parts": [
        {"id": p.id, "outline": np.asarray(p.outline_mm).tolist(),
         "holes": [np.asarray(h).tolist() for h in p.holes_mm], "z_bottom": p.z_bottom_mm, "z_top": p.z_top_mm}
        for p in scene.parts]}))
    code, out, _ = run_cli("grasp", path, "--json", capsys=capsys)
    d = json.loads(out)
    assert code == 0 and d["grasp_z_mm"] == 5.0 and d["joints"]["j3_mm"] == 5.0


def test_a_box_beside_low_parts_is_held_over_all_of_them(planner, usual):
    scene = box_beside_low_parts()
    with pytest.raises(NoFeasibleGrasp, match="no free outline"):
        usual.plan(scene)
    result = planner.plan(scene)
    # over 2.1, 3 and 4 the tips would rest on or within 1 mm of the next neighbour's top: 1 mm over the 5 mm one
    assert result.grasp.grasp_z_mm == 6.0
    held_over_neighbours(result, scene)


def test_a_neighbour_taller_than_the_targets_top_less_2_mm_still_blocks(planner, usual):
    # 11.5 mm: above the nut's z_top - 2 (11 mm), at every z the nut allows; no z is tried, nothing changes
    for gasket_top_mm in (11.5, 11.0):  # (11: the tips would rest on it at the highest z)
        scene = nut_in_gasket(gasket_top_mm=gasket_top_mm)
        with pytest.raises(NoFeasibleGrasp) as off:
            usual.plan(scene)
        with pytest.raises(NoFeasibleGrasp) as on:
            planner.plan(scene)
        assert on.value.reason == off.value.reason and "neighbours" not in on.value.reason
    # 9.9 mm: 10.9 mm is within it, and the nut is held there
    scene = nut_in_gasket(gasket_top_mm=9.9)
    result = planner.plan(scene)
    assert result.grasp.grasp_z_mm == pytest.approx(10.9)
    held_over_neighbours(result, scene)


def test_a_neighbour_less_than_the_margin_under_the_highest_z_is_passed_over_there(planner):
    """10.5 mm: the z 1 mm over it, 11.5 mm, is above the nut's z_top - 2 (11 mm); at 11 mm the tips pass 0.5 mm
    over it, and CONTRACT.md makes only obstacles taller than the grasp z collision regions: it had no grasp."""
    scene = nut_in_gasket(gasket_top_mm=10.5)
    result = planner.plan(scene)
    assert result.grasp.grasp_z_mm == pytest.approx(11.0)
    held_over_neighbours(result, scene)
    with pytest.raises(NoFeasibleGrasp):  # a recording made before it: none
        GraspPlanner(CELL, load_examples(None), replace(planner.params, grasp_z_top_fallback=False)).plan(scene)


def test_no_grasp_at_any_z_keeps_the_usual_zs_reason_and_counts_and_names_the_z_tried(planner, usual):
    # a nut ringed by a wall taller than it, 2.6-4.5 mm away, inside a 4 mm gasket: no z helps (a disc wider than
    # the stroke is not tried at any raised z: test_a_part_wider_than_the_stroke_is_tried_at_the_usual_z_only)
    nut = Part("nut", hexagon(24.0), (), 0.0, 13.0)
    wall = Part("wall", circle(24.0)[::-1], (circle(16.5),), 0.0, 40.0)
    gasket = Part("gasket", rect(290, -60, 410, 60), (circle(30.0),), 0.0, 4.0)
    scene = Scene((nut, wall, gasket), "nut")
    with pytest.raises(NoFeasibleGrasp) as off:
        usual.plan(scene)
    with pytest.raises(NoFeasibleGrasp) as on:
        planner.plan(scene)
    assert on.value.reason.startswith(off.value.reason)
    assert on.value.reason[len(off.value.reason):].startswith(" (and at the grasp z 5 mm over lower neighbours")
    assert str(on.value) == on.value.reason
    assert {k: v for k, v in on.value.counts.items() if k != "time_ms"} == \
        {k: v for k, v in off.value.counts.items() if k != "time_ms"}


def test_a_part_wider_than_the_stroke_is_tried_at_the_usual_z_only(planner, usual):
    # a disc 90 mm across in a 4 mm gasket: wider than the jaws take in every direction, at any z and step
    disc = Part("disc", circle(45.0), (), 0.0, 13.0)
    ring = Part("ring", rect(290, -60, 410, 60), (circle(47.0),), 0.0, 4.0)
    with pytest.raises(NoFeasibleGrasp) as e:
        planner.plan(Scene((disc, ring), "disc"))
    assert "(and at" not in e.value.reason


def test_a_low_part_out_of_the_fingers_reach_is_not_tried(planner, usual):
    # a nut ringed by a wall taller than it (no grasp at any z), a 4 mm plate 25 mm from it: beyond the fingers'
    # reach (22.5 mm), so no raised z is tried over it
    nut = Part("nut", hexagon(24.0), (), 0.0, 13.0)
    wall = Part("wall", circle(24.0)[::-1], (circle(16.5),), 0.0, 40.0)
    far = Part("plate", rect(390, -20, 430, 20), (), 0.0, 4.0)  # 25.1-26 mm from the nut's corners and flats
    scene = Scene((nut, wall, far), "nut")
    with pytest.raises(NoFeasibleGrasp) as off:
        usual.plan(scene)
    with pytest.raises(NoFeasibleGrasp) as on:
        planner.plan(scene)
    assert on.value.reason == off.value.reason
    near = Part("plate", rect(378, -20, 418, 20), (), 0.0, 4.0)  # 14 mm away: within reach, tried
    with pytest.raises(NoFeasibleGrasp) as tried:
        planner.plan(Scene((nut, wall, near), "nut"))
    assert "(and at the grasp z 5 mm over lower neighbours" in tried.value.reason


def test_a_neighbour_top_exactly_3_mm_under_the_parts_top_is_passed_over_at_z_top_minus_2():
    """1 mm over a top at z_top - 3 is z_top - 2 in the contract; in floats one printed step over it
    (4.02 - 2 = 2.0199999999999996, and 1.02 + 1 printed 2.02): it was left out, and the neighbour blocked."""
    for t in np.arange(1.01, 29.99, 0.01):
        z = raised_grasp_z_mm(0.0, t + 3.0, 1.0, [t], (0.0, 200.0))
        assert len(z) == 1 and z[0] <= t + 3.0 - TIP_BELOW_TOP_MM and z[0] >= t + TIP_ABOVE_NEIGHBOUR_MM - 1.01e-4, t


def test_the_reason_says_why_the_raised_z_gave_none_where_that_differs(planner):
    """An L bracket among ten low posts, inside a wall taller than the palm's bottom 18 mm away: the fingers meet
    the posts at the usual z; over them the fingers are clear and the palm meets the wall. The reason named only
    the posts (a reviewer's scene)."""
    from cell import parts_library as lib

    t = lib.place(lib.part("l_bracket_s"), 350, 0, 0, "t")
    ring = t.polygon.buffer(8).exterior
    posts = []
    for k in range(10):
        c = ring.interpolate(ring.length * k / 10)
        posts.append(Part(f"n{k}", rect(c.x - 2.5, c.y - 2.5, c.x + 2.5, c.y + 2.5), (), 0.0,
                          round(1.5 + (t.z_top_mm - 3.5) * k / 10, 2)))
    wall = t.polygon.buffer(28, join_style=2).difference(t.polygon.buffer(18, join_style=2))
    wall = Part("wall", np.asarray(wall.exterior.coords)[:-1], tuple(np.asarray(i.coords)[:-1] for i in wall.interiors),
                0.0, 200.0)
    with pytest.raises(NoFeasibleGrasp) as e:
        planner.plan(Scene((t, *posts, wall), "t"))
    reason = e.value.reason
    first, raised = reason.split(" over lower neighbours", 1)
    assert "palm" in raised and "palm" not in first, reason


def test_a_part_held_at_the_usual_z_is_planned_as_before(planner, usual):
    # a 4 mm gasket around a nut with room for the fingers (r = 30 mm hole): held at the usual z, as before
    nut = Part("nut", hexagon(24.0), (), 0.0, 13.0)
    gasket = Part("gasket", rect(290, -60, 410, 60), (circle(30.0),), 0.0, 4.0)
    scene = Scene((nut, gasket), "nut")
    a, b = planner.plan(scene).to_json(), usual.plan(scene).to_json()
    a.pop("time_ms"), b.pop("time_ms")
    assert a == b and a["grasp_z_mm"] == 1.0


@pytest.mark.parametrize("tops, j3, expected", [
    ([4.0], (0.0, 200.0), [5.0]),
    ([4.0, 10.5], (0.0, 200.0), [5.0, 11.0]),  # 11.5 is above z_top - 2 = 11: 11 itself, last
    ([10.5], (0.0, 10.9), []),  # ... within J3's range
    ([4.0, 11.0], (0.0, 200.0), [5.0]),  # at 11 the tips would rest on the 11 mm one
    ([4.0, 11.5], (0.0, 200.0), [5.0]),  # taller than any z the part allows
    ([10.0], (0.0, 200.0), [11.0]),  # z_top - 2 itself
    ([0.5, 1.0], (0.0, 200.0), []),  # not above the usual z (1 mm): they are passed over already
    ([4.0, 4.0, 7.0], (0.0, 200.0), [5.0, 8.0]),  # each top once, lowest first
    ([3.0, 3.5], (0.0, 200.0), [4.5]),  # at 4 mm the tips would be 0.5 mm over the 3.5 mm one
    ([3.0, 4.0], (0.0, 200.0), [5.0]),  # at 4 mm they would rest on the 4 mm one
    ([4.0, 7.0], (0.0, 6.0), [5.0]),  # J3 reaches 6 mm
    ([4.0], (5.5, 200.0), []),
])
def test_the_raised_z_lies_within_the_targets_z_bottom_to_z_top_less_2_and_j3(tops, j3, expected):
    assert raised_grasp_z_mm(0.0, 13.0, 1.0, tops, j3) == pytest.approx(expected)


def test_without_the_fallback_a_neighbour_under_the_margin_blocks_as_before():
    assert raised_grasp_z_mm(0.0, 13.0, 1.0, [4.0, 10.5], (0.0, 200.0), top_fallback=False) == [5.0]
    assert planner_from_meta({}, "here").grasp_z_top_fallback is False


def test_the_raised_z_of_a_part_on_a_plate_stays_above_its_bottom():
    # a part from 10 to 25 mm on a plate: usual z 11; a neighbour 12 mm tall gives 13
    assert raised_grasp_z_mm(10.0, 25.0, 11.0, [10.0, 12.0, 30.0], (0.0, 200.0)) == [13.0]


def test_a_recording_without_the_setting_replays_without_raised_z():
    assert planner_from_meta({}, "here").grasp_z_over_neighbours is False
    assert planner_from_meta({"grasp_z_over_neighbours": True}, "here").grasp_z_over_neighbours is True
    assert SynthesisParams().grasp_z_over_neighbours is True


@pytest.mark.parametrize("value", [1, 0, "yes", None, 1.0])
def test_bad_values_of_the_setting_are_refused(value):
    with pytest.raises(BadInput, match="grasp_z_over_neighbours must be true or false"):
        planner_from_meta({"grasp_z_over_neighbours": value}, "here")
    with pytest.raises(BadInput, match="grasp_z_over_neighbours must be true or false"):
        SynthesisParams(grasp_z_over_neighbours=value)


def test_the_run_loop_descends_to_the_raised_z_and_the_simulated_cell_holds_the_nut_there(tmp_path):
    from cell.runtime.session import RunConfig, run_session

    def part(p: Part) -> dict:
        return {"id": p.id, "outline": np.asarray(p.outline_mm).tolist(),
                "holes": [np.asarray(h).tolist() for h in p.holes_mm], "z_bottom": p.z_bottom_mm, "z_top": p.z_top_mm}

    nut = Part("nut", hexagon(24.0), (), 0.0, 13.0)
    gasket = Part("gasket", rect(325, -25, 375, 25), (circle(15.0),), 0.0, 4.0)  # 50 mm: within the stroke
    path = tmp_path / "nut_in_gasket.json"
    path.write_text(json.dumps({"units": "mm", "name": "nut_in_gasket", "parts": [part(nut), part(gasket)],
                                "sequence": ["nut", "gasket"]}))
    rec = tmp_path / "rec"
    s = run_session(RunConfig(assembly=path, record=rec, seed=3))
    assert s["status"] == "complete" and s["parts_removed"] == 2
    assert any(e.startswith("gripped nut") and "will not hold" not in e for e in s["sim_events"])
    decisions = [json.loads(line) for line in (rec / "decisions.jsonl").read_text().splitlines()]
    grasp = next(d for d in decisions if d["type"] == "grasp" and d["part"] == "nut")
    assert grasp["grasp_z_mm"] == 5.0 and grasp["joints"]["j3_mm"] == 5.0
    commands = next(d for d in decisions if d["type"] == "commands" and d["part"] == "nut")["commands"]
    assert next(c for c in commands if c["label"] == "descend")["joints"]["j3_mm"] == 5.0
    manifest = json.loads((rec / "manifest.json").read_text())
    assert manifest["meta"]["planner"]["grasp_z_over_neighbours"] is True
