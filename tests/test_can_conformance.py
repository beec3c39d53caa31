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
