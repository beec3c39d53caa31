"""The simulated drive's PDOs: RPDO1-3 (controlword, target, mode) as received, TPDO1 (status,
position, mode) on change, on its event timer and on SYNC, and the rules for the PDO communication
parameters (CiA 301).
"""

from __future__ import annotations

import logging

from canopen.sdo import SdoAbortedError

from drivers import codec
from drivers.sim_nmt import NMT_OPERATIONAL, next_phase

log = logging.getLogger("drivers.simdrive")  # the simulated drive's one logger, as before its split

TPDO_EVENT_MS = 50  # TPDO1 is also sent at least this often (canopen's BaseNode402 waits 0.2 s)
EMCY_PDO_LENGTH = 0x8210  # an RPDO shorter than its mapping: not processed (CiA 301)
EMCY_PARAMETER = 0x6320  # a value a PDO wrote that the drive does not take (CiA 402: parameter error)
TPDO_COMM_FIRST, TPDO_COMM_LAST = 0x1800, 0x1803  # the TPDO communication parameters
PDO_NO_RTR = 1 << 30  # COB-ID bit 30 of a TPDO: no RTR allowed (these drives answer none)


class Pdos:
    """The PDOs and SYNC of one simulated drive.

    A part of `drivers.simdrive.SimDrive`, whose `__init__` sets the state these methods use.
    """

    def _set_data_no_rtr(self, index: int, subindex: int, data: bytes, check_writable: bool = False) -> None:
        """A TPDO's COB-ID keeps bit 30 set whatever is written there: these drives answer no RTR (CiA 301:
        bit 30 = 1, no RTR allowed on this PDO), so a master that reads it back (canopen's PdoMap) knows it."""
        if TPDO_COMM_FIRST <= index <= TPDO_COMM_LAST and subindex == 1 and len(data) == 4:
            data = (int.from_bytes(data, "little") | PDO_NO_RTR).to_bytes(4, "little")
        self._set_data(index, subindex, data, check_writable)

    def _subscribe_sync(self, cob_entry: int) -> None:
        """Consume SYNC on the COB-ID of 0x1005."""
        if self._sync_cob is not None:
            self.network.unsubscribe(self._sync_cob, self._on_sync)
        self._sync_cob = cob_entry & 0x7FF
        self.network.subscribe(self._sync_cob, self._on_sync)

    def _check_pdo_comm_write(self, index: int, subindex: int, value: int) -> None:
        """CiA 301: while a PDO is valid (COB-ID bit 31 clear) its COB-ID (bits 0-29), and a TPDO's inhibit time,
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
        """A mode of operation this drive does not have keeps the mode it has: by SDO the write is aborted, a PDO
        cannot be, so the drive reports it by EMCY 0x6320 (parameter error; no fault, as for 0x8210)."""
        with self._lock:
            if (data := self._rpdo(data, 1)) is not None:
                try:
                    self._set_mode(codec.unpack_mode(data))
                except SdoAbortedError:
                    log.warning("%s: RPDO3 mode %s refused: EMCY 0x%04X", self.name, data.hex(), EMCY_PARAMETER)
                    self._emcy(EMCY_PARAMETER)

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
            self._last_tpdo_s = next_phase(self._last_tpdo_s, event_ms / 1000.0, now)
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
