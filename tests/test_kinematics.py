import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cell.cellconfig import default_cell
from cell.kinematics import Joints, forward, inverse, limit_violations, normalize_axis_deg

SCARA = default_cell().scara


@settings(max_examples=200, deadline=None)
@given(x=st.floats(200, 500), y=st.floats(-250, 250), z=st.floats(0, 200), axis=st.floats(-180, 180))
def test_ik_then_fk_round_trip_over_the_tray(x, y, z, axis):
    sols = inverse(x, y, z, axis, SCARA)
    assert sols, "every tray point is reachable by the default cell"
    for q in sols:
        p = forward(q, SCARA)
        assert math.hypot(p.x_mm - x, p.y_mm - y) < 1e-6
        assert p.z_mm == z
        assert abs(normalize_axis_deg(p.axis_deg - axis)) < 1e-6
        assert not limit_violations(q, SCARA)


def test_both_elbows_and_j4_turns_are_offered():
    sols = inverse(350, 50, 10, 0, SCARA)
    assert {q.elbow for q in sols} == {"left", "right"}
    for elbow in ("left", "right"):
        j4s = sorted(q.j4_deg for q in sols if q.elbow == elbow)
        assert all(abs((b - a) - 180.0) < 1e-9 for a, b in zip(j4s, j4s[1:]))
        assert len(j4s) >= 3  # J4 range of 720 deg holds at least three 180-deg turns


def test_unreachable_points_have_no_solution():
    assert inverse(700, 0, 10, 0, SCARA) == []
    assert inverse(10, 0, 10, 0, SCARA) == []  # inside the inner radius |L1 - L2| = 50


def test_joint_limits_remove_solutions():
    # Beside and behind the base one elbow needs J1 past 132 deg (145.8 here), the other does not (62.3)
    sols = inverse(-100, 400, 10, 0, SCARA)
    unlimited = inverse(-100, 400, 10, 0, SCARA, within_limits=False)
    assert 0 < len(sols) < len(unlimited)
    assert all(abs(q.j1_deg) <= 132 for q in sols)
    assert any(abs(q.j1_deg) > 132 for q in unlimited)
    assert inverse(-400, 10, 10, 0, SCARA) == []  # straight behind: J1 would need 135-138 deg either way


def test_limit_violations_name_the_joint():
    bad = Joints(140.0, 0.0, 250.0, 0.0)
    msgs = limit_violations(bad, SCARA)
    assert any(m.startswith("J1") for m in msgs) and any(m.startswith("J3") for m in msgs)
    assert limit_violations(Joints(0, 0, 0, float("nan")), SCARA)


@pytest.mark.parametrize("a,expected", [(90, 90), (-90, 90), (180, 0), (270, 90), (-135, 45), (0, 0)])
def test_axis_folds_into_half_open_interval(a, expected):
    assert normalize_axis_deg(a) == pytest.approx(expected)


def test_forward_of_straight_arm():
    p = forward(Joints(0, 0, 5, 0), SCARA)
    assert np.allclose([p.x_mm, p.y_mm], [600, 0])


@settings(max_examples=300, deadline=None)
@given(x=st.floats(-650, 650), y=st.floats(-650, 650), z=st.floats(-10, 210), axis=st.floats(-400, 400))
def test_the_vectorised_reachability_agrees_with_the_solutions(x, y, z, axis):
    from cell.kinematics import reachable_mask

    assert bool(reachable_mask([x], [y], z, [axis], SCARA)[0]) == bool(inverse(x, y, z, axis, SCARA))


@settings(max_examples=300, deadline=None)
@given(x=st.floats(200, 500), y=st.floats(-250, 250), past_deg=st.sampled_from([0.0, 1e-10, 1e-8, 1e-6, -1e-8]),
       limit=st.sampled_from([0, 1]), elbow=st.sampled_from([1.0, -1.0]))
def test_the_reachability_agrees_with_the_solutions_at_a_narrow_j4_limit(x, y, past_deg, limit, elbow):
    # J4 within (-20, 20): one turn of the axis at most, and the axis asked for puts J4 just at, inside or
    # past a limit (the turns' own slack, 1e-9 of a half turn, let 1e-8 deg past through)
    from dataclasses import replace

    from cell.kinematics import reachable_mask

    scara = replace(SCARA, j4_deg=(-20.0, 20.0))
    j = next((q for q in inverse(x, y, 50.0, 0.0, SCARA, within_limits=False) if q.j2_deg * elbow >= 0), None)
    if j is None:
        return
    axis = j.j1_deg + j.j2_deg + (scara.j4_deg[limit] + (1 if limit else -1) * past_deg)
    assert bool(reachable_mask([x], [y], 50.0, [axis], scara)[0]) == bool(inverse(x, y, 50.0, axis, scara))


def test_the_reachability_of_many_points_agrees_with_the_solutions():
    # more points than go through both elbows in one pass: the elbow-by-elbow path, point by point
    from cell.kinematics import ELBOWS_STACKED_MAX, reachable_mask

    rng = np.random.default_rng(3)
    n = ELBOWS_STACKED_MAX + 500
    x, y, axis = rng.uniform(-650, 650, n), rng.uniform(-650, 650, n), rng.uniform(-400, 400, n)
    many = reachable_mask(x, y, 50.0, axis, SCARA)
    assert 0 < many.sum() < n
    assert [bool(v) for v in many] == [bool(inverse(a, b, 50.0, c, SCARA)) for a, b, c in zip(x, y, axis, strict=True)]
