"""Findings of the outside check (CONTRACT.md, "The simulated drives"): canopen as an
independent master probes what a real CiA 301/402 drive does, over the virtual bus."""

from __future__ import annotations

import time

import canopen
import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from drivers import sim

pytestmark = needs_sim


@pytest.fixture
def master(open_test_bus):
    """A canopen master on the test's channel, disconnected at teardown."""
    networks = []

    def _master(drives, name):
        info = next(n for n in drives.nodes if n["name"] == name)
        network = canopen.Network(open_test_bus())
        network.connect()
        networks.append(network)
        node = canopen.BaseNode402(info["node_id"], info["eds"])
        network.add_node(node)
        return network, node

    yield _master
    for network in networks:
        network.disconnect()


@pytest.mark.parametrize(
    ("index", "subindex"),
    [(0x607D, 3), (0x1016, 2), (0x6041, 1), (0x6040, 1), (0x1017, 1)],
)
def test_a_subindex_the_object_does_not_have_is_refused(open_test_bus, sim_clock, master, index, subindex):
    """CiA 301: an SDO to a sub-index an object does not have aborts with 0x06090011
    (a VAR has only sub-index 0; an ARRAY only the entries it declares)."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        _, node = master(drives, "j1")
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo.upload(index, subindex)
        assert e.value.code == 0x06090011
        size = 2 if index in (0x6040, 0x6041, 0x1017) else 4
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo.download(index, subindex, bytes(size))
        assert e.value.code == 0x06090011
        assert drives.drives["j1"].controlword == 0  # the write to 0x6040 sub 1 changed nothing


def test_nmt_resets_restore_the_power_on_values(open_test_bus, sim_clock, master, cell_cfg):
    """CiA 301: Reset Communication sets the communication area (0x1000-0x1FFF) to its
    power-on values, Reset Node every object; the drive boots up again in PRE-OPERATIONAL."""
    with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as drives:
        _, node = master(drives, "j1")
        velocity = node.sdo[0x6081].raw
        node.sdo[0x1017].raw = 500
        node.sdo[0x1800][5].raw = 20
        node.sdo[0x1400][1].raw = 0x80000201  # RPDO1 (controlword) not valid
        node.sdo[0x6081].raw = velocity // 2
        node.sdo[0x6060].raw = 1
        node.nmt.state = "RESET COMMUNICATION"
        sim_clock.sleep(0.15)  # boot-up, then a heartbeat from PRE-OPERATIONAL
        deadline = time.monotonic() + 1.0  # this master's receive thread is not on the clock
        while node.nmt.state != "PRE-OPERATIONAL" and time.monotonic() < deadline:
            time.sleep(0.005)
        assert node.nmt.state == "PRE-OPERATIONAL"
        assert node.sdo[0x1017].raw == cell_cfg.can.heartbeat_ms
        assert node.sdo[0x1800][5].raw == 50
        assert node.sdo[0x1400][1].raw == 0x201
        assert node.sdo[0x6081].raw == velocity // 2  # the application area stays
        assert node.sdo[0x6060].raw == node.sdo[0x6061].raw == 1

        node.nmt.state = "RESET"
        sim_clock.sleep(0.05)
        assert node.sdo[0x6081].raw == velocity
        assert node.sdo[0x6060].raw == node.sdo[0x6061].raw == 0  # the mode and its display agree
        assert node.sdo[0x607A].raw == node.sdo[0x6064].raw  # no stale target after the reset
        # RPDO1 works again after the reset: the controlword by PDO walks the state machine
        node.tpdo.read()
        node.rpdo.read()
        node.nmt.state = "OPERATIONAL"
        node.rpdo[1]["Controlword"].raw = 0x06
        node.rpdo[1].transmit()
        sim_clock.sleep(0.05)
        assert node.sdo[0x6041].raw & 0x6F == 0x21  # READY TO SWITCH ON


def _enabled_pp(network, node, sim_clock):
    """NMT start, the 402 state machine to OPERATION ENABLED and profile position, by SDO
    (this master's receive thread is not on the simulated clock)."""
    node.nmt.state = "OPERATIONAL"
    for cw in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = cw
    node.sdo[0x6060].raw = 1
    sim_clock.sleep(0.01)
    assert node.sdo[0x6041].raw & 0x6F == 0x27 and node.sdo[0x6061].raw == 1


def _set_point(node, target, cw=0x0F):
    node.sdo["Target position"].raw = target
    node.sdo["Controlword"].raw = cw | 0x10
    assert node.sdo["Statusword"].raw & 0x1000  # acknowledged
    node.sdo["Controlword"].raw = cw


def test_halt_decelerates_on_the_profile_ramp_and_release_resumes_the_move(open_test_bus, sim_clock, master, cell_cfg):
    """CiA 402 profile position, controlword bit 8 (halt): the axis stops with the profile
    deceleration (0x6084), statusword bit 10 reports standstill; clearing bit 8 continues
    the positioning to the same target."""
    with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as drives:
        network, node = master(drives, "j1")
        _enabled_pp(network, node, sim_clock)
        v, d = node.sdo[0x6081].raw, node.sdo[0x6084].raw
        start = node.sdo[0x6064].raw
        target = start + 100_000
        _set_point(node, target)
        sim_clock.sleep(0.5)  # at full speed by now
        at_halt = node.sdo[0x6064].raw
        node.sdo["Controlword"].raw = 0x10F  # halt
        sim_clock.sleep(0.05)
        assert node.sdo[0x6064].raw > at_halt + 0.04 * v  # still moving: decelerating, no jump
        assert not node.sdo[0x6041].raw & 0x400
        sim_clock.sleep(v / d)
        stopped = node.sdo[0x6064].raw
        assert stopped == pytest.approx(at_halt + v * v / (2 * d), abs=0.02 * v)
        assert node.sdo[0x6041].raw & 0x400  # halted: velocity zero
        sim_clock.sleep(0.2)
        assert node.sdo[0x6064].raw == stopped
        node.sdo["Controlword"].raw = 0x0F  # halt released: the positioning continues
        sim_clock.sleep(0.05)
        assert node.sdo[0x6064].raw > stopped and not node.sdo[0x6041].raw & 0x400
        sim_clock.sleep(1.0)
        assert node.sdo[0x6064].raw == target and node.sdo[0x6041].raw & 0x400


def _frames(bus):
    got = []
    while (msg := bus.recv(timeout=0.05)) is not None:
        got.append(msg.arbitration_id)
    return got


@pytest.mark.parametrize("period_ms", [25, 45, 70, 100])
def test_heartbeat_and_event_timer_keep_their_period(open_test_bus, sim_clock, master, period_ms):
    """CiA 301: 0x1017 is the heartbeat's cycle time and 0x1800/5 the TPDO's event timer; on
    the 10 ms tick the drives still keep the period on average (no drift to the next tick)."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        _, node = master(drives, "j2")
        node.sdo[0x1017].raw = period_ms
        node.sdo[0x1800][5].raw = period_ms
        node.nmt.state = "OPERATIONAL"
        sim_clock.sleep(0.5)
        tap = open_test_bus()
        sim_clock.sleep(2.0)
        n = 2000 / period_ms
        frames = _frames(tap)
        assert frames.count(0x702) == pytest.approx(n, abs=1.01)
        assert frames.count(0x182) == pytest.approx(n, abs=1.01)


def test_a_buffered_set_point_keeps_the_acknowledge_until_the_buffer_is_free(open_test_bus, sim_clock, master):
    """CiA 402 profile position, single set-point (bit 5 = 0): a set-point sent during a move
    waits for the move's end; statusword bit 12 = 1 says the drive takes no further set-point,
    so it stays set (the buffer is full) until the buffered set-point becomes the running one."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        network, node = master(drives, "j1")
        _enabled_pp(network, node, sim_clock)
        start = node.sdo[0x6064].raw
        _set_point(node, start + 50_000)
        sim_clock.sleep(0.1)
        _set_point(node, start + 20_000)  # buffered
        sim_clock.sleep(0.01)
        assert node.sdo[0x6041].raw & 0x1000  # buffer full: no further set-point taken ...
        node.sdo["Target position"].raw = start + 90_000
        node.sdo["Controlword"].raw = 0x1F  # ... so this one is not
        node.sdo["Controlword"].raw = 0x0F
        deadline = sim_clock.now() + 3.0
        while node.sdo[0x6041].raw & 0x1000:
            assert sim_clock.now() < deadline
            sim_clock.sleep(0.01)
        assert node.sdo[0x6064].raw == pytest.approx(start + 50_000, abs=2_000)  # the first move's end
        sim_clock.sleep(2.0)
        assert node.sdo[0x6064].raw == start + 20_000 and node.sdo[0x6041].raw & 0x400


def test_a_target_beyond_the_limits_is_refused_and_reported_consistently(open_test_bus, sim_clock, master):
    """A set-point outside 0x607D is refused (no motion), and reported: FAULT, 0x603F 0x8612,
    an EMCY whose error register is 0x1001's; the refused set-point is not acknowledged
    (bit 12). A fault reset clears 0x603F and 0x1001 and sends the EMCY 'error reset'."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        network, node = master(drives, "j4")
        emcys = []
        node.emcy.add_callback(emcys.append)
        _enabled_pp(network, node, sim_clock)
        start = node.sdo[0x6064].raw
        node.sdo["Target position"].raw = node.sdo["Software position limit"]["Max position limit"].raw + 1
        node.sdo["Controlword"].raw = 0x1F
        sw = node.sdo["Statusword"].raw
        assert sw & 0x4F == 0x08 and not sw & 0x1000  # FAULT, the set-point not acknowledged
        assert node.sdo["Error code"].raw == 0x8612
        sim_clock.sleep(0.2)
        assert node.sdo[0x6064].raw == start
        deadline = time.monotonic() + 1.0
        while not emcys and time.monotonic() < deadline:
            time.sleep(0.005)
        assert emcys[0].code == 0x8612
        assert node.sdo["Error register"].raw == emcys[0].register != 0
        node.sdo["Controlword"].raw = 0x0F
        node.sdo["Controlword"].raw = 0x8F  # fault reset (rising edge of bit 7)
        assert node.sdo["Statusword"].raw & 0x4F == 0x40  # SWITCH ON DISABLED
        assert node.sdo["Error code"].raw == 0 and node.sdo["Error register"].raw == 0
        deadline = time.monotonic() + 1.0
        while len(emcys) < 2 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert emcys[1].code == 0


def test_a_relative_set_point_during_a_move_is_relative_to_the_preceding_target(open_test_bus, sim_clock, master):
    """CiA 402 profile position, bit 6 (relative) with the default positioning option code
    (0x60F2 = 0): relative to the preceding target position, not to where the axis is."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        network, node = master(drives, "j1")
        _enabled_pp(network, node, sim_clock)
        start = node.sdo[0x6064].raw
        _set_point(node, start + 60_000)
        sim_clock.sleep(0.15)
        _set_point(node, 10_000, cw=0x0F | 0x40 | 0x20)  # relative, change immediately
        sim_clock.sleep(3.0)
        assert node.sdo[0x6064].raw == start + 70_000
        _set_point(node, -5_000, cw=0x0F | 0x40)  # at rest: from the reached target
        sim_clock.sleep(2.0)
        assert node.sdo[0x6064].raw == start + 65_000


def test_leaving_profile_position_during_a_move_stops_the_axis(open_test_bus, sim_clock, master):
    """A drive whose mode of operation leaves profile position (0x6060 = 0, 'no mode') does
    not go on following the profile position move: it decelerates (0x6084) to standstill."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        network, node = master(drives, "j1")
        _enabled_pp(network, node, sim_clock)
        v, d = node.sdo[0x6081].raw, node.sdo[0x6084].raw
        start = node.sdo[0x6064].raw
        _set_point(node, start - 100_000)
        sim_clock.sleep(0.5)
        at_switch = node.sdo[0x6064].raw
        node.sdo["Modes of operation"].raw = 0
        sim_clock.sleep(v / d + 0.05)
        stopped = node.sdo[0x6064].raw
        assert stopped == pytest.approx(at_switch - v * v / (2 * d), abs=0.02 * v)
        sim_clock.sleep(0.5)
        assert node.sdo[0x6064].raw == stopped and node.sdo[0x6061].raw == 0
        node.sdo["Modes of operation"].raw = 1  # back in profile position: no stale move resumes
        sim_clock.sleep(0.5)
        assert node.sdo[0x6064].raw == stopped


def test_clocks_refuse_a_nan_sleep():
    """A NaN sleep on the SimClock ran the drives' jobs forever (no time compares to NaN)."""
    from drivers.clock import RealClock, SimClock

    for clock in (SimClock(), RealClock()):
        with pytest.raises(ValueError, match="nan"):
            clock.sleep(float("nan"))
        clock.close()


def test_serve_takes_a_cell_file_path_too(open_test_bus, sim_clock, tmp_path):
    import json

    from cell.cellconfig import default_cell_path

    d = json.loads(default_cell_path().read_text())
    d["can"]["nodes"]["j2"]["node_id"] = 42
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(d))
    with sim.serve(open_test_bus(), str(path), clock=sim_clock) as drives:
        assert {n["name"]: n["node_id"] for n in drives.nodes}["j2"] == 42
    from cell.errors import BadInput

    with pytest.raises(BadInput):
        sim.serve(open_test_bus(), tmp_path / "missing.json", clock=sim_clock)
