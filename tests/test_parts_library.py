import math
from collections import Counter

import numpy as np
import pytest
from shapely.geometry import Polygon

from cell import parts_library as L
from cell.errors import BadInput
from cell.operator import line_contacts


def _widths(part, n=180):
    """Caliper width of the outline for closing axes 0..179 deg."""
    xy = part.outline_mm
    out = []
    for k in range(n):
        a = np.array([math.cos(math.pi * k / n), math.sin(math.pi * k / n)])
        s = xy @ a
        out.append(s.max() - s.min())
    return np.array(out)


def test_library_has_fifty_parts_in_families_and_sizes():
    parts = L.parts()
    assert len(parts) >= 50
    assert len({p.id for p in parts}) == len(parts)
    fam = Counter(p.meta["family"] for p in parts)
    assert len(fam) >= 10
    for family in ("cover", "bracket", "plate", "gear", "nut", "washer", "housing", "pcb", "shaft", "clip"):
        assert fam[family] >= 2, family
    # several parts come in more than one size: same generator name, different size label
    stems = Counter(p.id.rsplit("_", 1)[0] for p in parts)
    assert sum(1 for n in stems.values() if n >= 2) >= 6


@pytest.mark.parametrize("part", L.parts(), ids=lambda p: p.id)
def test_every_part_is_a_valid_centred_ccw_outline_within_the_gripper_range(part):
    poly = part.polygon
    assert poly.is_valid and poly.area > 20
    x, y = part.outline_mm[:, 0], part.outline_mm[:, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0  # counter-clockwise
    c = np.asarray(poly.centroid.coords[0])
    assert np.allclose(c, 0, atol=1e-6)
    assert 2 <= part.height_mm <= 60
    assert part.meta["family"] and part.meta["size"] and part.meta["mass_g"] > 0
    # an 80 mm stroke with 2 x 5 mm approach clearance holds it somewhere: some line through or
    # near the centre of gravity crosses the outline over at most 70 mm
    outer = Polygon(part.outline_mm)
    spans = []
    for k in range(36):
        a = np.array([math.cos(math.pi * k / 36), math.sin(math.pi * k / 36)])
        for off in (-10, -5, 0, 5, 10):
            c = line_contacts(outer, off * np.array([-a[1], a[0]]), a)
            if c is not None:
                spans.append(np.linalg.norm(c[1] - c[0]))
    assert min(spans) <= 70


def test_some_parts_are_too_wide_in_one_direction():
    wide = [p.id for p in L.parts() if _widths(p).max() > 80]
    assert len(wide) >= 5


def test_generators_are_deterministic():
    a = L.spur_gear("m", teeth=18, tip_d=44, t=12)
    b = L.spur_gear("m", teeth=18, tip_d=44, t=12)
    assert np.array_equal(a.outline_mm, b.outline_mm)
    assert np.array_equal(L.part("spur_gear_m").outline_mm, a.outline_mm)


def test_gear_has_teeth_and_pcb_has_connectors_sticking_out():
    g = L.part("spur_gear_m")
    r = np.linalg.norm(g.outline_mm, axis=1)
    # radii cluster at root and tip: 18 teeth -> at least 36 tip vertices
    assert r.max() - r.min() > 3 and np.sum(r > r.max() - 0.1) >= 36
    pcb = L.part("pcb_m")
    xs, ys = pcb.outline_mm[:, 0], pcb.outline_mm[:, 1]
    # the board is 80 x 50; connectors make the outline larger than the board
    assert np.ptp(xs) > 80 or np.ptp(ys) > 50
    assert pcb.holes_mm  # mounting holes


def test_place_moves_rotates_and_renames():
    p = L.part("plate_holes_m")
    q = L.place(p, 350.0, -120.0, 30.0, "base", z_bottom_mm=6.0)
    assert q.id == "base" and q.meta["family"] == "plate"
    assert np.allclose(q.polygon.centroid.coords[0], (350, -120), atol=1e-6)
    assert q.polygon.area == pytest.approx(p.polygon.area)
    assert (q.z_bottom_mm, q.z_top_mm) == (6.0, 6.0 + p.height_mm)
    w = _widths(p)
    assert _widths(q).min() == pytest.approx(w.min(), abs=0.5)


def test_family_filter_and_unknown_names():
    assert {p.meta["family"] for p in L.parts(["gear", "nut"])} == {"gear", "nut"}
    with pytest.raises(BadInput, match="unknown part families: spring"):
        L.parts(["spring"])
    with pytest.raises(BadInput, match="no part"):
        L.part("flux_capacitor")
