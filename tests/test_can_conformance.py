"""The simulated drives as a CiA 301 / CiA 402 master outside the project sees them: a canopen master on
python-can's virtual bus, the drives in simulated time. Each test is one deviation from the standards that
an outside check found (and that the drives no longer show)."""

from __future__ import annotations

from contextlib import contextmanager

import canopen
import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from drivers import codec, sim

pytestmark = needs_sim


@contextmanager
def _master(open_test_bus, drives, name):
    """canopen's BaseNode402 on node `name` of the served drives, from a master bus of its own."""
    network = canopen.Network(open_test_bus())
    network.connect()
    try:
        info = next(n for n in drives.nodes if n["name"] == name)
        node = canopen.BaseNode402(info["node_id"], info["eds"])
        network.add_node(node)
        yield network, node
    finally:
        network.disconnect()


def test_switch_on_and_enable_operation_from_ready_to_switch_on_reaches_operation_enabled(
        open_test_bus, sim_clock):
    """CiA 402: controlword 0x000F (switch on + enable operation) in READY TO SWITCH ON takes transitions 3
    and 4; the drive used to stop in SWITCHED ON until the same controlword came again. Enabling never
    jumps: the axis stands where it was, even with bit 4 set."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j1") as (_, node):
        j1 = drives.drives["j1"]
        start = j1.position_counts
        node.sdo[0x6060].raw = codec.PP_MODE
        node.sdo[0x607A].raw = round(start) + 10_000
        for cw, want in ((0x06, "READY_TO_SWITCH_ON"), (0x0F, "OPERATION_ENABLED"), (0x06, "READY_TO_SWITCH_ON"),
                         (0x1F, "OPERATION_ENABLED")):
            node.sdo[0x6040].raw = cw
            sim_clock.sleep(0.05)
            assert codec.state_name(node.sdo[0x6041].raw) == want, f"after 0x{cw:04X}"
        assert j1.position_counts == start  # 0x1F enabled the drive, took no set-point


def _tap(open_test_bus, clock):
    """A listener on the test's channel: `take()` drains what it heard, each frame stamped with the
    simulated time it was drained at (call it after every step of the clock)."""
    bus = open_test_bus()
    heard = []

    def take():
        while (m := bus.recv(timeout=0)) is not None:
            heard.append((clock.now(), m))
        return heard

    return take


def _enable_pp(node, clock):
    """OPERATION ENABLED in profile position, by SDO, target = actual position."""
    node.nmt.state = "OPERATIONAL"
    node.sdo[0x6060].raw = codec.PP_MODE
    node.sdo[0x607A].raw = node.sdo[0x6064].raw
    for cw in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = cw
    clock.sleep(0.02)
    assert codec.state_name(node.sdo[0x6041].raw) == "OPERATION_ENABLED"


def test_tpdo_inhibit_time_is_the_least_gap_between_two_of_its_frames(open_test_bus, sim_clock):
    """CiA 301: 0x1800 sub 3 (in 100 us) is the least time between two transmissions of the TPDO. The drive
    took it and sent TPDO1 on every 10 ms tick of a move all the same. The changes held back meanwhile go
    out once it has passed: the last status (target reached) is sent."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j3") as (_, node):
        take = _tap(open_test_bus, sim_clock)
        cob = node.sdo[0x1800][1].raw
        node.sdo[0x1800][1].raw = cob | 0x80000000  # CiA 301: the PDO invalid while its parameters change
        node.sdo[0x1800][3].raw = 1000  # 100 ms
        node.sdo[0x1800][1].raw = cob
        _enable_pp(node, sim_clock)
        node.sdo[0x607A].raw = node.sdo[0x6064].raw - 40_000  # 40 mm
        node.sdo[0x6040].raw = 0x1F
        node.sdo[0x6040].raw = 0x0F
        before = len(take())  # stamped when drained: each tick's frames from here on
        for _ in range(150):
            sim_clock.sleep(0.01)
            take()
        tpdo = [(t, m) for t, m in take()[before:] if m.arbitration_id == 0x183]
        times = [t for t, _ in tpdo]
        assert len(times) >= 5
        assert min(b - a for a, b in zip(times, times[1:])) >= 0.1 - 1e-9
        last = codec.unpack_tpdo1(tpdo[-1][1].data)
        assert last.target_reached and last.position_counts == round(drives.drives["j3"].position_counts)


