"""One simulated CiA 402 drive (and the gripper) on a canopen `Network`: the drive logic
behind `drivers.sim.serve`.

A `canopen.LocalNode` provides the SDO server and the object dictionary (from the shipped
EDS); this module adds NMT with boot-up and heartbeat, the 402 state machine with faults,
profile position with the set-point handshake, trapezoidal motion on the shared clock,
TPDO1 on change and on its event timer, EMCY, the host heartbeat watch, the software
position limits, and fault injection.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

import canopen
from canopen.sdo import SdoAbortedError

from drivers import codec
from drivers.clock import Clock
from drivers.eds import GRIP_FORCE_INDEX, object_dictionary
from drivers.profile import Trapezoid, from_speed, trapezoid

log = logging.getLogger(__name__)

TICK_MS = 10  # the drives' tick (drivers.sim.TICK_S): no heartbeat or event timer shorter than that
TPDO_EVENT_MS = 50  # TPDO1 is also sent at least this often (canopen's BaseNode402 waits 0.2 s)
FAULT_KINDS = ("silent", "emcy", "following_error", "drop_sdo", "error_frames", "quick_stop", "disable",
               "ignore_set_point", "internal_limit")
# injected events that act on the drive at once, or `after_s` into its next move
TIMED_EVENTS = ("emcy", "quick_stop", "disable", "internal_limit")
NMT_OPERATIONAL, NMT_PREOP, NMT_STOPPED, NMT_INIT = 0x05, 0x7F, 0x04, 0x00
HOST_WATCH_STARVED_SHARE = 0.5  # a step this much of the host deadline after the last one: we were held up
QUICK_STOP_DECEL_FACTOR = 2.0  # quick stop / fault reaction ramp = this x the profile acceleration
# An axis whose drive function is disabled while it moves (option code 0, "disable drive function")
# is no longer driven: it runs out on friction alone, at this x its max acceleration (a figure of
# the simulated mechanics, not an object of the drive; no gravity, no holding brake)
COAST_DECEL_FACTOR = 0.5
EMCY_PDO_LENGTH = 0x8210  # an RPDO shorter than its mapping: not processed (CiA 301)
TPDO_COMM_FIRST, TPDO_COMM_LAST = 0x1800, 0x1803  # the TPDO communication parameters
PDO_NO_RTR = 1 << 30  # COB-ID bit 30 of a TPDO: no RTR allowed (these drives answer none)

# CiA 402 option codes (CiA 402-2 / IEC 61800-7-201): how the drive stops when it leaves OPERATION
# ENABLED. Per value: the deceleration object of the ramp, or None for "disable drive function"
# (the axis coasts). The values a drive supports are its own; these drives refuse the others
# (current- and voltage-limit stops, 3/4/7/8) with SDO abort 0x06090030.
QUICK_STOP_OPTIONS = {  # 0x605A: (ramp, state after the ramp); transition 11
    0: (None, "SWITCH_ON_DISABLED"),  # disable drive function
    1: (0x6084, "SWITCH_ON_DISABLED"),  # slow down on the slow-down ramp, then SWITCH ON DISABLED
    2: (0x6085, "SWITCH_ON_DISABLED"),  # quick stop ramp, then SWITCH ON DISABLED
    5: (0x6084, "QUICK_STOP_ACTIVE"),  # slow-down ramp, stay in QUICK STOP ACTIVE
    6: (0x6085, "QUICK_STOP_ACTIVE"),  # quick stop ramp, stay in QUICK STOP ACTIVE (this drive's default)
}
SHUTDOWN_OPTIONS = {0: None, 1: 0x6084}  # 0x605B, transition 8: coast (default) / slow-down ramp
DISABLE_OPERATION_OPTIONS = {0: None, 1: 0x6084}  # 0x605C, transition 5: coast / slow-down ramp (default)
HALT_OPTIONS = {1: 0x6084, 2: 0x6085}  # 0x605D: slow-down ramp (default) / quick stop ramp, stay enabled
FAULT_REACTION_OPTIONS = {0: None, 1: 0x6084, 2: 0x6085}  # 0x605E: coast / slow-down / quick stop (default)
# 0x6007: what the drive does when the connection is lost (here: the host's heartbeat missed, 0x1016):
# nothing, a fault (the fault reaction, this drive's default), disable voltage (the axis coasts) or a quick
# stop (as 0x605A says)
ABORT_CONNECTION_OPTIONS = {0: "nothing", 1: "fault", 2: "disable voltage", 3: "quick stop"}
OPTION_CODES = {
    0x6007: ABORT_CONNECTION_OPTIONS,
    0x605A: QUICK_STOP_OPTIONS,
    0x605B: SHUTDOWN_OPTIONS,
    0x605C: DISABLE_OPERATION_OPTIONS,
    0x605D: HALT_OPTIONS,
    0x605E: FAULT_REACTION_OPTIONS,
}


def power_on_values(*, counts_per_unit: float, limits: tuple[float, float], velocity: float, acceleration: float,
                    heartbeat_ms: int, tpdo_event_ms: int = TPDO_EVENT_MS,
                    grip_force_n: float | None = None) -> dict[tuple[int, int], int]:
    """(index, sub-index) -> value of the objects the cell file sets in a drive, as commissioning stored
    them: what the drive holds at power-on and after the NMT resets, and its EDS's DefaultValues."""
    c = counts_per_unit
    values = {
        (0x1017, 0): heartbeat_ms,
        (0x1800, 5): tpdo_event_ms,
        (0x607D, 1): codec.to_counts(limits[0], c),
        (0x607D, 2): codec.to_counts(limits[1], c),
        # rounded down, as the host sends them (a limit a quarter count under 2^32 rounded up past UNSIGNED32)
        (0x6081, 0): max(1, codec.rate_counts_within(velocity, c)),
        (0x6083, 0): max(1, codec.rate_counts_within(acceleration, c)),
        (0x6084, 0): max(1, codec.rate_counts_within(acceleration, c)),
        (0x6085, 0): max(1, round(QUICK_STOP_DECEL_FACTOR * acceleration * c)),
    }
    if grip_force_n is not None:
        values[(GRIP_FORCE_INDEX, 0)] = round(grip_force_n * 10)
    return values


