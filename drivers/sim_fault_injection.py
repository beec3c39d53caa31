"""Fault injection into a simulated drive, for tests: a silent node, dropped SDO answers, a deaf
set-point input, and events from the drive's own side (EMCY fault, following error, quick stop, STO,
internal limit, a reboot), at once or some time into the next move.
"""

from __future__ import annotations

from drivers import codec
from drivers.sim_nmt import NMT_OPERATIONAL

FAULT_KINDS = ("silent", "emcy", "following_error", "drop_sdo", "error_frames", "quick_stop", "disable",
               "ignore_set_point", "internal_limit", "reboot")
# injected events that act on the drive at once, or `after_s` into its next move
TIMED_EVENTS = ("emcy", "quick_stop", "disable", "internal_limit", "reboot")


class FaultInjection:
    """Injected misbehaviour of one simulated drive.

    A part of `drivers.simdrive.SimDrive`, whose `__init__` sets the state these methods use.
    """

    def arm(self, kind: str, **kw) -> None:
        with self._lock:
            if kind == "silent":
                self.silent = True
            elif kind == "drop_sdo":
                self.drop_sdo = int(kw.get("count", -1))
            elif kind == "ignore_set_point":
                self.ignore_set_point = True
            elif kind == "following_error":
                # the axis jams `after_s` into its next move; the drive trips on its window (0x6065)
                self._armed.append({"kind": kind, "after_s": float(kw.get("after_s") or 0.0)})
            elif kind in TIMED_EVENTS:
                event = {"kind": kind, "code": int(kw.get("code", 0x2310)), "auto_start": bool(kw.get("auto_start"))}
                if kw.get("after_s") is None:
                    self._event(event)
                    self._publish()
                else:
                    self._armed.append({**event, "after_s": float(kw["after_s"])})
            else:
                raise ValueError(f"unknown fault kind {kind!r}; one of {FAULT_KINDS}")

    def _event(self, event: dict) -> None:
        """An injected event from the drive's own side: an EMCY fault; a quick stop (its quick stop input,
        transition 11 as 0x605A says); or STO ('disable': the drive function off at once, SWITCH ON
        DISABLED, the axis coasts); or a reboot (a power glitch, its watchdog: the drive's own reset to its
        power-on values, the boot-up message, PRE-OPERATIONAL, the axis no longer driven; with `auto_start` it
        then starts itself, NMT OPERATIONAL in SWITCH ON DISABLED, as many drives do). The master's controlword
        is left as it was: the drive acts on the next command it receives, not on the level it still holds."""
        kind = event["kind"]
        if kind == "emcy":
            self._fault(event["code"])
        elif kind == "quick_stop" and self.state == "OPERATION_ENABLED":
            self._quick_stop()
        elif kind == "disable" and "FAULT" not in self.state:
            self._disable("SWITCH_ON_DISABLED")
        elif kind == "reboot":
            self._reset_node()
            if event["auto_start"]:
                self.nmt = NMT_OPERATIONAL
                self._last_tpdo = None  # its status at once, as on NMT start
        elif kind == "internal_limit" and self.state == "OPERATION_ENABLED" and self.motion is not None:
            # a limit switch or a torque limit: the move ends where the axis is, bits 10 and 11 set, no fault
            self.motion, self.pending = None, None
            if not self.controlword & codec.CW_NEW_SET_POINT:
                self.ack = False  # a buffered set-point is dropped: the buffer is free
            self.internal_limit = self.target_reached = True

    def heal(self) -> None:
        """Stop injected misbehaviour (the node talks again); latched drive faults stay."""
        with self._lock:
            self.silent = False
            self.drop_sdo = 0
            self.ignore_set_point = False
            self._armed.clear()
