import numpy as np
import pytest
from shapely.geometry import Polygon

from cell.runtime.matching import Located, Region, locate, register
from cell.scene import parse_part


def bracket(pid, x, y, z_top=10.0):
    # An L-shaped bracket: no symmetry, so its rotation is well defined.
    pts = np.array([[0, 0], [60, 0], [60, 15], [15, 15], [15, 40], [0, 40]], float) + (x, y)
    return parse_part({"id": pid, "outline": pts.tolist(), "z_top": z_top})


def region_of(part, index, merged=False):
    return Region(index, lambda zt, zb, p=part.polygon: p, merged=merged)


@pytest.mark.parametrize("dx,dy,dth", [(0, 0, 0), (7.5, -4.0, 12.0), (-15, 9, -25), (3, 3, 170)])
def test_register_recovers_the_pose(dx, dy, dth):
    p = bracket("b", 300, 0)
    moved = p.moved(dx, dy, dth)
    x, s = register(p.polygon, moved.polygon)
    assert s > 0.99
    back = p.moved(*x)
    assert back.polygon.symmetric_difference(moved.polygon).area < 0.01 * p.polygon.area


def test_locate_assigns_regions_and_reports_strangers():
    a, b = bracket("a", 250, -100), bracket("b", 400, 100, z_top=30)
    stranger = Polygon([(450, -200), (470, -200), (470, -180), (450, -180)])
    regions = [region_of(b.moved(4, -3, 6), 0), Region(1, lambda zt, zb: stranger), region_of(a.moved(-2, 5, -3), 2)]
    found, unclaimed = locate([a, b], regions)
    assert found["a"].region == 2 and found["b"].region == 0
    assert abs(found["b"].dtheta_deg - 6) < 0.5 and abs(found["a"].dx_mm + 2) < 0.3
    assert unclaimed == [1]


def test_a_part_that_is_gone_is_not_found():
    a = bracket("a", 250, -100)
    far = bracket("x", 250, 150)
    found, unclaimed = locate([a], [region_of(far, 0)])
    assert found == {} and unclaimed == [0]


def test_the_plane_height_is_asked_per_part():
    asked = []
    a = bracket("a", 250, -100, z_top=42.0)

    def at(zt, zb):
        asked.append((zt, zb))
        return a.polygon

    locate([a], [Region(0, at)])
    assert asked == [(42.0, 0.0)]


def test_a_region_of_its_own_beats_a_merged_one_and_merged_parts_share_theirs():
    a, b = bracket("a", 300, 0), bracket("b", 300, 45)  # touching: one merged region
    c = bracket("c", 380, 0)  # separate, but the merged region would cover it after a 60 mm move
    merged = a.moved(1, 1, 2).polygon.union(b.moved(-1, 0.5, -2).polygon)
    regions = [Region(0, lambda zt, zb: merged, merged=True), region_of(c.moved(0.5, -0.5, 1), 1)]
    found, unclaimed = locate([c, a, b], regions)
    assert found["c"].region == 1 and not found["c"].merged
    assert found["a"].region == 0 and found["b"].region == 0 and found["a"].merged
    for pid, (dx, dy) in (("a", (1, 1)), ("b", (-1, 0.5))):
        assert np.hypot(found[pid].dx_mm - dx, found[pid].dy_mm - dy) < 3.0, found[pid]
    assert unclaimed == []


def test_a_region_in_pieces_still_registers():
    a = bracket("a", 300, 0)
    moved = a.moved(2, -1, 5).polygon
    pieces = moved.difference(Polygon([(250, 14), (400, 14), (400, 16), (250, 16)]))  # a sliver cut
    assert pieces.geom_type == "MultiPolygon"
    found, _ = locate([a], [Region(0, lambda zt, zb: pieces)])
    assert abs(found["a"].dtheta_deg - 5) < 1.0


def disc(pid, x, y, r=12.0, z_top=10.0):
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    return parse_part({"id": pid, "outline": np.column_stack([x + r * np.cos(a), y + r * np.sin(a)]).tolist(),
                       "z_top": z_top})


