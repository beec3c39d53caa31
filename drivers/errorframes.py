"""Error frames: what they say and when they stop the arm.

python-can marks an error frame with `Message.is_error_frame`. What it says depends on the interface:
SocketCAN (linux/can/error.h) puts the error class in the id (python-can strips CAN_ERR_FLAG and gives the
class bits as `arbitration_id`) and the details in `data` (8 bytes: data[1] the controller's state, data[2..3]
the protocol violation, data[6..7] the error counters). PCAN and Kvaser set only the flag (PCAN's id and data
follow PCAN-Basic's own layout, Kvaser's carry no class): there the class cannot be told.

The policy (`ErrorFramePolicy`): a sporadic error frame is how CAN works (a disturbed bit, the frame resent by
the controllers), so it is counted, not a stop. A burst (more than `can.error_frames_max` within
`can.error_window_ms`, on the arm's clock) means a disturbed bus losing frames: stop. A frame saying the host
cannot take part in the bus any more stops at once: bus-off, transmit timeout, no ACK, error-passive, and a
controller restarted after bus-off (it was off the bus meanwhile). Lost arbitration and back to error-active
are no errors (CAN shares the bus by arbitration; back to active is the recovery): seen and counted in the
totals, not in the window.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass

import can

# linux/can/error.h (tests/test_can_error_frames.py checks them against the system's header where it has one)
CAN_ERR_DLC = 8
CAN_ERR_TX_TIMEOUT = 0x001  # TX timeout (by netdevice driver)
CAN_ERR_LOSTARB = 0x002  # lost arbitration / data[0]
CAN_ERR_CRTL = 0x004  # controller problems / data[1]
CAN_ERR_PROT = 0x008  # protocol violations / data[2..3]
CAN_ERR_TRX = 0x010  # transceiver status / data[4]
CAN_ERR_ACK = 0x020  # received no ACK on transmission
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080  # bus error (may flood)
CAN_ERR_RESTARTED = 0x100  # controller restarted
CAN_ERR_CNT = 0x200  # TX error counter data[6], RX error counter data[7]
CAN_ERR_MASK = 0x1FFFFFFF  # linux/can.h: the id without the EFF, RTR and ERR flags
CAN_ERR_CRTL_RX_OVERFLOW = 0x01
CAN_ERR_CRTL_TX_OVERFLOW = 0x02
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40  # recovered to error active state
CAN_ERR_PROT_LOC_ACK = 0x19  # ACK slot

# can-utils' names (candump -e), what a cell engineer reads on the bus
CLASS_NAMES = {
    CAN_ERR_TX_TIMEOUT: "tx-timeout",
    CAN_ERR_LOSTARB: "lost-arbitration",
    CAN_ERR_CRTL: "controller-problem",
    CAN_ERR_PROT: "protocol-violation",
    CAN_ERR_TRX: "transceiver-status",
    CAN_ERR_ACK: "no-acknowledgement-on-tx",
    CAN_ERR_BUSOFF: "bus-off",
    CAN_ERR_BUSERROR: "bus-error",
    CAN_ERR_RESTARTED: "restarted-after-bus-off",
    CAN_ERR_CNT: "error-counter-tx-rx",
}
CONTROLLER_NAMES = {
    CAN_ERR_CRTL_RX_OVERFLOW: "rx-overflow",
    CAN_ERR_CRTL_TX_OVERFLOW: "tx-overflow",
    CAN_ERR_CRTL_RX_WARNING: "rx-error-warning",
    CAN_ERR_CRTL_TX_WARNING: "tx-error-warning",
    CAN_ERR_CRTL_RX_PASSIVE: "rx-error-passive",
    CAN_ERR_CRTL_TX_PASSIVE: "tx-error-passive",
    CAN_ERR_CRTL_ACTIVE: "back-to-error-active",
}
PROTOCOL_NAMES = {  # data[2]
    0x01: "single-bit-error",
    0x02: "frame-format-error",
    0x04: "bit-stuffing-error",
    0x08: "tx-dominant-bit-error",
    0x10: "tx-recessive-bit-error",
    0x20: "bus-overload",
    0x40: "active-error",
    0x80: "error-on-tx",
}
UNCLASSIFIED = "unclassified"  # an interface that flags error frames without a class
# why each class stops the arm at once: the host is off the bus, or none of its frames get through
STOP_REASONS = {
    CAN_ERR_BUSOFF: "the host's CAN controller is off the bus",
    CAN_ERR_TX_TIMEOUT: "the host's CAN controller could not send",
    CAN_ERR_ACK: "no node acknowledged the host's frame (drives without power, cable open)",
    CAN_ERR_RESTARTED: "the host's CAN controller was off the bus and restarted",
}
PASSIVE_REASON = "the host's CAN controller's error counter passed 127 (its frames may be lost unannounced)"
# python-can buses that hand on SocketCAN's error class: SocketCAN itself, and the virtual bus of the
# simulation, whose error frames are made as SocketCAN presents them (drivers.sim)
SOCKETCAN_LAYOUT_BUSES = ("SocketcanBus", "VirtualBus")


def classes_readable(bus: can.BusABC) -> bool:
    """Whether `bus` hands on SocketCAN's error class in its error frames (otherwise every one is counted)."""
    return type(bus).__name__ in SOCKETCAN_LAYOUT_BUSES