def test_tpdos_say_they_answer_no_rtr(open_test_bus, sim_clock):
    """The drives answer no RTR, so every TPDO's COB-ID has bit 30 set (CiA 301: no RTR allowed), in the EDS
    and in the drive, also after a master wrote it without (the host restores TPDO1 as 0x180 + id); it said
    RTR allowed (bit 30 clear) and a master's RTR went unanswered."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j3") as (_, node):
        for k in range(4):
            assert node.object_dictionary[0x1800 + k][1].default & 0x40000000, f"EDS 0x{0x1800 + k:04X}"
            assert node.sdo[0x1800 + k][1].raw & 0x40000000, f"drive 0x{0x1800 + k:04X}"
        node.tpdo.read()
        assert not node.tpdo[1].rtr_allowed
        node.sdo[0x1800][1].raw = 0x80000183
        node.sdo[0x1800][1].raw = 0x183  # valid again, bit 30 written clear: held set
        assert node.sdo[0x1800][1].raw == 0x40000183
        take = _tap(open_test_bus, sim_clock)
        node.nmt.state = "OPERATIONAL"
        sim_clock.sleep(0.1)
        assert any(m.arbitration_id == 0x183 and not m.is_remote_frame for _, m in take())  # still sent


# process values: what the drive measures or is told while it runs (0x607A is the actual position at
# power-on and after Reset Node: enabling never jumps), not parameters an EDS gives a default for
PROCESS_VALUES = {0x1001, 0x603F, 0x6040, 0x6041, 0x6061, 0x6064, 0x607A}


def _parameters(od):
    for obj in od.values():
        if obj.index in PROCESS_VALUES:
            continue
        for var in [obj] if isinstance(obj, canopen.objectdictionary.ODVariable) else obj.values():
            if var.readable:
                yield var


def _differing(node):
    got = {}
    for var in _parameters(node.object_dictionary):
        value = node.sdo.upload(var.index, var.subindex)
        if var.decode_raw(value) != var.default:
            got[f"0x{var.index:04X}:{var.subindex}"] = (var.decode_raw(value), var.default)
    return got


def test_every_node_holds_its_eds_default_values_at_power_on_and_after_the_nmt_resets(open_test_bus, sim_clock):
    """A master that reads a node's EDS learns what the node holds: at power-on, after Reset Node and after
    Reset Communication, every parameter is its EDS DefaultValue (the TPDO1 event timer was 50 against 0,
    the limits and rates were the cell file's against generic ones, one EDS for all four axes)."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        assert len({n["eds"] for n in drives.nodes}) == 5  # an EDS per node
        for info in drives.nodes:
            with _master(open_test_bus, drives, info["name"]) as (_, node):
                assert _differing(node) == {}, f"{info['name']} at power-on"
                for reset in ("RESET", "RESET COMMUNICATION"):
                    node.sdo[0x1800][5].raw = 20
                    node.sdo[0x1017].raw = 50
                    node.sdo[0x607D][2].raw = 1000
                    node.sdo[0x6081].raw = 7
                    node.sdo[0x6085].raw = 9
                    node.nmt.state = reset
                    sim_clock.sleep(0.01)
                    left = _differing(node)
                    if reset == "RESET COMMUNICATION":  # the profile area (0x2000-) keeps what was written
                        assert left == {"0x607D:2": (1000, node.object_dictionary[0x607D][2].default),
                                        "0x6081:0": (7, node.object_dictionary[0x6081].default),
                                        "0x6085:0": (9, node.object_dictionary[0x6085].default)}
                    else:
                        assert left == {}, f"{info['name']} after {reset}"


def test_a_node_of_another_cell_gets_an_eds_of_its_own(open_test_bus, sim_clock, cell_cfg):
    """Served for another cell file (another heartbeat, here), the nodes hold that cell's values, and the
    EDS each names says so: a file of its own, not the shipped one."""
    from dataclasses import replace

    from drivers.eds import eds_path, node_eds_file

    cell = replace(cell_cfg, can=replace(cell_cfg.can, heartbeat_ms=40))
    with sim.serve(open_test_bus(), cell, clock=sim_clock) as drives:
        for info in drives.nodes:
            assert info["eds"] != str(eds_path(node_eds_file(info["name"])))
            assert canopen.import_od(info["eds"], info["node_id"])[0x1017].default == 40
        with _master(open_test_bus, drives, "j2") as (_, node):
            assert _differing(node) == {}


def _abort(fn):
    """The SDO abort code `fn` ends with (None: it went through)."""
    try:
        fn()
    except canopen.SdoAbortedError as e:
        return e.code
    return None


@pytest.mark.parametrize(("comm", "cob"), [(0x1800, 0x40000183), (0x1400, 0x203)], ids=["TPDO1", "RPDO1"])
def test_a_valid_pdo_keeps_its_cob_id_and_inhibit_time_and_29_bit_ids_are_refused(open_test_bus, sim_clock, comm,
                                                                                   cob):
    """CiA 301: the COB-ID (bits 0-29) and a TPDO's inhibit time of a valid PDO (bit 31 clear) cannot change
    (abort 0x06090030): a master makes it invalid first. These drives have no 29-bit frames: bit 29 is refused
    too. The drive took every such write. An RPDO's inhibit time is not used (CiA 301): taken at any time (it was
    refused while the RPDO was valid)."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j3") as (_, node):
        rec = node.sdo[comm]
        assert rec[1].raw == cob
        for write in (lambda: setattr(rec[1], "raw", cob + 0x100),  # another id, still valid
                      lambda: setattr(rec[1], "raw", cob | 0x20000000),  # 29-bit id
                      lambda: setattr(rec[1], "raw", cob | 0x00000800)):  # past 11 bits
            assert _abort(write) == 0x06090030
        if comm >= 0x1800:
            assert _abort(lambda: setattr(rec[3], "raw", 100)) == 0x06090030
        else:
            assert _abort(lambda: setattr(rec[3], "raw", 50)) is None and rec[3].raw == 50
            rec[3].raw = 0
        assert rec[1].raw == cob and rec[3].raw == 0
        assert _abort(lambda: setattr(rec[1], "raw", cob | 0x80000000)) is None  # invalid, same id
        assert _abort(lambda: setattr(rec[1], "raw", cob | 0xA0000000)) == 0x06090030  # 29-bit, invalid
        assert _abort(lambda: setattr(rec[3], "raw", 100)) is None
        assert _abort(lambda: setattr(rec[1], "raw", (cob + 0x100) | 0x80000000)) is None
        assert _abort(lambda: setattr(rec[1], "raw", cob)) is None  # valid again, on its id
        assert rec[1].raw == cob and rec[3].raw == 100
        assert _abort(lambda: setattr(rec[1], "raw", cob)) is None  # the same value again is no change


def test_an_rpdo_longer_than_mapped_is_taken_by_its_first_bytes_a_shorter_one_not_at_all(open_test_bus, sim_clock):
    """CiA 301: an RPDO with more bytes than mapped is processed with the first ones (a master that pads every
    frame to 8 bytes); one with fewer is not processed and the drive sends EMCY 0x8210. Both were dropped, in
    silence."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j1") as (net, node):
        j1 = drives.drives["j1"]
        take = _tap(open_test_bus, sim_clock)
        node.nmt.state = "OPERATIONAL"
        sim_clock.sleep(0.02)
        net.send_message(0x201, b"\x06\x00" + bytes(6))  # shutdown, padded to 8 bytes
        net.send_message(0x301, (12345).to_bytes(4, "little", signed=True) + bytes(4))
        net.send_message(0x401, b"\x01\x00\x00")
        sim_clock.sleep(0.02)
        assert j1.state == "READY_TO_SWITCH_ON" and j1._get(0x607A) == 12345 and j1.mode == codec.PP_MODE
        assert not [m for _, m in take() if m.arbitration_id == 0x81]  # no EMCY
        net.send_message(0x201, b"\x07")  # switch on, one byte short
        net.send_message(0x301, b"\x10\x27\x00")
        sim_clock.sleep(0.02)
        assert j1.state == "READY_TO_SWITCH_ON" and j1._get(0x607A) == 12345  # neither processed
        emcy = [codec.unpack_emcy(m.data) for _, m in take() if m.arbitration_id == 0x81]
        assert [e.code for e in emcy] == [0x8210, 0x8210]