@dataclass
class _Motion:
    t0_s: float
    start_counts: float
    target_counts: int
    profile: Trapezoid
    stopping: bool = False  # a ramp to standstill (quick stop, halt, fault reaction, ...)
    coasting: bool = False  # the drive function is disabled: the axis runs out on friction alone


def _next_phase(last_s: float, period_s: float, now_s: float) -> float:
    """When a periodic frame due at `last_s + period_s` goes out at `now_s` (on the next
    tick): keep the phase, so the period holds on average; start afresh when far behind."""
    due = last_s + period_s
    return due if now_s - due < period_s else now_s


class SimDrive:
    """One simulated CiA 402 drive on a canopen `Network`. Thread-safe (one lock)."""

    def __init__(
        self,
        name: str,
        node_id: int,
        eds: str,
        network: canopen.Network,
        clock: Clock,
        *,
        counts_per_unit: float,
        limits: tuple[float, float],
        velocity: float,
        acceleration: float,
        position: float,
        heartbeat_ms: int,
        tpdo_event_ms: int = TPDO_EVENT_MS,
        tick_ms: int = TICK_MS,
        grip_force_n: float | None = None,  # a gripper's (`SimGripper`)
    ):
        self.name, self.node_id, self.eds, self.clock = name, node_id, eds, clock
        self.tick_ms = tick_ms  # how often step() runs: the shortest period the drive keeps
        self.counts_per_unit = counts_per_unit
        self.coast_decel_counts = COAST_DECEL_FACTOR * acceleration * counts_per_unit
        self._lock = threading.RLock()
        self.network = network
        self.node = canopen.LocalNode(node_id, object_dictionary(eds, node_id))
        network.add_node(self.node)
        # NMT and heartbeats are ours (clock-driven), not canopen's send_periodic thread
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        network.unsubscribe(0, self.node.nmt.on_command)
        network.subscribe(0, self._on_nmt)
        self.node._find_object = self._find_object  # canopen's LocalNode lets any sub-index through
        self._set_data = self.node.set_data
        self.node.set_data = self._set_data_no_rtr
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self._sdo_send = self.node.sdo.send_response
        self.node.sdo.send_response = self._send_sdo_response
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        # RPDOs by their communication object (the COB-IDs are writable, as on real drives)
        self._rpdo_handlers = {0x1400: self._on_rpdo1, 0x1401: self._on_rpdo2, 0x1402: self._on_rpdo3}
        self._rpdo_cobs: dict[int, int] = {}
        for comm in self._rpdo_handlers:
            self._subscribe_rpdo(comm, int(self._get(comm, 1)))
        self._sync_cob: int | None = None
        self._subscribe_sync(int(self._get(0x1005)))
        self._sync_count = 0
        # object dictionary values the cell file sets (as a commissioning tool would; the node's EDS,
        # `drivers.sim.node_eds_paths`, has them as its DefaultValues)
        c = counts_per_unit
        for (index, sub), value in power_on_values(counts_per_unit=c, limits=limits, velocity=velocity,
                                                   acceleration=acceleration, heartbeat_ms=heartbeat_ms,
                                                   tpdo_event_ms=tpdo_event_ms, grip_force_n=grip_force_n).items():
            self._store(index, sub, value)
        # the power-on values (CiA 301: what the NMT resets restore), as stored by commissioning
        self._power_on = {i: dict(subs) for i, subs in self.node.data_store.items()}
        # the option code values this drive takes by SDO, and the objects it lacks (`configure_option_codes`)
        self._accepted = {index: set(values) for index, values in OPTION_CODES.items()}
        self._missing: set[int] = set()
        # drive state
        self.nmt = NMT_INIT
        self.state = "NOT_READY_TO_SWITCH_ON"
        self.position_counts = float(codec.to_counts(position, c))
        self._store(0x607A, 0, round(self.position_counts))
        self.mode = 0
        self.controlword = 0
        self.ack = False
        self.target_reached = True
        self.following_error = False
        self.internal_limit = False
        self.error_code = 0
        self.motion: _Motion | None = None
        self.pending: tuple[int, bool] | None = None  # buffered set-point (single set-point mode)
        self.halted: int | None = None  # the target a halt (controlword bit 8) interrupted
        # the state a transition that waits for its ramp enters at standstill (shutdown and disable
        # operation stay in OPERATION ENABLED until then; quick stop 1/2 in QUICK STOP ACTIVE;
        # the fault reaction in FAULT REACTION ACTIVE)
        self.after_ramp: str | None = None
        # enable operation (transition 4 or 16) received while the axis still ramped down or coasted:
        # held, and taken at standstill unless another command replaced it (the controlword is a level)
        self.enable_held = False
        self.emcy_log: list[int] = []
        # host heartbeat watch (0x1016)
        self._host_id = 0
        self._host_deadline_s = 0.0
        self._host_seen_s: float | None = None
        self._stepped_s: float | None = None  # when step() last ran
        # timers
        self._last_hb_s = -1e9
        self._last_tpdo_s = -1e9  # the event timer's phase
        self._tpdo_sent_s = -1e9  # when TPDO1 last went out (its inhibit time counts from there)
        self._last_tpdo: bytes | None = None
        # injected faults
        self.silent = False
        self.drop_sdo = 0  # number of SDO answers still to drop (-1: all)
        self.ignore_set_point = False  # alive (heartbeat, TPDO1) but deaf to the new set-point edge
        self._armed: list[dict] = []
        self._jammed_at: float | None = None  # actual position of a blocked axis (following error)

    # --- object dictionary plumbing --------------------------------------------------------
    def _store(self, index: int, subindex: int, value) -> None:
        od = self.node.object_dictionary[index]
        var = od if isinstance(od, canopen.objectdictionary.ODVariable) else od[subindex]
        self.node.data_store.setdefault(index, {})[subindex] = var.encode_raw(value)

    def _get(self, index: int, subindex: int = 0):
        od = self.node.object_dictionary[index]
        var = od if isinstance(od, canopen.objectdictionary.ODVariable) else od[subindex]
        raw = self.node.data_store.get(index, {}).get(subindex)
        return var.decode_raw(raw) if raw is not None else var.default

    def _find_object(self, index: int, subindex: int):
        """The object an SDO names, as a real drive checks it: abort 0x06020000 for an object
        it does not have, 0x06090011 for a sub-index the object does not have (a VAR has only
        sub-index 0; an ARRAY only the entries its EDS declares)."""
        od = self.node.object_dictionary
        if index not in od or index in self._missing:
            raise SdoAbortedError(0x06020000)
        obj = od[index]
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            if subindex != 0:
                raise SdoAbortedError(0x06090011)
            return obj
        if subindex not in obj.subindices:
            raise SdoAbortedError(0x06090011)
        return obj.subindices[subindex]

    def _set_data_no_rtr(self, index: int, subindex: int, data: bytes, check_writable: bool = False) -> None:
        """A TPDO's COB-ID keeps bit 30 set whatever is written there: these drives answer no RTR (CiA 301:
        bit 30 = 1, no RTR allowed on this PDO), so a master that reads it back (canopen's PdoMap) knows it."""
        if TPDO_COMM_FIRST <= index <= TPDO_COMM_LAST and subindex == 1 and len(data) == 4:
            data = (int.from_bytes(data, "little") | PDO_NO_RTR).to_bytes(4, "little")
        self._set_data(index, subindex, data, check_writable)

    def _on_read(self, index, subindex, od):
        with self._lock:
            if index == 0x6041:
                return self.statusword
            if index == 0x6064:
                return round(self.position_counts)
            if index == 0x6061:
                return self.mode
            if index == 0x603F:
                return self.error_code
            if index == 0x1001:
                return self.error_register
            if index == 0x6040:
                return self.controlword
        return None

    def _on_write(self, index, subindex, od, data):
        with self._lock:
            value = od.decode_raw(data)
            if (0x1400 <= index <= 0x1403 or TPDO_COMM_FIRST <= index <= TPDO_COMM_LAST) and subindex in (1, 3):
                self._check_pdo_comm_write(index, subindex, value)
            if index == 0x6040:
                self._on_controlword(value)
            elif index == 0x6060:
                self._set_mode(value)
            elif index == 0x1016 and subindex == 1:
                if value >> 16 & 0xFF > 127 or value >> 24:  # a node id 1-127 (0: the entry unused), bits 24-31 0
                    raise SdoAbortedError(0x06090030)
                self._set_host_watch(value)
            elif (index == 0x1017 or (TPDO_COMM_FIRST <= index <= TPDO_COMM_LAST and subindex == 5)) and (
                    0 < value < self.tick_ms):
                # a heartbeat or an event timer shorter than the drive's tick it could not keep (0: off)
                raise SdoAbortedError(0x06090032)  # value of parameter written too low
            elif 0x1400 <= index <= 0x1403 and subindex == 2 and value not in (254, 255):
                raise SdoAbortedError(0x06090030)  # RPDOs act on reception here (no SYNC-applied RPDOs)
            elif 0x1800 <= index <= 0x1803 and subindex == 2 and 240 < value < 254:
                raise SdoAbortedError(0x06090030)
            elif index == 0x1005:
                if value & 0xFFFFF800:  # bit 30: produce SYNC (these drives do not); bit 29: a 29-bit id
                    raise SdoAbortedError(0x06090030)
                self._subscribe_sync(value)
            elif index in self._rpdo_handlers and subindex == 1:
                self._subscribe_rpdo(index, value)
            elif index in OPTION_CODES and value not in self._accepted[index]:
                raise SdoAbortedError(0x06090030)  # value range of parameter exceeded

    def _subscribe_sync(self, cob_entry: int) -> None:
        """Consume SYNC on the COB-ID of 0x1005."""
        if self._sync_cob is not None:
            self.network.unsubscribe(self._sync_cob, self._on_sync)
        self._sync_cob = cob_entry & 0x7FF
        self.network.subscribe(self._sync_cob, self._on_sync)

    def _check_pdo_comm_write(self, index: int, subindex: int, value: int) -> None:
        """CiA 301: while a PDO is valid (COB-ID bit 31 clear) its COB-ID (bits 0-29) and its inhibit time
        stay as they are: make it invalid first. A 29-bit COB-ID (bit 29) is refused: these drives send and
        take standard frames only. Both with abort 0x06090030 (value range of parameter exceeded)."""
        cob = int(self._get(index, 1))
        valid = not cob & 0x80000000
        if subindex == 1:
            if value & 0x20000000 or value & 0x1FFFF800:
                raise SdoAbortedError(0x06090030)
            if valid and not value & 0x80000000 and (value ^ cob) & 0x3FFFFFFF & ~PDO_NO_RTR:
                raise SdoAbortedError(0x06090030)
        elif valid and value != int(self._get(index, 3)):
            raise SdoAbortedError(0x06090030)

    def _subscribe_rpdo(self, comm_index: int, cob_entry: int) -> None:
        handler = self._rpdo_handlers[comm_index]
        old = self._rpdo_cobs.pop(comm_index, None)
        if old is not None:
            self.network.unsubscribe(old, handler)
        if not cob_entry & 0x80000000:  # bit 31 set: PDO not valid
            self._rpdo_cobs[comm_index] = cob_entry & 0x7FF
            self.network.subscribe(cob_entry & 0x7FF, handler)

    def _on_sdo_request(self, can_id, data, timestamp) -> None:
        """An SDO request is not even carried out in NMT STOPPED (CiA 301: NMT and heartbeat only there); a
        write used to take effect with its answer held back."""
        with self._lock:
            if self.silent or self.nmt == NMT_STOPPED:
                return
        self.node.sdo.on_request(can_id, data, timestamp)

    def _send_sdo_response(self, response) -> None:
        with self._lock:
            if self.silent or self.nmt == NMT_STOPPED:
                return
            if self.drop_sdo:
                self.drop_sdo -= 1 if self.drop_sdo > 0 else 0
                return
        self._sdo_send(response)

    # --- received frames -------------------------------------------------------------------
    def _on_nmt(self, can_id, data, timestamp) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        with self._lock:
            if self.silent:
                return
            cmd = data[0]
            if cmd == codec.NMT_START:
                self.nmt = NMT_OPERATIONAL
                self._last_tpdo = None  # send the current status at once
            elif cmd == codec.NMT_STOP:
                self.nmt = NMT_STOPPED
            elif cmd == codec.NMT_PREOP:
                self.nmt = NMT_PREOP
            elif cmd in (codec.NMT_RESET_NODE, codec.NMT_RESET_COMM):
                if cmd == codec.NMT_RESET_NODE:
                    self._reset_application()
                self._reset_communication()
                self.boot()
                return
            self._publish()

    def _rpdo(self, data, size: int):
        """The bytes of an RPDO that maps `size` bytes, or None when it is not to be processed (CiA 301):
        a longer one is taken by its first `size` bytes; a shorter one is not processed and reported by
        EMCY 0x8210 (PDO not processed due to length error). Only in OPERATIONAL."""
        if self.silent or self.nmt != NMT_OPERATIONAL:
            return None
        if len(data) < size:
            log.warning("%s: RPDO of %d bytes, %d mapped: not processed", self.name, len(data), size)
            self._report(EMCY_PDO_LENGTH)
            return None
        return bytes(data[:size])

    def _on_rpdo1(self, can_id, data, timestamp) -> None:
        with self._lock:
            if (data := self._rpdo(data, 2)) is not None:
                self._on_controlword(codec.unpack_controlword(data))

    def _on_rpdo2(self, can_id, data, timestamp) -> None:
        with self._lock:
            if (data := self._rpdo(data, 4)) is not None:
                self._store(0x607A, 0, codec.unpack_target(data))

    def _on_rpdo3(self, can_id, data, timestamp) -> None:
        with self._lock:
            if (data := self._rpdo(data, 1)) is not None:
                try:
                    self._set_mode(codec.unpack_mode(data))
                except SdoAbortedError:
                    log.warning("%s: bad RPDO3 %s", self.name, data.hex())

    def on_host_heartbeat(self, can_id, data, timestamp) -> None:
        with self._lock:
            if not self.silent:
                self._host_seen_s = self.clock.now()

    # --- CiA 402 ---------------------------------------------------------------------------
    @property
    def statusword(self) -> int:
        return codec.statusword_for(
            self.state,
            target_reached=self._target_reached_bit(),
            ack=self.ack,
            following_error=self.following_error,
            internal_limit=self.internal_limit,
        )

    def _target_reached_bit(self) -> bool:
        """Statusword bit 10. In OPERATION ENABLED: the target reached, or standstill after a halt. In
        QUICK STOP ACTIVE: the quick stop ramp has ended and the axis stands (CiA 402, for 0x605A 5-8; with
        1 or 2 the drive leaves QUICK STOP ACTIVE at standstill). Clear in the other states."""
        if self.state == "OPERATION_ENABLED":
            return self.target_reached
        return self.state == "QUICK_STOP_ACTIVE" and self.motion is None

    @property
    def error_register(self) -> int:
        """0x1001, as in the EMCY: generic error, plus manufacturer-specific for monitoring codes."""
        code = self.error_code
        return 0 if not code else 0x01 | (0x80 if code >> 12 == 8 else 0)

    def _set_mode(self, mode: int) -> None:
        if mode not in (0, codec.PP_MODE):
            raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
        if mode != codec.PP_MODE:
            # leaving profile position: its move stops (decelerating on 0x6084), nothing resumes
            if self.motion is not None and not self.motion.stopping:
                self._ramp_down(0x6084)
            self.pending = self.halted = None
        self.mode = mode
        self._store(0x6060, 0, mode)
        self._publish()

    def configure_option_codes(self, values: dict[int, int] | None = None, *,
                               accepted: dict[int, set[int]] | None = None, missing=()) -> None:
        """Make this drive one of another make, as commissioning left it: `values` its factory (power-on)
        option codes, index -> value; `accepted` the values it takes by SDO, index -> set (others are
        refused with abort 0x06090030); `missing` the option code objects it lacks (abort 0x06020000 on
        any SDO access; it still stops as its `values` say). Only values this simulation honours."""
        values, accepted, missing = values or {}, accepted or {}, set(missing)
        asked = [(i, {v}) for i, v in values.items()] + [(i, set(a)) for i, a in accepted.items()]
        asked += [(i, set()) for i in missing]
        for index, wanted in asked:
            if index not in OPTION_CODES or not wanted <= set(OPTION_CODES[index]):
                raise ValueError(f"0x{index:04X} {sorted(wanted)}: not an option code value the simulation models")
        with self._lock:
            for index, value in values.items():
                self._store(index, 0, value)
                self._power_on[index] = dict(self.node.data_store[index])
            for index, allowed in accepted.items():
                self._accepted[index] = set(allowed)
            self._missing = missing

    def _option(self, index: int):
        """What the option code `index` (0x605A-0x605E) asks for; its value was checked on writing."""
        return OPTION_CODES[index][int(self._get(index))]

    def _on_controlword(self, cw: int) -> None:
        prev, self.controlword = self.controlword, cw
        self._store(0x6040, 0, cw)
        cmd = codec.command_of(cw)
        s = self.state
        if cmd != "ENABLE_OPERATION":
            self.enable_held = False  # another command replaces a held enable operation
        # OPERATION ENABLED also while a shutdown or disable operation waits for its ramp: those
        # commands are still taken (disable voltage, quick stop, the other of the two), no set-point
        enabled = s == "OPERATION_ENABLED"
        if s in ("FAULT", "FAULT_REACTION_ACTIVE"):
            if s == "FAULT" and cw & codec.CW_FAULT_RESET and not prev & codec.CW_FAULT_RESET:
                self._fault_reset()
        elif cmd == "DISABLE_VOLTAGE":
            self._disable("SWITCH_ON_DISABLED")  # 7, 9, 10, 12: the drive function off at once
        elif cmd == "QUICK_STOP":
            if enabled:
                self._quick_stop()  # 11
            elif s != "QUICK_STOP_ACTIVE":  # (in QUICK STOP ACTIVE, a quick stop is no transition)
                self._disable("SWITCH_ON_DISABLED")  # 7, 10
        elif cmd == "SHUTDOWN":
            if enabled:
                self._leave_enabled("READY_TO_SWITCH_ON", self._option(0x605B))  # 8
            elif s in ("SWITCH_ON_DISABLED", "SWITCHED_ON"):
                self._disable("READY_TO_SWITCH_ON")  # 2, 6
        elif cmd == "SWITCH_ON":
            if enabled:
                self._leave_enabled("SWITCHED_ON", self._option(0x605C))  # 5
            elif s == "READY_TO_SWITCH_ON":
                self._disable("SWITCHED_ON")  # 3
        elif cmd == "ENABLE_OPERATION":
            # 4; 16 only where the quick stop stays in QUICK STOP ACTIVE (0x605A 5-8)
            if s == "SWITCHED_ON" or (s == "QUICK_STOP_ACTIVE" and self.after_ramp is None):
                self._enable()
            elif s == "READY_TO_SWITCH_ON":
                # switch on + enable operation: transitions 3 and 4 (the controlword is a level)
                self._disable("SWITCHED_ON")
                self._enable()
        if s == self.state == "OPERATION_ENABLED" and self.after_ramp is None and self.mode == codec.PP_MODE:
            # only a drive that was already enabled takes a set-point: the controlword that
            # enables it never starts a move, even with bit 4 set (enabling never jumps)
            self._profile_position(prev, cw)
        self._publish()

    def _enable(self) -> None:
        """Transition 4 or 16. Not while the axis still ramps down or coasts (no drive stops it in zero
        time): the drive stays in its state and takes the held command at standstill (`_take_held_enable`)."""
        if self.motion is not None:  # out of OPERATION ENABLED every motion is a stop
            self.enable_held = True
            return
        self.enable_held = False
        # enabling never jumps: hold the actual position until the next set-point
        self._stop_motion()
        self.target_reached = True
        self.state = "OPERATION_ENABLED"

    def _take_held_enable(self) -> None:
        """At standstill, an enable operation held during the ramp or coast, if its transition is still one."""
        if not self.enable_held or self.motion is not None:
            return
        self.enable_held = False
        if self.state == "SWITCHED_ON" or (self.state == "QUICK_STOP_ACTIVE" and self.after_ramp is None):
            self._enable()

    def _disable(self, state: str) -> None:
        """Enter a state without the drive function (SWITCH ON DISABLED, READY TO SWITCH ON,
        SWITCHED ON): a motion still running is no longer driven and coasts."""
        self._coast()
        self.pending = self.halted = self.after_ramp = None
        self.ack = False
        self.state = state

    def _leave_enabled(self, target: str, decel_index: int | None) -> None:
        """Shutdown (8) or disable operation (5) as its option code says: with a ramp, the drive
        stays in OPERATION ENABLED while it slows down and enters `target` at standstill; with
        "disable drive function" (None) it enters `target` at once and the axis coasts."""
        if decel_index is None:
            self._disable(target)
            return
        self._ramp_down(decel_index)
        self.ack = False
        self.after_ramp = target
        if self.motion is None:
            self._end_ramp()

    def _quick_stop(self) -> None:
        """Quick stop (11) as 0x605A says: QUICK STOP ACTIVE while the axis ramps down, then either
        stay there (5, 6) or go on to SWITCH ON DISABLED (1, 2); 0 disables the drive function."""
        decel_index, final = self._option(0x605A)
        if decel_index is None:
            self._disable(final)
            return
        self._ramp_down(decel_index)
        self.ack = False
        self.state = "QUICK_STOP_ACTIVE"
        self.after_ramp = None if final == "QUICK_STOP_ACTIVE" else final
        if self.motion is None and self.after_ramp is not None:
            self._end_ramp()

    def _abort_connection(self) -> None:
        """The host's heartbeat missed (life guarding, CiA 301): as 0x6007 says; a drive without the object
        faults. Every way but a fault reports it by EMCY 0x8130 (a fault does on its own)."""
        action = "fault" if 0x6007 in self._missing else self._option(0x6007)
        if action == "fault":
            self._fault(0x8130)
            return
        if action == "disable voltage":
            self._disable("SWITCH_ON_DISABLED")
        elif action == "quick stop" and self.state == "OPERATION_ENABLED":
            self._quick_stop()
        self._emcy(0x8130)

    def _emcy(self, code: int) -> None:
        """Report `code` by EMCY (logged, unless silent), then the status it left."""
        self._report(code)
        self._publish()

    def _report(self, code: int) -> None:
        """An EMCY of `code` with the error register as it stands (logged; not sent while silent, nor in NMT
        STOPPED, where CiA 301 leaves a node NMT and error control (heartbeat) only)."""
        self.emcy_log.append(code)
        if not self.silent and self.nmt != NMT_STOPPED:
            self.network.send_message(codec.EMCY_BASE + self.node_id,
                                      codec.pack_emcy(codec.Emcy(code, self.error_register)))

    def _end_ramp(self) -> None:
        """Standstill after the ramp of a transition: enter its state (FAULT after the fault reaction)."""
        state, self.after_ramp = self.after_ramp, None
        if state == "FAULT":
            self.state = "FAULT"
        else:
            self._disable(state)

    def _profile_position(self, prev: int, cw: int) -> None:
        rising = cw & codec.CW_NEW_SET_POINT and not prev & codec.CW_NEW_SET_POINT and not self.ignore_set_point
        halt = bool(cw & codec.CW_HALT)
        if rising and not self.ack:
            target = int(self._get(0x607A))
            relative = bool(cw & codec.CW_RELATIVE)
            if self.halted is not None or (halt and self.motion is None):
                # halted: the new set-point is taken and runs when the halt is released
                if relative:  # relative to the preceding (the halted) target
                    target += self.halted if self.halted is not None else round(self.position_counts)
                self.halted = target
            elif self.motion is not None and not cw & codec.CW_CHANGE_IMMEDIATELY:
                self.pending = (target, relative)  # single set-point: after the current move
            else:
                self._start_move(target, relative)
            self.ack = self.state == "OPERATION_ENABLED"  # a refused set-point (fault) is not taken
        elif not cw & codec.CW_NEW_SET_POINT and self.ack and self.pending is None:
            self.ack = False  # (a buffered set-point keeps it: the buffer is full)
        if halt and self.motion is not None and not self.motion.stopping:
            # halt: stop as 0x605D says (default: the profile deceleration 0x6084); the target is
            # kept for the release
            target, pending = self.motion.target_counts, self.pending
            self._ramp_down(self._option(0x605D))
            self.halted, self.pending = target, pending
            if self.motion is None:
                self.target_reached = True
        elif not halt and self.halted is not None and self.motion is None:
            self._resume()

    def _resume(self) -> None:
        """Halt released at standstill: continue the positioning to the interrupted target."""
        target, self.halted = self.halted, None
        self._start_move(target, False)

    def _start_move(self, target: int, relative: bool) -> None:
        if relative:
            # CiA 402 (positioning option code 0x60F2 = 0): relative to the preceding target
            m = self.motion
            target += m.target_counts if m is not None and not m.stopping else round(self.position_counts)
        lo, hi = int(self._get(0x607D, 1)), int(self._get(0x607D, 2))
        if not lo <= target <= hi:
            self._fault(0x8612)
            return
        v = float(self._get(0x6081))
        a, d = float(self._get(0x6083)), float(self._get(0x6084))
        if v <= 0 or a <= 0 or d <= 0:
            self._fault(0x6320)
            return
        self.internal_limit = False
        self.target_reached = False
        now, m = self.clock.now(), self.motion
        v0 = m.profile.velocity_at(now - m.t0_s) if m is not None and not m.coasting else 0.0
        if v0:
            # a set-point taken at once during a move (change immediately): on from where the axis is and
            # the speed it has, not from rest
            here = m.start_counts + m.profile.position_at(now - m.t0_s)
            self.motion = _Motion(now, here, target, from_speed(target - here, v0, v, a, d))
        else:
            self.motion = _Motion(now, self.position_counts, target, trapezoid(target - self.position_counts, v, a, d))

    def _stop_motion(self) -> None:
        self.motion = None
        self.pending = None
        self.halted = None
        self.after_ramp = None

    def _ramp_down(self, decel_index: int = 0x6085) -> None:
        """Replace the running move by a ramp to standstill at the deceleration of object
        `decel_index` (quick stop 0x6085, profile 0x6084). A ramp already running at that
        deceleration goes on; a coasting axis is not driven, so it cannot be ramped."""
        m = self.motion
        self.pending = None
        self.halted = None
        if m is None or m.coasting:
            return
        d = float(self._get(decel_index))
        if m.stopping and m.profile.decel == d:
            return
        self._stop_on(m, d)

    def _coast(self) -> None:
        """The drive function is off: a running motion goes on undriven, slowed by friction alone."""
        m = self.motion
        if m is not None and not m.coasting:
            self._stop_on(m, self.coast_decel_counts, coasting=True)

    def _stop_on(self, m: _Motion, d: float, coasting: bool = False) -> None:
        now = self.clock.now()
        v0 = m.profile.velocity_at(now - m.t0_s)
        if v0 == 0.0 or d <= 0 or self._jammed_at is not None:
            # a jammed axis already stands (velocity actual 0): its stop ends at once, as its fault
            # reaction does; a ramp of the demand alone would never end (no bit 10, no state after it)
            self.motion = None
            return
        t_s = abs(v0) / d
        ramp = Trapezoid(v0 * t_s / 2, abs(v0), d, d, 0.0, 0.0, t_s)
        # from where the axis is now, not where the last tick left it: a command between two ticks (10 ms)
        # lost the travel since, 1620 counts at 180000 counts/s
        here = m.start_counts + m.profile.position_at(now - m.t0_s)
        self.motion = _Motion(now, here, round(here + ramp.distance), ramp, True, coasting)

    def _fault(self, code: int, *, following_error: bool = False) -> None:
        if self.state in ("FAULT", "FAULT_REACTION_ACTIVE"):
            return
        self.enable_held = False
        m = self.motion
        if self._jammed_at is not None:
            self._stop_motion()  # the axis is blocked mechanically
        elif m is not None and not m.coasting:
            # the fault reaction (0x605E): a ramp in FAULT REACTION ACTIVE, then FAULT (in _move),
            # or "disable drive function": FAULT at once and the axis coasts
            decel_index = self._option(0x605E)
            if decel_index is None:
                self._coast()
            else:
                self._ramp_down(decel_index)
        self.pending = self.halted = None
        if self.motion is not None and not self.motion.coasting:
            self.state, self.after_ramp = "FAULT_REACTION_ACTIVE", "FAULT"
        else:
            self.state, self.after_ramp = "FAULT", None
        self.ack = False
        self.following_error = following_error
        self.error_code = code
        self._emcy(code)

    def _fault_reset(self) -> None:
        self.state = "SWITCH_ON_DISABLED"
        self._jammed_at = None  # the operator cleared the blockage before resetting
        self.error_code = 0
        self.following_error = False
        self._armed = [f for f in self._armed if f["kind"] not in ("emcy", "following_error")]
        if not self.silent and self.nmt != NMT_STOPPED:
            self.network.send_message(codec.EMCY_BASE + self.node_id, codec.pack_emcy(codec.Emcy(0, 0)))

    def _restore_power_on(self, lo: int, hi: int) -> None:
        """Objects lo..hi back to their power-on values (CiA 301 NMT resets)."""
        store = self.node.data_store
        for index in [i for i in store if lo <= i <= hi]:
            del store[index]
        for index, subs in self._power_on.items():
            if lo <= index <= hi:
                store[index] = dict(subs)

    def _reset_application(self) -> None:
        """NMT Reset Node: the application and profile area (0x2000-0xFFFF) to power-on values;
        the actual position stays (absolute encoders) and becomes the target. The drive function is
        off: an axis still moving is no longer driven and coasts, as a disabled axis does."""
        self.state = "NOT_READY_TO_SWITCH_ON"
        self._coast()
        self.pending = self.halted = self.after_ramp = None
        self.enable_held = False
        self.ack, self.error_code, self.following_error, self.mode = False, 0, False, 0
        self.controlword, self.internal_limit, self.target_reached = 0, False, True
        self._restore_power_on(0x2000, 0xFFFF)
        self._store(0x607A, 0, round(self.position_counts))

    def _reset_communication(self) -> None:
        """NMT Reset Communication: the communication area (0x1000-0x1FFF) to power-on values,
        with what depends on it: RPDO COB-IDs, the host heartbeat watch, TPDO timing."""
        self._restore_power_on(0x1000, 0x1FFF)
        self._subscribe_sync(int(self._get(0x1005)))
        for comm in self._rpdo_handlers:
            self._subscribe_rpdo(comm, int(self._get(comm, 1)))
        self._set_host_watch(int(self._get(0x1016, 1)))
        self._last_tpdo, self._sync_count, self._tpdo_sent_s = None, 0, -1e9

    # --- host heartbeat watch --------------------------------------------------------------
    def _set_host_watch(self, entry: int) -> None:
        if self._host_id:
            self.network.unsubscribe(codec.HEARTBEAT_BASE + self._host_id, self.on_host_heartbeat)
        self._host_id, ms = codec.split_consumer_heartbeat_entry(entry)
        self._host_deadline_s = ms / 1000.0
        self._host_seen_s = None  # CiA 301: monitoring starts with the first heartbeat received
        if self._host_id and ms:
            self.network.subscribe(codec.HEARTBEAT_BASE + self._host_id, self.on_host_heartbeat)

    # --- time steps ------------------------------------------------------------------------
    def boot(self) -> None:
        """Power-up: boot-up message, then PRE-OPERATIONAL with heartbeats."""
        with self._lock:
            self.nmt = NMT_INIT
            if self.state == "NOT_READY_TO_SWITCH_ON":
                self.state = "SWITCH_ON_DISABLED"  # automatic transition 1
            if not self.silent:
                self.network.send_message(codec.HEARTBEAT_BASE + self.node_id, codec.pack_heartbeat(0))
            self.nmt = NMT_PREOP
            self._last_hb_s = self.clock.now()

    def step(self, now: float) -> None:
        with self._lock:
            if self.silent:
                # a dead node also stops hearing the host: it stops driving (as a real drive would)
                if self.state == "OPERATION_ENABLED":
                    self._fault(0x8130)
                self._host_seen_s = None  # watching restarts with the next heartbeat heard
                self._advance(now)  # the mechanics go on (the fault reaction ramp), in silence
                return
            starved = (self._stepped_s is not None
                       and now - self._stepped_s > HOST_WATCH_STARVED_SHARE * self._host_deadline_s)
            self._stepped_s = now
            if self._host_id and self._host_seen_s is not None and self._host_deadline_s > 0:
                if starved:
                    # the simulation itself was held up (it shares the host's process and clock
                    # thread): the host's silence meanwhile cannot be told from ours, so it counts
                    # from now; a real drive keeps time on its own and needs no such rule
                    self._host_seen_s = max(self._host_seen_s, now)
                if now - self._host_seen_s > self._host_deadline_s and "FAULT" not in self.state:
                    driven = self.motion is not None and not self.motion.coasting
                    if self.state in ("OPERATION_ENABLED", "QUICK_STOP_ACTIVE") or driven:
                        self._abort_connection()
                    self._host_seen_s = None  # report once; re-armed by the next heartbeat
            self._advance(now)
            self._publish(now)
            hb_s = int(self._get(0x1017)) / 1000.0
            if hb_s > 0 and now - self._last_hb_s >= hb_s - 1e-9:
                self._last_hb_s = _next_phase(self._last_hb_s, hb_s, now)
                self.network.send_message(codec.HEARTBEAT_BASE + self.node_id, codec.pack_heartbeat(self.nmt))

    def _advance(self, now: float) -> None:
        """One step of the mechanics, then what waits for standstill."""
        self._move(now)
        self._take_held_enable()

    def _move(self, now: float) -> None:
        m = self.motion
        if m is None:
            return
        elapsed = now - m.t0_s
        demand = m.start_counts + m.profile.position_at(elapsed)
        for f in list(self._armed) if not m.stopping else ():
            if elapsed >= f["after_s"]:
                self._armed.remove(f)
                if f["kind"] == "following_error":
                    self._jammed_at = self.position_counts  # the axis is blocked mechanically
                else:
                    self.position_counts = demand
                    self._event(f)
                    return
        if self._jammed_at is not None:
            # the actual position stays; the drive faults once the demand leaves the window (a stop of a
            # jammed axis ends at once, in _stop_on: only a move's demand runs on here)
            self.position_counts = self._jammed_at
            if abs(demand - self._jammed_at) > int(self._get(0x6065)):
                self._fault(0x8611, following_error=True)
            return
        self.position_counts = demand
        if self._blocked(m):
            if self.motion is None and self.after_ramp is not None:
                self._end_ramp()
            return
        if m.stopping:
            if elapsed >= m.profile.duration_s:
                self.motion = None
                if self.after_ramp is not None:
                    self._end_ramp()
                elif self.halted is not None:
                    if self.controlword & codec.CW_HALT:
                        self.target_reached = True  # halted: statusword bit 10 = standstill
                    else:
                        self._resume()  # the halt was released during the ramp
            return
        if elapsed >= m.profile.duration_s:
            self.position_counts = float(m.target_counts)
            self.motion = None
            if self.pending is not None:
                target, relative = self.pending
                self.pending = None
                self._start_move(target, relative)
                if not self.controlword & codec.CW_NEW_SET_POINT:
                    self.ack = False  # the buffer is free again
            else:
                self.target_reached = True

    def _blocked(self, m: _Motion) -> bool:
        """Hook for the gripper: True when the motion was stopped by something physical."""
        return False

    def _tpdo1_data(self) -> bytes:
        return codec.pack_tpdo1(codec.DriveStatus(self.statusword, round(self.position_counts), self.mode))

    def _publish(self, now: float | None = None) -> None:
        """Event-driven TPDO1 (transmission type 254/255): when the status changed, or when the
        event timer is due, but never sooner than the inhibit time (0x1800 sub 3, 100 us units)
        after the last one: a change meanwhile goes out, as it then stands, once the inhibit time
        has passed (on the tick after it). Synchronous types are sent on SYNC instead (`_on_sync`)."""
        if self.silent or self.nmt != NMT_OPERATIONAL:
            return
        cob = int(self._get(0x1800, 1))
        if cob & 0x80000000 or int(self._get(0x1800, 2)) <= 240:
            return
        now = self.clock.now() if now is None else now
        if now - self._tpdo_sent_s < int(self._get(0x1800, 3)) * 1e-4 - 1e-9:
            return  # inhibited
        data = self._tpdo1_data()
        event_ms = int(self._get(0x1800, 5))
        due = event_ms > 0 and now - self._last_tpdo_s >= event_ms / 1000.0 - 1e-9
        if data != self._last_tpdo:  # an event: the event timer restarts
            self._last_tpdo, self._last_tpdo_s = data, now
        elif due:
            self._last_tpdo_s = _next_phase(self._last_tpdo_s, event_ms / 1000.0, now)
        else:
            return
        self._tpdo_sent_s = now
        self.network.send_message(cob & 0x7FF, data)

    def _on_sync(self, can_id, data, timestamp) -> None:
        """Synchronous TPDO1: type 0 on SYNC when changed, types 1-240 on every n-th SYNC."""
        with self._lock:
            if self.silent or self.nmt != NMT_OPERATIONAL:
                return
            self._sync_count += 1
            cob, kind = int(self._get(0x1800, 1)), int(self._get(0x1800, 2))
            if cob & 0x80000000 or kind > 240:
                return
            data = self._tpdo1_data()
            if (kind == 0 and data != self._last_tpdo) or (kind > 0 and self._sync_count % kind == 0):
                self._last_tpdo, self._last_tpdo_s = data, self.clock.now()
                self._tpdo_sent_s = self._last_tpdo_s
                self.network.send_message(cob & 0x7FF, data)

    # --- fault injection -------------------------------------------------------------------
    def arm(self, kind: str, **kw) -> None:
        with self._lock:
            if kind == "silent":
                self.silent = True
            elif kind == "drop_sdo":
                self.drop_sdo = int(kw.get("count", -1))
            elif kind == "ignore_set_point":
                self.ignore_set_point = True
            elif kind == "following_error":
                # the axis jams `after_s` into its next move; the drive trips on its window (0x6065)
                self._armed.append({"kind": kind, "after_s": float(kw.get("after_s") or 0.0)})
            elif kind in TIMED_EVENTS:
                event = {"kind": kind, "code": int(kw.get("code", 0x2310))}
                if kw.get("after_s") is None:
                    self._event(event)
                    self._publish()
                else:
                    self._armed.append({**event, "after_s": float(kw["after_s"])})
            else:
                raise ValueError(f"unknown fault kind {kind!r}; one of {FAULT_KINDS}")

    def _event(self, event: dict) -> None:
        """An injected event from the drive's own side: an EMCY fault; a quick stop (its quick stop input,
        transition 11 as 0x605A says); or STO ('disable': the drive function off at once, SWITCH ON
        DISABLED, the axis coasts). The master's controlword is left as it was: the drive acts on the next
        command it receives, not on the level it still holds."""
        kind = event["kind"]
        if kind == "emcy":
            self._fault(event["code"])
        elif kind == "quick_stop" and self.state == "OPERATION_ENABLED":
            self._quick_stop()
        elif kind == "disable" and "FAULT" not in self.state:
            self._disable("SWITCH_ON_DISABLED")
        elif kind == "internal_limit" and self.state == "OPERATION_ENABLED" and self.motion is not None:
            # a limit switch or a torque limit: the move ends where the axis is, bits 10 and 11 set, no fault
            self.motion, self.pending = None, None
            if not self.controlword & codec.CW_NEW_SET_POINT:
                self.ack = False  # a buffered set-point is dropped: the buffer is free
            self.internal_limit = self.target_reached = True

    def heal(self) -> None:
        """Stop injected misbehaviour (the node talks again); latched drive faults stay."""
        with self._lock:
            self.silent = False
            self.drop_sdo = 0
            self.ignore_set_point = False
            self._armed.clear()

    def position(self) -> float:
        with self._lock:
            return codec.from_counts(self.position_counts, self.counts_per_unit)


