import numpy as np
import pytest
from shapely.geometry import Polygon

from cell.runtime.matching import Region, locate, register
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
