"""Pure codecs of the CANopen frames the cell uses (CiA 301 + CiA 402), no I/O.

Every byte that goes on the bus is packed here and every byte that comes back is unpacked
here, so the same functions serve the master (`drivers.axis`) and the simulated drives
(`drivers.sim`), and round-trip tests cover them.

PDO layout (static mapping, the same in the EDS files):
    RPDO1 0x200+id  controlword 0x6040 (u16)
    RPDO2 0x300+id  target position 0x607A (i32, counts)
    RPDO3 0x400+id  modes of operation 0x6060 (i8)
    TPDO1 0x180+id  statusword 0x6041 (u16), position actual 0x6064 (i32), modes display 0x6061 (i8)
One object per RPDO so a master that writes one object never resends stale copies of others.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

# --- COB-IDs (CiA 301 pre-defined connection set) -----------------------------------------
NMT_COB = 0x000
SYNC_COB = 0x080
EMCY_BASE = 0x080
TPDO1_BASE = 0x180
RPDO1_BASE = 0x200
RPDO2_BASE = 0x300
RPDO3_BASE = 0x400
SDO_TX_BASE = 0x580  # server -> client
SDO_RX_BASE = 0x600  # client -> server
HEARTBEAT_BASE = 0x700

# the static PDO mapping (0x1A00 / 0x1600-0x1602 entries: index << 16 | subindex << 8 | bits)
TPDO1_MAPPING = (0x60410010, 0x60640020, 0x60610008)
RPDO_MAPPINGS = ((0x60400010,), (0x607A0020,), (0x60600008,))
RPDO_BASES = (RPDO1_BASE, RPDO2_BASE, RPDO3_BASE)
PDO_EVENT_DRIVEN = 255  # transmission type: on change (device profile specific) and event timer

# NMT states as sent in heartbeats, and NMT command specifiers
NMT_STATE_NAMES = {0x00: "INITIALISING", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
NMT_BOOT_UP, NMT_OPERATIONAL = 0x00, 0x05  # a heartbeat frame's state: the boot-up message, OPERATIONAL

PP_MODE = 1  # profile position, 0x6060 value
SUPPORTED_MODES_PP = 0x00000001  # 0x6502 bit 0: profile position

# --- controlword 0x6040 -------------------------------------------------------------------
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_FAULT_RESET = 0x0080
CW_NEW_SET_POINT = 0x0010  # bit 4, profile position
CW_CHANGE_IMMEDIATELY = 0x0020  # bit 5
CW_RELATIVE = 0x0040  # bit 6
CW_HALT = 0x0100  # bit 8

# --- statusword 0x6041 --------------------------------------------------------------------
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5  # 1 = quick stop NOT active
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11  # the gripper: force limit reached (holding)
SW_SET_POINT_ACK = 1 << 12
SW_FOLLOWING_ERROR = 1 << 13

# (mask, value, name) in the order of CiA 402 table 30; names as the CONTRACT spells them.
_STATE_BITS = (
    (0x4F, 0x00, "NOT_READY_TO_SWITCH_ON"),
    (0x4F, 0x40, "SWITCH_ON_DISABLED"),
    (0x6F, 0x21, "READY_TO_SWITCH_ON"),
    (0x6F, 0x23, "SWITCHED_ON"),
    (0x6F, 0x27, "OPERATION_ENABLED"),
    (0x6F, 0x07, "QUICK_STOP_ACTIVE"),
    (0x4F, 0x0F, "FAULT_REACTION_ACTIVE"),
    (0x4F, 0x08, "FAULT"),
)
STATES = tuple(name for _, _, name in _STATE_BITS)
# The statusword bits a drive shows in each state (bit 5 set where quick stop is not active).
STATE_WORDS = {
    "NOT_READY_TO_SWITCH_ON": 0x00,
    "SWITCH_ON_DISABLED": 0x40,
    "READY_TO_SWITCH_ON": 0x21 | SW_VOLTAGE_ENABLED,
    "SWITCHED_ON": 0x23 | SW_VOLTAGE_ENABLED,
    "OPERATION_ENABLED": 0x27 | SW_VOLTAGE_ENABLED,
    "QUICK_STOP_ACTIVE": 0x07 | SW_VOLTAGE_ENABLED,
    "FAULT_REACTION_ACTIVE": 0x0F,
    "FAULT": 0x08,
}


def state_name(statusword: int) -> str:
    """The CiA 402 state a statusword shows, e.g. 'OPERATION_ENABLED'; 'UNKNOWN' if none."""
    for mask, value, name in _STATE_BITS:
        if statusword & mask == value:
            return name
    return "UNKNOWN"


def statusword_for(
    state: str,
    *,
    target_reached: bool = False,
    ack: bool = False,
    following_error: bool = False,
    internal_limit: bool = False,
    warning: bool = False,
) -> int:
    """Compose a statusword from a state name and the profile-position bits."""
    if state not in STATE_WORDS:
        raise ValueError(f"unknown CiA 402 state {state!r}")
    word = STATE_WORDS[state] | SW_REMOTE
    for flag, bit in (
        (target_reached, SW_TARGET_REACHED),
        (ack, SW_SET_POINT_ACK),
        (following_error, SW_FOLLOWING_ERROR),
        (internal_limit, SW_INTERNAL_LIMIT),
        (warning, SW_WARNING),
    ):
        if flag:
            word |= bit
    return word


def command_of(controlword: int) -> str:
    """The device-control command a controlword carries (CiA 402 table 28), by its low bits.

    One of 'FAULT_RESET' (bit 7; the drive acts on its rising edge), 'DISABLE_VOLTAGE',
    'QUICK_STOP', 'SHUTDOWN', 'SWITCH_ON', 'ENABLE_OPERATION'.
    """
    if controlword & CW_FAULT_RESET:
        return "FAULT_RESET"
    if not controlword & 0x2:
        return "DISABLE_VOLTAGE"
    if not controlword & 0x4:
        return "QUICK_STOP"
    if not controlword & 0x1:
        return "SHUTDOWN"
    if not controlword & 0x8:
        return "SWITCH_ON"
    return "ENABLE_OPERATION"


# --- PDO payloads -------------------------------------------------------------------------
_TPDO1 = struct.Struct("<HiB")  # statusword, position actual, modes display (i8 stored as its byte)
_I8 = struct.Struct("<b")


@dataclass(frozen=True)
class DriveStatus:
    """What TPDO1 carries: the drive's statusword, actual position (counts) and mode."""

    statusword: int
    position_counts: int
    mode: int

    @property
    def state(self) -> str:
        return state_name(self.statusword)

    @property
    def target_reached(self) -> bool:
        return bool(self.statusword & SW_TARGET_REACHED)

    @property
    def ack(self) -> bool:
        return bool(self.statusword & SW_SET_POINT_ACK)

    @property
    def internal_limit(self) -> bool:
        return bool(self.statusword & SW_INTERNAL_LIMIT)

    @property
    def following_error(self) -> bool:
        return bool(self.statusword & SW_FOLLOWING_ERROR)