@dataclass(frozen=True)
class ErrorFrameVerdict:
    action: str  # "stop" (latch at once), "count" (in the sliding window), "note" (no error: totals only)
    names: tuple[str, ...]  # the class names (can-utils' words), UNCLASSIFIED when the interface says none
    text: str  # for people: the names with the controller state and error counters, and why it stops

    @property
    def stops(self) -> bool:
        return self.action == "stop"

    @property
    def is_error(self) -> bool:
        """Counted or stopping: not lost arbitration, not the recovery."""
        return self.action != "note"


def classify(msg: can.Message, readable: bool = True) -> ErrorFrameVerdict:
    """What an error frame says and what the host does about it (`readable`: see `classes_readable`)."""
    cls = msg.arbitration_id & CAN_ERR_MASK if readable else 0
    if not cls:
        why = "error frame of no class" if readable else "error frame (this interface gives no class)"
        return ErrorFrameVerdict("count", (UNCLASSIFIED,), why)
    data = bytes(msg.data)[:CAN_ERR_DLC].ljust(CAN_ERR_DLC, b"\0")
    names = tuple(name for bit, name in CLASS_NAMES.items() if cls & bit) or (f"class-0x{cls:X}",)
    crtl = data[1] if cls & CAN_ERR_CRTL else 0
    parts = []
    for bit, name in CLASS_NAMES.items():
        if not cls & bit:
            continue
        if bit == CAN_ERR_CRTL and crtl:
            name += "{" + ",".join(n for b, n in CONTROLLER_NAMES.items() if crtl & b) + "}"
        elif bit == CAN_ERR_PROT and data[2]:
            name += "{" + ",".join(n for b, n in PROTOCOL_NAMES.items() if data[2] & b) + "}"
        elif bit == CAN_ERR_CNT:
            name += f"{{tx {data[6]}, rx {data[7]}}}"
        parts.append(name)
    reasons = [why for bit, why in STOP_REASONS.items() if cls & bit]
    if crtl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
        reasons.append(PASSIVE_REASON)
    text = ", ".join(parts) or f"class 0x{cls:X}"
    if reasons:
        return ErrorFrameVerdict("stop", names, f"{text}: {'; '.join(reasons)}")
    what = cls & ~CAN_ERR_CNT  # the error counters come along with any class
    if what == CAN_ERR_LOSTARB or (what == CAN_ERR_CRTL and crtl == CAN_ERR_CRTL_ACTIVE):
        return ErrorFrameVerdict("note", names, text)
    return ErrorFrameVerdict("count", names, text)


class ErrorFramePolicy:
    """Every error frame the host hears, and whether the bus is faulty. Not thread-safe: the arm calls it
    under its lock.

    Parameters
    ----------
    max_frames : int
        Error frames allowed within the window; one more is a fault (0: the first one is).
    window_ms : int
        The sliding window, on the clock whose times `observe` is given.
    readable : bool
        The bus hands on SocketCAN's error class (`classes_readable`); otherwise every frame is counted.
    """

    def __init__(self, max_frames: int, window_ms: int, readable: bool):
        if max_frames < 0 or window_ms <= 0:
            raise ValueError(f"error frame window: max_frames >= 0 and window_ms > 0, got {max_frames}, {window_ms}")
        self.max_frames, self.window_ms, self.readable = max_frames, window_ms, readable
        self.total = 0
        self.errors = 0  # the frames that are errors: counted or stopping (not lost arbitration, not the recovery)
        self.by_class: Counter[str] = Counter()
        self.last: ErrorFrameVerdict | None = None
        self._times: deque[float] = deque()

    def observe(self, msg: can.Message, now_s: float) -> str | None:
        """Count one error frame heard at `now_s`; the reason the bus is faulty, or None."""
        v = classify(msg, self.readable)
        self.total += 1
        self.by_class.update(v.names)
        self.last = v
        self.errors += v.is_error
        if v.stops:
            return f"bus: error frame {v.text}"
        if v.action == "note":
            return None
        self._times.append(now_s)
        n = self._in_window(now_s)
        if n > self.max_frames:
            frames = "error frames" if n > 1 else "error frame"
            return (
                f"bus: {n} {frames} within {self.window_ms} ms (more than can.error_frames_max = {self.max_frames} "
                f"in can.error_window_ms = {self.window_ms}); the last: {v.text}"
            )
        return None

    def _in_window(self, now_s: float) -> int:
        start_s = now_s - self.window_ms / 1000.0
        while self._times and self._times[0] <= start_s:
            self._times.popleft()
        return len(self._times)

    def restart_window(self) -> None:
        """Forget the window (after `reset_faults()`): the burst that stopped the arm does not count again."""
        self._times.clear()

    def summary(self, now_s: float) -> dict:
        """For status: totals since the arm was made, per class, in the window now, the limits, the last one."""
        return {
            "error_frames": self.total,
            "errors": self.errors,
            "by_class": dict(self.by_class),
            "in_window": self._in_window(now_s),
            "error_frames_max": self.max_frames,
            "error_window_ms": self.window_ms,
            "last": None if self.last is None else self.last.text,
        }


def by_class_text(by_class: dict) -> str:
    """The per-class counts of a bus state as people read them: "3 bus-error, 1 rx-overflow" (by class name)."""
    return ", ".join(f"{n} {c}" for c, n in sorted(by_class.items()))
