"""The same outline listed from another vertex, or the other way round, is the same part: the planner gives the
same grasp (the samples started at the vertex the file listed first, and a hexagon listed reversed planned a
grasp one way and none the other; a clip's grasp moved 13 mm). Through scene files, as `cell grasp` reads them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cell.cellconfig import default_cell
from cell.errors import NoFeasibleGrasp
from cell.examples import load_examples
from cell.grasp.outline import own_first_vertex, part_rings
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import GraspPlanner
from cell.parts_library import part, place
from cell.scene import load_scene

HEXAGON = [[263.64, 69.3], [264.29, 70.42], [263.56, 83.1], [241.04, 73.13], [247.72, 64.89], [258.7, 64.92]]
PARTS = ["hairpin_clip_m", "plate_holes_m", "spur_gear_s", "hex_nut_m12", "l_bracket_m", "conrod_m",
         "heatsink_s", "washer_m16", "lever_m", "pcb_round_m"]


def _relisted(ring, shift: int, reverse: bool) -> list:
    r = np.roll(np.asarray(ring, float), shift, axis=0)
    return (r[::-1] if reverse else r).tolist()


def _scene_file(tmp_path, name, outline, holes, shift, reverse) -> str:
    path = tmp_path / f"{name}_{shift}_{int(reverse)}.json"
    path.write_text(json.dumps({"units": "mm", "target": "t", "parts": [{
        "id": "t", "outline": _relisted(outline, shift, reverse),
        "holes": [_relisted(h, shift, reverse) for h in holes], "z_bottom": 0, "z_top": 10}]}))
    return str(path)


ASYMMETRIC = {"hexagon", "hairpin_clip_m", "l_bracket_m", "conrod_m", "lever_m"}


def _grasp(planner, path):
    try:
        g = planner.plan(load_scene(path)).grasp
    except NoFeasibleGrasp:
        return None
    return g


@pytest.fixture(scope="module")
def planner():
    return GraspPlanner(default_cell(), load_examples(None))


@pytest.mark.parametrize("name", ["hexagon", *PARTS])
def test_another_first_vertex_or_the_reverse_order_gives_the_same_grasp(tmp_path, planner, name):
    if name == "hexagon":
        outline, holes = HEXAGON, []
    else:
        p = place(part(name), 350.0, 0.0, 181.7)
        outline, holes = p.outline_mm.tolist(), [h.tolist() for h in p.holes_mm]
    first = _grasp(planner, _scene_file(tmp_path, name, outline, holes, 0, False))
    assert first is not None
    for shift, reverse in ((1, False), (len(outline) // 2, False), (0, True), (3, True)):
        again = _grasp(planner, _scene_file(tmp_path, name, outline, holes, shift, reverse))
        assert again is not None, (shift, reverse)
        # a symmetric part's grasp may be another of its alike ones (its ties go to the first vertex listed)
        assert (again.opening_mm, again.distance_to_example, again.grasp_z_mm) == pytest.approx(
            (first.opening_mm, first.distance_to_example, first.grasp_z_mm), abs=1e-6), (shift, reverse)
        if name in ASYMMETRIC:
            np.testing.assert_allclose(np.sort(again.contacts_mm, axis=0), np.sort(first.contacts_mm, axis=0),
                                       atol=1e-6, err_msg=f"shift {shift}, reversed {reverse}")


def test_each_ring_starts_at_its_own_vertex_which_moves_with_the_part():
    p = place(part("hairpin_clip_m"), 350.0, 0.0, 181.7)
    rolled = np.roll(p.outline_mm, 7, axis=0)
    assert np.array_equal(rolled[own_first_vertex(rolled)], p.outline_mm[own_first_vertex(p.outline_mm)])
    moved = place(part("hairpin_clip_m"), 300.0, 40.0, 181.7 + 33.0)
    assert own_first_vertex(moved.outline_mm) == own_first_vertex(p.outline_mm)
    # off (a recording made before it): the rings as listed
    assert np.array_equal(part_rings(p)[0].vertices, p.outline_mm)
    assert not SynthesisParams(vertex_order_free=False).vertex_order_free and SynthesisParams().vertex_order_free
