"""Trapezoidal (or triangular) point-to-point motion profiles: pure functions, any unit.

The simulated drives move along these profiles and `Arm.move_time_s` reports them, so the
cycle time the cell computes is the time the drives take.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Trapezoid:
    """A rest-to-rest move of `distance` (signed) with the phases' durations in seconds."""

    distance: float
    v_peak: float  # reached speed (>= 0)
    accel: float
    decel: float
    t_accel_s: float
    t_cruise_s: float
    t_decel_s: float

    @property
    def duration_s(self) -> float:
        return self.t_accel_s + self.t_cruise_s + self.t_decel_s

    def position_at(self, t_s: float) -> float:
        """Distance travelled (signed) after `t_s` seconds; clamped to [0, duration]."""
        sign = 1.0 if self.distance >= 0 else -1.0
        t = min(max(t_s, 0.0), self.duration_s)
        ta, tc = self.t_accel_s, self.t_cruise_s
        if t <= ta:
            s = 0.5 * self.accel * t * t
        elif t <= ta + tc:
            s = 0.5 * self.accel * ta * ta + self.v_peak * (t - ta)
        else:
            td = t - ta - tc
            s = 0.5 * self.accel * ta * ta + self.v_peak * tc + self.v_peak * td - 0.5 * self.decel * td * td
        s = min(s, abs(self.distance))
        return sign * s

    def positions_at(self, t_s: np.ndarray) -> np.ndarray:
        """`position_at` for an array of times, element by element the same arithmetic (the same floats)."""
        sign = 1.0 if self.distance >= 0 else -1.0
        t = np.minimum(np.maximum(t_s, 0.0), self.duration_s)
        ta, tc = self.t_accel_s, self.t_cruise_s
        td = t - ta - tc
        s = np.where(t <= ta, 0.5 * self.accel * t * t,
                     np.where(t <= ta + tc, 0.5 * self.accel * ta * ta + self.v_peak * (t - ta),
                              0.5 * self.accel * ta * ta + self.v_peak * tc + self.v_peak * td
                              - 0.5 * self.decel * td * td))
        return sign * np.minimum(s, abs(self.distance))

    def velocities_at(self, t_s: np.ndarray) -> np.ndarray:
        """`velocity_at` for an array of times."""
        sign = 1.0 if self.distance >= 0 else -1.0
        t = np.minimum(np.maximum(t_s, 0.0), self.duration_s)
        ta, tc = self.t_accel_s, self.t_cruise_s
        v = np.where(t <= ta, self.accel * t,
                     np.where(t <= ta + tc, self.v_peak, np.maximum(0.0, self.v_peak - self.decel * (t - ta - tc))))
        return sign * v

    def velocity_at(self, t_s: float) -> float:
        sign = 1.0 if self.distance >= 0 else -1.0
        t = min(max(t_s, 0.0), self.duration_s)
        ta, tc = self.t_accel_s, self.t_cruise_s
        if t <= ta:
            v = self.accel * t
        elif t <= ta + tc:
            v = self.v_peak
        else:
            v = max(0.0, self.v_peak - self.decel * (t - ta - tc))
        return sign * v


