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
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time

import can
import canopen

from cell.cellconfig import (
    HEARTBEAT_DEADLINE_FACTOR,
    HOST_POLL_MS,
    MIN_STOP_LAG_MS,
    QUICK_STOP_DECEL_FACTOR,
    grip_force_units,
)
from cell.kinematics import Joints, forward
from drivers import codec
from drivers.axis import Axis
from drivers.clock import Clock, RealClock
from drivers.eds import GRIP_FORCE_INDEX, eds_path, node_eds_file
from drivers.errorframes import ErrorFramePolicy, classes_readable
from drivers.errors import (
    BusFault,
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
from drivers.gripper import GRIPPER_ACCEL_FACTOR, Gripper
from drivers.limits import JOINT_FIELDS, command_violations
from drivers.profile import coordinated_move_s, coordinated_path, velocity_for_duration
from drivers.pump import BusPump

log = logging.getLogger(__name__)

HOST_NODE_ID = 0x7F  # the host's own heartbeat id (the drives watch it)
# A watchdog run this much of a deadline after the previous one, and this many of its periods, was itself
# held up (a loaded machine, a long pause of the process): heartbeats that arrived meanwhile may still be
# queued behind it, so silence is counted from that run on, not from the last heartbeat handled. (The
# share alone took every run for a held-up one where a poll is half a deadline or more: no node was ever
# found silent.)
WATCH_STARVED_SHARE = 0.5
WATCH_STARVED_PERIODS = 3
WATCH_MIN_PERIOD_S = 0.005
FRAMES_MS = MIN_STOP_LAG_MS - HOST_POLL_MS  # of the stop lag, the frames' time (the status in, the quick stops out)
POSITION_TOLERANCE_COUNTS = 2
# wall time an axis gets to show it started at the halt's release (its answer takes ms; meanwhile the axes
# released before it run)
START_CONFIRM_S = 0.2
QUICK_STOP_CONFIRM_S = 0.2  # wall time a drive gets to confirm a quick stop (it stops on its own when the host is gone)
STANDSTILL_MARGIN_S = 2.0  # waiting for standstill after a stop: this much past the slowest quick stop ramp
TPDO_EVENT_TIMER_MS = 50  # status at least every 50 ms when nothing changes (the watch sees a stuck drive)


def _to_each(axes, act) -> None:
    """act(ax) for every axis, whatever happens at one: a bus or drive error there is passed over (the others
    matter more), and an interrupt (Ctrl-C between two quick stops, or while one drive is told to shut down)
    goes up once every other axis has had its turn."""
    surprise = None
    for ax in axes:
        try:
            act(ax)
        except (can.CanError, DriverError):
            pass
        except BaseException as e:
            surprise = surprise or e
    if surprise is not None:
        raise surprise


# mm or deg: a drive at rest this far past a joint limit (a home at the limit, settled a few counts past it) is
# enabled holding the limit; further out it is not enabled
SETTLED_PAST_LIMIT = 0.5


class Arm:
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

    # --- lifecycle -------------------------------------------------------------------------
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

    def _start(self, axes: list[Axis]) -> None:
        """NMT start, then wait for each node's first status and a heartbeat saying OPERATIONAL: from then on a
        heartbeat saying anything else is a fault (`Axis.lost_setup`)."""
        for ax in axes:
            ax.nmt(codec.NMT_START)
        for ax in axes:
            ax.wait_status(lambda s: True, None, "first TPDO after NMT start")
            ax.wait_nmt(self.clock, codec.NMT_OPERATIONAL, self.boot_timeout_s, self.poll_s)
            ax.started = True

    def _configure(self, ax: Axis) -> None:
        """Everything the host sets up in a node (SDO), and the host's record of what it wrote there."""
        c = self.cell
        # a boot-up message from here on is a reboot: what follows would be lost (`Axis.lost_setup`)
        ax.boots_at_setup, ax.started = ax.boot_count, False
        device_type = ax.sdo_read(0x1000)
        if device_type & 0xFFFF != 402:
            raise DriveFault(
                f"{ax.name} (node {ax.node_id}) is not a CiA 402 drive (0x1000 = 0x{device_type:08X})",
                node=ax.name,
                node_id=ax.node_id,
            )
        if ax.sdo_read(0x6502) & codec.SUPPORTED_MODES_PP == 0:
            raise DriveFault(
                f"{ax.name} (node {ax.node_id}) does not support profile position mode",
                node=ax.name,
                node_id=ax.node_id,
            )
        ax.setup_pdos(TPDO_EVENT_TIMER_MS)
        for warning in ax.setup_option_codes():  # 0x6007 = 1, 0x605A = 6, 0x605E = 2
            log.warning("%s", warning)
        ax.sdo_write(0x1017, 0, c.can.heartbeat_ms)
        deadline_ms = round(HEARTBEAT_DEADLINE_FACTOR * c.can.host_heartbeat_ms)
        ax.sdo_write(0x1016, 1, codec.consumer_heartbeat_entry(HOST_NODE_ID, deadline_ms))
        if ax.name == "gripper":
            lo, hi = c.gripper.opening_mm
            velocity, accel = c.gripper.speed_mm_s, GRIPPER_ACCEL_FACTOR * c.gripper.speed_mm_s
            ax.sdo_write(GRIP_FORCE_INDEX, 0, grip_force_units(c.gripper.grip_force_n))
            self.gripper._force_n = c.gripper.grip_force_n
        else:
            lo, hi = c.scara.limits(ax.name)
            velocity, accel = c.scara.max_velocity[ax.name], c.scara.max_acceleration[ax.name]
        ax.sdo_write(0x607D, 1, ax.to_counts(lo))
        ax.sdo_write(0x607D, 2, ax.to_counts(hi))
        # rounded down: never past the cell file's limits (the cell file is refused where they are under a count)
        v = codec.rate_counts_within(velocity, ax.counts_per_unit)
        ax.sdo_write(0x6081, 0, v)
        self._velocity_counts[ax.name] = v
        a = codec.rate_counts_within(accel, ax.counts_per_unit)
        ax.sdo_write(0x6083, 0, a)
        ax.sdo_write(0x6084, 0, a)
        ax.sdo_write(0x6085, 0, max(1, round(QUICK_STOP_DECEL_FACTOR * accel * ax.counts_per_unit)))

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

    def enable(self) -> None:
        """Enable every drive, holding where it stands: the `connect(enable=False)` session's second half, for a
        host that asks the operator before the motors hold torque. A drive in FAULT or standing outside its
        limits is not enabled; its fault is latched and raised here."""
        self._require_connected()
        self._enable_all()
        with self._lock:
            refused = next(iter(self._faults.values()), None)
        if refused is not None:
            raise refused

    def require_enableable(self) -> None:
        """Raise FaultLatched (nothing sent) naming every drive `enable()` would not enable: one in FAULT, one
        standing past its limits. A host that asks the operator first says so before the question, not after
        the yes with the other drives holding torque."""
        self._require_connected()
        refused = {ax.name: str(err) for ax in self.axes.values() if (err := self._enable_refusal(ax)) is not None}
        if refused:
            raise FaultLatched(refused)

    def _enable_all(self) -> None:
        """Enable every drive. A drive found in FAULT (say, after a host crash) is not reset
        here: its fault is latched with its error code, and only `reset_faults()` clears it."""
        for ax in self.axes.values():
            err = self._enable_refusal(ax)
            if err is not None:
                self._latch(err)
                continue
            ax.enable(STANDSTILL_MARGIN_S + self._slowest_quick_stop_s(), self.poll_s, self._enable_hold(ax)[0])

    def _enable_refusal(self, ax: Axis) -> DriveFault | None:
        """Why `ax` is not to be enabled (None: it may be): in FAULT, with its error code; or standing outside its
        limits (`_enable_hold`); or without the setup the host gave it (rebooted: `reset_faults` sets it up again).
        """
        lost = self._lost_setup_fault(ax)
        if lost is not None:
            return lost
        if ax.state == "FAULT":
            code = ax.sdo_read(0x603F)
            return DriveFault(f"{ax.name} (node {ax.node_id}): in FAULT, error code 0x{code:04X} "
                              f"{codec.emcy_text(code)}", node=ax.name, node_id=ax.node_id, emcy_code=code)
        _, outside = self._enable_hold(ax)
        if outside:  # enabling sends the axis' position as its target: not one outside its limits
            return DriveFault(f"{ax.name} (node {ax.node_id}): {outside}; not enabled: move it back inside by hand "
                              "(brake released), then reset", node=ax.name, node_id=ax.node_id)
        return None

    def _enable_hold(self, ax: Axis):
        """(the target a drive is enabled with, for its position in counts; why it is not enabled). Its position,
        within the joint's limits (the gripper: its opening's range); a drive at rest up to SETTLED_PAST_LIMIT past
        one (a few counts past a home at the limit) is enabled holding the limit. Further out it coasted there (safe
        torque off, a jam, power lost mid-move: J1 stopped at 146 deg of 132) and is not enabled: its position would
        be sent as its target."""
        gripper = ax.name == "gripper"
        # the gripper: its opening's range (jaws found at 85 mm of 80 were held at 85), and held at the end of it
        # however far out: the jaws moving by a few mm is no danger, and jaws pressed past 0 kept the arm off
        lo, hi = self.cell.gripper.opening_mm if gripper else self.cell.scara.limits(ax.name)
        if ax.status is None:
            ax.wait_status(lambda s: True, None, "first TPDO")
        cpu = ax.counts_per_unit
        value = ax.status.position_counts / cpu
        if gripper or lo - SETTLED_PAST_LIMIT <= value <= hi + SETTLED_PAST_LIMIT:
            lo_c, hi_c = math.ceil(lo * cpu), math.floor(hi * cpu)
            return (lambda counts: min(max(counts, lo_c), hi_c)), None
        return None, f"stands at {value:.3f} {ax.unit}, outside its limits [{lo:g}, {hi:g}]"

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
            _to_each([ax for ax in self.axes.values()
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

    # --- supervision -----------------------------------------------------------------------
    def _send_host_heartbeat(self) -> None:
        if self._network is not None:
            try:
                self._network.send_message(codec.HEARTBEAT_BASE + HOST_NODE_ID,
                                           codec.pack_heartbeat(codec.NMT_OPERATIONAL))
            except can.CanError as e:  # latched (the next check stops the arm), not raised in the clock's job
                self._latch(BusFault(f"bus: sending the host heartbeat failed: {e}"), key="bus")

    def _on_frame(self, msg: can.Message) -> None:
        if not msg.is_error_frame:
            return
        with self._lock:
            reason = self._error_policy.observe(msg, self.clock.now())
            latched = "bus" in self._faults
            if reason is not None and not latched:
                self._faults["bus"] = BusFault(reason)
            last = self._error_policy.last
            error = last.is_error
            text = reason or f"bus: error frame {last.text} ({'counted' if error else 'seen, not counted'})"
        if not latched:  # after the latch a disturbed bus may flood: the count goes on, the log stops
            # (lost arbitration is how CAN shares the bus: a healthy bus may show it between every two frames)
            log.log(logging.WARNING if reason or error else logging.DEBUG, "%s", text)

    @property
    def error_frames(self) -> int:
        """Error frames heard since the arm was made (a reset does not clear them: each stays visible)."""
        with self._lock:
            return self._error_policy.total

    def bus_state(self) -> dict:
        """The bus as the host sees it: error frames in all and per class (can-utils' names), in the window
        now, the window's limits, the last one's text, and the bus fault latched (or None)."""
        with self._lock:
            out = self._error_policy.summary(self.clock.now())
            fault = self._faults.get("bus")
        return {**out, "fault": None if fault is None else str(fault)}

    def _watch(self, stops: bool = False) -> None:
        """Periodic check of every node: heartbeat deadline, EMCY, FAULT state; and the host's receiving. One
        look at a time (the watchdog's job and a waiting command both look): a look that finds an EMCY already
        marked seen by the other, still on its way to latching it, would otherwise pass it for a poll. stops: a
        look after which the host stops the axes on what it found (a waiting command's; the watchdog's only
        latches), timed for `look_timing`."""
        with self._watch_lock:
            now = self.clock.now()
            if stops:
                self._time_look(now)
            self._look(now)

    def _look(self, now: float) -> None:
        if self._pump is not None and self._pump.errors:  # the receive thread ended: the host hears nothing
            self._latch(BusFault(f"bus: receiving failed: {self._pump.errors[0]}"), key="bus")
        with self._lock:
            if self._watched_s is not None and now - self._watched_s > self._watch_starved_s:
                self._silence_from_s = now
            self._watched_s = now
            silence_from_s = self._silence_from_s
        for ax in list(self.axes.values()):
            # first: a rebooted node's stale status and its EMCY are not the cause
            err: DriverError | None = self._lost_setup_fault(ax)
            if ax.emcy_seq != self._emcy_seen.get(ax.name, 0):
                self._emcy_seen[ax.name] = ax.emcy_seq
                e = ax.last_emcy
                if err is None and e is not None and e.code != 0:
                    err = DriveFault(
                        f"{ax.name} (node {ax.node_id}): EMCY 0x{e.code:04X} {e.text}",
                        node=ax.name,
                        node_id=ax.node_id,
                        emcy_code=e.code,
                    )
            if err is None and ax.state in ("FAULT", "FAULT_REACTION_ACTIVE"):
                err = DriveFault(
                    f"{ax.name} (node {ax.node_id}): {ax.fault_text()}",
                    node=ax.name,
                    node_id=ax.node_id,
                    emcy_code=ax.last_emcy.code if ax.last_emcy else None,
                )
            if err is None and ax.name in self._pending[0]:
                err = self._left_operation(ax, "during a move", self._move_seqs.get(ax.name))
            if (
                err is None
                and ax.last_heartbeat_s is not None
                and now - max(ax.last_heartbeat_s, silence_from_s) > self.heartbeat_deadline_s
            ):
                err = NodeSilent(
                    f"{ax.name} (node {ax.node_id}): no heartbeat for {now - ax.last_heartbeat_s:.3f} s "
                    f"(deadline {self.heartbeat_deadline_s:g} s){self._held_part_note()}",
                    node=ax.name,
                    node_id=ax.node_id,
                )
            if err is not None:
                self._latch(err)

    def _time_look(self, now: float) -> None:
        """Count the looks during a move and how long the host went without one (`look_timing`). Only a move's
        start and the wait for it look with `stops`: every such look is during one."""
        move, last_s = self._last_look
        if move == self._move_no:
            gap_s = now - last_s
            self._looks["looks"] += 1
            self._looks["late"] += gap_s > self._allowed_look_gap_s() + 1e-9  # (a poll of exactly the gap is on time)
            self._looks["worst_gap_s"] = max(self._looks["worst_gap_s"], gap_s)
        self._last_look = (self._move_no, now)

    def _allowed_look_gap_s(self) -> float:
        return (self.cell.can.stop_lag_ms - FRAMES_MS) / 1000.0

    def look_timing(self) -> dict:
        """How promptly the host looked at the drives during moves, counting the looks after which it stops the
        axes on what it found (waiting for a move or for its start; not the watchdog's, which only latch):
        looks (after a move's first), late (gaps longer than can.stop_lag_ms less FRAMES_MS: a drive stopping
        on its own then would have been answered later than the way check's stop model has it,
        `drivers.limits`), the worst gap and the allowed one (ms). A loaded host (Python keeps no deadline)
        shows here on a real clock; on a simulated one the gaps are the poll by construction."""
        with self._watch_lock:
            return {"looks": self._looks["looks"], "late": self._looks["late"],
                    "worst_gap_ms": round(1000.0 * self._looks["worst_gap_s"], 1),
                    "allowed_gap_ms": round(1000.0 * self._allowed_look_gap_s(), 1)}

    def _left_operation(self, ax: Axis, when: str, since_seq: int | None = None) -> DriverError | None:
        """An axis that left OPERATION ENABLED without a fault while the host still commands enable
        operation (a quick stop or STO from the drive's side, another master). During a move it will never
        arrive and the others must not go on alone; before one, the host's enable operation with the
        set-point would re-enable it (transition 16) behind that side's back. The host's own stops send
        another command. since_seq (the axis' status_seq when its move was commanded): also an axis that
        left since then and is enabled again, by the move's release or another master (transition 16
        drops the set-point: it stands while the others run). Also a drive whose mode of operation another master
        changed: the set-point bits mean other things there (bit 4 starts homing in mode 6). First of all, a node
        that lost its setup (rebooted: its status is stale, or says SWITCH ON DISABLED in mode 0)."""
        lost = self._lost_setup_fault(ax)
        if lost is not None:
            return lost
        st = ax.status
        if st is None or "FAULT" in st.state or codec.command_of(ax.controlword) != "ENABLE_OPERATION":
            return None
        if st.mode != codec.PP_MODE:
            return DriveFault(f"{ax.name} (node {ax.node_id}): its mode of operation (0x6061) is {st.mode} {when}, not "
                              f"profile position ({codec.PP_MODE}): changed by another master; no set-point is sent "
                              "in another mode", node=ax.name, node_id=ax.node_id)
        if st.state != "OPERATION_ENABLED":
            return DriveDisabled(
                f"{ax.name} (node {ax.node_id}): left OPERATION ENABLED {when} without a fault, now in "
                f"{st.state} (stopped from the drive's side: its quick stop input, STO or another master)",
                node=ax.name,
                node_id=ax.node_id,
                state=st.state,
            )
        left = ax.left_operation
        if since_seq is None or left is None or left[0] <= since_seq:
            return None
        return DriveDisabled(
            f"{ax.name} (node {ax.node_id}): left OPERATION ENABLED {when} (reported {left[1]}) and was enabled "
            "again without its set-point (transition 16: the move's release or another master): it stands while "
            "the others would run",
            node=ax.name,
            node_id=ax.node_id,
            state=left[1],
        )

    def _lost_setup_fault(self, ax: Axis) -> NodeRebooted | None:
        """The fault of a node that lost its setup (`Axis.lost_setup`), or None. Like a silent node it stops every
        axis; the reset sets it up again (`_set_up_again`). Before, only the heartbeats' timing was watched: a
        rebooted J2 coasted while J1 and J4 ran their whole moves, the host said "target not reached" a second
        later, and the reset enabled it without its host-heartbeat watch."""
        why = ax.lost_setup()
        if why is None:
            return None
        if ax.boot_count != ax.boots_at_setup:
            force = ", the grip force 0x2100" if ax.name == "gripper" else ""
            what = (f"its setup is lost, back at its power-on values (the host-heartbeat watch 0x1016, the software "
                    f"limits 0x607D, the option codes, the profile values{force}), and it no longer drives its axis")
        else:
            what = ("it takes no set-point and sends no status (another master's NMT command, or a reboot whose "
                    "boot-up message was lost)")
        return NodeRebooted(f"{why}: {what}; reset sets it up again as connect did{self._held_part_note()}",
                            node=ax.name, node_id=ax.node_id)

    def _held_part_note(self) -> str:
        """For a node lost while the jaws may hold a part: say so, and where the arm stood (as last heard), or ''."""
        width_mm = self.gripper.closed_on_mm
        if width_mm is None:
            return ""
        at = {joint: self.axes[joint].position for joint, _, _ in JOINT_FIELDS if joint in self.axes}
        if None in at.values() or len(at) != len(JOINT_FIELDS):
            return f"; a part may still be in the jaws (they closed on something at {width_mm:.1f} mm)"
        tool = forward(Joints(*at.values()), self.cell.scara)
        joints = ", ".join(f"{joint} {value:.1f} {self.axes[joint].unit}" for joint, value in at.items())
        return (f"; a part may still be in the jaws (they closed on something at {width_mm:.1f} mm); the arm stood "
                f"at {joints} (tool x {tool.x_mm:.1f}, y {tool.y_mm:.1f}, z {tool.z_mm:.1f} mm, as last heard)")

    def _latch(self, err: DriverError, key: str | None = None) -> None:
        """Remember the first fault per node ('bus' for the bus, 'stop' for an operator's stop). One already latched
        and raised again (a move's frame refused by `_unless_latched`) stays where it is."""
        with self._lock:
            key = key or err.node or "bus"
            self._stops += key == "stop"  # (each one: `reset_faults` clears only those latched before it began)
            if key not in self._faults and all(v is not err for v in self._faults.values()):
                self._faults[key] = err

    @contextlib.contextmanager
    def _unless_latched(self):
        """Held while a move's frame that enables operation goes out (`Axis.move_gate`): a fault latched meanwhile
        from another thread (the operator's stop, the watchdog) comes before the frame, which is then not sent (the
        fault is raised), or after it, and the stop's quick stops follow it on the bus. Before, a release already
        past the move's last look could re-enable (transition 16) an axis the operator's stop had just stopped."""
        with self._lock:
            if self._faults:
                raise next(iter(self._faults.values()))
            yield

    @contextlib.contextmanager
    def _unless_stopped(self):
        """Held while `Axis.enable` sends enable operation (`Axis.enable_gate`): not after a stop was latched (the
        operator's, an interrupt's), which leaves the axes in QUICK STOP ACTIVE until the next `reset_faults`.
        Other faults let the rest enable: at connect a drive found in FAULT is latched and the others enabled."""
        with self._lock:
            if "stop" in self._faults:
                raise self._faults["stop"]
            yield

    @property
    def faults(self) -> dict[str, str]:
        """Latched faults: node name (or 'bus') -> reason. Empty when all is well."""
        with self._lock:
            return {k: str(v) for k, v in self._faults.items()}

    def stop(self) -> None:
        """Quick-stop every enabled axis now (Ctrl-C, an operator's stop) and wait until they
        stand still. Latched like a fault: the drives stay in QUICK STOP ACTIVE (0x605A = 6, set at
        connect; a drive that kept 1 or 2 ends in SWITCH ON DISABLED) and commands are refused until
        `reset_faults()`, which enables them from either. A stop before the arm is connected (or while it
        connects, from another thread) is latched all the same, and `connect` then enables no axis (before, it
        was lost and every drive enabled)."""
        # latched first: a move starting in another thread meanwhile (the station's loop) is refused
        # instead of releasing axes this stop has stopped
        self._latch(DriverError("quick stop requested by the operator"), key="stop")
        if self._connected:
            self._stop_all()
            self._pending = ({}, 0.0)

    @staticmethod
    def _moving(ax) -> bool:
        """Enabled, its last statusword without target reached: a profile-position move runs."""
        return ax.state == "OPERATION_ENABLED" and ax.status is not None and not ax.status.target_reached

    def _stop_all(self) -> None:
        """Quick-stop every axis still enabled, then wait (on the clock) until all stand still. A faulted node
        gets the quick stop too, without waiting for its answer: one that only answered late (no set-point
        acknowledge within the wall-time bound, a starved host) holds the set-point controlword and would run
        its move alone once it takes it, after every other axis stopped. Every axis gets its quick stop
        first, back to back, and the confirmations are waited for after: the axes ramp down together (the
        way check's quick stops, `drivers.limits`), not one a round trip after the other."""
        sent = {}

        def quick_stop(ax: Axis) -> None:
            sent[ax.name] = ax.send_quick_stop()

        _to_each(self.axes.values(), quick_stop)
        for name, seq in sent.items():
            if seq is not None and name not in self._faults:
                try:
                    self.axes[name].confirm_quick_stop(seq, QUICK_STOP_CONFIRM_S)
                except (can.CanError, DriverError):
                    pass  # stopping the others matters more than this one's answer
        self._wait_standstill()

    def _wait_standstill(self, timeout_s: float | None = None) -> None:
        """Until no drive ramps any more: positions unchanged over a poll, no fault reaction, and every drive
        in QUICK STOP ACTIVE reporting the end of its ramp (statusword bit 10, CiA 402). A drive enables an
        axis only once it stands. By default up to STANDSTILL_MARGIN_S past the cell's slowest quick stop."""
        if timeout_s is None:
            timeout_s = STANDSTILL_MARGIN_S + self._slowest_quick_stop_s()
        deadline = self.clock.now() + timeout_s
        last = None
        while self.clock.now() < deadline:
            now = {n: (ax.status.position_counts if ax.status else None, ax.state) for n, ax in self.axes.items()}
            ramping = any(
                ax.state == "FAULT_REACTION_ACTIVE"
                or (ax.state == "QUICK_STOP_ACTIVE" and not ax.status.target_reached)
                for ax in self.axes.values()
            )
            if now == last and not ramping:
                return
            last = now
            self.clock.sleep(max(self.poll_s, 0.02))

    def _slowest_quick_stop_s(self) -> float:
        """The longest quick stop ramp of the cell: from max velocity at the quick stop deceleration (the
        gripper accelerates at GRIPPER_ACCEL_FACTOR x its speed, so it stops in 1 / (2 x 10) s)."""
        s = self.cell.scara
        ramps = [s.max_velocity[j] / (QUICK_STOP_DECEL_FACTOR * s.max_acceleration[j]) for j in s.max_velocity]
        return max(ramps + [1.0 / (QUICK_STOP_DECEL_FACTOR * GRIPPER_ACCEL_FACTOR)])

    def _check_faults(self, during_move: bool) -> None:
        with self._lock:
            faults = dict(self._faults)
        if not faults:
            return
        if during_move:
            self._stop_all()
            raise next(iter(faults.values()))
        raise FaultLatched({k: str(v) for k, v in faults.items()})

    def reset_faults(self) -> None:
        """Clear latched faults: fault-reset every faulted drive and enable all again. Raises
        (and stays latched) when a node is still silent or faults again, or when a stop (`stop()`, from another
        thread) comes meanwhile: the axes it stopped are not enabled again."""
        self._require_connected()
        with self._lock:
            stops_before = self._stops  # a stop latched during the reset is not cleared
        self._pending = ({}, 0.0)  # the move the fault ended is over (a move sent without waiting)
        self._watch()
        self._wait_standstill()  # a drive in its fault reaction finishes its ramp first
        for ax in self.axes.values():
            if ax.last_heartbeat_s is None or self.clock.now() - ax.last_heartbeat_s > self.heartbeat_deadline_s:
                # give a node that went quiet one deadline to show up again
                ax.last_heartbeat_s = None
                try:
                    ax.wait_heartbeat(self.clock, self.heartbeat_deadline_s, self.poll_s)
                except NodeSilent as e:
                    self._latch(e)
                    raise
        try:
            for ax in self.axes.values():
                if ax.lost_setup() is not None:
                    self._set_up_again(ax)
            for ax in self.axes.values():
                ax.fault_reset()
            with self._lock:
                stop = self._faults.get("stop")
                self._faults.clear()
                self._error_policy.restart_window()
                if self._stops != stops_before:  # pressed while the drives were reset: it stays, nothing is enabled
                    self._faults["stop"] = stop
                    raise stop
                for ax in self.axes.values():
                    self._emcy_seen[ax.name] = ax.emcy_seq
            self.enable()  # a drive not enabled (outside its limits, in FAULT again): latched, told
        except DriverError as e:
            self._latch(e)
            raise

    def _set_up_again(self, ax: Axis) -> None:
        """A node that lost its setup (`Axis.lost_setup`): all of it again, as connect does, then NMT start. Its
        power-on values need not be the cell's (its host-heartbeat watch was 0: J2 ran its move on when the host
        died); the host's record of what it wrote (profile velocity, grip force) is rewritten with it."""
        log.warning("%s: set up again (%s)", ax.name, ax.lost_setup())
        ax.forget_status()  # from before the reboot: the first after NMT start is the one to go by
        self._configure(ax)
        self._send_host_heartbeat()  # its host watch starts at the first heartbeat it hears (CiA 301)
        self._start([ax])

    # --- commands --------------------------------------------------------------------------
    def _begin_command(self) -> None:
        """Every command: connected, the previous move finished, no fault latched, every drive the host
        enabled still in OPERATION ENABLED."""
        self._require_connected()
        if self._pending[0]:
            self.wait_idle()
        self._check_faults(during_move=False)
        # every status after this that is not OPERATION ENABLED is the drive's side's doing (`_left_operation`):
        # taken before the look below, so that none slips in between it and the move's first frame
        self._move_seqs = {name: ax.status_seq for name, ax in self.axes.items()}
        for ax in self.axes.values():
            err = self._left_operation(ax, "while idle")
            if err is not None:
                self._latch(err)
                raise err  # nothing sent: the axes still enabled stand

    def _stop_on(self, err: DriverError) -> None:
        """A fault the host found itself (not at a look at the drives): latched, every axis stopped, raised."""
        self._latch(err)
        self._stop_all()
        raise err

    def _require_connected(self) -> None:
        if not self._connected:
            raise NotConnected("the arm is not connected: call connect() first")

    def joints(self) -> Joints:
        """The actual joint values (from the drives' last TPDOs)."""
        self._require_connected()
        vals = []
        for joint, _, _ in JOINT_FIELDS:
            p = self.axes[joint].position
            if p is None:
                raise NotConnected(f"{joint}: no position received yet")
            vals.append(p)
        return Joints(*vals)

    def move_time_s(self, start: Joints, target: Joints) -> float:
        """Duration of the coordinated move (every axis arrives with the slowest), from the
        trapezoidal profiles under the cell file's speed and acceleration limits."""
        return coordinated_move_s(self.cell.scara, start, target)

    def path(self, start: Joints, target: Joints, step_deg: float = 2.0) -> list[Joints]:
        """Where the axes are during the coordinated move from `start` to `target` (the end
        included): sampled in time so that J1 and J2 turn at most about step_deg between samples.
        Each axis follows its own trapezoid to arrive with the slowest, so the joints do not move in
        proportion (the long axis ramps, the short one nearly cruises)."""
        return coordinated_path(self.cell.scara, start, target, step_deg)

    def move_joints(self, target: Joints, *, wait: bool = True) -> Joints:
        """Move all four axes to `target` in one coordinated profile-position move.

        Refuses (`LimitError`, nothing sent) anything outside the joint limits, the workspace
        box or the maximum step; refuses (`FaultLatched`) while a fault is latched. Returns
        the command actually sent (the targets rounded to whole counts). With `wait`, returns
        when every axis reports target reached; a fault during the move, or an axis leaving
        OPERATION ENABLED (`DriveDisabled`), quick-stops all axes and raises the node's error,
        within a poll (the way check's can.stop_lag_ms). Without `wait` the host answers such a
        fault only when it next waits (`wait_idle()`) or commands: meanwhile the other axes run on.
        """
        self._begin_command()
        current = self.joints()
        problems = command_violations(self.cell, target, current)
        if problems:
            raise LimitError("move refused, nothing sent: " + "; ".join(problems))
        s = self.cell.scara
        duration_s = self.move_time_s(current, target)
        targets: dict[str, int] = {}
        for joint, field, _ in JOINT_FIELDS:
            ax = self.axes[joint]
            counts = ax.to_counts(getattr(target, field))
            distance = getattr(target, field) - getattr(current, field)
            if counts == ax.status.position_counts:
                continue
            targets[joint] = counts
            v = velocity_for_duration(distance, duration_s, s.max_acceleration[joint]) if duration_s > 0 else 0.0
            # at least the mean speed, so that a move of a few counts does not crawl at 1 count/s
            mean_counts_s = abs(counts - ax.status.position_counts) / duration_s if duration_s > 0 else 1.0
            v_counts = max(1, round(v * ax.counts_per_unit), math.ceil(mean_counts_s))
            v_counts = min(v_counts, codec.rate_counts_within(s.max_velocity[joint], ax.counts_per_unit))
            if self._velocity_counts.get(joint) != v_counts:
                self._guarded(ax.sdo_write, 0x6081, 0, v_counts)
                self._velocity_counts[joint] = v_counts
        sent = Joints(
            *(self.axes[j].from_counts(targets.get(j, self.axes[j].status.position_counts)) for j, _, _ in JOINT_FIELDS)
        )
        self._run_moves(targets, wait=wait, timeout_s=1.5 * duration_s + 1.0)
        return sent

    def _guarded(self, fn, *args):
        """Run an SDO/handshake step; a failure latches the fault (and stops everything)."""
        try:
            return fn(*args)
        except DriverError as e:
            self._latch(e)
            self._stop_all()
            also = self._silent_besides(e.node) if getattr(e, "unanswered", False) else ""
            if also:
                raise SdoError(f"{e}; {also}", node=e.node, node_id=e.node_id) from e
            raise

    def _silent_besides(self, node: str | None) -> str:
        """After a node gave no SDO answer: the other nodes silent too, a heartbeat deadline on (a dead bus or
        power named only the first node asked, j1, and sent the operator to its wiring)."""
        self.clock.sleep(self.heartbeat_deadline_s)
        self._watch()
        with self._lock:
            silent = [name for name, err in self._faults.items() if name != node and isinstance(err, NodeSilent)]
        if not silent:
            return ""
        return (f"{', '.join(silent)} silent too (no heartbeat within {self.heartbeat_deadline_s:g} s): look at the "
                f"bus (cable, termination, the drives' power), not {node} alone")

    def _run_moves(self, targets: dict[str, int], *, wait: bool, timeout_s: float) -> None:
        self._move_no += 1
        # (none runs on, and none keeps a set-point that a later release would start)
        with self._stopped_if_interrupted("a move was interrupted while its axes took their set-points or started"):
            if self.cell.can.coordinated_start and len(targets) > 1:
                self._start_together(targets)
            else:
                for name, counts in targets.items():
                    # one stopped from its side during an earlier axis' handshake: its own would re-enable it
                    self._stop_on_faults(targets, "while the axes took their set-points")
                    self._guarded(self.axes[name].start_move, counts)
            self._pending = (targets, self.clock.now() + timeout_s)
        if wait:
            self.wait_idle()

    @contextlib.contextmanager
    def _stopped_if_interrupted(self, what: str):
        """Something other than the drives' own errors (which stop and latch where they are raised) ending a move:
        Ctrl-C, a bug. The stop is latched first (a second Ctrl-C during the stop leaves the commands refused all
        the same), then every axis quick-stopped, and the error goes on up."""
        try:
            yield
        except DriverError:
            raise
        except BaseException:
            self._latch(DriverError(f"{what}: every axis quick-stopped"), key="stop")
            self._stop_all()
            raise

    def _start_together(self, targets: dict[str, int]) -> None:
        """Every axis takes its set-point under halt, then all are released back to back: they start within
        the release frames' time on the bus, as the way check (drivers.limits) has them. One after another,
        each axis would start a handshake's round trips (ms on real drives) after the one before, off the
        checked path, and run on alone while a later drive did not acknowledge."""
        for name, counts in targets.items():
            # one stopped from its side since the command began: its handshake's enable operation would re-enable
            # it (transition 16) without taking the set-point
            self._stop_on_faults(targets, "while the axes took their set-points")
            self._guarded(self.axes[name].arm_move, counts)
        # an armed axis stopped from the drive's side meanwhile (its quick stop input, STO, another
        # master): the release (enable operation) would re-enable it behind that side's back (transition
        # 16), without its set-point, and the others would run alone
        self._stop_on_faults(targets, "while its set-point waited for the other axes")
        seqs = {name: self._guarded(self.axes[name].release) for name in targets}
        self._confirm_started(targets, seqs)

    def _stop_on_faults(self, targets, when: str) -> None:
        """A latched fault, or an axis of `targets` that left OPERATION ENABLED on its own `when`: stop every
        axis and raise it."""
        self._check_faults(during_move=True)
        for name in targets:
            err = self._left_operation(self.axes[name], when, self._move_seqs.get(name))
            if err is not None:
                self._latch(err)
                self._stop_all()
                raise err

    def _confirm_started(self, targets: dict[str, int], seqs: dict[str, int]) -> None:
        """Every released axis must show within START_CONFIRM_S (wall time) that it started, or all are
        stopped. Meanwhile the host looks at every drive each poll, as `wait_idle` does: an axis that faults or
        stops on its own (its quick stop input) as the move starts stops the others within can.stop_lag_ms."""
        deadline = time.monotonic() + START_CONFIRM_S
        waiting = dict(targets)
        while True:
            waiting = {n: c for n, c in waiting.items()
                       if not self.axes[n].has_started(seqs[n], c, POSITION_TOLERANCE_COUNTS)}
            self._watch(stops=True)
            self._stop_on_faults(targets, "as its move started")
            if not waiting:
                return
            name, counts = next(iter(waiting.items()))
            left = deadline - time.monotonic()
            try:  # a poll's wait, woken by this axis' status
                self.axes[name].confirm_started(seqs[name], counts, POSITION_TOLERANCE_COUNTS,
                                                max(0.0, min(self.poll_s, left)), told_s=START_CONFIRM_S)
            except NodeSilent:
                if left > self.poll_s:
                    continue  # not yet: look at every drive again
                self._guarded(self.axes[name].confirm_started, seqs[name], counts, POSITION_TOLERANCE_COUNTS,
                              0.0, START_CONFIRM_S)  # (latches the timeout and stops every axis)
            except DriverError as e:  # it faulted meanwhile
                self._latch(e)
                self._stop_all()
                raise

    def wait_idle(self) -> None:
        """Wait (on the shared clock) until the last move's axes report target reached. Anything else that
        ends the wait (Ctrl-C, an error in a look at the drives) quick-stops every axis and latches a stop
        before it goes on up."""
        targets, deadline = self._pending
        try:
            with self._stopped_if_interrupted("waiting for a move was interrupted"):
                while targets:
                    # every poll, not only at the watchdog's: an axis that stopped on its own (a fault, its quick
                    # stop input) is answered within a poll, as the way check's can.stop_lag_ms has it
                    self._watch(stops=True)
                    self._check_faults(during_move=True)
                    self._stop_if_stopped_short(targets)
                    if all(self._arrived(self.axes[n], c) for n, c in targets.items()):
                        return
                    if self.clock.now() > deadline:
                        late = [n for n, c in targets.items() if not self._arrived(self.axes[n], c)]
                        err = MoveTimeout(
                            f"{', '.join(late)}: target not reached in time",
                            node=late[0],
                            node_id=self.axes[late[0]].node_id,
                        )
                        self._latch(err)
                        self._stop_all()
                        raise err
                    self.clock.sleep(self.poll_s)
        finally:
            self._pending = ({}, 0.0)

    @staticmethod
    def _ended(st) -> bool:
        """The drive says its move ended: target reached in OPERATION ENABLED, no set-point being taken (bit 10
        also reports the end of a quick stop ramp in QUICK STOP ACTIVE, CiA 402: no arrival)."""
        return st is not None and st.state == "OPERATION_ENABLED" and st.target_reached and not st.ack

    @classmethod
    def _arrived(cls, ax: Axis, counts: int) -> bool:
        """The move ended at the target (a count or two short of it is no arrival after a quick stop: `_ended`).
        The gripper's jaws stopped on a part (internal limit active) have arrived where the part is."""
        st = ax.status
        return cls._ended(st) and (abs(st.position_counts - counts) <= POSITION_TOLERANCE_COUNTS
                                   or (ax.name == "gripper" and st.internal_limit))

    def _stop_if_stopped_short(self, targets: dict[str, int]) -> None:
        """An arm axis whose drive reports its move ended with internal limit active, away from the target: a
        limit switch, a torque or current limit, a target clipped to the drive's own limits. It was taken for
        arrival (the pick record said the axis stood where it was sent): every axis is stopped and the fault
        latched, naming where the axis stands."""
        for name, counts in targets.items():
            ax = self.axes[name]
            st = ax.status
            if name == "gripper" or not self._ended(st) or not st.internal_limit or self._arrived(ax, counts):
                continue
            err = DriveFault(f"{name} (node {ax.node_id}): stopped at {ax.position:g} {ax.unit}, short of "
                             f"{ax.from_counts(counts):g} {ax.unit}: the drive reports an internal limit (a limit "
                             "switch, a torque or current limit, or its own position limits)", node=name,
                             node_id=ax.node_id)
            self._latch(err)
            self._stop_all()
            raise err

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
