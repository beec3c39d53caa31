"""The simulated drive's CiA 402 state machine: controlword commands and their transitions, the
statusword, faults and fault reset, and the option codes that say how the drive stops when it leaves
OPERATION ENABLED.
"""

from __future__ import annotations

from drivers import codec

# CiA 402 option codes (CiA 402-2 / IEC 61800-7-201): how the drive stops when it leaves OPERATION
# ENABLED. Per value: the deceleration object of the ramp, or None for "disable drive function"
# (the axis coasts). The values a drive supports are its own; these drives refuse the others
# (current- and voltage-limit stops, 3/4/7/8) with SDO abort 0x06090030.
QUICK_STOP_OPTIONS = {  # 0x605A: (ramp, state after the ramp); transition 11
    0: (None, "SWITCH_ON_DISABLED"),  # disable drive function
    1: (0x6084, "SWITCH_ON_DISABLED"),  # slow down on the slow-down ramp, then SWITCH ON DISABLED
    2: (0x6085, "SWITCH_ON_DISABLED"),  # quick stop ramp, then SWITCH ON DISABLED
    5: (0x6084, "QUICK_STOP_ACTIVE"),  # slow-down ramp, stay in QUICK STOP ACTIVE
    6: (0x6085, "QUICK_STOP_ACTIVE"),  # quick stop ramp, stay in QUICK STOP ACTIVE (this drive's default)
}
SHUTDOWN_OPTIONS = {0: None, 1: 0x6084}  # 0x605B, transition 8: coast (default) / slow-down ramp
DISABLE_OPERATION_OPTIONS = {0: None, 1: 0x6084}  # 0x605C, transition 5: coast / slow-down ramp (default)
HALT_OPTIONS = {1: 0x6084, 2: 0x6085}  # 0x605D: slow-down ramp (default) / quick stop ramp, stay enabled
FAULT_REACTION_OPTIONS = {0: None, 1: 0x6084, 2: 0x6085}  # 0x605E: coast / slow-down / quick stop (default)
# 0x6007: what the drive does when the connection is lost (here: the host's heartbeat missed, 0x1016):
# nothing, a fault (the fault reaction, this drive's default), disable voltage (the axis coasts) or a quick
# stop (as 0x605A says)
ABORT_CONNECTION_OPTIONS = {0: "nothing", 1: "fault", 2: "disable voltage", 3: "quick stop"}
OPTION_CODES = {
    0x6007: ABORT_CONNECTION_OPTIONS,
    0x605A: QUICK_STOP_OPTIONS,
    0x605B: SHUTDOWN_OPTIONS,
    0x605C: DISABLE_OPERATION_OPTIONS,
    0x605D: HALT_OPTIONS,
    0x605E: FAULT_REACTION_OPTIONS,
}


