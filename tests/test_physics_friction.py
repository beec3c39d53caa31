"""The pads' one friction budget (`cell/physics.py`, centre of gravity near the jaw line).

Slip, tilt across the jaws and roll about the jaw line draw on the same friction at each pad:
the vertical forces of slip and tilt add up at the pad nearer the centre of gravity, and what a
pad's vertical force uses is lost to its torsion (soft-finger limit curve m <= mu N rho (1 -
(f / mu N)^2)). Until the fix each was tested alone with the whole budget, so every grasp below
that is refused now passed. Default cell: grip force 40 N, mu 0.3, safety factor 2; a 20 mm
tall part is gripped at z 2 (the pads overlap it by 18 mm), a 2.5 mm plate at z 0.5 (by 2 mm).
"""

import math

import numpy as np
import pytest
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

from cell.physics import check_grasp
from cell.scene import Part

MU_N = 0.3 * 40.0  # one pad's friction budget, N
SAFETY = 2.0


def from_shape(pid, geom, z_top, mass_g):
    return Part(pid, np.asarray(geom.exterior.coords)[:-1], (), 0.0, z_top, meta={"mass_g": mass_g})


def h_plate(mass_g):
    """A 20 mm web (x 0..20) with two 60 x 30 flanges beyond the second pad: centre of gravity on
    the jaw line, 18 mm along the axis from the pads' midpoint (x 10), 8 mm beyond the second pad."""
    return from_shape("h", unary_union([box(0, -10, 20, 10), box(0, 10, 60, 40), box(0, -40, 60, -10)]),
                      10.0, mass_g)


def bar(mass_g):
    """120 x 20 x 20 mm; held across at x 50, its centre of gravity (x 60) is 10 mm off the jaw line."""
    return from_shape("bar", box(0, -10, 120, 10), 20.0, mass_g)


def tipped_plate(mass_g):
    """2.5 mm thick: a 30 x 60 plate (y -20..40) with a 120 deg tip at (64.6, 0), held between its
    flat left side (a 12 mm patch) and the tip (0.58 mm, counted as 1 mm): unequal torsion radii,
    centre of gravity off the jaw line and nearer the first pad."""
    b = 20 / math.tan(math.radians(30))
    tip = Polygon([(30, -20), (30 + b, 0), (30, 20)])
    return from_shape("tipped", unary_union([box(0, -20, 30, 40), tip]), 2.5, mass_g)


TIP_X = 30 + 20 / math.tan(math.radians(30))


def held_ratio(mass_g, d_perp_mm, shares, rho_mm):
    """SAFETY x weight over the largest weight the pads hold, found by bisection on the pads'
    conditions themselves: each pad's vertical force within mu N, and the torsion W d_perp within
    the sum of what each pad has left, mu N rho (1 - (f / mu N)^2)."""
    weight_n = mass_g / 1000 * 9.81

    def holds(w_n):
        f = [abs(s) * w_n / MU_N for s in shares]
        left = sum(r * (1 - x * x) for r, x in zip(rho_mm, f))
        return max(f) <= 1 and w_n * d_perp_mm <= MU_N * left

    lo, hi = 0.0, 1e4
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return SAFETY * weight_n / lo


RHO_BAR = math.hypot(12, 18) / 4
RHO_FLAT_2MM, RHO_TIP_2MM = math.hypot(12, 2) / 4, math.hypot(1, 2) / 4


@pytest.mark.parametrize("contacts", [[[0, 0], [20, 0]], [[20, 0], [0, 0]]])
@pytest.mark.parametrize("mass_g, ok", [(430.0, True), (445.0, False)])
def test_slip_and_tilt_add_up_at_the_pad_nearer_the_centre_of_gravity(contacts, mass_g, ok):
    # the second pad carries W (1/2 + 18/20) = 1.4 W: at most 12 / 1.4 / 2 = 4.29 N, 437 g (before:
    # slip 2 W / 24 and tilt 2 W 18 / 240 alone, both under 1 up to 680 g)
    v = check_grasp(h_plate(mass_g), contacts)
    ratio = SAFETY * mass_g / 1000 * 9.81 * 1.4 / MU_N
    assert v.cog_along_mm == pytest.approx(18.0)
    assert v.torque_ratio == pytest.approx(ratio) and v.extra["ratios"]["slip"] == pytest.approx(ratio)
    assert v.ok is ok, v.reasons
    if not ok:
        assert v.reasons == (f"the part would slip out of the jaws (demand/capacity {ratio:.2f}; centre of gravity "
                             "0.0 mm from the jaw line, 18.0 mm along it from the pads' midpoint)",)


@pytest.mark.parametrize("mass_g, ok", [(520.0, True), (580.0, False)])
def test_roll_gets_only_the_torsion_the_vertical_force_leaves(mass_g, ok):
    # each pad carries W / 2 and half of W x 10 mm: before, slip (0.43 at 520 g, 0.47 at 580 g) and
    # roll (0.80, 0.89) each passed alone
    v = check_grasp(bar(mass_g), [[50, -10], [50, 10]])
    ratio = held_ratio(mass_g, 10.0, (0.5, 0.5), (RHO_BAR, RHO_BAR))
    assert 0.95 < ratio < 1.1
    assert v.cog_offset_mm == pytest.approx(10.0) and v.cog_along_mm == pytest.approx(0.0, abs=1e-9)
    assert v.torque_ratio == pytest.approx(ratio, rel=1e-6)
    assert v.extra["ratios"]["roll about the jaw line"] == pytest.approx(ratio, rel=1e-6)
    assert v.ok is ok, v.reasons
    if not ok:
        assert v.reasons == (f"the part would roll about the jaw line out of the jaws (demand/capacity {ratio:.2f}; "
                             "centre of gravity 10.0 mm from the jaw line, 0.0 mm along it from the pads' midpoint)",)


@pytest.mark.parametrize("mass_g, ok", [(275.0, True), (286.0, False)])
def test_each_pad_loses_torsion_to_its_own_vertical_force(mass_g, ok):
    # the flat pad (first, the nearer to the centre of gravity) carries the larger share and has the
    # larger torsion radius; pairing the shares the other way round gives another figure (before: roll
    # 2 W 7.2 mm / (mu N (rho_flat + rho_tip)) alone, 0.94 at 286 g)
    v = check_grasp(tipped_plate(mass_g), [[0, 0], [TIP_X, 0]])
    e_mm = -v.cog_along_mm  # towards the first pad
    shares = (0.5 - e_mm / TIP_X, 0.5 + e_mm / TIP_X)
    assert shares[0] > 0.6 and v.extra["pad_shares"] == pytest.approx(shares)
    ratio = held_ratio(mass_g, v.cog_offset_mm, shares, (RHO_FLAT_2MM, RHO_TIP_2MM))
    swapped = held_ratio(mass_g, v.cog_offset_mm, shares[::-1], (RHO_FLAT_2MM, RHO_TIP_2MM))
    assert abs(swapped - ratio) > 0.01 and 0.95 < ratio < 1.05
    assert v.torque_ratio == pytest.approx(ratio, rel=1e-6)
    assert v.ok is ok, v.reasons


def test_a_light_part_centred_keeps_the_old_slip_figure():
    # nothing to share: centre of gravity on the jaw line, midway between the pads
    v = check_grasp(from_shape("sq", box(300, -20, 340, 20), 10.0, 1200.0), [[300, 0], [340, 0]])
    assert v.torque_ratio == pytest.approx(SAFETY * 1.2 * 9.81 / (2 * MU_N)) and v.ok
