"""Errors of the driver layer, part of the cell's one error family (`cell.errors`).

    CellError
    +-- DriverError                  anything the drives or the bus refuse or report (exit 1)
        +-- LimitError (+BadInput)   a command outside joint/workspace/step limits (exit 2);
        |                            raised before any frame is sent
        +-- NotConnected             a command before connect() or after disconnect()
        +-- DriveFault               a node reported a fault (EMCY, fault state, following error)
        |   +-- DriveDisabled        a moving axis left OPERATION ENABLED without a fault
        |   +-- NodeRebooted         a node rebooted (boot-up message) or left OPERATIONAL: its setup is lost
        +-- NodeSilent               a node's heartbeat (or boot-up) missed its deadline
        +-- SdoError                 an SDO transfer failed (no answer, or aborted)
        +-- BusFault                 error frames or a broken bus
        |   +-- BusUnavailable (+BadInput)  the interface or channel named cannot be opened (exit 2)
        +-- FaultLatched             a command while a fault is latched: call reset_faults()
        +-- MoveTimeout              a move did not reach its target in time

Every error that concerns one node carries `node` (its name, e.g. 'j2') and `node_id`.
"""

from __future__ import annotations

from cell.errors import BadInput, CellError


class DriverError(CellError):
    """Base of the driver layer's errors."""

    def __init__(self, message: str, *, node: str | None = None, node_id: int | None = None):
        super().__init__(message)
        self.node = node
        self.node_id = node_id


class LimitError(DriverError, BadInput):
    """The command violates a joint limit, the workspace box or the maximum step; nothing was sent."""

    exit_code = 2


class NotConnected(DriverError):
    pass


class DriveFault(DriverError):
    """A drive is in FAULT; `emcy_code` is the last EMCY error code it sent (or 0x603F)."""

    def __init__(
        self,
        message: str,
        *,
        node: str | None = None,
        node_id: int | None = None,
        emcy_code: int | None = None,
    ):
        super().__init__(message, node=node, node_id=node_id)
        self.emcy_code = emcy_code


class DriveDisabled(DriveFault):
    """A drive left OPERATION ENABLED during a move without a fault, while the host still commanded
    enable operation: its own quick stop input, STO, another master. `state` is the CiA 402 state
    found (QUICK_STOP_ACTIVE, SWITCH_ON_DISABLED, ...). Latched and handled like a fault."""

    def __init__(self, message: str, *, node: str | None = None, node_id: int | None = None, state: str = ""):
        super().__init__(message, node=node, node_id=node_id)
        self.state = state


class NodeRebooted(DriveFault):
    """A node the host set up sent a boot-up message (a power glitch, a watchdog reset: it is back at its
    power-on values, its axis no longer driven), or, set OPERATIONAL, its heartbeat reports another NMT state
    (it takes no set-point and sends no status). Latched and handled like a fault; `reset_faults()` sets the
    node up again as `connect()` did."""


class NodeSilent(DriverError):
    pass


class SdoError(DriverError):
    pass


class BusFault(DriverError):
    pass


class BusUnavailable(BusFault, BadInput):
    """The CAN interface or channel the user named cannot be opened (no such device, no driver
    library): bad input, exit 2, like any path that cannot be used."""

    exit_code = 2


class FaultLatched(DriverError):
    """Nothing moves after a fault until `reset_faults()`; `faults` maps node -> reason."""

    def __init__(self, faults: dict[str, str]):
        text = "; ".join(f"{k}: {v}" for k, v in faults.items())
        super().__init__(f"fault latched, reset first: cell hw reset, the station's Reset, or Arm.reset_faults() "
                         f"({text})", node=next(iter(faults), None))
        self.faults = dict(faults)


class MoveTimeout(DriverError):
    pass