def test_a_stopped_node_sends_no_emcy(open_test_bus, sim_clock):
    """CiA 301: in NMT STOPPED a node takes part in NMT and error control (its heartbeat) only. A drive that
    lost its host there faults as before (0x8130) but sends no EMCY (it did); heartbeats go on."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j2") as (net, node):
        _enable_pp(node, sim_clock)
        node.sdo[0x1016][1].raw = codec.consumer_heartbeat_entry(0x7F, 100)
        net.send_message(0x77F, b"\x05")  # the host's heartbeat: the watch starts
        sim_clock.sleep(0.02)
        take = _tap(open_test_bus, sim_clock)
        node.nmt.state = "STOPPED"
        for _ in range(50):
            sim_clock.sleep(0.01)
        assert drives.drives["j2"].state == "FAULT" and drives.drives["j2"].error_code == 0x8130
        ids = {m.arbitration_id for _, m in take() if m.arbitration_id & 0x7F == 2}
        assert ids == {0x702}, [hex(i) for i in ids]  # no EMCY 0x82, no TPDO 0x182


def test_the_sync_the_drives_consume_is_in_their_object_dictionary(open_test_bus, sim_clock):
    """Synchronous TPDO1 types work, so 0x1005 (COB-ID SYNC, 0x80) is in the EDS and the drive (it was
    missing); it can move, and the drive consumes SYNC there. Producing SYNC (bit 30) or a 29-bit id is
    refused (abort 0x06090030, as CiA 301 says for a device that cannot); bit 31 is "do not care": taken (it was
    refused)."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j3") as (net, node):
        assert node.object_dictionary[0x1005].default == 0x80 and node.sdo[0x1005].raw == 0x80
        assert _abort(lambda: setattr(node.sdo[0x1005], "raw", 0x40000080)) == 0x06090030
        assert _abort(lambda: setattr(node.sdo[0x1005], "raw", 0x20000080)) == 0x06090030
        assert _abort(lambda: setattr(node.sdo[0x1005], "raw", 0x80000080)) is None
        node.sdo[0x1800][1].raw = 0xC0000183
        node.sdo[0x1800][2].raw = 1  # on every SYNC
        node.sdo[0x1800][1].raw = 0x40000183
        node.nmt.state = "OPERATIONAL"
        take = _tap(open_test_bus, sim_clock)

        def tpdos_on(cob_id):
            before = len(take())
            net.send_message(cob_id, b"")
            sim_clock.sleep(0.01)
            return sum(m.arbitration_id == 0x183 for _, m in take()[before:])

        assert tpdos_on(0x80) == 1
        node.sdo[0x1005].raw = 0xFF
        assert tpdos_on(0x80) == 0 and tpdos_on(0xFF) == 1
        node.nmt.state = "RESET COMMUNICATION"  # back to 0x80
        sim_clock.sleep(0.01)
        assert node.sdo[0x1005].raw == 0x80


