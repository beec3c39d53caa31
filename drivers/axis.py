"""Master side of one CiA 402 node: SDO set-up, NMT, the 402 state machine and the
profile-position handshake, over PDOs, with every frame packed by `drivers.codec`.

Received frames (TPDO1, EMCY, heartbeat) arrive in the bus pump's thread and only update
this object's view (under a condition variable); every frame is sent from the caller's
thread. Waiting for an answer that needs no time to pass (an acknowledge, a state change)
uses a wall-clock timeout; what waits for the axis to stand (enabling after a ramp or a
coast) and waiting for motion sleep on the shared clock.
"""

from __future__ import annotations

import contextlib
import threading
import time

import can
import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers import codec, option_codes
from drivers.clock import Clock
from drivers.eds import object_dictionary
from drivers.errors import BusFault, DriveDisabled, DriveFault, DriverError, NodeSilent, SdoError

ANSWER_TIMEOUT_S = 1.0  # wall time a drive gets to answer a controlword with a TPDO
# time (on the shared clock) a quick stop ramp may take before enable() gives up; the arm passes
# its own bound (2 s past the cell's slowest quick stop ramp)
QUICK_STOP_END_TIMEOUT_S = 10.0
FAULT_STATES = ("FAULT", "FAULT_REACTION_ACTIVE")  # a wait for anything else ends in the fault's error


