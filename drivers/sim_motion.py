"""The simulated drive's motion: profile position mode with the set-point handshake, halt and
resume, the software position limits, trapezoidal moves on the shared clock, the ramps and the coast
that stop them, and a jammed axis' following error.
"""

from __future__ import annotations

from dataclasses import dataclass

from canopen.sdo import SdoAbortedError

from drivers import codec
from drivers.profile import Trapezoid, from_speed, trapezoid

# An axis whose drive function is disabled while it moves (option code 0, "disable drive function")
# is no longer driven: it runs out on friction alone, at this x its max acceleration (a figure of
# the simulated mechanics, not an object of the drive; no gravity, no holding brake)
COAST_DECEL_FACTOR = 0.5


@dataclass
class Motion:
    """One motion of the axis, a move or a ramp to standstill: from `start_counts` at `t0_s` along `profile`."""

    t0_s: float
    start_counts: float
    target_counts: int
    profile: Trapezoid
    stopping: bool = False  # a ramp to standstill (quick stop, halt, fault reaction, ...)
    coasting: bool = False  # the drive function is disabled: the axis runs out on friction alone


class ProfilePosition:
    """Profile position and the mechanics of one simulated drive.

    A part of `drivers.simdrive.SimDrive`, whose `__init__` sets the state these methods use.
    """

    def _set_mode(self, mode: int) -> None:
        if mode not in (0, codec.PP_MODE):
            raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
        if mode != codec.PP_MODE:
            # leaving profile position: its move stops (decelerating on 0x6084), nothing resumes
            if self.motion is not None and not self.motion.stopping:
                self._ramp_down(0x6084)
            self.pending = self.halted = None
        self.mode = mode
        self._store(0x6060, 0, mode)
        self._publish()

    def _profile_position(self, prev: int, cw: int) -> None:
        rising = cw & codec.CW_NEW_SET_POINT and not prev & codec.CW_NEW_SET_POINT and not self.ignore_set_point
        halt = bool(cw & codec.CW_HALT)
        if rising and not self.ack:
            target = int(self._get(0x607A))
            relative = bool(cw & codec.CW_RELATIVE)
            if self.halted is not None or (halt and self.motion is None):
                # halted: the new set-point is taken and runs when the halt is released
                if relative:  # relative to the preceding (the halted) target
                    target += self.halted if self.halted is not None else round(self.position_counts)
                self.halted = target
            elif self.motion is not None and not cw & codec.CW_CHANGE_IMMEDIATELY:
                self.pending = (target, relative)  # single set-point: after the current move
            else:
                self._start_move(target, relative)
            self.ack = self.state == "OPERATION_ENABLED"  # a refused set-point (fault) is not taken
        elif not cw & codec.CW_NEW_SET_POINT and self.ack and self.pending is None:
            self.ack = False  # (a buffered set-point keeps it: the buffer is full)
        if halt and self.motion is not None and not self.motion.stopping:
            # halt: stop as 0x605D says (default: the profile deceleration 0x6084); the target is
            # kept for the release
            target, pending = self.motion.target_counts, self.pending
            self._ramp_down(self._option(0x605D))
            self.halted, self.pending = target, pending
            if self.motion is None:
                self.target_reached = True
        elif not halt and self.halted is not None and self.motion is None:
            self._resume()

    def _resume(self) -> None:
        """Halt released at standstill: continue the positioning to the interrupted target."""
        target, self.halted = self.halted, None
        self._start_move(target, False)

    def _start_move(self, target: int, relative: bool) -> None:
        if relative:
            # CiA 402 (positioning option code 0x60F2 = 0): relative to the preceding target
            m = self.motion
            target += m.target_counts if m is not None and not m.stopping else round(self.position_counts)
        lo, hi = int(self._get(0x607D, 1)), int(self._get(0x607D, 2))
        if not lo <= target <= hi:
            self._fault(0x8612)
            return
        v = float(self._get(0x6081))
        a, d = float(self._get(0x6083)), float(self._get(0x6084))
        if v <= 0 or a <= 0 or d <= 0:
            self._fault(0x6320)
            return
        self.internal_limit = False
        self.target_reached = False
        now, m = self.clock.now(), self.motion
        v0 = m.profile.velocity_at(now - m.t0_s) if m is not None and not m.coasting else 0.0
        if v0:
            # a set-point taken at once during a move (change immediately): on from where the axis is and
            # the speed it has, not from rest
            here = m.start_counts + m.profile.position_at(now - m.t0_s)
            self.motion = Motion(now, here, target, from_speed(target - here, v0, v, a, d))
        else:
            self.motion = Motion(now, self.position_counts, target, trapezoid(target - self.position_counts, v, a, d))

    def _stop_motion(self) -> None:
        self.motion = None
        self.pending = None
        self.halted = None
        self.after_ramp = None

    def _ramp_down(self, decel_index: int = 0x6085) -> None:
        """Replace the running move by a ramp to standstill at the deceleration of object
        `decel_index` (quick stop 0x6085, profile 0x6084). A ramp already running at that
        deceleration goes on; a coasting axis is not driven, so it cannot be ramped."""
        m = self.motion
        self.pending = None
        self.halted = None
        if m is None or m.coasting:
            return
        d = float(self._get(decel_index))
        if m.stopping and m.profile.decel == d:
            return
        self._stop_on(m, d)

    def _coast(self) -> None:
        """The drive function is off: a running motion goes on undriven, slowed by friction alone."""
        m = self.motion
        if m is not None and not m.coasting:
            self._stop_on(m, self.coast_decel_counts, coasting=True)

    def _stop_on(self, m: Motion, d: float, coasting: bool = False) -> None:
        now = self.clock.now()
        v0 = m.profile.velocity_at(now - m.t0_s)
        if v0 == 0.0 or d <= 0 or self._jammed_at is not None:
            # a jammed axis already stands (velocity actual 0): its stop ends at once, as its fault
            # reaction does; a ramp of the demand alone would never end (no bit 10, no state after it)
            self.motion = None
            return
        t_s = abs(v0) / d
        ramp = Trapezoid(v0 * t_s / 2, abs(v0), d, d, 0.0, 0.0, t_s)
        # from where the axis is now, not where the last tick left it: a command between two ticks (10 ms)
        # lost the travel since, 1620 counts at 180000 counts/s
        here = m.start_counts + m.profile.position_at(now - m.t0_s)
        self.motion = Motion(now, here, round(here + ramp.distance), ramp, True, coasting)

    def _move(self, now: float) -> None:
        m = self.motion
        if m is None:
            return
        elapsed = now - m.t0_s
        demand = m.start_counts + m.profile.position_at(elapsed)
        for f in list(self._armed) if not m.stopping else ():
            if elapsed >= f["after_s"]:
                self._armed.remove(f)
                if f["kind"] == "following_error":
                    self._jammed_at = self.position_counts  # the axis is blocked mechanically
                else:
                    self.position_counts = demand
                    self._event(f)
                    return
        if self._jammed_at is not None:
            # the actual position stays; the drive faults once the demand leaves the window (a stop of a
            # jammed axis ends at once, in _stop_on: only a move's demand runs on here)
            self.position_counts = self._jammed_at
            if abs(demand - self._jammed_at) > int(self._get(0x6065)):
                self._fault(0x8611, following_error=True)
            return
        self.position_counts = demand
        if self._blocked(m):
            if self.motion is None and self.after_ramp is not None:
                self._end_ramp()
            return
        if m.stopping:
            if elapsed >= m.profile.duration_s:
                self.motion = None
                if self.after_ramp is not None:
                    self._end_ramp()
                elif self.halted is not None:
                    if self.controlword & codec.CW_HALT:
                        self.target_reached = True  # halted: statusword bit 10 = standstill
                    else:
                        self._resume()  # the halt was released during the ramp
            return
        if elapsed >= m.profile.duration_s:
            self.position_counts = float(m.target_counts)
            self.motion = None
            if self.pending is not None:
                target, relative = self.pending
                self.pending = None
                self._start_move(target, relative)
                if not self.controlword & codec.CW_NEW_SET_POINT:
                    self.ack = False  # the buffer is free again
            else:
                self.target_reached = True

    def _blocked(self, m: Motion) -> bool:
        """Hook for the gripper: True when the motion was stopped by something physical."""
        return False
