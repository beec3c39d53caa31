import json

import numpy as np
import pytest

from cell.cellconfig import default_cell
from cell.examples import load_examples
from cell.grasp.height import grasp_z_mm
from cell.operator import Operator
from cell.physics import check_grasp, lift_clear
from cell.scene import load_assembly
from cell.study.assemblies import RECIPES, gaps_mm, shipped_assembly_paths, verify, write_all

PATHS = shipped_assembly_paths()


@pytest.fixture(scope="module")
def planner():
    from cell.grasp.synthesis import GraspPlanner

    return GraspPlanner(default_cell(), load_examples())


def test_three_assemblies_are_shipped_and_match_their_recipes(tmp_path):
    assert {p.stem for p in PATHS} >= {"default", "fig18_product", "drive_unit"} and len(PATHS) >= 3
    for p in write_all(tmp_path):
        assert json.loads(p.read_text()) == json.loads((PATHS[0].parent / p.name).read_text())
    assert set(RECIPES) == {p.stem for p in PATHS}


@pytest.mark.parametrize("path", PATHS, ids=lambda p: p.stem)
def test_tight_gaps_and_both_kinds_of_neighbour(path):
    a = load_assembly(path)
    gaps = [g for _, _, g in gaps_mm(a)]
    assert any(2.0 - 1e-6 <= g <= 6.0 + 1e-6 for g in gaps)
    assert all(g >= 2.0 - 1e-6 for g in gaps)  # side-by-side parts never touch
    dark = light = 0
    for k in range(len(a.sequence)):
        scene = a.scene_at(k)
        t = scene.target_part
        gz = grasp_z_mm(t.z_bottom_mm, t.z_top_mm, default_cell().gripper)
        for o in scene.obstacles:
            if o.polygon.distance(t.polygon) < 20:
                dark += o.z_top_mm > gz
                light += o.z_top_mm <= gz
    assert dark and light


def test_default_assembly_lies_side_by_side_inside_the_tray():
    a = load_assembly(PATHS[0].parent / "default.json")
    assert 5 <= len(a.parts) <= 7
    tray = default_cell().tray
    for i, p in enumerate(a.parts):
        assert p.z_bottom_mm == 0.0
        x0, y0, x1, y1 = p.polygon.bounds
        assert tray.x_mm[0] <= x0 and x1 <= tray.x_mm[1] and tray.y_mm[0] <= y0 and y1 <= tray.y_mm[1]
        for q in a.parts[i + 1:]:
            assert p.polygon.distance(q.polygon) >= 2.0 - 1e-6  # no stacking, no touching


@pytest.mark.parametrize("path", PATHS, ids=lambda p: p.stem)
def test_every_step_has_a_planned_grasp_that_is_collision_free_stable_and_liftable(path, planner):
    reports = verify(load_assembly(path), planner)
    bad = [(r.step, r.target, r.reasons) for r in reports if not r.ok]
    assert not bad


@pytest.mark.parametrize("path", PATHS, ids=lambda p: p.stem)
def test_every_step_is_feasible_for_the_operator_too(path):
    """Independent of the planner: the simulated operator finds a grasp at every step."""
    a = load_assembly(path)
    op = Operator(rng=np.random.default_rng(0))
    for k in range(len(a.sequence)):
        scene = a.scene_at(k)
        t = scene.target_part
        g = op.choose_grasp(t, scene.obstacles)
        assert g is not None, (k, t.id)
        assert check_grasp(t, g.contacts_mm, g.axis_deg, g.grasp_z_mm, scene.obstacles).ok
        assert lift_clear(t, scene.obstacles, g.contacts_mm, g.grasp_z_mm).ok


def test_lift_is_blocked_out_of_sequence():
    a = load_assembly(PATHS[0].parent / "fig18_product.json")
    base = next(p for p in a.parts if p.id == "base")
    blocked = lift_clear(base, [p for p in a.parts if p.id != "base"])
    assert not blocked.ok and set(blocked.blocking) == {"pcb", "nut", "washer"}