def pack_tpdo1(status: DriveStatus) -> bytes:
    return _TPDO1.pack(status.statusword & 0xFFFF, _check_i32(status.position_counts), _I8.pack(status.mode)[0])


def unpack_tpdo1(data: bytes) -> DriveStatus:
    if len(data) != _TPDO1.size:
        raise ValueError(f"TPDO1 must be {_TPDO1.size} bytes, got {len(data)}")
    sw, pos, mode_byte = _TPDO1.unpack(bytes(data))
    return DriveStatus(sw, pos, _I8.unpack(bytes([mode_byte]))[0])


def pack_controlword(controlword: int) -> bytes:
    if not 0 <= controlword <= 0xFFFF:
        raise ValueError(f"controlword must be 0..0xFFFF, got {controlword}")
    return struct.pack("<H", controlword)


def unpack_controlword(data: bytes) -> int:
    if len(data) != 2:
        raise ValueError(f"RPDO1 (controlword) must be 2 bytes, got {len(data)}")
    return struct.unpack("<H", bytes(data))[0]


def pack_target(position_counts: int) -> bytes:
    return struct.pack("<i", _check_i32(position_counts))


def unpack_target(data: bytes) -> int:
    if len(data) != 4:
        raise ValueError(f"RPDO2 (target position) must be 4 bytes, got {len(data)}")
    return struct.unpack("<i", bytes(data))[0]


def pack_mode(mode: int) -> bytes:
    return _I8.pack(mode)


def unpack_mode(data: bytes) -> int:
    if len(data) != 1:
        raise ValueError(f"RPDO3 (modes of operation) must be 1 byte, got {len(data)}")
    return _I8.unpack(bytes(data))[0]


def _check_i32(v: int) -> int:
    if not -(2**31) <= v < 2**31:
        raise ValueError(f"position {v} counts does not fit INTEGER32")
    return int(v)


# --- heartbeat and NMT --------------------------------------------------------------------
def pack_heartbeat(nmt_state: int) -> bytes:
    return bytes([nmt_state & 0x7F])


def unpack_heartbeat(data: bytes) -> int:
    if len(data) != 1:
        raise ValueError(f"heartbeat must be 1 byte, got {len(data)}")
    return data[0] & 0x7F


