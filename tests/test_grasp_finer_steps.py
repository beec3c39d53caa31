"""Where the configured step gives no grasp, the outline is sampled again at half and a quarter of it
(SynthesisParams.finer_steps), with the same trees."""

import json

import numpy as np
import pytest
from conftest import run_cli

from cell import parts_library as lib
from cell.cellconfig import default_cell
from cell.errors import BadInput, NoFeasibleGrasp
from cell.examples import load_examples
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import GraspPlanner
from cell.physics import check_grasp
from cell.scene import Part, Scene
from cell.study.stability import simple_shapes

CELL = default_cell()


@pytest.fixture(scope="module")
def shipped():
    return load_examples(None)


def strip(width_mm: float, length_mm: float = 40.0, turn_deg: float = 10.0, at=(350.0, 0.0)) -> Part:
    a, b = width_mm / 2, length_mm / 2
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    xy = np.array([[-a, -b], [a, -b], [a, b], [-a, b]]) @ np.array([[c, s], [-s, c]]) + at
    return Part("strip", xy, (), 0.0, 5.0)


@pytest.mark.parametrize("width_mm", [0.8, 1.0, 1.2])
@pytest.mark.parametrize("turn_deg", [0.0, 10.0, 77.0])
def test_a_strip_about_a_millimetre_wide_is_held_across_at_a_finer_step(shipped, width_mm, turn_deg):
    """The facing points of a strip 1 mm wide lie up to a step apart along it: 45 degrees off the closing
    line at 2 mm, and no pair passed the antipodal stage. Sampled at 1 mm, it is held across."""
    part = strip(width_mm, turn_deg=turn_deg)
    with pytest.raises(NoFeasibleGrasp, match="antipodal"):
        GraspPlanner(CELL, shipped, SynthesisParams(finer_steps=0)).plan(Scene((part,), "strip"))
    result = GraspPlanner(CELL, shipped).plan(Scene((part,), "strip"))
    g = result.grasp
    assert result.step_mm == 1.0 and result.to_json()["step_mm"] == 1.0
    assert g.opening_mm == pytest.approx(width_mm, abs=1e-6)
    assert check_grasp(part, g.contacts_mm, g.axis_deg, g.grasp_z_mm, cell=CELL).ok


def test_a_part_planned_at_the_configured_step_says_no_step(shipped):
    result = GraspPlanner(CELL, shipped).plan(Scene((strip(10.0),), "strip"))
    assert result.step_mm is None and "step_mm" not in result.to_json()


def pentagon(r_mm: float) -> Part:
    return next(p for p in simple_shapes() if p.id == f"5-gon_r{r_mm:g}")


def test_parts_without_a_grasp_at_2_mm_are_held_stably_at_a_finer_step(shipped):
    """Regular pentagons 10 and 26 mm round have no grasp at the 2 mm step, whatever their pose (the gusset had
    none either, until each ring was sampled from its own first vertex, `vertex_order_free`; the small gear
    until the examples of 2026-12-04 taught pads resting on gear tips: test_grasp_gears.py)."""
    planner = GraspPlanner(CELL, shipped)
    coarse = GraspPlanner(CELL, shipped, SynthesisParams(finer_steps=0))
    for shape, th in [(pentagon(13), 0.0), (pentagon(13), 75.0), (pentagon(5), 30.0)]:
        part = lib.place(shape, 360.0, -40.0, th)
        with pytest.raises(NoFeasibleGrasp):
            coarse.plan(Scene((part,), part.id))
        result = planner.plan(Scene((part,), part.id))
        g = result.grasp
        assert result.step_mm in (1.0, 0.5)
        assert check_grasp(part, g.contacts_mm, g.axis_deg, g.grasp_z_mm, cell=CELL).ok, shape.id