def test_periods_shorter_than_the_drives_tick_are_refused(open_test_bus, sim_clock):
    """The drives tick every 10 ms: a heartbeat (0x1017) or TPDO event timer (0x1800 sub 5) of 1-9 ms would
    not be kept (a 1 ms heartbeat came every 10 ms), so it is refused with abort 0x06090032 (value too low);
    0 (off) and 10 ms are taken, and a heartbeat of 10 ms is kept."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j4") as (_, node):
        for var in (node.sdo[0x1017], node.sdo[0x1800][5]):
            for value in (1, 5, 9):
                assert _abort(lambda v=var, x=value: setattr(v, "raw", x)) == 0x06090032
            for value in (0, 10, 15):
                assert _abort(lambda v=var, x=value: setattr(v, "raw", x)) is None and var.raw == value
        node.sdo[0x1017].raw = 10
        take = _tap(open_test_bus, sim_clock)
        before = len(take())
        for _ in range(20):
            sim_clock.sleep(0.01)
            take()
        beats = [t for t, m in take()[before:] if m.arbitration_id == 0x704]
        assert len(beats) == 20 and all(b - a == pytest.approx(0.01) for a, b in zip(beats, beats[1:]))


def _cruise_j1(node, clock, distance=100_000, for_s=0.35):
    """j1 (180000 counts/s at most, 720000 counts/s^2) sent `distance` counts on by SDO, `for_s` into its
    move: cruising at full speed from 0.25 s on."""
    _enable_pp(node, clock)
    node.sdo[0x607A].raw = node.sdo[0x6064].raw + distance
    node.sdo[0x6040].raw = 0x1F
    node.sdo[0x6040].raw = 0x0F
    clock.sleep(for_s)


def test_reset_node_during_a_move_lets_the_axis_coast(open_test_bus, sim_clock, cell_cfg):
    """NMT Reset Node turns the drive function off: a moving axis is no longer driven and runs out on
    friction (COAST_DECEL_FACTOR x its max acceleration), as a disabled axis does in the simulation; it used
    to stand still at once, 180 deg/s to 0 in no time."""
    from drivers.simdrive import COAST_DECEL_FACTOR

    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j1") as (_, node):
        j1 = drives.drives["j1"]
        _cruise_j1(node, sim_clock)
        node.nmt.state = "RESET"
        at_reset = j1.position_counts
        sim_clock.sleep(1.0)
        decel = COAST_DECEL_FACTOR * cell_cfg.scara.max_acceleration["j1"] * 1000
        assert j1.position_counts - at_reset == pytest.approx(180_000**2 / (2 * decel), abs=1)  # 45000
        assert j1.state == "SWITCH_ON_DISABLED" and j1.motion is None


@pytest.mark.parametrize("new_target", [120_000, 40_000, 25_000, -20_000],
                         ids=["further", "nearer", "overshot", "behind"])
def test_change_immediately_goes_on_from_the_speed_the_axis_has(open_test_bus, sim_clock, new_target):
    """A set-point with bit 5 (change immediately) during a move starts the new profile from the axis' speed
    and where it is: no step in speed, every change of speed on the ramps (0x6083 / 0x6084), the new target
    reached at rest. It restarted from rest: 180000 counts/s to 0 within a tick. A target it cannot stop for
    any more (overshot) or one behind it is reached after a stop on the deceleration ramp."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j1") as (_, node):
        j1 = drives.drives["j1"]
        start = round(j1.position_counts)
        _cruise_j1(node, sim_clock, 60_000, 0.19)
        a, d = node.sdo[0x6083].raw, node.sdo[0x6084].raw
        node.sdo[0x607A].raw = start + new_target
        positions = [j1.position_counts]
        sim_clock.sleep(0.01)  # at 0.2 s still speeding up: 144000 counts/s
        positions.append(j1.position_counts)
        sim_clock.sleep(0.005)  # between two ticks, as a set-point may come
        node.sdo[0x6040].raw = 0x3F
        node.sdo[0x6040].raw = 0x2F
        for _ in range(300):
            sim_clock.sleep(0.01)
            positions.append(j1.position_counts)
        v = [(q - p) / 0.01 for p, q in zip(positions, positions[1:])]
        dv = [(w - u) / 0.01 for u, w in zip(v, v[1:])]
        assert max(abs(x) for x in dv) <= max(a, d) * 1.001
        assert j1.position_counts == start + new_target and j1.target_reached and j1.motion is None


