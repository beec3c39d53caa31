"""The simulated drive's object dictionary as its SDO server serves it: the values commissioning
stored (power-on values, restored by the NMT resets), the objects computed on reading, the checks and
side effects of writing, SDO aborts for what the drive lacks, and option codes of another make.
"""

from __future__ import annotations

import canopen
from canopen.sdo import SdoAbortedError

from drivers import codec
from drivers.eds import GRIP_FORCE_INDEX
from drivers.sim_nmt import NMT_STOPPED
from drivers.sim_pdo import TPDO_COMM_FIRST, TPDO_COMM_LAST, TPDO_EVENT_MS
from drivers.sim_state_machine import OPTION_CODES

QUICK_STOP_DECEL_FACTOR = 2.0  # quick stop / fault reaction ramp = this x the profile acceleration


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


class ObjectDictionary:
    """The objects and SDO server of one simulated drive.

    A part of `drivers.simdrive.SimDrive`, whose `__init__` sets the state these methods use.
    """

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
            # (an RPDO's inhibit time, sub 3, is not used, CiA 301: taken at any time, as the same value again was)
            if (0x1400 <= index <= 0x1403 and subindex == 1) or (
                    TPDO_COMM_FIRST <= index <= TPDO_COMM_LAST and subindex in (1, 3)):
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
                # bit 30: produce SYNC (these drives do not), bit 29: a 29-bit id, refused as CiA 301 says (abort
                # 0x06090030); bit 31 is "do not care" there: taken (it was refused)
                if value & 0x7FFFF800:
                    raise SdoAbortedError(0x06090030)
                self._subscribe_sync(value)
            elif index in self._rpdo_handlers and subindex == 1:
                self._subscribe_rpdo(index, value)
            elif index in OPTION_CODES and value not in self._accepted[index]:
                raise SdoAbortedError(0x06090030)  # value range of parameter exceeded

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

    def _restore_power_on(self, lo: int, hi: int) -> None:
        """Objects lo..hi back to their power-on values (CiA 301 NMT resets)."""
        store = self.node.data_store
        for index in [i for i in store if lo <= i <= hi]:
            del store[index]
        for index, subs in self._power_on.items():
            if lo <= index <= hi:
                store[index] = dict(subs)