def test_the_best_fits_are_taken_first_over_all_parts():
    """Two look-alike discs 60 mm apart: b moved 2 mm lies alone, a lies touching a bracket (one
    merged region). Asked in turn, a took b's region (58 mm off, a perfect fit) and b was lost;
    best-and-nearest first, b keeps its region and a is found in the merged one."""
    a, b, other = disc("a", 300, 0), disc("b", 360, 0), bracket("c", 285, 14)
    merged = a.moved(3, 0).polygon.union(other.polygon)
    regions = [region_of(b.moved(-2, 0), 0), Region(1, lambda zt, zb: merged, merged=True)]
    found, unclaimed = locate([a, b, other], regions)
    assert found["b"].region == 0 and abs(found["b"].dx_mm + 2) < 0.3
    assert found["a"].region == 1 and abs(found["a"].dx_mm - 3) < 0.5
    assert unclaimed == []


def test_a_region_much_larger_than_a_missing_part_is_searched_like_a_merged_one():
    """A washer touching a tall neighbour whose wall the split gave to the washer: the region is
    twice the washer and not flagged; the washer is still found in it, where it lies."""
    washer = disc("w", 380, 50, r=8.0, z_top=3.0)
    wall = Polygon([(366, 55), (396, 55), (396, 62), (366, 62)])  # along the washer's far side, touching it
    region = washer.moved(1.5, -2.0).polygon.union(wall)
    assert region.area > 1.6 * washer.polygon.area
    found, _ = locate([washer], [Region(0, lambda zt, zb: region)])
    assert found["w"].merged and abs(found["w"].dx_mm - 1.5) < 0.5 and abs(found["w"].dy_mm + 2.0) < 0.5


def test_material_no_located_part_explains_becomes_an_obstacle():
    from cell.runtime.matching import unexplained

    a, tall = bracket("a", 250, -100, z_top=3.0), bracket("t", 400, 100, z_top=45.0)
    clip = Polygon([(270, -110), (285, -110), (285, -100), (270, -100)])  # a 2 mm clip touching a, not located
    # parallax: the tall part's region lies 5 mm further out when mapped at z = 0 than at its top
    regions = [Region(0, lambda zt, zb: a.polygon.union(clip)),
               Region(1, lambda zt, zb: tall.moved(5 * (1 - zt / 45.0), 0).polygon)]
    seen = {"a": a, "t": tall}
    found, _ = locate([a, tall], regions)
    obstacles = unexplained(regions, seen, found, z_top_mm=2.0)
    assert len(obstacles) == 1 and obstacles[0].meta["region"] == 0
    assert obstacles[0].z_top_mm == 2.0 and obstacles[0].z_bottom_mm == 0.0
    # the clip less the 2 mm margin around a (the tall part's region, mapped at its own height, leaves nothing)
    assert obstacles[0].polygon.area == pytest.approx(clip.difference(a.polygon.buffer(2.0)).area, rel=0.05)
    assert unexplained(regions[1:], seen, found, z_top_mm=2.0) == []


def test_a_part_cut_into_pieces_is_found_from_its_pieces():
    """A washer whose highlight the colour split cut off: two regions, neither alone like it."""
    washer = disc("w", 380, 50, r=10.0, z_top=3.0)
    moved = washer.moved(1.0, 1.5).polygon
    cut = Polygon([(365, 30), (380.5, 30), (380.5, 70), (365, 70)])  # about half of it
    regions = [Region(0, lambda zt, zb: moved.difference(cut)), Region(1, lambda zt, zb: moved.intersection(cut))]
    found, unclaimed = locate([washer], regions)
    assert found["w"].merged and found["w"].region == 0 and unclaimed == []
    assert abs(found["w"].dx_mm - 1.0) < 0.3 and abs(found["w"].dy_mm - 1.5) < 0.3
    alone, _ = locate([washer], regions[:1])
    assert alone == {}  # the larger piece alone is not it


def test_a_region_far_larger_than_a_missing_part_does_not_place_it():
    """Coverage is 1 anywhere inside a large region: a disc touching an unknown object (together
    3.7 x the disc) would be 'found' wherever it was expected, and the object ignored."""
    a = disc("a", 300, 0, r=15)
    blob = Polygon([(316.2, -30), (346, -30), (346, 30), (316.2, 30)])
    region = a.moved(1, 0).polygon.union(blob)
    found, strangers = locate([a], [Region(0, lambda zt, zb: region)])
    assert found == {} and strangers == [0]


def test_a_part_found_in_pieces_owns_them_all():
    """A washer cut in two halves, and a clip designed beside it that is gone: the clip must not be
    'found' by coverage inside the washer's second half."""
    washer = disc("washer", 380, 50, r=20.0, z_top=3.0)
    clip = parse_part({"id": "clip", "outline": [[354, 45], [364, 45], [364, 55], [354, 55]], "z_top": 3.0})
    moved = washer.moved(1.0, 0.5).polygon
    cut = Polygon([(350, 20), (381, 20), (381, 80), (350, 80)])
    regions = [Region(0, lambda zt, zb: moved.difference(cut)), Region(1, lambda zt, zb: moved.intersection(cut))]
    found, unclaimed = locate([washer, clip], regions)
    assert set(found) == {"washer"} and unclaimed == []