def test_a_stopped_node_carries_out_no_sdo_request(open_test_bus, sim_clock):
    """CiA 301: no SDO in NMT STOPPED. A write there took effect with only its answer held back: a master
    that timed out on it believed nothing had changed."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j4") as (net, node):
        before = node.sdo[0x6081].raw
        node.nmt.state = "STOPPED"
        sim_clock.sleep(0.02)
        net.send_message(0x604, bytes([0x23, 0x81, 0x60, 0x00]) + (before // 2).to_bytes(4, "little"))
        sim_clock.sleep(0.05)
        node.nmt.state = "PRE-OPERATIONAL"
        sim_clock.sleep(0.02)
        assert node.sdo[0x6081].raw == before
        assert drives.drives["j4"].nmt == 0x7F


def test_the_host_heartbeat_watch_takes_node_ids_1_to_127_only(open_test_bus, sim_clock):
    """0x1016 sub 1 is (node id << 16) | time in ms, bits 24-31 reserved (CiA 301): node 200 or a reserved bit
    was taken, and the drive watched a heartbeat no node can send. Node 0 leaves the entry unused."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j1") as (_, node):
        before = node.sdo[0x1016][1].raw
        assert _abort(lambda: setattr(node.sdo[0x1016][1], "raw", (200 << 16) | 100)) == 0x06090030
        assert _abort(lambda: setattr(node.sdo[0x1016][1], "raw", (1 << 24) | (0x7F << 16) | 100)) == 0x06090030
        assert node.sdo[0x1016][1].raw == before
        for entry in (codec.consumer_heartbeat_entry(0x7F, 100), 100):  # node 0: unused
            assert _abort(lambda e=entry: setattr(node.sdo[0x1016][1], "raw", e)) is None
            assert node.sdo[0x1016][1].raw == entry


