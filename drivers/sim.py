"""Simulated CiA 402 drives of the cell (j1-j4 and the gripper) that answer on a real CAN bus.

`serve(bus, cell=None, clock=None)` puts five CANopen nodes on a python-can bus made by the
caller. Each node is a `canopen.LocalNode` (its SDO server and object dictionary come from
the shipped EDS file) plus the drive logic here: NMT with boot-up and heartbeat, the 402
state machine with faults, profile position with the set-point handshake (a target without
the rising edge of controlword bit 4 never moves), trapezoidal motion in the clock's time,
statusword/position/mode in TPDO1 (on change and on the event timer), EMCY on faults, a
consumer heartbeat on the host (the drive faults when the host falls silent), software
position limits (0x607D) as a second line of defence, and a gripper that stops on a part
of a given width or closes fully when there is none.

Fault injection (`SimHandle.inject_fault`) covers: a silent node, an EMCY during a move, a
following error, dropped SDO answers, error frames on the bus (of a given class, as SocketCAN
presents them), a drive leaving OPERATION ENABLED without a fault (its own quick stop,
STO), and a drive that reboots (a power glitch). Faults latch in the drive until a fault reset (controlword
bit 7 rising edge), as on a real drive.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import threading
import weakref
from pathlib import Path

import can
import canopen

from drivers import errorframes as ef
from drivers.clock import Clock, RealClock
from drivers.eds import eds_path, node_eds_file, render_eds
from drivers.pump import BusPump
from drivers.simdrive import FAULT_KINDS, TPDO_EVENT_MS, SimDrive, SimGripper, power_on_values

TICK_S = 0.01  # motion and timer resolution of the simulated drives (TPDO1 at most 100 Hz)
# Error frames as the Linux CAN drivers make them (linux/can/error.h: the class in the id, details in 8 data
# bytes) and python-can's SocketCAN interface hands them on (CAN_ERR_FLAG stripped, a standard id, dlc 8):
# class bits, data. The error counters (CAN_ERR_CNT, data[6] tx, data[7] rx) as a controller would hold them.
_PROT_BIT_IN_DATA = (0, 0, 0x01, 0x0A, 0, 0, 8, 0)  # a single bit error (data[2]) in the data field (data[3])
ERROR_FRAMES = {
    "bus_error": (ef.CAN_ERR_PROT | ef.CAN_ERR_BUSERROR | ef.CAN_ERR_CNT, _PROT_BIT_IN_DATA),
    "error_warning": (ef.CAN_ERR_CRTL | ef.CAN_ERR_CNT, (0, ef.CAN_ERR_CRTL_TX_WARNING, 0, 0, 0, 0, 96, 0)),
    "error_passive": (ef.CAN_ERR_CRTL | ef.CAN_ERR_CNT, (0, ef.CAN_ERR_CRTL_TX_PASSIVE, 0, 0, 0, 0, 128, 0)),
    "back_to_error_active": (ef.CAN_ERR_CRTL | ef.CAN_ERR_CNT, (0, ef.CAN_ERR_CRTL_ACTIVE, 0, 0, 0, 0, 90, 0)),
    "bus_off": (ef.CAN_ERR_BUSOFF | ef.CAN_ERR_CNT, (0, 0, 0, 0, 0, 0, 255, 0)),
    "restarted": (ef.CAN_ERR_RESTARTED, (0,) * 8),
    "tx_timeout": (ef.CAN_ERR_TX_TIMEOUT, (0,) * 8),
    # a missed ACK comes as a bus error of the ACK slot (flexcan, m_can)
    "no_ack": (ef.CAN_ERR_ACK | ef.CAN_ERR_PROT | ef.CAN_ERR_BUSERROR, (0, 0, 0, ef.CAN_ERR_PROT_LOC_ACK, 0, 0, 0, 0)),
    "lost_arbitration": (ef.CAN_ERR_LOSTARB, (3, 0, 0, 0, 0, 0, 0, 0)),  # data[0]: the bit it was lost in
    "unclassified": (0, (0,) * 8),  # as an interface that gives no class would (Kvaser: the flag alone)
}


def error_frame(error_class: str) -> can.Message:
    """An error frame of one of ERROR_FRAMES, as python-can's SocketCAN interface hands it on."""
    if error_class not in ERROR_FRAMES:
        raise ValueError(f"unknown error frame class {error_class!r}; one of {sorted(ERROR_FRAMES)}")
    cls, data = ERROR_FRAMES[error_class]
    return can.Message(is_error_frame=True, arbitration_id=cls, is_extended_id=False, data=bytes(data), dlc=8)


