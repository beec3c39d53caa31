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
from cell.grasp.candidates import candidate_points
from cell.grasp.cascade import Context, Pairs, run_brute_force, run_cascade
from cell.grasp.height import grasp_z_mm
from cell.grasp.pairs import EXACT_SPACING_MM, _kept, exact_outline
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import GraspPlanner
from cell.scene import Scene


def _disc(n: int, r_mm: float = 25.0, wobble_mm: float = 0.0):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = r_mm + wobble_mm * np.random.default_rng(0).normal(size=n)
    return replace(shapes.rectangle("d", 10, 10), outline_mm=np.column_stack([350 + r * np.cos(a), r * np.sin(a)]),
                   holes_mm=[])


def test_library_outlines_reach_the_exact_stages_vertex_for_vertex():
    for part in lib.parts():
        _, rings, shift = exact_outline(part)
        assert len(rings) == 1 + len(part.holes_mm) and shift == 0.0
        for got, given_ in zip(rings, [part.outline_mm, *part.holes_mm], strict=True):
            assert np.array_equal(got, given_), part.id


def test_a_finely_drawn_disc_is_thinned_and_planned_on_its_own_outline():
    dense = _disc(5000, wobble_mm=0.03)  # a vertex every 0.03 mm
    poly, rings, shift = exact_outline(dense)
    assert 0 < shift < 0.2  # the wobble's largest excursions (about 4 sigma) off the chords
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
    keep = _kept(ring, EXACT_SPACING_MM)
    seg = np.hypot(*(np.roll(ring, -1, axis=0) - ring).T)
    if n * EXACT_SPACING_MM <= seg.sum():
        assert keep is None
        return
    if keep is None:  # fewer than 3 stretches: kept whole
        assert seg.sum() < 3.5 * EXACT_SPACING_MM
        return
    assert len(keep) >= 3 and np.all(np.diff(keep) > 0)  # a subsequence of the ring, in order
    at = np.concatenate([[0.0], np.cumsum(seg)])
    gaps = np.diff(np.concatenate([at[keep], [at[-1] + at[keep[0]]]]))  # arc length between kept vertices
    assert gaps.max() <= 2 * EXACT_SPACING_MM + seg.max() + 1e-9


def _densified(corners: np.ndarray, spacing_mm: float) -> np.ndarray:
    out = []
    for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):
        n = max(1, int(np.ceil(np.hypot(*(b - a)) / spacing_mm)))
        out.append(a + (np.arange(n) / n)[:, None] * (b - a))
    return np.vstack(out)


def test_the_cascade_keeps_what_the_brute_force_keeps_on_a_thinned_outline():
    """A 40 x 20 plate drawn every 0.13 mm with a spike 1.09 mm high: thinned, the spike is lower, so
    the pre-check, which looks at the samples of the outline as given, must allow for the shift
    (it once rejected a pair the exact stages keep)."""
    sx, sh, sw = -13.983, 1.0934, 0.2764
    corners = np.array([[-20, -10], [sx - sw / 2, -10], [sx, -10 - sh], [sx + sw / 2, -10], [20, -10], [20, 10],
                        [-20, 10]]) + [350.0, 0.0]
    part = replace(shapes.rectangle("t", 10, 10), outline_mm=_densified(corners, 0.127), holes_mm=[])
    params, cell = SynthesisParams(), default_cell()
    op, free = candidate_points(part, [], params)
    idx = np.flatnonzero(free)
    vp = op.subset(idx)
    ctx = Context.build(part, [], cell, params, grasp_z_mm(part.z_bottom_mm, part.z_top_mm, cell.gripper),
                        op.points, op.ring)
    assert ctx.outline_shift_mm > 0.05 and len(ctx.edge_ax) < len(part.outline_mm) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        cascade = run_cascade(ctx, Pairs.of(vp.points, vp.normals, idx))
        brute = run_brute_force(ctx, Pairs.of(vp.points, vp.normals, idx))
    assert len(cascade.survivors) > 0
    assert np.array_equal(np.sort(cascade.survivors), np.sort(brute.survivors))