class StateMachine:
    """The CiA 402 states of one simulated drive.

    A part of `drivers.simdrive.SimDrive`, whose `__init__` sets the state these methods use.
    """

    @property
    def statusword(self) -> int:
        return codec.statusword_for(
            self.state,
            target_reached=self._target_reached_bit(),
            ack=self.ack,
            following_error=self.following_error,
            internal_limit=self.internal_limit,
        )

    def _target_reached_bit(self) -> bool:
        """Statusword bit 10. In OPERATION ENABLED: the target reached, or standstill after a halt. In
        QUICK STOP ACTIVE: the quick stop ramp has ended and the axis stands (CiA 402, for 0x605A 5-8; with
        1 or 2 the drive leaves QUICK STOP ACTIVE at standstill). Clear in the other states."""
        if self.state == "OPERATION_ENABLED":
            return self.target_reached
        return self.state == "QUICK_STOP_ACTIVE" and self.motion is None

    def _option(self, index: int):
        """What the option code `index` (0x605A-0x605E) asks for; its value was checked on writing."""
        return OPTION_CODES[index][int(self._get(index))]

    def _on_controlword(self, cw: int) -> None:
        prev, self.controlword = self.controlword, cw
        self._store(0x6040, 0, cw)
        cmd = codec.command_of(cw)
        s = self.state
        if cmd != "ENABLE_OPERATION":
            self.enable_held = False  # another command replaces a held enable operation
        # OPERATION ENABLED also while a shutdown or disable operation waits for its ramp: those
        # commands are still taken (disable voltage, quick stop, the other of the two), no set-point
        enabled = s == "OPERATION_ENABLED"
        if s in ("FAULT", "FAULT_REACTION_ACTIVE"):
            if s == "FAULT" and cw & codec.CW_FAULT_RESET and not prev & codec.CW_FAULT_RESET:
                self._fault_reset()
        elif cmd == "DISABLE_VOLTAGE":
            self._disable("SWITCH_ON_DISABLED")  # 7, 9, 10, 12: the drive function off at once
        elif cmd == "QUICK_STOP":
            if enabled:
                self._quick_stop()  # 11
            elif s != "QUICK_STOP_ACTIVE":  # (in QUICK STOP ACTIVE, a quick stop is no transition)
                self._disable("SWITCH_ON_DISABLED")  # 7, 10
        elif cmd == "SHUTDOWN":
            if enabled:
                self._leave_enabled("READY_TO_SWITCH_ON", self._option(0x605B))  # 8
            elif s in ("SWITCH_ON_DISABLED", "SWITCHED_ON"):
                self._disable("READY_TO_SWITCH_ON")  # 2, 6
        elif cmd == "SWITCH_ON":
            if enabled:
                self._leave_enabled("SWITCHED_ON", self._option(0x605C))  # 5
            elif s == "READY_TO_SWITCH_ON":
                self._disable("SWITCHED_ON")  # 3
        elif cmd == "ENABLE_OPERATION":
            # 4; 16 only where the quick stop stays in QUICK STOP ACTIVE (0x605A 5-8)
            if s == "SWITCHED_ON" or (s == "QUICK_STOP_ACTIVE" and self.after_ramp is None):
                self._enable()
            elif s == "READY_TO_SWITCH_ON":
                # switch on + enable operation: transitions 3 and 4 (the controlword is a level)
                self._disable("SWITCHED_ON")
                self._enable()
        if s == self.state == "OPERATION_ENABLED" and self.after_ramp is None and self.mode == codec.PP_MODE:
            # only a drive that was already enabled takes a set-point: the controlword that
            # enables it never starts a move, even with bit 4 set (enabling never jumps)
            self._profile_position(prev, cw)
        self._publish()

    def _enable(self) -> None:
        """Transition 4 or 16. Not while the axis still ramps down or coasts (no drive stops it in zero
        time): the drive stays in its state and takes the held command at standstill (`_take_held_enable`)."""
        if self.motion is not None:  # out of OPERATION ENABLED every motion is a stop
            self.enable_held = True
            return
        self.enable_held = False
        # enabling never jumps: hold the actual position until the next set-point
        self._stop_motion()
        self.target_reached = True
        self.state = "OPERATION_ENABLED"

    def _take_held_enable(self) -> None:
        """At standstill, an enable operation held during the ramp or coast, if its transition is still one."""
        if not self.enable_held or self.motion is not None:
            return
        self.enable_held = False
        if self.state == "SWITCHED_ON" or (self.state == "QUICK_STOP_ACTIVE" and self.after_ramp is None):
            self._enable()

    def _disable(self, state: str) -> None:
        """Enter a state without the drive function (SWITCH ON DISABLED, READY TO SWITCH ON,
        SWITCHED ON): a motion still running is no longer driven and coasts."""
        self._coast()
        self.pending = self.halted = self.after_ramp = None
        self.ack = False
        self.state = state

    def _leave_enabled(self, target: str, decel_index: int | None) -> None:
        """Shutdown (8) or disable operation (5) as its option code says: with a ramp, the drive
        stays in OPERATION ENABLED while it slows down and enters `target` at standstill; with
        "disable drive function" (None) it enters `target` at once and the axis coasts."""
        if decel_index is None:
            self._disable(target)
            return
        self._ramp_down(decel_index)
        self.ack = False
        self.after_ramp = target
        if self.motion is None:
            self._end_ramp()

    def _quick_stop(self) -> None:
        """Quick stop (11) as 0x605A says: QUICK STOP ACTIVE while the axis ramps down, then either
        stay there (5, 6) or go on to SWITCH ON DISABLED (1, 2); 0 disables the drive function."""
        decel_index, final = self._option(0x605A)
        if decel_index is None:
            self._disable(final)
            return
        self._ramp_down(decel_index)
        self.ack = False
        self.state = "QUICK_STOP_ACTIVE"
        self.after_ramp = None if final == "QUICK_STOP_ACTIVE" else final
        if self.motion is None and self.after_ramp is not None:
            self._end_ramp()

    def _end_ramp(self) -> None:
        """Standstill after the ramp of a transition: enter its state (FAULT after the fault reaction)."""
        state, self.after_ramp = self.after_ramp, None
        if state == "FAULT":
            self.state = "FAULT"
        else:
            self._disable(state)

    def _fault(self, code: int, *, following_error: bool = False) -> None:
        if self.state in ("FAULT", "FAULT_REACTION_ACTIVE"):
            return
        self.enable_held = False
        m = self.motion
        if self._jammed_at is not None:
            self._stop_motion()  # the axis is blocked mechanically
        elif m is not None and not m.coasting:
            # the fault reaction (0x605E): a ramp in FAULT REACTION ACTIVE, then FAULT (in _move),
            # or "disable drive function": FAULT at once and the axis coasts
            decel_index = self._option(0x605E)
            if decel_index is None:
                self._coast()
            else:
                self._ramp_down(decel_index)
        self.pending = self.halted = None
        if self.motion is not None and not self.motion.coasting:
            self.state, self.after_ramp = "FAULT_REACTION_ACTIVE", "FAULT"
        else:
            self.state, self.after_ramp = "FAULT", None
        self.ack = False
        self.following_error = following_error
        self.error_code = code
        self._emcy(code)

    def _fault_reset(self) -> None:
        self.state = "SWITCH_ON_DISABLED"
        self._jammed_at = None  # the operator cleared the blockage before resetting
        self.error_code = 0
        self.following_error = False
        self._armed = [f for f in self._armed if f["kind"] not in ("emcy", "following_error")]
        self._report(0)  # error reset (CiA 301), logged like every EMCY (it went unlogged)
