"""The outside check of CONTRACT.md: canopen's own BaseNode402 drives the simulated drives
over the virtual bus in the same process, with the simulated motion in real time."""

from __future__ import annotations

import time
from contextlib import contextmanager

import canopen
import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from drivers import sim

pytestmark = needs_sim

SW_ACK, SW_TARGET_REACHED = 1 << 12, 1 << 10


def _wait_bit(node, bit, value=True, timeout_s=2.0):
    deadline = time.monotonic() + timeout_s
    while bool(node.statusword & bit) != value:
        assert time.monotonic() < deadline, f"statusword bit {bit:#x} not {value}"
        node.check_statusword()


@contextmanager
def _j1_in_profile_position(open_test_bus):
    """The simulated drives (real-time motion) and canopen's BaseNode402 on j1 (node 1), walked to
    OPERATION ENABLED in profile position mode: (drives, node)."""
    with sim.serve(open_test_bus()) as drives:
        network = canopen.Network(open_test_bus())
        network.connect()
        try:
            node = canopen.BaseNode402(1, drives.nodes[0]["eds"])
            network.add_node(node)
            node.nmt.wait_for_heartbeat(timeout=2.0)
            node.setup_402_state_machine(read_pdos=True)
            node.nmt.state = "OPERATIONAL"
            node.state = "OPERATION ENABLED"
            node.op_mode = "PROFILED POSITION"
            yield drives, node
        finally:
            network.disconnect()  # also shuts the master bus down


def test_serve_refuses_a_cell_it_cannot_use_and_a_second_set_of_nodes_on_one_bus(open_test_bus):
    bus = open_test_bus()
    with pytest.raises(TypeError, match="cell must be None .* not int"):
        sim.serve(bus, 42)
    with sim.serve(bus):
        with pytest.raises(RuntimeError, match="already served on this bus"):
            sim.serve(bus)  # five more nodes with ids 1-5 would answer every request twice
    with sim.serve(bus) as again:  # once left, the bus can be served again
        assert [n["name"] for n in again.nodes][-1] == "gripper"


def test_serve_handle_lists_the_nodes_and_their_eds(open_test_bus):
    with sim.serve(open_test_bus()) as drives:
        assert [(n["node_id"], n["name"]) for n in drives.nodes] == [
            (1, "j1"),
            (2, "j2"),
            (3, "j3"),
            (4, "j4"),
            (5, "gripper"),
        ]
        for n in drives.nodes:
            od = canopen.import_od(n["eds"], n["node_id"])
            for index in (
                0x1000,
                0x1017,
                0x603F,
                0x6040,
                0x6041,
                0x6060,
                0x6061,
                0x6064,
                0x607A,
                0x607D,
                0x6081,
                0x6083,
                0x6084,
                0x6502,
                *range(0x1400, 0x1404),
                *range(0x1600, 0x1604),
                *range(0x1800, 0x1804),
                *range(0x1A00, 0x1A04),
            ):
                assert index in od, f"{n['name']}: 0x{index:04X} missing from {n['eds']}"


@pytest.mark.parametrize("name", ["j2", "gripper"])
def test_base_node_402_drives_a_simulated_node(open_test_bus, cell_cfg, name):
    sim_bus, master_bus = open_test_bus(), open_test_bus()
    with sim.serve(sim_bus) as drives:  # no clock: real-time motion in a background thread
        info = next(n for n in drives.nodes if n["name"] == name)
        network = canopen.Network(master_bus)
        network.connect()
        try:
            node = canopen.BaseNode402(info["node_id"], info["eds"])
            network.add_node(node)
            node.nmt.wait_for_heartbeat(timeout=2.0)
            node.setup_402_state_machine(read_pdos=True)  # PDO set-up read by SDO
            assert 0x6041 in node.tpdo_values and 0x6040 in node.rpdo_pointers
            assert node.sdo[0x1000].raw == 0x00020192
            node.nmt.state = "OPERATIONAL"
            node.state = "OPERATION ENABLED"
            assert node.state == "OPERATION ENABLED"
            node.op_mode = "PROFILED POSITION"
            assert node.op_mode == "PROFILED POSITION"

            start = node.sdo[0x6064].raw
            target = start - 5000  # 5 mm or 5 degrees
            node.sdo[0x607A].raw = target
            time.sleep(0.1)  # a target alone, without the set-point edge, does not move
            assert abs(node.sdo[0x6064].raw - start) <= 1

            node.controlword = 0x1F  # enable operation + new set-point
            _wait_bit(node, SW_ACK, True)
            node.controlword = 0x0F
            _wait_bit(node, SW_ACK, False)
            _wait_bit(node, SW_TARGET_REACHED, True, timeout_s=3.0)
            assert node.sdo[0x6064].raw == target
            unit = cell_cfg.can.nodes[name].counts_per_unit
            assert drives.positions()[name] == pytest.approx(target / unit)
        finally:
            network.disconnect()  # also shuts the master bus down


