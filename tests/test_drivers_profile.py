"""Trapezoidal profiles: the same functions move the simulated drives and time the cycle."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from cell.cellconfig import default_cell
from cell.kinematics import Joints, forward, tool_xy
from drivers.profile import coordinated_path, coordinated_path_array, from_speed, trapezoid, velocity_for_duration

pos = st.floats(0.5, 5000)


def test_long_move_cruises_at_v_max():
    p = trapezoid(100.0, 50.0, 100.0)
    assert p.v_peak == 50.0 and p.t_accel_s == pytest.approx(0.5) and p.t_decel_s == pytest.approx(0.5)
    assert p.duration_s == pytest.approx(0.5 + 1.5 + 0.5)  # 25 mm in each ramp, 50 mm at 50 mm/s
    assert p.position_at(p.duration_s) == pytest.approx(100.0)


def test_short_move_is_a_triangle():
    p = trapezoid(1.0, 50.0, 100.0)
    assert p.t_cruise_s == 0.0 and p.v_peak == pytest.approx(10.0)
    assert p.duration_s == pytest.approx(0.2)


@given(d=st.floats(-1000, 1000, allow_nan=False), v=pos, a=pos, dec=pos)
def test_profile_ends_at_the_distance_and_respects_limits(d, v, a, dec):
    p = trapezoid(d, v, a, dec)
    assert p.position_at(p.duration_s) == pytest.approx(d, abs=1e-6 * max(1, abs(d)))
    assert p.position_at(0.0) == 0.0
    assert p.v_peak <= v + 1e-9
    ts = [p.duration_s * i / 50 for i in range(51)]
    xs = [abs(p.position_at(t)) for t in ts]
    assert all(b >= a_ - 1e-9 for a_, b in zip(xs, xs[1:], strict=False))  # monotone: no overshoot
    assert all(abs(p.velocity_at(t)) <= v + 1e-9 for t in ts)


@given(d=st.floats(-1000, 1000, allow_nan=False), v=pos, a=pos, dec=pos)
def test_positions_at_an_array_of_times_are_position_at_bit_for_bit(d, v, a, dec):
    # the way checks take the array form; the drives and the step-by-step checks the scalar one
    p = trapezoid(d, v, a, dec)
    ts = np.array([-1.0, 0.0, p.t_accel_s, p.t_accel_s + p.t_cruise_s, p.duration_s, p.duration_s + 1.0,
                   *np.linspace(0.0, p.duration_s, 37)])
    assert p.positions_at(ts).tolist() == [p.position_at(t) for t in ts.tolist()]


def test_the_way_checked_is_the_path_the_arm_reports_sample_by_sample():
    cell = default_cell()
    a, b = Joints(10.0, 60.0, 150.0, 0.0), Joints(-40.0, 100.0, 120.0, 30.0)
    rows = coordinated_path_array(cell.scara, a, b, 0.5)
    path = coordinated_path(cell.scara, a, b, 0.5)
    assert len(path) == len(rows) == 200 and path[-1] == b  # 2 x 50 deg / 0.5 deg
    assert [list(j.as_array()) for j in path] == rows.tolist()
    x, y = tool_xy(rows, cell.scara)
    tools = [forward(j, cell.scara) for j in path]
    assert np.allclose(x, [t.x_mm for t in tools], rtol=0, atol=1e-9)
    assert np.allclose(y, [t.y_mm for t in tools], rtol=0, atol=1e-9)


@given(d=st.floats(0.1, 1000), v=pos, a=pos, stretch=st.floats(1.0, 5.0))
def test_velocity_for_duration_stretches_a_move_to_the_given_time(d, v, a, stretch):
    t = trapezoid(d, v, a).duration_s * stretch
    v2 = velocity_for_duration(d, t, a)
    assert v2 <= v * (1 + 1e-9)
    assert trapezoid(d, v2, a).duration_s == pytest.approx(t, rel=1e-6)


def test_velocity_for_an_impossible_duration_is_refused():
    with pytest.raises(ValueError, match="cannot last"):
        velocity_for_duration(100.0, 0.1, 10.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_bad_limits_are_refused(bad):
    with pytest.raises(ValueError, match="positive"):
        trapezoid(10.0, bad, 1.0)


def test_sim_clock_runs_jobs_in_time_order_and_only_when_slept():
    from drivers.clock import SimClock

    clock, seen = SimClock(), []
    clock.every(0.1, lambda: seen.append(("a", round(clock.now(), 6))))
    job = clock.every(0.25, lambda: seen.append(("b", round(clock.now(), 6))))
    assert seen == [] and clock.now() == 0.0
    clock.sleep(0.5)
    assert seen == [
        ("a", 0.1),
        ("a", 0.2),
        ("b", 0.25),
        ("a", 0.3),
        ("a", 0.4),
        ("b", 0.5),
        ("a", 0.5),
    ]  # ties: first scheduled first
    job.cancel()
    clock.sleep(0.25)
    assert seen[-1] == ("a", 0.7) and clock.now() == pytest.approx(0.75)


def test_real_clock_can_be_reused_after_close():
    import threading

    from drivers.clock import RealClock

    clock, ticks = RealClock(), threading.Event()
    clock.every(0.01, ticks.set)
    assert ticks.wait(1.0)
    clock.close()
    ticks.clear()
    clock.every(0.01, ticks.set)
    assert ticks.wait(1.0)
    clock.close()


@given(distance=st.floats(-5000, 5000), v0=st.floats(-300, 300), v_max=pos, accel=pos, decel=pos)
@example(distance=5e-324, v0=5e-324, v_max=1.0, accel=0.5, decel=0.5)  # every ramp's time 0: it said 0, not v0
def test_a_profile_from_speed_starts_at_it_and_ends_at_rest_on_the_target_within_the_ramps(distance, v0, v_max,
                                                                                            accel, decel):
    """`from_speed` (change immediately): from `v0`, never faster than it or `v_max`, every phase on a ramp,
    at rest `distance` away at the end."""
    p = from_speed(distance, v0, v_max, accel, decel)
    assert p.velocity_at(0.0) == v0
    assert p.distance == pytest.approx(distance, abs=1e-6 * max(1.0, abs(distance)))
    assert p._state_at(p.duration_s)[1] == pytest.approx(0.0, abs=1e-6 * max(1.0, abs(v0), v_max))
    assert all(a in (0.0, accel, -accel, decel, -decel) for _, a in p.phases)
    top = max(abs(v0), v_max) * (1 + 1e-9) + 1e-9
    assert all(abs(p.velocity_at(t)) <= top for t in np.linspace(0.0, p.duration_s, 40))