_CLASSES = [(0x2310, 0x03), (0x3210, 0x05), (0x4310, 0x09), (0x8130, 0x11), (0x8611, 0x21), (0xFF01, 0x81),
            (0x5000, 0x01)]


@pytest.mark.parametrize(("code", "register"), _CLASSES, ids=[f"0x{code:04X}" for code, _ in _CLASSES])
def test_the_error_register_has_the_class_bits_of_the_fault(open_test_bus, sim_clock, code, register):
    """CiA 301: 0x1001 sets bit 0 for any error and the bit of its class (current, voltage, temperature,
    communication, device profile, manufacturer), and the EMCY carries it in byte 2; the fault reset's EMCY
    (0x0000) with 0, logged like the others. Bits 0 and 7 were all it set (7 for every 8xxx code), and the
    reset's EMCY was missing from `emcy_log`."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j2") as (_, node):
        take = _tap(open_test_bus, sim_clock)
        node.nmt.state = "OPERATIONAL"
        drives.inject_fault("emcy", "j2", code=code)
        sim_clock.sleep(0.02)
        assert node.sdo[0x1001].raw == register
        node.sdo[0x6040].raw = 0x80  # fault reset
        sim_clock.sleep(0.02)
        assert node.sdo[0x1001].raw == 0
        emcy = [codec.unpack_emcy(m.data) for _, m in take() if m.arbitration_id == 0x82]
        assert [(e.code, e.register) for e in emcy] == [(code, register), (0, 0)]
        assert drives.drives["j2"].emcy_log == [code, 0]


def test_errors_without_a_fault_carry_their_bits_in_the_emcy(open_test_bus, sim_clock):
    """An RPDO one byte short (EMCY 0x8210, a communication error) and a mode of operation the drive does not
    have written by RPDO3 (EMCY 0x6320 parameter error: an SDO write is aborted, a PDO cannot be; it was dropped
    with a log line alone): no fault, the drive keeps its state and mode, and each EMCY's register has its class
    bits (it said 0, "no error"); 0x1001 stays 0 (no fault held)."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j1") as (net, node):
        j1 = drives.drives["j1"]
        _enable_pp(node, sim_clock)
        take = _tap(open_test_bus, sim_clock)
        net.send_message(0x401, bytes([6]))  # homing: a mode these drives do not have
        net.send_message(0x201, b"\x0f")  # a controlword one byte short
        sim_clock.sleep(0.02)
        assert (j1.state, j1.mode, node.sdo[0x6061].raw) == ("OPERATION_ENABLED", codec.PP_MODE, codec.PP_MODE)
        emcy = [codec.unpack_emcy(m.data) for _, m in take() if m.arbitration_id == 0x81]
        assert [(e.code, e.register) for e in emcy] == [(0x6320, 0x01), (0x8210, 0x11)]
        assert j1.emcy_log == [0x6320, 0x8210] and node.sdo[0x1001].raw == 0
