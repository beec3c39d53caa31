import numpy as np
import pytest
from shapely.geometry import Point

from cell.physics import MU, check_grasp, close_jaws, lift_clear, part_mass_g
from cell.scene import Part


def rect(pid, x0, y0, x1, y1, z_top=10.0, z_bottom=0.0, **meta):
    xy = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
    return Part(pid, xy, (), z_bottom, z_top, meta=meta)


def circle(pid, cx, cy, r, z_top=10.0):
    ring = np.asarray(Point(cx, cy).buffer(r, quad_segs=16).exterior.coords)[:-1]
    return Part(pid, ring, (), 0.0, z_top)


SQUARE = rect("sq", 300, -20, 340, 20)


def test_centred_grasp_on_a_square_holds_and_reports_the_jaw_width(cell_cfg):
    v = check_grasp(SQUARE, [[300, 0], [340, 0]], cell=cell_cfg)
    assert v.ok, v.reasons
    assert v.jaw_width_mm == pytest.approx(40.0)
    assert np.allclose(v.contacts_mm, [[300, 0], [340, 0]], atol=1e-6)
    assert v.approach_opening_mm == pytest.approx(50.0)
    assert v.patch_width_mm == pytest.approx((12.0, 12.0))
    assert v.to_json()["ok"] is True


def test_jaw_width_of_a_disc_is_its_diameter():
    v = check_grasp(circle("disc", 400, 0, 15), [[385, 0], [415, 0]])
    assert v.ok and v.jaw_width_mm == pytest.approx(30.0, abs=0.05)


def test_both_pads_on_sharp_corners_is_refused():
    diamond = SQUARE.moved(0, 0, 45)
    c = np.asarray(diamond.polygon.centroid.coords[0])
    h = 20 * np.sqrt(2)
    v = check_grasp(diamond, [c - (h, 0), c + (h, 0)])
    assert not v.ok and v.sharp == (True, True)
    assert any("sharp corners" in r for r in v.reasons)


def test_pads_stopping_elsewhere_than_reported_are_caught():
    # a U from above: the line through its mouth reports contacts on the inner walls, but the pads
    # (12 mm band) can not get there from outside
    xy = np.array([[0, 0], [50, 0], [50, 40], [40, 40], [40, 10], [10, 10], [10, 40], [0, 40]], float)
    u = Part("u", xy, z_top_mm=20)
    v = check_grasp(u, [[10, 30], [40, 30]], axis_deg=0)
    assert not v.ok
    assert any("stop" in r or "lands on the part" in r for r in v.reasons)
    ok = check_grasp(u, [[0, 5], [50, 5]], axis_deg=0)
    assert ok.ok, ok.reasons


def test_friction_cone_on_a_slope():
    # the left side leans: the left pad's edge touches a slope at the band border
    steep = Part("steep", np.array([[-20, -20], [20, -20], [20, 20], [0, 20]], float), z_top_mm=10)
    mild = Part("mild", np.array([[-20, -20], [20, -20], [20, 20], [-14, 20]], float), z_top_mm=10)
    y = 0.0
    x_steep = -20 + 20 * (y + 20) / 40
    x_mild = -20 + 6 * (y + 20) / 40
    vs = check_grasp(steep, [[x_steep, y], [20, y]], axis_deg=0)
    vm = check_grasp(mild, [[x_mild, y], [20, y]], axis_deg=0)
    friction_deg = np.degrees(np.arctan(MU))
    assert vs.slope_angle_deg[0] > friction_deg and not vs.ok
    assert any("friction cone" in r for r in vs.reasons)
    assert vm.slope_angle_deg[0] < friction_deg
    assert not any("friction cone" in r for r in vm.reasons)


def test_centre_of_gravity_far_from_the_jaw_line_depends_on_the_weight():
    # a 120 x 20 bar held across, 50 mm from its centre: heavy steel rolls out, a light strip holds
    heavy = rect("bar", 0, -10, 120, 10, z_top=20, mass_g=800.0)
    light = rect("strip", 0, -10, 120, 10, z_top=20, mass_g=20.0)
    grasp = [[10, -10], [10, 10]]
    vh, vl = check_grasp(heavy, grasp), check_grasp(light, grasp)
    assert vh.cog_offset_mm == pytest.approx(50.0) and vh.cog_along_mm == pytest.approx(0.0, abs=1e-6)
    assert not vh.ok and any("tilt" in r or "roll" in r for r in vh.reasons)
    assert vl.ok, vl.reasons
    centred = check_grasp(heavy, [[60, -10], [60, 10]])
    assert centred.ok and centred.torque_ratio < vh.torque_ratio


def test_mass_defaults_to_aluminium():
    p = rect("a", 0, 0, 10, 10, z_top=10)
    assert part_mass_g(p) == pytest.approx(1000 * 2.7 / 1000)


def test_opening_beyond_the_stroke_is_refused():
    wide = rect("wide", 0, 0, 75, 30)
    v = check_grasp(wide, [[0, 15], [75, 15]])
    assert not v.ok and any("stroke" in r for r in v.reasons)


