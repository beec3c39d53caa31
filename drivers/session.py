"""Ready-made sessions: the whole cell on the bus, simulated or real, as one context manager.

with simulated_cell(cell) as (arm, drives):     # both in simulated time, fresh channel
    arm.move_joints(...); drives.gripper_object_width_mm = 25.0

with real_cell("socketcan", "can0", cell) as arm:
    ...
"""

from __future__ import annotations

import contextlib
import itertools
import os

from drivers import sim
from drivers.arm import Arm
from drivers.bus import open_bus
from drivers.clock import Clock, SimClock
from drivers.record import BusRecorder

_channels = itertools.count()


@contextlib.contextmanager
def simulated_cell(
    cell=None,
    clock: Clock | None = None,
    *,
    channel: str | None = None,
    record=None,
    on_record_failed=None,
    enable: bool = True,
    **arm_kw,
):
    """The simulated drives and a connected arm on a virtual channel of their own.

    Parameters
    ----------
    cell : Cell, optional
    clock : Clock, optional
        Default: a new `SimClock` (simulated time; `arm.clock.now()` is the cell's time).
        Pass `RealClock()` for wall time.
    channel : str, optional
        Virtual channel name (default: unique per session).
    record : path, optional
        Record all CAN traffic to this python-can log (.asc, .log, .blf).
    on_record_failed : callable, optional
        Called with the log's RecordingFailed when a write into it fails (`BusRecorder`'s on_failed).
    Yields (arm, sim_handle).
    """
    clock = clock if clock is not None else SimClock()
    channel = channel or f"cell-sim-{os.getpid()}-{next(_channels)}"
    buses = []

    def _bus():
        b = open_bus("virtual", channel)
        buses.append(b)
        return b

    try:
        with contextlib.ExitStack() as stack:
            if record is not None:
                stack.enter_context(BusRecorder(_bus(), record, clock=clock if clock.simulated else None,
                                                 on_failed=on_record_failed))
            drives = stack.enter_context(sim.serve(_bus(), cell, clock=clock))
            arm = Arm(_bus(), drives.cell, clock=clock, **arm_kw)
            arm.connect(enable=enable)
            stack.callback(arm.disconnect)
            yield arm, drives
    finally:
        for b in buses:
            b.shutdown()


@contextlib.contextmanager
def real_cell(interface: str, channel: str, cell=None, *, record=None, on_record_failed=None, enable: bool = True,
              **arm_kw):
    """A connected arm on a real bus (bitrate from the cell file). Yields the arm. `record`, `on_record_failed`:
    as `simulated_cell`'s."""
    if cell is None:
        from cell.cellconfig import default_cell

        cell = default_cell()
    bus = open_bus(interface, channel, cell.can.bitrate)
    buses = [bus]
    try:
        with contextlib.ExitStack() as stack:
            if record is not None:
                tap = open_bus(interface, channel, cell.can.bitrate)
                buses.append(tap)
                stack.enter_context(BusRecorder(tap, record, on_failed=on_record_failed))
            arm = Arm(bus, cell, **arm_kw)
            arm.connect(enable=enable)
            stack.callback(arm.disconnect)
            yield arm
    finally:
        for b in buses:
            b.shutdown()