class SimGripper(SimDrive):
    """A parallel gripper on the 402 profile: position = jaw opening. Closing onto a part of
    width `object_width_mm` stops there with the force limit reached (statusword bit 11)."""

    def __init__(self, *args, grip_force_n: float, **kw):
        super().__init__(*args, grip_force_n=grip_force_n, **kw)  # a power-on value: a reset keeps it
        self.object_width_mm: float | None = None
        # A simulated world may say instead what lies between the jaws when they start closing:
        # called once per closing move, returns the part's width or None.
        self.object_width_fn = None
        self._fn_motion, self._fn_width = None, None

    def _blocked(self, m: _Motion) -> bool:
        w = self.object_width_mm
        if self.object_width_fn is not None and m.target_counts < m.start_counts:
            if m is not self._fn_motion:
                self._fn_motion, self._fn_width = m, self.object_width_fn()
            w = self._fn_width
        if w is None:
            return False
        w_counts = w * self.counts_per_unit
        closing = m.target_counts < m.start_counts
        if closing and m.start_counts >= w_counts > m.target_counts and self.position_counts <= w_counts:
            self.position_counts = w_counts
            self.motion = None
            self.pending = None
            if not self.controlword & codec.CW_NEW_SET_POINT:
                self.ack = False  # a buffered set-point is dropped: the buffer is free
            self.internal_limit = True
            self.target_reached = True
            return True
        return False

    @property
    def grip_force_n(self) -> float:
        return int(self._get(GRIP_FORCE_INDEX)) / 10.0