def test_finger_collisions_depend_on_the_obstacle_height(cell_cfg):
    # grasp z of a 10 mm part is 1 mm; the finger sweeps from 35 mm left of the centre to the contact
    tall = rect("tall", 283, -5, 292, 5, z_top=30)
    low = rect("low", 283, -5, 292, 5, z_top=0.5)
    clear = rect("clear", 270, -5, 284, 5, z_top=30)  # beyond the finger's outer face (x 285)
    assert check_grasp(SQUARE, [[300, 0], [340, 0]], obstacles=[tall]).collisions == ("tall",)
    assert check_grasp(SQUARE, [[300, 0], [340, 0]], obstacles=[low]).ok
    assert check_grasp(SQUARE, [[300, 0], [340, 0]], obstacles=[clear]).ok
    # the palm (90 x 40, bottom at grasp z + 40 = 41) only meets obstacles taller than that
    beside = rect("beside", 358, -5, 364, 5, z_top=35)  # beyond the right finger (x 355), under the palm
    tower = rect("tower", 358, -5, 364, 5, z_top=60)
    assert check_grasp(SQUARE, [[300, 0], [340, 0]], obstacles=[beside]).ok
    v = check_grasp(SQUARE, [[300, 0], [340, 0]], obstacles=[tower])
    assert v.collisions == ("tower",) and "palm" in v.reasons[0]


def test_finger_landing_on_the_part_itself():
    # an L: closing along x at y = 12 reports the stem, but the second finger's footprint (its pad
    # band y 6..18) covers the foot (x 10..60, y 0..10); at y = 20 the band clears the foot
    ell = Part("ell", np.array([[0, 0], [60, 0], [60, 10], [10, 10], [10, 50], [0, 50]], float), z_top_mm=20)
    v = check_grasp(ell, [[0, 12], [10, 12]], axis_deg=0)
    assert not v.ok and "the second finger lands on the part at the approach opening" in v.reasons
    assert not any("first finger" in r for r in v.reasons)
    assert check_grasp(ell, [[0, 20], [10, 20]], axis_deg=0).ok


def test_lift_clear():
    base = rect("base", 250, -60, 450, 60, z_top=6)
    cover = rect("cover", 300, -20, 340, 20, z_top=9, z_bottom=6)
    lid = rect("lid", 310, -30, 330, 30, z_top=12, z_bottom=9)
    beside = rect("beside", 345, -20, 360, 20, z_top=30)
    assert lift_clear(cover, [base]).ok  # what lies below does not block
    blocked = lift_clear(cover, [base, lid])
    assert not blocked.ok and blocked.blocking == ("lid",)
    assert lift_clear(cover, [base, beside]).ok
    # the gripper holding it across x: its right finger (x 340..350) meets the tall neighbour
    g = lift_clear(cover, [base, beside], contacts_mm=[[300, 0], [340, 0]])
    assert not g.ok and "finger" in g.reasons[0]


def test_close_jaws_reports_what_the_gripper_would_measure():
    assert close_jaws(SQUARE, (320, 0), 0.0, 60.0) == pytest.approx(40.0)
    assert close_jaws(SQUARE, (320, 0), 90.0, 60.0) == pytest.approx(40.0)
    assert close_jaws(SQUARE, (320, 30), 0.0, 60.0) is None  # band beside the part: closes on air
    assert close_jaws(SQUARE, (320, 0), 0.0, 60.0, grasp_z_mm=15.0) is None  # pads above the part
    assert close_jaws(SQUARE.moved(0, 0, 45), (320, 0), 0.0, 70.0) == pytest.approx(40 * np.sqrt(2), abs=1e-6)


@pytest.mark.parametrize("name", ["spur_gear_m", "pcb_m", "hex_nut_m16", "l_bracket_s", "heatsink_s"])
def test_verdict_is_independent_of_the_pose(name):
    """Moving part and contacts together changes nothing (seeded rigid motions)."""
    from cell import parts_library as L
    from cell.operator import Operator

    base = L.part(name)
    g = Operator(rng=np.random.default_rng(1)).choose_grasp(L.place(base, 0, 0, 0))
    ref = check_grasp(L.place(base, 0, 0, 0), g.contacts_mm, g.axis_deg, g.grasp_z_mm)
    bad = [[g.contacts_mm[0][0] + 3, g.contacts_mm[0][1]], g.contacts_mm[1]]  # skewed: may fail
    ref_bad = check_grasp(L.place(base, 0, 0, 0), bad)
    rng = np.random.default_rng(5)
    for _ in range(4):
        x, y, th = rng.uniform(200, 500), rng.uniform(-200, 200), rng.uniform(-180, 180)
        t = np.radians(th)
        R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
        part = L.place(base, x, y, th)
        for contacts, axis, want in ((g.contacts_mm, g.axis_deg + th, ref), (bad, None, ref_bad)):
            moved = np.asarray(contacts) @ R.T + (x, y)
            v = check_grasp(part, moved, axis, g.grasp_z_mm)
            assert v.ok == want.ok and v.jaw_width_mm == pytest.approx(want.jaw_width_mm, abs=1e-6)
            assert v.torque_ratio == pytest.approx(want.torque_ratio, rel=1e-6, abs=1e-9)
            assert v.sharp == want.sharp