def node_settings(cell, name: str, tpdo_event_ms: int = TPDO_EVENT_MS) -> dict:
    """The keyword arguments of node `name`'s `SimDrive` (`SimGripper`) for `cell`: its counts, the
    cell file's limits and rates, where it stands at power-on."""
    n = cell.can.nodes[name]
    common = dict(counts_per_unit=n.counts_per_unit, heartbeat_ms=cell.can.heartbeat_ms, tpdo_event_ms=tpdo_event_ms)
    if name == "gripper":
        g = cell.gripper
        return dict(limits=g.opening_mm, velocity=g.speed_mm_s, acceleration=10 * g.speed_mm_s,
                    position=g.opening_mm[1], grip_force_n=g.grip_force_n, **common)
    s, home = cell.scara, cell.motion.home_joints
    start = {"j1": home["j1_deg"], "j2": home["j2_deg"], "j3": home["j3_mm"], "j4": home["j4_deg"]}
    return dict(limits=s.limits(name), velocity=s.max_velocity[name], acceleration=s.max_acceleration[name],
                position=start[name], **common)


def node_eds_text(cell, name: str, tpdo_event_ms: int = TPDO_EVENT_MS) -> str:
    """The EDS of node `name` in `cell`: its DefaultValues are what the node holds at power-on and after
    the NMT resets."""
    settings = node_settings(cell, name, tpdo_event_ms)
    settings.pop("position")
    return render_eds(name == "gripper", power_on_values(**settings), name)


def node_eds_paths(cell, tpdo_event_ms: int = TPDO_EVENT_MS) -> dict[str, Path]:
    """Node name -> the path of its EDS: the shipped files for the shipped cell; for another cell (other
    limits, rates, heartbeat) files of its own, written once into a folder under the temporary directory
    named by their content."""
    texts = {name: node_eds_text(cell, name, tpdo_event_ms) for name in cell.can.nodes}
    shipped = {name: eds_path(node_eds_file(name)) for name in texts}
    if all(shipped[name].read_text(encoding="utf-8") == text for name, text in texts.items()):
        return shipped
    digest = hashlib.sha256("\n".join(f"{n}\n{t}" for n, t in sorted(texts.items())).encode()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / f"drivers-eds-{os.getuid()}" / digest
    paths = {name: folder / node_eds_file(name) for name in texts}
    for name, text in texts.items():
        path = paths[name]
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder / f".{path.name}.{os.getpid()}.{threading.get_ident()}"
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, path)  # atomic: another process serving the same cell reads a whole file
    return paths


