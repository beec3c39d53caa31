"""The exact stages see a densely drawn outline thinned to one vertex per EXACT_SPACING_MM; outlines
no denser than that (the parts library's, a 0.5 mm/px camera's) are kept vertex for vertex."""

from dataclasses import replace

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from cell import parts_library as lib
from cell.cellconfig import default_cell
from cell.examples import load_examples
from cell.grasp import shapes
from cell.grasp.pairs import EXACT_SPACING_MM, _thinned, exact_outline
from cell.grasp.synthesis import GraspPlanner
from cell.scene import Scene


def _disc(n: int, r_mm: float = 25.0, wobble_mm: float = 0.0):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = r_mm + wobble_mm * np.random.default_rng(0).normal(size=n)
    return replace(shapes.rectangle("d", 10, 10), outline_mm=np.column_stack([350 + r * np.cos(a), r * np.sin(a)]),
                   holes_mm=[])


def test_library_outlines_reach_the_exact_stages_vertex_for_vertex():
    for part in lib.parts():
        _, rings = exact_outline(part)
        assert len(rings) == 1 + len(part.holes_mm)
        for got, given_ in zip(rings, [part.outline_mm, *part.holes_mm], strict=True):
            assert np.array_equal(got, given_), part.id


def test_a_finely_drawn_disc_is_thinned_and_planned_on_its_own_outline():
    dense = _disc(5000, wobble_mm=0.03)  # a vertex every 0.03 mm
    poly, rings = exact_outline(dense)
    perimeter = dense.polygon.length
    assert len(rings[0]) <= perimeter / EXACT_SPACING_MM + 1 and len(rings[0]) > perimeter / EXACT_SPACING_MM / 2
    originals = {tuple(p) for p in dense.outline_mm}
    assert all(tuple(p) in originals for p in rings[0])  # kept vertices, none made up
    assert poly.is_valid and abs(poly.area - dense.polygon.area) < 0.001 * dense.polygon.area
    planner = GraspPlanner(default_cell(), load_examples(None))
    grasp = planner.plan(Scene((dense,), "d")).grasp
    outline = dense.polygon.exterior
    for c in grasp.contacts_mm:  # the contacts lie on the outline as given, not only on the thinned one
        assert outline.distance(shapely.Point(c)) < 0.05
    assert abs(grasp.opening_mm - 50.0) < 0.3


@settings(max_examples=60, deadline=None)
@given(st.integers(3, 4000), st.floats(0.5, 60.0), st.floats(0.0, 0.2))
def test_thinning_keeps_original_vertices_at_most_two_spacings_apart(n, r_mm, wobble_mm):
    ring = _disc(n, r_mm, wobble_mm).outline_mm
    out = _thinned(ring, EXACT_SPACING_MM)
    seg = np.hypot(*(np.roll(ring, -1, axis=0) - ring).T)
    if n * EXACT_SPACING_MM <= seg.sum():
        assert out is ring
        return
    assert len(out) >= 3
    idx = np.array([np.flatnonzero((ring == p).all(1))[0] for p in out])  # where each kept vertex was
    assert np.all(np.diff(idx) > 0)  # a subsequence of the ring, in order
    at = np.concatenate([[0.0], np.cumsum(seg)])
    gaps = np.diff(np.concatenate([at[idx], [at[-1] + at[idx[0]]]]))  # arc length between kept vertices
    assert gaps.max() <= 2 * EXACT_SPACING_MM + seg.max() + 1e-9