def trapezoid(distance: float, v_max: float, accel: float, decel: float | None = None) -> Trapezoid:
    """The time-optimal rest-to-rest profile for `distance` under the speed and acceleration
    limits; triangular when the move is too short to reach `v_max`."""
    decel = accel if decel is None else decel
    for name, v in (("v_max", v_max), ("accel", accel), ("decel", decel)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be positive and finite, got {v}")
    if not math.isfinite(distance):
        raise ValueError(f"distance must be finite, got {distance}")
    d = abs(distance)
    if d == 0.0:
        return Trapezoid(distance, 0.0, accel, decel, 0.0, 0.0, 0.0)
    # distance needed to reach v_max and stop again
    d_ramps = v_max * v_max / (2 * accel) + v_max * v_max / (2 * decel)
    if d >= d_ramps:
        ta, td = v_max / accel, v_max / decel
        return Trapezoid(distance, v_max, accel, decel, ta, (d - d_ramps) / v_max, td)
    v_peak = math.sqrt(2 * d * accel * decel / (accel + decel))
    return Trapezoid(distance, v_peak, accel, decel, v_peak / accel, 0.0, v_peak / decel)


@dataclass(frozen=True)
class Phases:
    """A move from velocity `v0` (signed) by phases of constant acceleration: (duration s, acceleration
    signed), ending at rest `distance` (signed) from where it started. The same interface as `Trapezoid`
    for the simulated drives (`position_at`, `velocity_at`, `duration_s`, `decel`)."""

    v0: float
    phases: tuple[tuple[float, float], ...]
    decel: float  # the deceleration of its last ramp

    @property
    def duration_s(self) -> float:
        return sum(t for t, _ in self.phases)

    @property
    def distance(self) -> float:
        return self.position_at(self.duration_s)

    def _state_at(self, t_s: float) -> tuple[float, float]:
        """(position, velocity) after `t_s` seconds, clamped to [0, duration]."""
        t, s, v = max(t_s, 0.0), 0.0, self.v0
        for dt, a in self.phases:
            step = min(t, dt)
            s += v * step + 0.5 * a * step * step
            v += a * step
            t -= step
            if t <= 0.0:
                break
        return s, v

    def position_at(self, t_s: float) -> float:
        return self._state_at(t_s)[0]

    def velocity_at(self, t_s: float) -> float:
        if t_s >= self.duration_s > 0.0:
            return 0.0
        # (no phase at all: a speed so small that every ramp's time is 0 in floats, 5e-324 mm/s; it is what it is)
        return self._state_at(t_s)[1]


def from_speed(distance: float, v0: float, v_max: float, accel: float, decel: float | None = None) -> Phases:
    """The profile of a set-point taken at once (CiA 402 "change immediately") while the axis runs at `v0`
    (signed): from that speed, on the ramps (`accel` to speed up, `decel` to slow down), to rest `distance`
    (signed) away: one speed-up or slow-down to the cruise speed, cruise, one ramp down, where the target
    lies ahead far enough to stop; else first to rest on the deceleration ramp, then a rest-to-rest move
    back to it (an overshoot, or an axis running away from the new target)."""
    decel = accel if decel is None else decel
    for name, v in (("v_max", v_max), ("accel", accel), ("decel", decel)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be positive and finite, got {v}")
    if not (math.isfinite(distance) and math.isfinite(v0)):
        raise ValueError(f"distance and v0 must be finite, got {distance}, {v0}")
    sign = 1.0 if distance > 0 or (distance == 0 and v0 < 0) else -1.0
    u0, d = v0 * sign, abs(distance)  # towards the target: positive
    stop = u0 * u0 / (2 * decel)
    if u0 < 0 or stop > d:  # to rest first, then back (or on) to the target from there
        t_stop = abs(u0) / decel
        travelled = u0 * t_stop - 0.5 * decel * t_stop * t_stop * (1 if u0 >= 0 else -1)
        rest = trapezoid(sign * (d - travelled), v_max, accel, decel)
        back = 1.0 if rest.distance >= 0 else -1.0
        phases = [(t_stop, -sign * decel * (1 if u0 >= 0 else -1)), (rest.t_accel_s, back * accel),
                  (rest.t_cruise_s, 0.0), (rest.t_decel_s, -back * decel)]
    elif u0 <= v_max:
        v_peak = min(v_max, math.sqrt((2 * accel * decel * d + decel * u0 * u0) / (accel + decel)))
        ramps = (v_peak * v_peak - u0 * u0) / (2 * accel) + v_peak * v_peak / (2 * decel)
        phases = [((v_peak - u0) / accel, sign * accel), (max(0.0, d - ramps) / v_peak if v_peak else 0.0, 0.0),
                  (v_peak / decel, -sign * decel)]
    else:  # faster than the profile velocity now allows: down to it, cruise, down to rest
        phases = [((u0 - v_max) / decel, -sign * decel), ((d - stop) / v_max, 0.0), (v_max / decel, -sign * decel)]
    return Phases(v0, tuple((t, a) for t, a in phases if t > 0.0), decel)


def velocity_for_duration(distance: float, duration_s: float, accel: float, decel: float | None = None) -> float:
    """The cruise speed that makes a move of `distance` last `duration_s` with the given ramps
    (for coordinated moves: every axis arrives with the slowest). Requires `duration_s` at least
    the time-optimal duration at unbounded speed."""
    decel = accel if decel is None else decel
    d = abs(distance)
    if d == 0.0:
        return 0.0
    # d = v*T - v^2/2 * (1/a + 1/dec)  ->  k v^2 - T v + d = 0 with k = (1/a + 1/dec) / 2
    k = 0.5 * (1.0 / accel + 1.0 / decel)
    disc = duration_s * duration_s - 4 * k * d
    if -1e-9 * duration_s * duration_s < disc < 0:
        disc = 0.0  # exactly the time-optimal triangle, up to rounding
    if disc < 0:
        raise ValueError(f"a move of {d} cannot last only {duration_s} s with these ramps")
    return (duration_s - math.sqrt(disc)) / (2 * k)


def coordinated_move_s(scara, start, target) -> float:
    """Duration of a coordinated move of the four joints (`Joints`): every axis arrives with
    the slowest, each under its own speed and acceleration limits (`scara`: the cell file's)."""
    from drivers.limits import JOINT_FIELDS

    return max(trapezoid(getattr(target, f) - getattr(start, f), scara.max_velocity[j],
                         scara.max_acceleration[j]).duration_s for j, f, _ in JOINT_FIELDS)


def coordinated_path(scara, start, target, step_deg: float = 2.0) -> list:
    """`Joints` along the coordinated move from start to target (the end included), in time:
    each axis on the trapezoid with its own ramps and the cruise speed that makes it arrive with
    the slowest (as `Arm.move_joints` commands them). Samples close enough that J1 and J2 turn
    at most about step_deg between two (the progress of an axis is at most twice its mean)."""
    from cell.kinematics import Joints

    return [Joints(*row) for row in coordinated_path_array(scara, start, target, step_deg).tolist()]


def coordinated_path_array(scara, start, target, step_deg: float = 2.0) -> np.ndarray:
    """`coordinated_path` as an (n, 4) array of j1_deg, j2_deg, j3_mm, j4_deg (the last row the
    target itself): the way checks take every sample of a move, for every move a plan considers."""
    return coordinated_motion_array(scara, start, target, step_deg)[0]


@dataclass(frozen=True)
class CoordinatedMove:
    """A coordinated move as the drives run it: from `start` (4,) to `target` (4,) (j1_deg, j2_deg, j3_mm,
    j4_deg), each axis on its own trapezoid (None: it stays), all arriving after duration_s."""

    start: np.ndarray
    target: np.ndarray
    duration_s: float
    profiles: tuple

    def sample_times_s(self, step_deg: float) -> np.ndarray:
        """(n,): times along the move at which J1 and J2 turn at most about step_deg between two (the
        progress of an axis is at most twice its mean), the last one the end."""
        turn = float(np.abs(self.target[:2] - self.start[:2]).max())
        n = max(1, math.ceil(2.0 * turn / step_deg))
        return self.duration_s * np.arange(1, n + 1) / n  # as duration * k / n, sample by sample

    def axis_at(self, col: int, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Axis col's position and speed (signed, per s) at the times t_s (any shape); still after the end."""
        profile = self.profiles[col]
        speed = np.zeros(np.shape(t_s)) if profile is None else profile.velocities_at(t_s)
        return self.positions_at(col, t_s), speed

    def top_speed(self) -> np.ndarray:
        """(4,): each axis's peak speed on this move (0: it stays)."""
        return np.array([0.0 if p is None else p.v_peak for p in self.profiles])

    def positions_at(self, col: int, t_s: np.ndarray) -> np.ndarray:
        """Axis col's position at the times t_s (any shape), as `axis_at` has it."""
        profile = self.profiles[col]
        if profile is None:
            return np.full(np.shape(t_s), self.start[col])
        return self.start[col] + profile.positions_at(t_s)

    def motion_at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 4) positions and (n, 4) speeds at the times t_s (n,); exactly the target, standing, from the end on."""
        path, speed = np.empty((len(t_s), 4)), np.empty((len(t_s), 4))
        for col in range(4):
            path[:, col], speed[:, col] = self.axis_at(col, t_s)
        done = t_s >= self.duration_s
        path[done], speed[done] = self.target, 0.0
        return path, speed


def coordinated_move(scara, start, target) -> CoordinatedMove:
    """The coordinated move from start to target (`Joints`): each axis on the trapezoid with its own ramps
    and the cruise speed that makes it arrive with the slowest (as `Arm.move_joints` commands them)."""
    from drivers.limits import JOINT_FIELDS

    duration = coordinated_move_s(scara, start, target)
    profiles = []
    for j, f, _ in JOINT_FIELDS:
        d = getattr(target, f) - getattr(start, f)
        a = scara.max_acceleration[j]
        v = velocity_for_duration(d, duration, a) if duration > 0 else 0.0
        profiles.append(trapezoid(d, v, a) if d != 0.0 and v > 0 else None)
    return CoordinatedMove(np.array([getattr(start, f) for _, f, _ in JOINT_FIELDS], float),
                           np.array([getattr(target, f) for _, f, _ in JOINT_FIELDS], float), duration,
                           tuple(profiles))


def coordinated_motion_array(scara, start, target, step_deg: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """`coordinated_path_array` and, row for row, the axes' speeds there (n, 4) (per s, signed; 0 at the
    end)."""
    return coordinated_motion(scara, start, target, step_deg)[2:]


def coordinated_motion(scara, start, target, step_deg: float = 2.0):
    """The move (`coordinated_move`), its sample times (n,) and, at them, the positions (n, 4) and speeds
    (n, 4) of `coordinated_motion_array`."""
    move = coordinated_move(scara, start, target)
    t = move.sample_times_s(step_deg)
    path, speed = move.motion_at(t)
    path[-1], speed[-1] = move.target, 0.0  # (duration * n / n may round below the duration)
    return move, t, path, speed


def _stop_decel(scara, decel_factor: float) -> np.ndarray:
    """(2,): J1's and J2's quick stop deceleration, decel_factor x its max acceleration (the drives' 0x6085)."""
    return np.array([decel_factor * scara.max_acceleration[j] for j in ("j1", "j2")])


def quick_stop_deg(scara, speed: np.ndarray, decel_factor: float) -> np.ndarray:
    """(n, 2): how far J1 and J2 turn (deg) when they quick-stop from the speeds (n, >= 2) (deg/s), each at
    decel_factor x its max acceleration (the drives' 0x6085)."""
    return speed[:, :2] ** 2 / (2 * _stop_decel(scara, decel_factor))


def quick_stop_reach_mm(scara, speed: np.ndarray, decel_factor: float, lag_s: float = 0.0,
                        top_speed: np.ndarray | None = None) -> np.ndarray:
    """(n,): how far the tool can move at most while the arm quick-stops from the speeds (n, >= 2): J1 and J2
    turn by at most s1 and s2 (`quick_stop_deg`, radians here), the tool by at most (l1 + l2) s1 + l2 s2
    (an arc is no shorter than its chord). With lag_s, J1 or J2 may go on along its move for up to that long
    before it ramps down (`stops_one_first`; the other ramps at once): meanwhile it speeds up by at most its max
    acceleration, up to top_speed (2,) (its move's peak; default unbounded), so it turns by at most
    v lag_s + v^2 / (2 x its deceleration), v its speed plus that."""
    at_once = np.radians(quick_stop_deg(scara, speed, decel_factor))
    if not lag_s > 0:
        return (scara.l1_mm + scara.l2_mm) * at_once[:, 0] + scara.l2_mm * at_once[:, 1]
    accel = np.array([scara.max_acceleration[j] for j in ("j1", "j2")])
    v = np.abs(speed[:, :2]) + accel * lag_s
    if top_speed is not None:
        v = np.minimum(v, np.maximum(top_speed, np.abs(speed[:, :2])))
    late = np.radians(v * lag_s + v * v / (2 * _stop_decel(scara, decel_factor)))
    arm = scara.l1_mm + scara.l2_mm
    return np.maximum(arm * at_once[:, 0] + scara.l2_mm * late[:, 1], arm * late[:, 0] + scara.l2_mm * at_once[:, 1])


def quick_stop_poses_array(scara, pose: np.ndarray, speed: np.ndarray, step_deg: float,
                           decel_factor: float) -> np.ndarray:
    """(m, 2) j1_deg, j2_deg of the poses the arm passes through when it quick-stops at each of the poses
    (n, >= 2) moving at speed (n, >= 2): each axis ramps down at decel_factor x its max acceleration, on its
    own, so the arm leaves the coordinated path (the axes do not stop in proportion). Sampled so that J1
    and J2 turn at most about step_deg between two poses of one stop."""
    vel, decel = speed[:, :2], _stop_decel(scara, decel_factor)
    stop_s = np.abs(vel) / decel  # (n, 2): how long each axis takes to stand
    longest = stop_s.max(1)  # (n,)
    # an axis turns at most |v| x the stop's duration: that many steps of step_deg
    k = max(1, math.ceil(float((np.abs(vel) * longest[:, None]).max(initial=0.0)) / step_deg))
    tau = np.minimum(longest[:, None, None] * (np.arange(k + 1) / k)[None, :, None], stop_s[:, None, :])
    poses = pose[:, None, :2] + vel[:, None, :] * tau - 0.5 * np.sign(vel)[:, None, :] * decel * tau * tau
    return poses.reshape(-1, 2)


def stops_one_first(scara, move: CoordinatedMove, t_s: np.ndarray, lag_s: float, step_deg: float,
                    decel_factor: float) -> list[tuple[str, np.ndarray]]:
    """[("j1", poses), ("j2", poses)]: (m, 2) j1_deg, j2_deg of the poses the arm passes through when, at
    each of the times t_s (n,) of the move, that axis stops on its own (its fault reaction, its quick stop
    input: its ramp at once, decel_factor x its max acceleration) and the host stops the other lag_s later:
    the other goes on along the move meanwhile, then ramps down. Sampled so that J1 and J2 turn at most
    about step_deg between two poses of one stop."""
    decel = _stop_decel(scara, decel_factor)
    return [(first, _stops(move, t_s, ramp_from_s, decel, step_deg))
            for first, ramp_from_s in (("j1", (0.0, lag_s)), ("j2", (lag_s, 0.0)))]


def _stops(move: CoordinatedMove, t_s: np.ndarray, ramp_from_s: tuple, decel: np.ndarray, step_deg: float):
    """(n (k + 1), 2): J1 and J2 from each time t_s (n,) of the move: axis j goes on along it for
    ramp_from_s[j], then ramps down at decel[j] from where it is and the speed it has then."""
    vel, stop_s, top = [], [], 0.0
    for j in (0, 1):
        _, v = move.axis_at(j, t_s + ramp_from_s[j])  # (n,) the speed it ramps down from
        vel.append(v)
        stop_s.append(np.abs(v) / decel[j])
        on_way = ramp_from_s[j] > 0 and move.profiles[j] is not None
        top = max(top, float(np.abs(v).max(initial=0.0)), move.profiles[j].v_peak if on_way else 0.0)
    end = np.maximum(ramp_from_s[0] + stop_s[0], ramp_from_s[1] + stop_s[1])  # (n,) both stand
    # an axis turns at most its top speed x the stop's duration: that many steps of step_deg
    k = max(1, math.ceil(top * float(end.max(initial=0.0)) / step_deg))
    tau = end[:, None] * (np.arange(k + 1) / k)[None, :]  # (n, k + 1) from the first axis's stop
    cols = []
    for j in (0, 1):
        # on its way until its ramp starts (then where it ramps from), and the ramp after
        if ramp_from_s[j] > 0:
            way = move.positions_at(j, t_s[:, None] + np.minimum(tau, ramp_from_s[j]))
        else:
            way = move.positions_at(j, t_s)[:, None]
        e = np.minimum(np.maximum(tau - ramp_from_s[j], 0.0), stop_s[j][:, None])
        v = vel[j][:, None]
        cols.append(way + v * e - 0.5 * np.sign(v) * decel[j] * e * e)
    return np.stack(cols, axis=-1).reshape(-1, 2)
