"""The arm's safety supervision, all in the host: its heartbeat, error frames, the watch on every node
(heartbeat deadline, EMCY, FAULT, a node that lost its setup, an axis leaving OPERATION ENABLED on its own),
latched faults, the quick stop of every axis and the wait for standstill, and the reset.
"""

from __future__ import annotations

import contextlib
import logging

import can

from cell.cellconfig import HOST_POLL_MS, MIN_STOP_LAG_MS, QUICK_STOP_DECEL_FACTOR
from cell.kinematics import Joints, forward
from drivers import codec
from drivers.axis import Axis
from drivers.errors import BusFault, DriveDisabled, DriveFault, DriverError, FaultLatched, NodeRebooted, NodeSilent
from drivers.gripper import GRIPPER_ACCEL_FACTOR
from drivers.limits import JOINT_FIELDS

log = logging.getLogger("drivers.arm")  # the arm's one logger (tests and users filter on it)

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
QUICK_STOP_CONFIRM_S = 0.2  # wall time a drive gets to confirm a quick stop (it stops on its own when the host is gone)
STANDSTILL_MARGIN_S = 2.0  # waiting for standstill after a stop: this much past the slowest quick stop ramp


def to_each(axes, act) -> None:
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


class Supervision:
    """The host's supervision of the drives.

    A part of `drivers.arm.Arm`, whose `__init__` sets the state these methods use.
    """

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
            e = ax.last_emcy  # a drive may leave OPERATIONAL on its own at a communication error (0x1029): say which
            told = (f"; its EMCY before: 0x{e.code:04X} {e.text}" if e is not None and e.code != 0
                    and ax.emcy_seq != self._emcy_seen.get(ax.name, 0) else "")
            what = ("it takes no set-point and sends no status (its own reaction to a communication error, object "
                    "0x1029, another master's NMT command, or a reboot whose boot-up message was lost)" + told)
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

        to_each(self.axes.values(), quick_stop)
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
                # read back too: a drive that rebooted and started itself, its boot-up message lost, looks set up
                if ax.lost_setup() is not None or ax.sdo_read(0x1016, 1) != ax.host_watch_entry:
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