def pack_nmt(command: int, node_id: int) -> bytes:
    return bytes([command, node_id])


def consumer_heartbeat_entry(producer_id: int, time_ms: int) -> int:
    """A 0x1016 sub-entry: watch `producer_id`'s heartbeat with a deadline of `time_ms`."""
    if not 1 <= producer_id <= 127 or not 0 <= time_ms <= 0xFFFF:
        raise ValueError(f"bad consumer heartbeat entry: node {producer_id}, {time_ms} ms")
    return (producer_id << 16) | time_ms


def split_consumer_heartbeat_entry(entry: int) -> tuple[int, int]:
    return (entry >> 16) & 0x7F, entry & 0xFFFF


# --- EMCY ---------------------------------------------------------------------------------
EMCY_TEXT = {
    0x0000: "error reset / no error",
    0x1000: "generic error",
    0x2310: "continuous over-current",
    0x3210: "DC link over-voltage",
    0x4310: "drive temperature too high",
    0x5530: "EEPROM / data memory error",
    0x6320: "parameter error",
    0x8110: "CAN overrun (frames lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error (host silent)",
    0x8140: "recovered from bus off",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8611: "following error",
    0x8612: "reference limit (target outside the software position limits)",
    0xFF00: "device specific",
}
_EMCY = struct.Struct("<HB5s")


@dataclass(frozen=True)
class Emcy:
    code: int
    register: int
    data: bytes = b"\x00" * 5

    @property
    def text(self) -> str:
        return emcy_text(self.code)


def emcy_text(code: int) -> str:
    if code in EMCY_TEXT:
        return EMCY_TEXT[code]
    for mask in (0xFF00, 0xF000):
        if code & mask in EMCY_TEXT and code & mask:
            return EMCY_TEXT[code & mask] + f" (0x{code:04X})"
    return f"error 0x{code:04X}"


def pack_emcy(e: Emcy) -> bytes:
    if len(e.data) > 5:
        raise ValueError("EMCY manufacturer data is at most 5 bytes")
    return _EMCY.pack(e.code, e.register, e.data.ljust(5, b"\x00"))


def unpack_emcy(data: bytes) -> Emcy:
    if len(data) != 8:
        raise ValueError(f"EMCY must be 8 bytes, got {len(data)}")
    code, reg, extra = _EMCY.unpack(bytes(data))
    return Emcy(code, reg, extra)


# --- units --------------------------------------------------------------------------------
def to_counts(value: float, counts_per_unit: float) -> int:
    """Joint value (deg or mm) -> drive counts, rounded to the nearest count."""
    if not math.isfinite(value):
        raise ValueError(f"cannot convert {value} to counts")
    return _check_i32(round(value * counts_per_unit))


def rate_counts_within(limit_per_s: float, counts_per_unit: float) -> int:
    """A speed or acceleration limit (unit/s or unit/s^2) -> the most counts/s (counts/s^2) within it:
    rounded down, as rounding to the nearest could send up to half a count past the limit
    (1e-9 count of float noise forgiven: 0.29 x 100 is 28.999999999999996)."""
    if not (math.isfinite(limit_per_s) and limit_per_s > 0):
        raise ValueError(f"a rate limit must be a positive number, got {limit_per_s}")
    counts = math.floor(limit_per_s * counts_per_unit + 1e-9)
    if counts > 0xFFFFFFFF:  # 0x6081 / 0x6083 / 0x6084 / 0x6085 are UNSIGNED32
        raise ValueError(f"a rate of {counts} counts does not fit UNSIGNED32")
    return counts


def from_counts(counts: int, counts_per_unit: float) -> float:
    """Drive counts -> joint value (deg or mm)."""
    return counts / counts_per_unit


# --- bus load -----------------------------------------------------------------------------
def frame_bits(dlc: int, *, extended: bool = False, stuffing: bool = True) -> int:
    """Bits one classic CAN data frame occupies on the wire, including the 3-bit interframe space.

    11-bit id: 44 + 8*dlc bits from start of frame to end of frame; worst-case bit stuffing adds
    one bit per 4 of the 34 + 8*dlc stuffable bits (the usual (34 + 8n - 1) / 4 bound).
    Extended ids add 20 bits (18 id bits, SRR, IDE).
    """
    if not 0 <= dlc <= 8:
        raise ValueError(f"classic CAN dlc is 0..8, got {dlc}")
    base, stuffable = (64, 54) if extended else (44, 34)
    bits = base + 8 * dlc
    if stuffing:
        bits += (stuffable + 8 * dlc - 1) // 4
    return bits + 3