class SimHandle:
    """The running simulated cell drives; a context manager (leaving it stops them)."""

    def __init__(self, bus: can.BusABC, cell, clock: Clock | None, tick_s: float, tpdo_event_ms: int):
        self.bus = bus
        self.cell = cell
        self._own_clock = clock is None
        self.clock = clock or RealClock()
        self.network = canopen.Network(bus)
        self.drives: dict[str, SimDrive] = {}
        eds = node_eds_paths(cell, tpdo_event_ms)
        for name, n in cell.can.nodes.items():
            cls = SimGripper if name == "gripper" else SimDrive
            settings = node_settings(cell, name, tpdo_event_ms) | {"tick_ms": math.ceil(tick_s * 1000 - 1e-9)}
            d = cls(name, n.node_id, str(eds[name]), self.network, self.clock, **settings)
            self.drives[name] = d
        self.nodes = [{"node_id": d.node_id, "name": name, "eds": d.eds} for name, d in self.drives.items()]
        self.pump = BusPump(bus, [self.network.listeners[0]], name="sim-drives-rx")
        self.clock.add_settler(self.pump.settle)
        for d in self.drives.values():
            d.boot()
        self._job = self.clock.every(tick_s, self._tick, name="sim-drives")
        self._closed = False

    def _tick(self) -> None:
        now = self.clock.now()
        for d in self.drives.values():
            d.step(now)

    @property
    def gripper_object_width_mm(self) -> float | None:
        """Width of the part between the jaws (set by the simulated world); None = no part."""
        return self.drives["gripper"].object_width_mm

    @gripper_object_width_mm.setter
    def gripper_object_width_mm(self, width_mm: float | None) -> None:
        self.drives["gripper"].object_width_mm = None if width_mm is None else float(width_mm)

    def inject_fault(self, kind: str, node: str | None = None, **kw) -> None:
        """Make the simulated cell misbehave.

        kind : 'silent' (node stops sending and hearing), 'emcy' (the node faults with EMCY
            `code`, default 0x2310 over-current; with `after_s`, that many seconds into its
            next move), 'following_error' (the axis jams `after_s` into its next move, default
            at once; the drive faults with EMCY 0x8611 and statusword bit 13 when the demand
            leaves the following error window 0x6065),
            'quick_stop' (the drive quick-stops on its own, as by its quick stop input: transition
            11 as 0x605A says, no fault), 'disable' (STO: the drive function off at once, SWITCH
            ON DISABLED, the axis coasts, no fault), 'internal_limit' (the move ends where the axis
            is, with statusword bits 10 and 11, as on a limit switch or a torque limit, no fault), 'reboot'
            (a power glitch: the drive's own reset to its power-on values, its boot-up message, PRE-OPERATIONAL,
            the axis no longer driven; `auto_start=True`: it then starts itself, NMT OPERATIONAL); all,
            like 'emcy', at once or `after_s` into the next move,
            'drop_sdo' (the next `count` SDO answers are lost; default all, until `heal`),
            'error_frames' (`count` error frames on the bus, default 3, of `error_class`, default 'bus_error':
            one of ERROR_FRAMES, as SocketCAN presents them through python-can; no node needed).
        """
        if kind == "error_frames":
            frame = error_frame(kw.get("error_class", "bus_error"))
            for _ in range(int(kw.get("count", 3))):
                self.bus.send(frame)
            return
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {kind!r}; one of {FAULT_KINDS}")
        self._check_node(node, all_allowed=False)
        self.drives[node].arm(kind, **kw)

    def _check_node(self, node: str | None, *, all_allowed: bool = True) -> None:
        """A misspelt node would make a test's misbehaviour (or its cure) silently apply to nobody."""
        if not (node in self.drives or (all_allowed and node is None)):
            raise ValueError(f"unknown node {node!r}; one of {sorted(self.drives)}")

    def configure_option_codes(self, node: str | None = None, **kw) -> None:
        """Drives of another make (all nodes, or one): factory option codes, the values they take by
        SDO, objects they lack; see `SimDrive.configure_option_codes`."""
        self._check_node(node)
        for name, d in self.drives.items():
            if node in (None, name):
                d.configure_option_codes(**kw)

    def heal(self, node: str | None = None) -> None:
        """Undo injected misbehaviour (all nodes, or one); latched drive faults stay latched."""
        self._check_node(node)
        for name, d in self.drives.items():
            if node in (None, name):
                d.heal()

    def positions(self) -> dict[str, float]:
        return {name: d.position() for name, d in self.drives.items()}

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._job.cancel()
        self.clock.remove_settler(self.pump.settle)
        self.pump.stop()
        if self._own_clock:
            self.clock.close()

    def __enter__(self) -> SimHandle:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def serve(
    bus: can.BusABC,
    cell=None,
    clock: Clock | None = None,
    *,
    tick_s: float = TICK_S,
    tpdo_event_ms: int = TPDO_EVENT_MS,
) -> SimHandle:
    """Start the simulated drives of `cell` (default: the shipped cell) on `bus`.

    With no clock, motion runs in real time in a background thread (`RealClock`); pass a
    `drivers.clock.SimClock` shared with the master for fast deterministic runs. The bus
    stays the caller's: leaving the handle stops the drives but does not shut the bus down.
    `cell` may also be the path of a cell file (read and validated as `--cell FILE` is).
    """
    from cell.cellconfig import Cell

    if cell is None:
        from cell.cellconfig import default_cell

        cell = default_cell()
    elif isinstance(cell, (str, os.PathLike)):
        from cell.cellconfig import load_cell

        cell = load_cell(cell)
    elif not isinstance(cell, Cell):
        raise TypeError(f"serve(bus, cell): cell must be None (the shipped cell), a cell file's path or a "
                        f"cell.cellconfig.Cell, not {type(cell).__name__}")
    if any(h.bus is bus and not h._closed for h in _SERVING):  # two sets of nodes with the same ids on one bus
        raise RuntimeError("the simulated drives are already served on this bus: leave that handle first")
    handle = SimHandle(bus, cell, clock, tick_s, tpdo_event_ms)
    _SERVING.add(handle)
    return handle


_SERVING: weakref.WeakSet = weakref.WeakSet()  # the handles serve() started (dropped once unreferenced)
