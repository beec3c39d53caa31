"""The simulated drive's CiA 301 network side: NMT commands and resets, boot-up, EMCY, and the
watch on the host's heartbeat (0x1016) with what a missed one does (0x6007). The drive's own heartbeat
goes out in `SimDrive.step`.
"""

from __future__ import annotations

from drivers import codec

NMT_OPERATIONAL, NMT_PREOP, NMT_STOPPED, NMT_INIT = 0x05, 0x7F, 0x04, 0x00


def error_register_bits(code: int) -> int:
    """The error register (0x1001) bits an error of EMCY `code` sets (CiA 301; 0: no error): bit 0 (generic) for
    every error, and its class: current 2xxx bit 1, voltage 3xxx bit 2, temperature 4xxx bit 3, communication
    81xx and protocol 82xx bit 4 (both communication errors, as lely's and CANopenNode's stacks have them), the
    device profile's monitoring codes 83xx-8Fxx (CiA 402: following error 0x8611, position limit 0x8612) bit 5,
    manufacturer specific FFxx bit 7. Other codes (hardware 5xxx, software 6xxx, ...) set bit 0 alone."""
    if not code:
        return 0
    group = code >> 12
    bits = 0x01
    if group in (2, 3, 4):
        bits |= 1 << (group - 1)
    elif 0x8100 <= code <= 0x82FF:
        bits |= 0x10
    elif 0x8300 <= code <= 0x8FFF:
        bits |= 0x20
    elif code >> 8 == 0xFF:
        bits |= 0x80
    return bits


def next_phase(last_s: float, period_s: float, now_s: float) -> float:
    """When a periodic frame due at `last_s + period_s` goes out at `now_s` (on the next
    tick): keep the phase, so the period holds on average; start afresh when far behind."""
    due = last_s + period_s
    return due if now_s - due < period_s else now_s


class NetworkManagement:
    """NMT, EMCY and the host heartbeat watch of one simulated drive.

    A part of `drivers.simdrive.SimDrive`, whose `__init__` sets the state these methods use.
    """

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
            elif cmd == codec.NMT_RESET_NODE:
                self._reset_node()
                return
            elif cmd == codec.NMT_RESET_COMM:
                self._reset_communication()
                self.boot()
                return
            self._publish()

    def on_host_heartbeat(self, can_id, data, timestamp) -> None:
        with self._lock:
            if not self.silent:
                self._host_seen_s = self.clock.now()

    @property
    def error_register(self) -> int:
        """0x1001: the bits of the fault the drive holds (`error_register_bits`); 0 without one."""
        return error_register_bits(self.error_code)

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
        """An EMCY of `code` (0: error reset) with the error register in its byte 2 as it stands with that error
        (CiA 301): the fault's bits and `code`'s. An error without a fault (a PDO of the wrong length, a bad mode
        by PDO, the host's heartbeat missed where 0x6007 says no fault) is over with its report: 0x1001 keeps the
        fault's bits alone. Logged; not sent while silent, nor in NMT STOPPED, where CiA 301 leaves a node NMT
        and error control (heartbeat) only."""
        self.emcy_log.append(code)
        if not self.silent and self.nmt != NMT_STOPPED:
            register = self.error_register | error_register_bits(code)
            self.network.send_message(codec.EMCY_BASE + self.node_id, codec.pack_emcy(codec.Emcy(code, register)))

    def _reset_node(self) -> None:
        """The drive's own reset, as NMT Reset Node or a power glitch brings it: power-on values, the boot-up
        message, PRE-OPERATIONAL."""
        self._reset_application()
        self._reset_communication()
        self.boot()

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

    def _set_host_watch(self, entry: int) -> None:
        if self._host_id:
            self.network.unsubscribe(codec.HEARTBEAT_BASE + self._host_id, self.on_host_heartbeat)
        self._host_id, ms = codec.split_consumer_heartbeat_entry(entry)
        self._host_deadline_s = ms / 1000.0
        self._host_seen_s = None  # CiA 301: monitoring starts with the first heartbeat received
        if self._host_id and ms:
            self.network.subscribe(codec.HEARTBEAT_BASE + self._host_id, self.on_host_heartbeat)

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
