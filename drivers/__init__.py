"""The driver layer: CANopen CiA 402 drives over python-can, simulated drives, supervision.

    open_bus(interface, channel, bitrate) -> can.BusABC   the bus, built from configuration
    Arm(bus, cell, clock)                                 the SCARA axes and the gripper
    sim.serve(bus, cell, clock)                           simulated drives on the same bus
    clock.SimClock / clock.RealClock                      the time both sides share
    record.BusRecorder(bus, path)                         python-can logger of all traffic
    simulated_cell(cell, clock) -> (arm, drives)          all of the above in one context manager
    execute.run_commands(arm, commands) -> records        a pick's command list on the arm

Data flow: joint command -> limits (drivers.limits) -> counts (codec) -> RPDO / SDO frames
(drivers.axis) -> bus; TPDO / EMCY / heartbeat frames -> codec -> supervision (drivers.arm_supervision).
"""

from drivers.arm import Arm
from drivers.bus import open_bus
from drivers.clock import RealClock, SimClock
from drivers.errors import (
    BusFault,
    BusUnavailable,
    DriveDisabled,
    DriveFault,
    DriverError,
    FaultLatched,
    LimitError,
    MoveTimeout,
    NodeRebooted,
    NodeSilent,
    NotConnected,
    SdoError,
)
from drivers.gripper import Gripper, GripResult
from drivers.session import real_cell, simulated_cell

CellDrives = Arm

__all__ = [
    "Arm",
    "CellDrives",
    "GripResult",
    "Gripper",
    "open_bus",
    "RealClock",
    "SimClock",
    "BusFault",
    "BusUnavailable",
    "DriveDisabled",
    "DriveFault",
    "DriverError",
    "FaultLatched",
    "LimitError",
    "MoveTimeout",
    "NodeRebooted",
    "NodeSilent",
    "NotConnected",
    "SdoError",
    "real_cell",
    "simulated_cell",
]