def test_material_in_a_region_no_part_was_found_in_is_as_tall_as_asked():
    """Something nobody modelled (a tool) beside a part: as tall as the tallest part on the tray,
    not as the 2 mm clip that happens to be missing elsewhere."""
    from cell.runtime.matching import unexplained

    cover = parse_part({"id": "cover", "outline": [[300, 0], [360, 0], [360, 40], [300, 40]], "z_top": 30.0})
    tool = Polygon([(365, 0), (395, 0), (395, 40), (365, 40)])
    regions = [Region(0, lambda zt, zb: cover.moved(0.5, 0).polygon), Region(1, lambda zt, zb: tool)]
    found, strangers = locate([cover], regions)
    seen = {"cover": found["cover"].apply(cover)}
    obstacles = unexplained(regions, seen, found, z_top_mm=2.0, stranger_z_mm=30.0)
    assert strangers == [1] and [(o.meta["region"], o.z_top_mm) for o in obstacles] == [(1, 30.0)]
    assert obstacles[0].polygon.area == pytest.approx(tool.area, rel=0.02)


def test_unexplained_material_round_a_part_keeps_its_hole():
    """A ring of material round a located part (a gasket it sits in): the obstacle is the ring, not
    a disc that would cover the part itself."""
    from cell.runtime.matching import unexplained

    part = disc("p", 350, 0, r=10.0)
    ring = disc("r", 350, 0, r=20.0).polygon.difference(disc("h", 350, 0, r=14.0).polygon)
    regions = [Region(0, lambda zt, zb: part.polygon), Region(1, lambda zt, zb: ring)]
    found, _ = locate([part], regions)
    obstacles = unexplained(regions, {"p": found["p"].apply(part)}, found, z_top_mm=5.0, stranger_z_mm=5.0)
    assert len(obstacles) == 1 and len(obstacles[0].holes_mm) == 1
    assert not obstacles[0].polygon.intersects(part.polygon)


def test_with_nothing_missing_a_misfit_is_no_obstacle_but_more_material_is():
    """Beside a part placed in a region, with every part found: a sliver the registration left (a
    poor fit) is the part's own; something as large as half the part is not, and is unknown."""
    from cell.runtime.matching import unexplained

    washer = disc("w", 380, 50, r=12.0, z_top=3.0)
    area = washer.polygon.area
    for extra_mm2, counted in [(0.3 * area, False), (0.7 * area, True)]:
        side = extra_mm2 / 10.0
        extra = Polygon([(392.5, 45), (392.5 + side, 45), (392.5 + side, 55), (392.5, 55)])
        region = washer.polygon.union(extra)
        located = {"w": Located("w", 0, 0.0, 0.0, 0.0, 0.9, True)}
        obstacles = unexplained([Region(0, lambda zt, zb, g=region: g)], {"w": washer}, located, z_top_mm=40.0,
                                stranger_z_mm=40.0, missing=False)
        assert bool(obstacles) == counted, extra_mm2
        assert all(o.z_top_mm == 40.0 for o in obstacles)


def test_the_poser_gives_shapely_affinitys_outline_float_for_float():
    """Registration poses the model with its own arithmetic (matching.Poser): it must be the very outline
    affinity.rotate and affinity.translate give, holes included, or registration (and every recording's
    replay) would drift."""
    from shapely import affinity

    from cell import parts_library as lib
    from cell.runtime.matching import Poser

    rng = np.random.default_rng(7)
    models = [lib.place(p, 350, 0, 20).polygon for p in lib.parts()[::5]] + [bracket("b", 300, 0).polygon]
    assert any(m.interiors for m in models)
    for model in models:
        before, c = model.wkb, model.centroid.coords[0]
        posed = Poser(model, c)
        for x in [np.zeros(3), np.array([0, 0, 90.0]), np.array([0, 0, 180.0]), *rng.normal(0, [8, 8, 90], (25, 3))]:
            want = affinity.translate(affinity.rotate(model, x[2], origin=c), x[0], x[1])
            assert posed(x).wkb == want.wkb, x
        assert model.wkb == before  # posing leaves the model as it was
