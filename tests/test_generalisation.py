"""Train on some part families, plan for families never seen: the grasps must be physically sound."""

import numpy as np
import pytest

from cell import parts_library as L
from cell.cellconfig import default_cell
from cell.examples import load_examples
from cell.study.stability import (
    evaluate,
    gear_shapes,
    holed_shapes,
    make_planner,
    presentations,
    random_baseline,
    simple_shapes,
    star_shapes,
)

SEEN = ["cover", "plate", "nut", "washer", "housing", "pcb", "bracket"]
UNSEEN = [f for f in L.list_families() if f not in SEEN]


@pytest.fixture(scope="module")
def unseen_result():
    cell = default_cell()
    train = [e for e in load_examples() if e.part.meta.get("family") in SEEN]
    assert train and all(e.part.meta["family"] not in UNSEEN for e in train)
    planner = make_planner(train, cell)
    shown = presentations(L.parts(UNSEEN), poses=1, seed=3, cell=cell)
    return shown, evaluate(planner, shown, cell)


def test_grasps_on_unseen_families_pass_the_physical_check(unseen_result):
    shown, t = unseen_result
    assert t.presented == len(shown) >= 20
    # jaws close where reported, no collision, centre of gravity near the jaw line, friction
    # cone, not both pads on sharp corners, opening within the stroke
    assert t.failures == []
    assert t.stable == t.planned


def test_the_planner_grasps_most_unseen_parts(unseen_result):
    _, t = unseen_result
    assert t.planned_share >= 0.6, t.no_grasp


def test_the_check_discriminates(unseen_result):
    """The same parts grasped at random outline points mostly fail the check."""
    shown, t = unseen_result
    base = random_baseline(shown, seed=3)
    assert base.presented >= 20
    assert base.stable_share < 0.5 < t.stable_share


def test_simple_shapes_outside_the_library_are_held_soundly():
    """Squares of every side 6-40 mm, rectangles, regular polygons, discs, L-shapes: never in the
    examples. Until the trees' leaves held at least 4 rows, squares of odd side were held by two
    opposite corners (the check: 'both pads sit on sharp corners')."""
    cell = default_cell()
    shown = presentations(simple_shapes(), poses=1, seed=5, cell=cell)
    t = evaluate(make_planner(load_examples(), cell), shown, cell)
    assert t.failures == []
    assert t.planned_share >= 0.8, t.no_grasp  # triangles are never held (no face faces a face)
    squares = [pid for pid, _ in t.no_grasp if pid.startswith("square")]
    assert len(squares) <= 3, squares


def test_bench_stability_command(capsys):
    import json

    from conftest import run_cli

    code, out, err = run_cli("bench", "stability", "--poses", "1", "--families", "gear,pcb", "--json",
                             capsys=capsys)
    assert code == 0 and "left-out family" in out and "whole library" in err
    s = json.loads(out.strip().splitlines()[-1])
    assert s["whole"]["presented"] == len(L.parts())
    assert s["whole"]["stable_share"] >= 0.95 and s["unseen_families"]["stable_share"] >= 0.95
    assert s["random_points"]["stable_share"] < 0.5
    assert s["clutter"]["presented"] == len(L.parts()) and s["clutter"]["stable_share"] >= 0.95
    assert s["simple_shapes"]["presented"] == len(simple_shapes()) and s["simple_shapes"]["stable_share"] == 1.0
    # rings and plates with a hole, all planned (96 of 114 before the relative distance took in the holes)
    assert s["holed_shapes"]["presented"] == len(holed_shapes()) == s["holed_shapes"]["planned"]
    assert s["holed_shapes"]["stable_share"] == 1.0
    # gears not in the library, fine teeth too, all held across their tips (21 of 78 poses before 2026-12-04)
    assert s["gears"]["presented"] == len(gear_shapes()) == s["gears"]["planned"]
    assert s["gears"]["stable_share"] == 1.0
    assert s["stars"]["presented"] == len(star_shapes()) and s["stars"]["planned"] >= 1
    assert s["stars"]["stable_share"] == 1.0
    assert set(s["per_family"]) == {"gear", "pcb"}
    assert s["unseen_families"]["presented"] == len(L.parts(["gear", "pcb"]))
    code, _, err = run_cli("bench", "stability", "--poses", "0", capsys=capsys)
    assert code == 2 and "--poses" in err
    code, _, err = run_cli("bench", "stability", "--families", "gears", capsys=capsys)
    assert code == 2 and "unknown part families" in err


def test_gear_shapes_are_other_gears_than_the_library_s_and_fit_the_stroke():
    gears = gear_shapes()
    ids = [g.id for g in gears]
    assert len(set(ids)) == len(ids) == 26 and not set(ids) & {p.id for p in L.parts()}
    assert {g.meta["family"] for g in gears} == {"gear"} and {g.meta["material"] for g in gears} == {"steel"}
    widths = [float(np.linalg.norm(g.outline_mm[:, None] - g.outline_mm[None], axis=2).max()) for g in gears]
    assert max(widths) <= 70.0 + 1e-6 and min(widths) == pytest.approx(0.8 * 16, abs=0.01)  # module 0.8, 14 teeth
    assert "spur_gear_m0.8z14" in ids and "spur_gear_m3z20" in ids and "spur_gear_m3z30" not in ids  # 96 mm