def test_no_grasp_at_any_step_names_the_steps_tried_and_keeps_the_configured_steps_counts(shipped, tmp_path,
                                                                                           capsys):
    # a 1 mm strip between walls taller than the grasp z, 3 mm from its long faces: no finger fits beside it
    part = strip(1.0, turn_deg=0.0)
    walls = [Part(f"w{k}", np.array([[3, -30], [6, -30], [6, 30], [3, 30]]) * (s, 1) + (350, 0), (), 0.0, 40.0)
             for k, s in enumerate((1, -1))]
    scene = {"units": "mm", "target": "strip", "parts": [
        {"id": p.id, "outline": np.asarray(p.outline_mm).tolist(), "z_bottom": 0, "z_top": p.z_top_mm}
        for p in (part, *walls)]}
    path = tmp_path / "boxed.json"
    path.write_text(json.dumps(scene))
    code, out, _ = run_cli("grasp", path, "--json", capsys=capsys)
    d = json.loads(out)
    assert code == 3 and d["error"] == "no_feasible_grasp"
    assert d["reason"].endswith("(and at the finer steps 1 and 0.5 mm)"), d["reason"]
    with pytest.raises(NoFeasibleGrasp) as e:
        GraspPlanner(CELL, shipped, SynthesisParams(finer_steps=0)).plan(Scene((part, *walls), "strip"))
    assert d["reason"].startswith(e.value.reason)
    assert {k: v for k, v in d["counts"].items() if k != "time_ms"} == \
        {k: v for k, v in e.value.counts.items() if k != "time_ms"}


def _box(x0, y0, x1, y1, z_top, **meta) -> Part:
    return Part("box", np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float), (), 0.0, z_top, meta=meta)


@pytest.mark.parametrize("part, says", [
    (_box(330, -10, 370, 10, 1.0), "1 mm tall"),  # too thin for the pads 2 mm under its top, before sampling
    (_box(320, -25, 380, 25, 50.0, mass_g=3000), "too heavy"),
    (_box(300, -100, 500, 100, 5.0), "wider than the gripper's stroke"),  # in every direction
])
def test_no_finer_step_is_tried_where_none_can_give_a_grasp(shipped, part, says):
    with pytest.raises(NoFeasibleGrasp, match=says) as e:
        GraspPlanner(CELL, shipped).plan(Scene((part,), "box"))
    assert "finer step" not in e.value.reason


def test_a_large_part_is_not_sampled_finer_than_the_bound_on_its_valid_points(shipped):
    """A bar 60 x 400 mm between walls taller than it, 2 mm off its long sides, has no grasp: 1 mm is tried, not
    0.5 mm (more than 600 valid points)."""
    bar = Part("bar", np.array([[150, -30], [550, -30], [550, 30], [150, 30]], float), (), 0.0, 5.0)
    walls = [Part(f"w{k}", np.array([[140, 0], [560, 0], [560, 10], [140, 10]], float) * (1, s) + (0, s * 32), (),
                  0.0, 40.0) for k, s in enumerate((1, -1))]
    with pytest.raises(NoFeasibleGrasp) as e:
        GraspPlanner(CELL, shipped).plan(Scene((bar, *walls), "bar"))
    assert e.value.counts["valid_points"] * 2 <= 600 < e.value.counts["valid_points"] * 4
    assert e.value.reason.endswith("(and at the finer step 1 mm)"), e.value.reason


def test_a_long_outline_walled_in_is_not_sampled_finer_than_the_bound_on_its_outline_samples(shipped):
    """A bar 1500 x 20 mm walled in 1 mm off both long sides but for 100 mm of one: few candidates, but 1520
    outline samples at 2 mm. The bound looked at the candidates only, and a 10 m outline so walled in reached
    the planner's limit on outline samples at 0.5 mm: bad input (exit 2) for a part with no grasp."""
    bar = Part("bar", np.array([[-700, -10], [800, -10], [800, 10], [-700, 10]], float), (), 0.0, 5.0)
    walls = [Part("w0", np.array([[-710, 11], [810, 11], [810, 20], [-710, 20]], float), (), 0.0, 40.0),
             Part("w1", np.array([[-710, -20], [300, -20], [300, -11], [-710, -11]], float), (), 0.0, 40.0),
             Part("w2", np.array([[400, -20], [810, -20], [810, -11], [400, -11]], float), (), 0.0, 40.0)]
    with pytest.raises(NoFeasibleGrasp) as e:
        GraspPlanner(CELL, shipped).plan(Scene((bar, *walls), "bar"))
    assert e.value.counts["outline_points"] * 2 <= 4000 < e.value.counts["outline_points"] * 4
    assert e.value.reason.endswith("(and at the finer step 1 mm)"), e.value.reason


