"""The cell's drives as one object: four SCARA axes and the gripper over CANopen.

    with Arm(bus, cell, clock) as arm:          # connect(): heartbeats, SDO set-up, enable
        sent = arm.move_joints(Joints(...))     # limits checked here, before any frame
        result = arm.gripper.grip(32.0)         # GripResult(width_mm, holding)
        arm.state()                             # per node: state, position, faults

Safety supervision, all in the host:
- every command is checked by `drivers.limits` first; a violation raises `LimitError` and
  nothing is sent;
- the host sends its own heartbeat and configures each drive (0x1016) to fault when it
  falls silent; it watches every node's heartbeat against a deadline (and the boot-up
  deadline at connect);
- EMCY frames, FAULT states, heartbeat timeouts, SDO failures, an error frame saying the host is off the
  bus (bus-off, transmit timeout, no ACK, error-passive) and a burst of other error frames (more than
  `can.error_frames_max` within `can.error_window_ms`; a sporadic one is counted, `drivers.errorframes`) latch a
  fault: the running move is quick-stopped on every axis, the error names the node and
  the reason, and nothing moves again until `reset_faults()`. So does an axis of the move
  that leaves OPERATION ENABLED without a fault (`DriveDisabled`: a quick stop or STO from
  the drive's side, another master), seen in its next TPDO1.

Here: the arm's state (`__init__`), connect, disconnect and the state report; the nodes' setup and enable are in
`drivers.arm_setup`, the supervision in `drivers.arm_supervision`, the moves in `drivers.arm_moves`.
"""

from __future__ import annotations

import logging
import math
import threading

import can
import canopen

from cell.cellconfig import HEARTBEAT_DEADLINE_FACTOR, HOST_POLL_MS
from drivers import codec
from drivers.arm_moves import Moves
from drivers.arm_setup import Setup
from drivers.arm_supervision import (
    FRAMES_MS,
    WATCH_MIN_PERIOD_S,
    WATCH_STARVED_PERIODS,
    WATCH_STARVED_SHARE,
    Supervision,
    to_each,
)
from drivers.axis import Axis
from drivers.clock import Clock, RealClock
from drivers.eds import eds_path, node_eds_file
from drivers.errorframes import ErrorFramePolicy, classes_readable
from drivers.errors import DriverError
from drivers.gripper import Gripper
from drivers.pump import BusPump

log = logging.getLogger(__name__)