def test_drive_faults_on_a_target_outside_0x607d(open_test_bus, cell_cfg):
    with _j1_in_profile_position(open_test_bus) as (drives, node):
        hi = node.sdo[0x607D][2].raw
        assert hi == round(cell_cfg.scara.j1_deg[1] * 1000)
        emcys = []
        node.emcy.add_callback(emcys.append)
        node.sdo[0x607A].raw = hi + 1
        node.controlword = 0x1F
        deadline = time.monotonic() + 2.0
        while node.state != "FAULT":
            assert time.monotonic() < deadline
            node.check_statusword()
        assert node.sdo[0x603F].raw == 0x8612
        deadline = time.monotonic() + 1.0
        while not emcys and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emcys and emcys[0].code == 0x8612
        assert drives.positions()["j1"] == pytest.approx(cell_cfg.motion.home_joints["j1_deg"])


def test_pdo_settings_can_be_saved_and_sync_drives_the_tpdo(open_test_bus, sim_clock):
    """A master may rewrite the PDO communication parameters (canopen's PdoMap.save) and use
    synchronous TPDOs; the static mapping survives the save."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        bus = open_test_bus()
        network = canopen.Network(bus)
        network.connect()
        try:
            node = canopen.BaseNode402(3, drives.nodes[2]["eds"])
            network.add_node(node)
            node.tpdo.read()
            node.tpdo[1].trans_type = 2  # every second SYNC
            node.tpdo[1].save()
            assert node.sdo[0x1800][2].raw == 2
            assert [v.index for v in node.tpdo[1]] == [0x6041, 0x6064, 0x6061]
            node.nmt.state = "OPERATIONAL"
            got = []
            node.tpdo[1].add_callback(lambda m: got.append(m["Statusword"].raw))
            sim_clock.sleep(0.5)  # no SYNC: no TPDO, whatever the event timer says
            assert got == []
            for _ in range(4):
                network.sync.transmit()
                sim_clock.sleep(0.01)
            deadline = time.monotonic() + 1.0  # this master's receive thread is not on the clock
            while len(got) < 2 and time.monotonic() < deadline:
                time.sleep(0.005)
            time.sleep(0.05)
            assert len(got) == 2 and got[0] & 0x4F == 0x40  # SWITCH ON DISABLED
        finally:
            network.disconnect()


def test_a_drive_mapped_differently_is_refused(open_test_bus, sim_clock, cell_cfg):
    from drivers import Arm, DriveFault

    with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as drives:
        drives.drives["j2"]._store(0x1A00, 0, 2)  # this drive's TPDO1 lacks the mode display
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock)
        with pytest.raises(DriveFault, match=r"j2 \(node 2\): PDO mapping differs"):
            arm.connect()
        assert not arm.is_connected


def test_the_host_restores_the_pdo_communication_it_needs(open_test_bus, sim_clock, cell_cfg):
    from cell.kinematics import Joints
    from drivers import Arm

    with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as drives:
        j3 = drives.drives["j3"]
        j3._store(0x1800, 1, 0x80000183)  # someone left TPDO1 disabled ...
        j3._store(0x1800, 2, 1)  # ... and synchronous
        with Arm(open_test_bus(), cell_cfg, clock=sim_clock) as arm:
            assert j3._get(0x1800, 1) == 0x40000183 and j3._get(0x1800, 2) == 255  # valid (bit 30: no RTR)
            s = arm.joints()
            arm.move_joints(Joints(s.j1_deg, s.j2_deg, s.j3_mm - 30.0, s.j4_deg))
            assert drives.positions()["j3"] == pytest.approx(s.j3_mm - 30.0)


def test_base_node_402_leaving_quick_stop_waits_for_the_end_of_the_ramp(open_test_bus):
    """canopen's BaseNode402 asks for OPERATION ENABLED (transition 16) at once after a quick stop of a
    j1 cruising at 180 deg/s: the drive stays in QUICK STOP ACTIVE until its ramp (v^2 / 2d = 11250
    counts) has ended, then enables where the axis stands. It used to enable at once and stop dead."""
    with _j1_in_profile_position(open_test_bus) as (drives, node):
        node.sdo[0x607A].raw = node.sdo[0x6064].raw - 120_000
        node.controlword = 0x1F
        _wait_bit(node, SW_ACK, True)
        node.controlword = 0x0F
        time.sleep(0.4)  # cruising at 180000 counts/s
        at_stop = node.sdo[0x6064].raw
        node.state = "QUICK STOP ACTIVE"
        node.state = "OPERATION ENABLED"
        enabled_at = node.sdo[0x6064].raw
        time.sleep(0.2)
        assert node.state == "OPERATION ENABLED" and node.sdo[0x6064].raw == enabled_at  # standing
        d = node.sdo[0x6085].raw
        assert at_stop - enabled_at >= 0.9 * 180_000**2 / (2 * d)  # the whole ramp ran out