def test_a_heavy_part_whose_few_points_fail_tree_1_at_2_mm_is_told_it_is_too_heavy(shipped):
    """At 2 mm tree 1 left too few points of a small part; the finer steps got past tree 1 to the weight check,
    and the reason said only 'tree 1 keeps 1 of 4'."""
    small = Part("small", np.array([[380.3617, 1.0275], [379.0815, -0.3072], [379.6326, -0.8683], [381.0512, -1.2928],
                                    [381.0976, -1.2394], [381.311, -1.3162], [381.6824, -0.1973]]), (), 0.0, 6.0)
    light = GraspPlanner(CELL, shipped).plan(Scene((small,), "small"))
    assert light.step_mm in (1.0, 0.5)
    heavy = Part("small", small.outline_mm, (), 0.0, 6.0, meta={"mass_g": 1400})
    with pytest.raises(NoFeasibleGrasp, match="too heavy") as e:
        GraspPlanner(CELL, shipped).plan(Scene((heavy,), "small"))
    assert "tree 1" not in e.value.reason


def _circle(r, clockwise=False):
    a = np.arange(128) * (-1 if clockwise else 1) * 2 * np.pi / 128
    return r * np.column_stack([np.cos(a), np.sin(a)])


@pytest.mark.parametrize("value", [5, 1.0, True, "2"])
def test_finer_steps_must_be_a_small_whole_number(value):
    with pytest.raises(BadInput, match="finer_steps must be a whole number from 0 to 4"):
        SynthesisParams(finer_steps=value)


def test_the_finer_steps_stop_at_the_smallest_step():
    assert [p.step_mm for p in SynthesisParams().finer()] == [1.0, 0.5]
    assert [p.step_mm for p in SynthesisParams(step_mm=1.0, finer_steps=4).finer()] == [0.5]
    assert SynthesisParams(finer_steps=0).finer() == []


def test_the_run_loop_records_the_finer_step_and_the_text_outputs_name_it(tmp_path, capsys):
    """A pentagon 26 mm round, planned at 1 mm: the run's grasp decision says so (its counts are that step's),
    the recording replays, and `cell plan` / `cell grasp` say it in words too. (Its outline at full precision,
    as lib.place gives it: the run located it on that, the replay on the recording's 4 decimals, 0.009 deg
    apart, and the replay diverged at its first perception; the run now takes the model as recorded.)"""
    from cell.runtime.session import RunConfig, run_session

    pentagon_part = lib.place(pentagon(13), 360.0, -40.0, 0.0)
    raw = {"id": "pentagon", "outline": np.asarray(pentagon_part.outline_mm).tolist(),
           "holes": [np.asarray(h).tolist() for h in pentagon_part.holes_mm], "z_bottom": pentagon_part.z_bottom_mm,
           "z_top": pentagon_part.z_top_mm, "mass_g": 20}
    path = tmp_path / "pentagon_part.json"
    path.write_text(json.dumps({"units": "mm", "name": "pentagon", "parts": [raw], "sequence": ["pentagon"]}))
    rec = tmp_path / "rec"
    s = run_session(RunConfig(assembly=path, record=rec, seed=3))
    assert s["status"] == "complete" and s["parts_removed"] == 1
    decisions = [json.loads(line) for line in (rec / "decisions.jsonl").read_text().splitlines()]
    grasp = next(d for d in decisions if d["type"] == "grasp")
    assert grasp["step_mm"] == 1.0
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0 and "decisions match" in out, err
    code, out, _ = run_cli("plan", path, capsys=capsys)
    assert code == 0 and "pentagon (at the finer 1 mm outline step)" in out
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"units": "mm", "target": "pentagon", "parts": [raw]}))
    code, out, _ = run_cli("grasp", scene, capsys=capsys)
    assert code == 0 and "grasp 'pentagon' (at the finer 1 mm outline step)" in out


def test_cell_run_takes_an_assembly_naming_its_own_cell_file_by_a_relative_path(tmp_path, monkeypatch):
    """The run reads the assembly as its recording keeps it (a second read of its JSON): that read joined the
    assembly's own "cell" path onto its folder again (asm/asm/mycell.json: the run refused a good file)."""
    from cell.cellconfig import default_cell_path
    from cell.runtime.session import RunConfig, default_assembly_path, run_session

    (tmp_path / "asm").mkdir()
    (tmp_path / "asm" / "mycell.json").write_text(default_cell_path().read_text())
    one = json.loads(default_assembly_path().read_text())
    one["parts"], one["sequence"] = [p for p in one["parts"] if p["id"] == one["sequence"][0]], one["sequence"][:1]
    one["cell"] = "mycell.json"
    (tmp_path / "asm" / "one.json").write_text(json.dumps(one))
    monkeypatch.chdir(tmp_path)
    s = run_session(RunConfig(assembly="asm/one.json"))
    assert s["status"] == "complete" and s["parts_removed"] == 1