class Axis:
    """One CiA 402 drive as seen from the host.

    Parameters
    ----------
    name : str            'j1' ... 'j4' or 'gripper'
    node_id : int
    eds : str             path of the node's EDS file
    network : canopen.Network
    clock : Clock         for heartbeat time stamps
    counts_per_unit : float
    unit : str            'deg' or 'mm'
    """

    # Held around every frame of a move that enables operation (a set-point's controlwords, the halt's release);
    # raises where enabling is no longer allowed. The owner (`Arm`) sets its own: a stop latched from another
    # thread then lands before such a frame (which is not sent) or after it (its quick stops follow it).
    move_gate = contextlib.nullcontext
    # The same around `enable`'s enable-operation frames (no set-point: the axis holds where it stands).
    enable_gate = contextlib.nullcontext

    def __init__(
        self,
        name: str,
        node_id: int,
        eds: str,
        network: canopen.Network,
        clock: Clock,
        counts_per_unit: float,
        unit: str,
        sdo_timeout_s: float = 0.3,
    ):
        self.name, self.node_id, self.unit = name, node_id, unit
        self.counts_per_unit = counts_per_unit
        self.clock = clock
        self.network = network
        self.node = canopen.RemoteNode(node_id, object_dictionary(eds, node_id))
        self.node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
        self.node.sdo.MAX_RETRIES = 2  # canopen counts attempts: one retry after a lost answer
        network.add_node(self.node)
        self._cond = threading.Condition()
        self.status: codec.DriveStatus | None = None
        self.status_seq = 0
        # (status_seq, state) of the last status outside OPERATION ENABLED: a drive stopped from its side and
        # enabled again between two looks of the host (transition 16) shows it only here
        self.left_operation: tuple[int, str] | None = None
        self.last_heartbeat_s: float | None = None
        self.nmt_state: int | None = None
        self.boot_count = 0  # boot-up messages heard
        # what `lost_setup` compares with: the boot-ups heard when the host set the node up (`Arm._configure`), and
        # whether the host then set it OPERATIONAL (`Arm._start`)
        self.boots_at_setup = 0
        self.started = False
        self.host_watch_entry: int | None = None  # what the host wrote to 0x1016:1 (read back at a reset)
        self.last_emcy: codec.Emcy | None = None
        self.emcy_seq = 0
        self.controlword = 0
        self.option_codes: dict[int, int | None] = {}  # 0x6007, 0x605A, 0x605E as set up at connect (None: missing)
        self._subs = [
            (codec.TPDO1_BASE + node_id, self._on_tpdo1),
            (codec.EMCY_BASE + node_id, self._on_emcy),
            (codec.HEARTBEAT_BASE + node_id, self._on_heartbeat),
        ]
        for cob, fn in self._subs:
            network.subscribe(cob, fn)

    def detach(self) -> None:
        for cob, fn in self._subs:
            if fn in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, fn)

    # --- received frames (bus pump thread) -------------------------------------------------
    def _on_tpdo1(self, can_id, data, timestamp) -> None:
        try:
            status = codec.unpack_tpdo1(data)
        except ValueError:
            return
        with self._cond:
            self.status = status
            self.status_seq += 1
            if status.state != "OPERATION_ENABLED":
                self.left_operation = (self.status_seq, status.state)
            self._cond.notify_all()

    def _on_emcy(self, can_id, data, timestamp) -> None:
        try:
            e = codec.unpack_emcy(data)
        except ValueError:
            return
        with self._cond:
            self.last_emcy = e
            self.emcy_seq += 1
            self._cond.notify_all()

    def _on_heartbeat(self, can_id, data, timestamp) -> None:
        try:
            state = codec.unpack_heartbeat(data)
        except ValueError:
            return
        with self._cond:
            if state == codec.NMT_BOOT_UP:
                self.boot_count += 1
            self.nmt_state = state
            self.last_heartbeat_s = self.clock.now()
            self._cond.notify_all()

    # --- views -----------------------------------------------------------------------------
    @property
    def state(self) -> str:
        """The CiA 402 state of the last status; UNKNOWN without one, or while the heartbeat says the node is
        out of OPERATIONAL: it sends no status then, and the last one is stale (a rebooted J2 was shown
        OPERATION_ENABLED beside PRE-OPERATIONAL)."""
        if self.status is None or self.nmt_state not in (None, codec.NMT_OPERATIONAL):
            return "UNKNOWN"
        return self.status.state

    def lost_setup(self) -> str | None:
        """Why the node no longer holds what the host set up (None: it does), as the start of a message: a boot-up
        message heard since (a power glitch, its watchdog: back at its power-on values, its axis no longer
        driven, even where it then starts itself), or, once set OPERATIONAL, a heartbeat in another NMT state (it
        takes no set-point and sends no status)."""
        if self.boot_count != self.boots_at_setup:
            return f"{self.name} (node {self.node_id}) rebooted (boot-up message)"
        if self.started and self.nmt_state != codec.NMT_OPERATIONAL:
            return (f"{self.name} (node {self.node_id}): its heartbeat reports "
                    f"{codec.NMT_STATE_NAMES.get(self.nmt_state, self.nmt_state)}, not OPERATIONAL")
        return None

    def forget_status(self) -> None:
        """The last status is stale (the node rebooted since): none until the next one arrives."""
        with self._cond:
            self.status = None

    def _nmt_note(self) -> str:
        """For a wait that got no answer: the node's heartbeat says it is not OPERATIONAL (no PDO in or out), or ''."""
        if self.nmt_state in (None, codec.NMT_OPERATIONAL):
            return ""
        return (f"; its heartbeat reports {codec.NMT_STATE_NAMES.get(self.nmt_state, self.nmt_state)}: a node not "
                "OPERATIONAL takes no set-point and sends no status")

    @property
    def position(self) -> float | None:
        if self.status is None:
            return None
        return codec.from_counts(self.status.position_counts, self.counts_per_unit)

    def to_counts(self, value: float) -> int:
        return codec.to_counts(value, self.counts_per_unit)

    def from_counts(self, counts: int) -> float:
        return codec.from_counts(counts, self.counts_per_unit)

    def fault_text(self) -> str:
        code = self.last_emcy.code if self.last_emcy is not None and self.last_emcy.code else None
        if code is None:
            return "drive in FAULT"
        return f"EMCY 0x{code:04X} {codec.emcy_text(code)}"

    # --- SDO -------------------------------------------------------------------------------
    def _sdo_var(self, index: int, subindex: int):
        obj = self.node.sdo[index]
        return obj if subindex == 0 and not _is_compound(self.node, index) else obj[subindex]

    def _sdo_failed(self, e: Exception, what: str) -> SdoError:
        if isinstance(e, SdoCommunicationError):
            text = f"no SDO answer {what} ({e})"
        else:
            text = f"SDO {what} aborted: {e}"
        err = SdoError(f"{self.name} (node {self.node_id}): {text}", node=self.name, node_id=self.node_id)
        err.unanswered = isinstance(e, SdoCommunicationError)  # (an abort is an answer: the node is there)
        return err

    def sdo_read(self, index: int, subindex: int = 0):
        try:
            return self._sdo_var(index, subindex).raw
        except (SdoCommunicationError, SdoAbortedError) as e:
            raise self._sdo_failed(e, f"reading 0x{index:04X}:{subindex}") from None
        except can.CanError as e:
            raise self._send_failed(e, f"SDO read 0x{index:04X}:{subindex}") from None

    def sdo_write(self, index: int, subindex: int, value) -> None:
        try:
            self._sdo_var(index, subindex).raw = value
        except (SdoCommunicationError, SdoAbortedError) as e:
            raise self._sdo_failed(e, f"writing 0x{index:04X}:{subindex} = {value}") from None
        except can.CanError as e:
            raise self._send_failed(e, f"SDO write 0x{index:04X}:{subindex}") from None

    def _send_failed(self, e: can.CanError, what: str) -> BusFault:
        """The host's own interface refused a frame (bus-off, interface down, a full transmit queue): a fault
        of the bus, latched and stopped like any other, not a bare python-can exception past the supervision."""
        return BusFault(f"bus: sending {what} to {self.name} (node {self.node_id}) failed: {e}")

    def _send(self, cob_id: int, data: bytes, what: str) -> None:
        try:
            self.network.send_message(cob_id, data)
        except can.CanError as e:
            raise self._send_failed(e, what) from None

    def setup_pdos(self, event_timer_ms: int) -> None:
        """Check the drive's PDO mapping is the one `drivers.codec` packs (a drive mapped
        differently is refused, not misread) and set the communication parameters: TPDO1
        event-driven with an event timer, RPDO1-3 valid on their default COB-IDs."""
        tpdo = tuple(self.sdo_read(0x1A00, i) for i in range(1, self.sdo_read(0x1A00, 0) + 1))
        rpdo = tuple(
            tuple(self.sdo_read(0x1600 + k, i) for i in range(1, self.sdo_read(0x1600 + k, 0) + 1)) for k in range(3)
        )
        if tpdo != codec.TPDO1_MAPPING or rpdo != codec.RPDO_MAPPINGS:
            raise DriveFault(
                f"{self.name} (node {self.node_id}): PDO mapping differs from the cell's "
                f"(TPDO1 {[hex(m) for m in tpdo]}, RPDO1-3 {[[hex(m) for m in r] for r in rpdo]})",
                node=self.name,
                node_id=self.node_id,
            )
        self._ensure_cob_id(0x1800, codec.TPDO1_BASE + self.node_id)
        self._ensure(0x1800, 2, codec.PDO_EVENT_DRIVEN)
        self._ensure(0x1800, 5, event_timer_ms)
        for k, base in enumerate(codec.RPDO_BASES):
            self._ensure_cob_id(0x1400 + k, base + self.node_id)
            self._ensure(0x1400 + k, 2, codec.PDO_EVENT_DRIVEN)

    def setup_option_codes(self) -> list[str]:
        """The abort connection, quick stop and fault reaction option codes the host relies on
        (`drivers.option_codes.WANTED`): written where they differ and read back. Returns a warning per object
        the drive lacks (SDO abort 0x06020000) or keeps at another value (a refused write, say 0x06090030);
        raises DriveFault where its quick stop would not stop the axis under control, or where it would not
        stop the axis when the host falls silent. `self.option_codes` keeps what the drive has (None: no such
        object)."""
        warnings = []
        for index, wanted in option_codes.WANTED.items():
            have, refused = self._option_code(index), None
            if have is not None and have != wanted:
                try:
                    self._sdo_var(index, 0).raw = wanted
                except SdoAbortedError as e:
                    refused = e.code
                except SdoCommunicationError as e:
                    raise self._sdo_failed(e, f"writing 0x{index:04X}:0 = {wanted}") from None
                have = self.sdo_read(index)  # what it took
            self.option_codes[index] = have
            warning = option_codes.review(self.name, self.node_id, index, have, refused)
            if warning is not None:
                warnings.append(warning)
        return warnings

    def _option_code(self, index: int) -> int | None:
        """An option code's value, None when the drive has no such object."""
        try:
            return self._sdo_var(index, 0).raw
        except SdoAbortedError as e:
            if e.code == option_codes.OBJECT_DOES_NOT_EXIST:
                return None
            raise self._sdo_failed(e, f"reading 0x{index:04X}:0") from None
        except SdoCommunicationError as e:
            raise self._sdo_failed(e, f"reading 0x{index:04X}:0") from None

    def _ensure(self, index: int, subindex: int, value: int) -> None:
        """Write only what differs: fewer frames, and no writes a drive may refuse while running."""
        if self.sdo_read(index, subindex) != value:
            self.sdo_write(index, subindex, value)

    def _ensure_cob_id(self, comm_index: int, cob_id: int) -> None:
        """A valid PDO on `cob_id`; CiA 301 wants the PDO invalid (bit 31) while its id changes."""
        current = self.sdo_read(comm_index, 1)
        if current & 0x7FF == cob_id and not current & 0x80000000:
            return
        if not current & 0x80000000:
            self.sdo_write(comm_index, 1, current | 0x80000000)
        self.sdo_write(comm_index, 1, cob_id)

    # --- frames out ------------------------------------------------------------------------
    def nmt(self, command: int) -> None:
        self._send(codec.NMT_COB, codec.pack_nmt(command, self.node_id), "NMT")

    def send_controlword(self, cw: int) -> int:
        """Send the controlword (RPDO1); returns the status sequence number before sending."""
        with self._cond:
            seq = self.status_seq
        self.controlword = cw
        self._send(codec.RPDO1_BASE + self.node_id, codec.pack_controlword(cw), f"controlword 0x{cw:04X}")
        return seq

    def send_target(self, counts: int) -> None:
        self._send(codec.RPDO2_BASE + self.node_id, codec.pack_target(counts), "target position")

    def send_mode(self, mode: int) -> int:
        with self._cond:
            seq = self.status_seq
        self._send(codec.RPDO3_BASE + self.node_id, codec.pack_mode(mode), "mode of operation")
        return seq

    # --- waiting ---------------------------------------------------------------------------
    def wait_status(self, pred, after_seq: int | None, what: str, timeout_s: float = ANSWER_TIMEOUT_S,
                    told_s: float | None = None, hint: str = ""):
        """Wait (wall time) for a TPDO newer than `after_seq` whose status satisfies `pred`. `hint`: added to the
        timeout's message where the node is OPERATIONAL (where it is not, that is said instead)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                st = self.status
                if st is not None and (after_seq is None or self.status_seq > after_seq) and pred(st):
                    return st
                if st is not None and st.state in FAULT_STATES and "FAULT" not in what:
                    raise self._faulted_while(what)
                left = deadline - time.monotonic()
                if left <= 0:
                    got = st.state if st is not None else "no status"
                    raise NodeSilent(
                        f"{self.name} (node {self.node_id}): no answer ({what}{self._nmt_note() or hint}) within "
                        f"{timeout_s if told_s is None else told_s:g} s, last status: {got}",
                        node=self.name,
                        node_id=self.node_id,
                    )
                self._cond.wait(left)

    def _faulted_while(self, what: str) -> DriveFault:
        return DriveFault(
            f"{self.name} (node {self.node_id}): {self.fault_text()} while waiting for {what}",
            node=self.name,
            node_id=self.node_id,
            emcy_code=self.last_emcy.code if self.last_emcy else None,
        )

    def wait_heartbeat(self, clock: Clock, timeout_s: float, step_s: float, start_s: float | None = None) -> None:
        """Wait for a heartbeat (or boot-up) on the shared clock: the boot-up deadline,
        `timeout_s` after `start_s` (default: now)."""
        start = clock.now() if start_s is None else start_s
        while self.last_heartbeat_s is None:
            if clock.now() - start >= timeout_s:
                raise NodeSilent(
                    f"{self.name} (node {self.node_id}): no boot-up or heartbeat within {timeout_s:g} s",
                    node=self.name,
                    node_id=self.node_id,
                )
            clock.sleep(step_s)

    def wait_started(self, clock: Clock, timeout_s: float, step_s: float) -> bool:
        """After NMT start, on the shared clock: its first status and a heartbeat reporting OPERATIONAL (True), or
        a boot-up message since its setup (False: it rebooted, as `lost_setup` says; waiting on would only end in
        "did not report OPERATIONAL")."""
        start = clock.now()
        while self.boot_count == self.boots_at_setup:
            if self.status is not None and self.nmt_state == codec.NMT_OPERATIONAL:
                return True
            if clock.now() - start >= timeout_s:
                if self.status is None:
                    what = f"no status (first TPDO after NMT start{self._nmt_note()})"
                else:
                    what = (f"heartbeat did not report OPERATIONAL (last: "
                            f"{codec.NMT_STATE_NAMES.get(self.nmt_state, 'nothing')})")
                raise NodeSilent(f"{self.name} (node {self.node_id}): {what} within {timeout_s:g} s",
                                 node=self.name, node_id=self.node_id)
            clock.sleep(step_s)
        return False

    # --- CiA 402 state machine -------------------------------------------------------------
    def enable(self, quick_stop_timeout_s: float = QUICK_STOP_END_TIMEOUT_S, step_s: float = 0.01,
               hold=None) -> None:
        """Walk the 402 state machine to OPERATION ENABLED in profile position mode, with the
        target set to the actual position first so that enabling never jumps (`hold`: the target for an actual
        position in counts, where that is not the position itself: a joint limit). From QUICK STOP
        ACTIVE it first waits (on the clock, up to `quick_stop_timeout_s`) for the end of the quick
        stop ramp: statusword bit 10 where the drive stays there (0x605A 5-8; then transition 16),
        or SWITCH ON DISABLED where it does not (1, 2; then the walk from there)."""
        if self.status is None:
            self.wait_status(lambda s: True, None, "first TPDO")
        if self.state == "FAULT":
            raise DriveFault(
                f"{self.name} (node {self.node_id}): {self.fault_text()}; reset faults first",
                node=self.name,
                node_id=self.node_id,
                emcy_code=self.last_emcy.code if self.last_emcy else None,
            )
        if self.status.mode != codec.PP_MODE:
            seq = self.send_mode(codec.PP_MODE)
            self.wait_status(lambda s: s.mode == codec.PP_MODE, seq, "profile position mode")
        hold = hold or (lambda counts: counts)
        self.send_target(hold(self.status.position_counts))
        steps = {
            "QUICK_STOP_ACTIVE": (codec.CW_ENABLE_OPERATION, "OPERATION_ENABLED"),
            "SWITCH_ON_DISABLED": (codec.CW_SHUTDOWN, "READY_TO_SWITCH_ON"),
            "NOT_READY_TO_SWITCH_ON": (None, "SWITCH_ON_DISABLED"),
            "READY_TO_SWITCH_ON": (codec.CW_SWITCH_ON, "SWITCHED_ON"),
            "SWITCHED_ON": (codec.CW_ENABLE_OPERATION, "OPERATION_ENABLED"),
        }
        for _ in range(6):
            state = self.state
            if state == "OPERATION_ENABLED":
                return
            if state == "QUICK_STOP_ACTIVE" and not self._quick_stop_ended():
                self._wait_quick_stop_end(quick_stop_timeout_s, step_s)
                continue
            if state not in steps:
                raise DriveFault(
                    f"{self.name} (node {self.node_id}): cannot enable from {state}",
                    node=self.name,
                    node_id=self.node_id,
                )
            cw, nxt = steps[state]
            if cw is None:
                self.wait_status(lambda s, n=nxt: s.state == n, None, nxt)
                continue
            if state in ("SWITCHED_ON", "QUICK_STOP_ACTIVE"):
                # the drive may have drifted while switched on, or ramped down: target = actual, once more
                self.send_target(hold(self.status.position_counts))
            if cw == codec.CW_ENABLE_OPERATION:
                with self.enable_gate():
                    seq = self.send_controlword(cw)
                self._wait_enabled(seq, quick_stop_timeout_s, step_s, hold)
                try:  # a stop latched while the frame was on its way passed this axis by as not enabled
                    with self.enable_gate():
                        pass
                except DriverError:
                    self.send_quick_stop()
                    raise
            else:
                seq = self.send_controlword(cw)
                self.wait_status(lambda s, n=nxt: s.state == n, seq, nxt)
        raise DriveFault(
            f"{self.name} (node {self.node_id}): did not reach OPERATION_ENABLED (at {self.state})",
            node=self.name,
            node_id=self.node_id,
        )

    def _quick_stop_ended(self) -> bool:
        """Out of QUICK STOP ACTIVE, or in it with bit 10 where the drive stays there (0x605A 5-8, or not
        known); where it goes on to SWITCH ON DISABLED (1-4), transition 16 is none: wait for that."""
        if self.state != "QUICK_STOP_ACTIVE":
            return True
        leaves = self.option_codes.get(option_codes.QUICK_STOP) in range(1, 5)
        return self.status.target_reached and not leaves

    def _wait_quick_stop_end(self, timeout_s: float, step_s: float) -> None:
        """Wait on the clock, not wall time: a ramp takes time, simulated or not."""
        deadline = self.clock.now() + timeout_s
        while not self._quick_stop_ended():
            if self.clock.now() >= deadline:
                raise DriveFault(
                    f"{self.name} (node {self.node_id}): still in QUICK STOP ACTIVE {timeout_s:g} s on "
                    f"(statusword bit 10 {'set' if self.status.target_reached else 'clear'}); not enabled",
                    node=self.name,
                    node_id=self.node_id,
                )
            self.clock.sleep(step_s)

    def _wait_enabled(self, after_seq: int, timeout_s: float, step_s: float, hold) -> None:
        """Wait on the clock, not wall time, for OPERATION ENABLED after enable operation: a drive whose
        axis still coasts or ramps down holds the command until the axis stands (CiA 402), which takes
        time, simulated or not. A drive that does not answer at all gives up after `timeout_s` too.
        `hold`: the target for where it stands (`enable`)."""
        deadline = self.clock.now() + timeout_s
        self.clock.sleep(0)  # a SimClock settles: the answers already sent are handled
        waited = False
        while True:
            with self._cond:
                st, fresh = self.status, self.status_seq > after_seq
            if fresh and st.state == "OPERATION_ENABLED":
                if waited:  # the axis may have run on past the target set before: set it where it stands
                    self.send_target(hold(st.position_counts))
                    self.clock.sleep(0)
                return
            if st.state in FAULT_STATES:
                raise self._faulted_while("OPERATION_ENABLED")
            if self.clock.now() >= deadline:
                raise NodeSilent(
                    f"{self.name} (node {self.node_id}): not OPERATION_ENABLED {timeout_s:g} s after enable "
                    f"operation, last status: {st.state}",
                    node=self.name,
                    node_id=self.node_id,
                )
            waited = True
            if self.clock.simulated:
                self.clock.sleep(step_s)
            else:
                with self._cond:  # wall time: wake at the next status rather than a poll later
                    self._cond.wait(step_s)

    def send_quick_stop(self) -> int | None:
        """Quick stop (402 transition 11), not waited for (`Arm` stops every axis first, then waits): the
        status sequence number before it, or None where the drive was not in OPERATION ENABLED (nothing sent)."""
        if self.state != "OPERATION_ENABLED":
            return None
        return self.send_controlword(codec.CW_QUICK_STOP)

    def confirm_quick_stop(self, seq: int, timeout_s: float) -> None:
        """Wait briefly for the drive to leave OPERATION ENABLED after the quick stop sent at `seq`."""
        try:
            self.wait_status(lambda s: s.state != "OPERATION_ENABLED", seq, "quick stop FAULT", timeout_s)
        except NodeSilent:
            pass  # a silent drive stops on its own when it misses the host's heartbeat

    def disable(self) -> None:
        """No torque: shutdown (402 transition 8 or 6), or, from QUICK STOP ACTIVE, where shutdown
        is no transition, disable voltage (12)."""
        if self.state == "QUICK_STOP_ACTIVE":
            self.send_controlword(codec.CW_DISABLE_VOLTAGE)
        elif self.state not in ("FAULT", "SWITCH_ON_DISABLED", "UNKNOWN"):
            self.send_controlword(codec.CW_SHUTDOWN)

    def fault_reset(self) -> None:
        """Rising edge of controlword bit 7; the drive goes to SWITCH ON DISABLED."""
        if self.state != "FAULT":
            return
        self.send_controlword(codec.CW_DISABLE_VOLTAGE)
        seq = self.send_controlword(codec.CW_FAULT_RESET)
        self.wait_status(lambda s: s.state != "FAULT", seq, "fault reset (leaving FAULT)")
        self.send_controlword(codec.CW_DISABLE_VOLTAGE)

    def start_move(self, target_counts: int) -> None:
        """Profile-position handshake: target, new set-point (bit 4), acknowledge (bit 12),
        clear bit 4, acknowledge cleared. Motion starts at the set-point."""
        self._set_point_handshake(target_counts, 0, "set-point acknowledge")

    def arm_move(self, target_counts: int) -> None:
        """The same handshake under halt (controlword bit 8): the drive takes the set-point and stands
        until `release`. Arming every axis of a move, then releasing them back to back, starts them
        together (`Arm.move_joints`). Only at standstill: on a moving axis the halt would stop it off its
        way (`Arm` waits for the previous move first)."""
        self._set_point_handshake(target_counts, codec.CW_HALT, "set-point acknowledge under halt",
                                  "; a drive that takes no set-point while halted needs can.coordinated_start false")

    def release(self) -> int:
        """Clear the halt: an armed axis starts its set-point (CiA 402: the positioning continues).
        Not waited for: the next axis' release follows at once (`confirm_started` after). Returns the status
        sequence number before it."""
        with self.move_gate():
            return self.send_controlword(codec.CW_ENABLE_OPERATION)

    def confirm_started(self, seq: int, target_counts: int, tolerance_counts: int, timeout_s: float,
                        told_s: float | None = None) -> None:
        """Wait (wall time) for a status after the release sent at `seq` showing the axis on its way (bit 10
        cleared) or already there: a drive that took the set-point under halt but does not run it on the
        release would leave the other axes running alone. told_s: the time the timeout's message names (the
        whole wait, when this is one slice of it)."""
        self.wait_status(_started(target_counts, tolerance_counts), seq, "start of the set-point at the halt's release",
                         timeout_s, told_s, "; a drive that does not run a set-point taken under halt needs "
                         "can.coordinated_start false")

    def has_started(self, seq: int, target_counts: int, tolerance_counts: int) -> bool:
        """`confirm_started`'s condition, now, without waiting."""
        st = self.status
        return st is not None and self.status_seq > seq and _started(target_counts, tolerance_counts)(st)

    def _set_point_handshake(self, target_counts: int, extra_bits: int, ack: str, no_ack_hint: str = "") -> None:
        self.send_target(target_counts)
        with self.move_gate():
            seq = self.send_controlword(codec.CW_ENABLE_OPERATION | codec.CW_NEW_SET_POINT | extra_bits)
        self._wait_in_operation(lambda s: s.ack, seq, ack, no_ack_hint)
        with self.move_gate():
            seq = self.send_controlword(codec.CW_ENABLE_OPERATION | extra_bits)
        self._wait_in_operation(lambda s: not s.ack, seq, "set-point acknowledge cleared")

    def _wait_in_operation(self, pred, seq: int, what: str, no_answer_hint: str = "") -> None:
        """A handshake's wait, ended at once by a status outside OPERATION ENABLED: a drive stopped meanwhile (the
        operator's stop, its quick stop input) takes no set-point, and waiting out the answer's timeout blamed
        it for not answering (the hint is for that timeout). A fault ends it in the fault's error (`wait_status`,
        with its EMCY); a stop the owner latched (`enable_gate`) in that stop's; anything else is `DriveDisabled`."""
        st = self.wait_status(lambda s: s.state not in FAULT_STATES and (pred(s) or s.state != "OPERATION_ENABLED"),
                              seq, what, hint=no_answer_hint)
        if st.state != "OPERATION_ENABLED":
            with self.enable_gate():  # (raises the stop the host latched, which this one is; no other fault)
                pass
            raise DriveDisabled(f"{self.name} (node {self.node_id}): left OPERATION ENABLED (reported {st.state}) "
                                f"while waiting for {what}", node=self.name, node_id=self.node_id, state=st.state)


def _started(target_counts: int, tolerance_counts: int):
    """Is a status that of an axis on its way (bit 10 cleared) or already at target_counts?"""
    return lambda s: s.state == "OPERATION_ENABLED" and (
        not s.target_reached or abs(s.position_counts - target_counts) <= tolerance_counts)


def _is_compound(node, index: int) -> bool:
    return not isinstance(node.object_dictionary[index], canopen.objectdictionary.ODVariable)
