"""Build the python-can bus from configuration (the only place drivers' users make one)."""

from __future__ import annotations

import can

from cell.errors import BadInput
from drivers.errors import BusUnavailable

DEFAULT_INTERFACE = "virtual"
DEFAULT_CHANNEL = "disassembly-cell"
DEFAULT_BITRATE = 1_000_000


def open_bus(
    interface: str = DEFAULT_INTERFACE,
    channel: str = DEFAULT_CHANNEL,
    bitrate: int = DEFAULT_BITRATE,
    **kwargs,
) -> can.BusABC:
    """A python-can bus: any interface python-can knows ('virtual' here, 'socketcan' on the
    cell). Open one per participant: on 'virtual', a bus does not hear its own frames."""
    if interface not in can.VALID_INTERFACES:
        raise BadInput(
            f"unknown CAN interface {interface!r}; python-can knows: {', '.join(sorted(can.VALID_INTERFACES))}"
        )
    try:
        if interface == "virtual":
            return can.Bus(interface=interface, channel=channel, **kwargs)
        return can.Bus(interface=interface, channel=channel, bitrate=bitrate, **kwargs)
    except (can.CanError, OSError, ValueError, ImportError) as e:
        raise BusUnavailable(f"cannot open CAN interface {interface!r} channel {channel!r}: {e}") from None