class Arm(Setup, Supervision, Moves):
    """The SCARA arm and the gripper on a CAN bus made by the caller (see `drivers.open_bus`).

    Parameters
    ----------
    bus : can.BusABC
        Never created nor shut down here.
    cell : cell.cellconfig.Cell, optional
        Joint limits, speeds, workspace, gripper and CAN node table (default: the shipped cell).
    clock : Clock, optional
        Share a `SimClock` with `drivers.sim.serve` for simulated time; default wall time.
    sdo_timeout_s : float
        Wall time an SDO answer may take (canopen retries once).
    error_frames_max, error_window_ms : int, optional
        More than this many error frames within this window (on `clock`) latch a bus fault; default the cell
        file's `can.error_frames_max` / `can.error_window_ms`. Bus-off, transmit timeout, no ACK and
        error-passive latch at once (`drivers.errorframes`).
    """

    def __init__(
        self,
        bus: can.BusABC,
        cell=None,
        clock: Clock | None = None,
        *,
        sdo_timeout_s: float = 0.3,
        boot_timeout_s: float | None = None,
        error_frames_max: int | None = None,
        error_window_ms: int | None = None,
        poll_s: float = HOST_POLL_MS / 1000.0,
    ):
        if cell is None:
            from cell.cellconfig import default_cell

            cell = default_cell()
        self.bus, self.cell = bus, cell
        self._own_clock = clock is None
        self.clock = clock or RealClock()
        self.sdo_timeout_s = sdo_timeout_s
        hb_s = cell.can.heartbeat_ms / 1000.0
        self.heartbeat_deadline_s = HEARTBEAT_DEADLINE_FACTOR * hb_s
        self.boot_timeout_s = boot_timeout_s if boot_timeout_s is not None else max(1.0, 5 * hb_s)
        self._error_policy = ErrorFramePolicy(
            cell.can.error_frames_max if error_frames_max is None else error_frames_max,
            cell.can.error_window_ms if error_window_ms is None else error_window_ms,
            classes_readable(bus),
        )
        if not 0 < poll_s * 1000.0 <= cell.can.stop_lag_ms - FRAMES_MS:
            # during a move the host answers one axis stopping on its own within a poll and the frames' time:
            # the way check (drivers.limits) follows the other axes on their way that long
            raise ValueError(f"poll_s = {poll_s} s: must be more than 0 and, with {FRAMES_MS:g} ms "
                             f"for the frames, no more than can.stop_lag_ms = {cell.can.stop_lag_ms:g} ms (the host "
                             "stops the other axes within a poll of one stopping on its own)")
        self.poll_s = poll_s
        self._watch_period_s = max(poll_s, WATCH_MIN_PERIOD_S)
        self._watch_starved_s = max(WATCH_STARVED_SHARE * self.heartbeat_deadline_s,
                                    WATCH_STARVED_PERIODS * self._watch_period_s)
        self.axes: dict[str, Axis] = {}
        self.gripper = Gripper(self)
        self._faults: dict[str, DriverError] = {}
        self._stops = 0  # stops latched so far (`_latch`)
        self._lock = threading.Lock()
        self._watch_lock = threading.Lock()  # one `_watch` at a time
        # the host's looks at the drives during moves (`look_timing`): the way check's stop model assumes
        # one within can.stop_lag_ms less the frames' time of any drive stopping on its own
        self._move_no, self._last_look = 0, (-1, 0.0)  # (the move it was in, when)
        self._looks = {"looks": 0, "late": 0, "worst_gap_s": 0.0}
        self._emcy_seen: dict[str, int] = {}
        self._network: canopen.Network | None = None
        self._pump: BusPump | None = None
        self._jobs: list = []
        self._velocity_counts: dict[str, int] = {}
        self._connected = False
        self._pending: tuple[dict, float] = ({}, 0.0)
        self._move_seqs: dict[str, int] = {}  # each axis' status_seq when the last command began
        self.state_at_failure: dict | None = None
        self._watched_s: float | None = None  # when the watchdog last ran
        self._silence_from_s = -math.inf  # silence before this (a held-up watchdog) is not counted

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self, *, enable: bool = True) -> None:
        """Bring every node up: boot-up/heartbeat deadline, SDO set-up (PDOs, quick stop and fault
        reaction option codes, heartbeats both ways, software limits, profile parameters), NMT start,
        and (unless `enable=False`) the 402 state machine to OPERATION ENABLED with target = actual
        position. A drive that keeps other option codes is logged (`drivers.option_codes`)."""
        if self._connected:
            return
        self._network = canopen.Network(self.bus)
        for name, n in self.cell.can.nodes.items():
            eds = eds_path(node_eds_file(name))  # the object types; values are read from the drive
            self.axes[name] = Axis(
                name,
                n.node_id,
                str(eds),
                self._network,
                self.clock,
                n.counts_per_unit,
                n.unit,
                sdo_timeout_s=self.sdo_timeout_s,
            )
            self.axes[name].move_gate = self._unless_latched
            self.axes[name].enable_gate = self._unless_stopped
        self._pump = BusPump(self.bus, [self._network.listeners[0], self._on_frame], name="arm-rx")
        self.clock.add_settler(self._pump.settle)
        host_period_s = self.cell.can.host_heartbeat_ms / 1000.0
        self._host_job = self.clock.every(host_period_s, self._send_host_heartbeat, name="host-heartbeat")
        self._jobs.append(self._host_job)
        self._send_host_heartbeat()
        self._connected = True
        try:
            t0 = self.clock.now()
            for ax in self.axes.values():
                ax.wait_heartbeat(self.clock, self.boot_timeout_s, self.poll_s, start_s=t0)
            for ax in self.axes.values():
                self._configure(ax)
            # CiA 301: a drive watches the host from the first heartbeat it hears after 0x1016 is set: start
            # every watch now, not a period later (a host gone meanwhile would never be noticed)
            self._send_host_heartbeat()
            self._start(list(self.axes.values()))
            self._stop_what_was_left_running()
            self._jobs.append(self.clock.every(self._watch_period_s, self._watch, name="arm-watchdog"))
            if enable:
                self._enable_all()
        except BaseException:
            self.state_at_failure = self.state()
            self.disconnect()
            raise

    def _stop_what_was_left_running(self) -> None:
        """A drive found in OPERATION ENABLED at connect was left so by another host: one that died and came back
        within the drives' host-heartbeat deadline, or another master. It may still run that host's move, or hold
        a set-point under halt that the next controlword starts: taken as enabled and idle, the first command was
        checked from a snapshot mid-move and the axis first ran on to the old target. Such drives are
        quick-stopped (that discards their set-points) and, once every axis stands, enabled afresh by the
        usual walk."""
        left = [ax.name for ax in self.axes.values() if ax.state == "OPERATION_ENABLED"]
        if left:
            log.warning("%s found enabled at connect (left so by another host): quick-stopped before anything else",
                        ", ".join(left))
            self._stop_all()

    def disconnect(self) -> None:
        """Disable the drives cleanly (they hold no torque and stop watching the host), stop
        the host heartbeat and the receive thread. The bus stays open. A move still running (one
        sent without waiting, or left by an error while it ran) is quick-stopped first: a drive
        told to shut down mid-move may let its axis coast (0x605B), so it stops on its ramp."""
        if not self._connected:
            return
        def shut_down(ax: Axis) -> None:  # (a node that cannot be told is stopped by its host-heartbeat watch)
            ax.disable()
            ax.sdo_write(0x1016, 1, 0)

        try:
            if self._pending[0] or any(self._moving(ax) for ax in self.axes.values()):
                self._stop_all()
            to_each([ax for ax in self.axes.values()
                      if ax.last_heartbeat_s is not None and self._faults.get(ax.name) is None], shut_down)
        finally:
            for job in self._jobs:
                job.cancel()
            self._jobs.clear()
            if self._pump is not None:
                self.clock.remove_settler(self._pump.settle)
                self._pump.stop()
            for ax in self.axes.values():
                ax.detach()
            self.axes.clear()
            self._connected = False
            if self._own_clock:
                self.clock.close()

    def __enter__(self) -> Arm:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.disconnect()

    def state(self) -> dict[str, dict]:
        """Per node: name, node_id, state (CiA 402 name), position (deg or mm), unit, nmt,
        fault (latched reason or None), emcy ({code, text} of the last EMCY or None)."""
        out = {}
        faults = self.faults
        now = self.clock.now()
        for name, n in self.cell.can.nodes.items():
            ax = self.axes.get(name)
            e = ax.last_emcy if ax is not None else None
            out[name] = {
                "name": name,
                "node_id": n.node_id,
                "state": ax.state if ax is not None else "UNKNOWN",
                "position": ax.position if ax is not None else None,
                "unit": n.unit,
                "nmt": codec.NMT_STATE_NAMES.get(ax.nmt_state, "UNKNOWN")
                if ax and ax.nmt_state is not None
                else "UNKNOWN",
                "heartbeat_age_s": (now - ax.last_heartbeat_s) if ax and ax.last_heartbeat_s is not None else None,
                "fault": faults.get(name),
                "emcy": {"code": e.code, "text": e.text} if e is not None else None,
            }
        return out
