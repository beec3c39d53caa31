"""The host sets the abort connection, quick stop and fault reaction option codes at connect (0x6007 = 1,
0x605A = 6, 0x605E = 2) and reads them back; drives of another make (simulated, over the virtual bus) that
ship other values, refuse them or lack the objects are driven as `drivers.option_codes` decides, with a
warning, or refused."""

from __future__ import annotations

import logging

import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints
from drivers import Arm, DriveFault, sim

pytestmark = needs_sim

NODES = ("j1", "j2", "j3", "j4", "gripper")


@pytest.fixture
def drives(open_test_bus, sim_clock, cell_cfg):
    with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as handle:
        yield handle


@pytest.fixture
def connect(drives, open_test_bus, sim_clock, cell_cfg, caplog):
    """Connect an arm to the drives as configured by the test; yields (arm, warnings logged)."""
    arms = []

    def _connect():
        arm = Arm(open_test_bus(), cell_cfg, clock=sim_clock)
        arms.append(arm)
        with caplog.at_level(logging.WARNING, logger="drivers.arm"):
            arm.connect()
        return arm, [r.getMessage() for r in caplog.records if r.name == "drivers.arm"]

    yield _connect
    for arm in arms:
        arm.disconnect()


def _codes(drives):
    return {name: (d._get(0x605A), d._get(0x605E)) for name, d in drives.drives.items()}


def _stop_mid_move(arm, drives):
    start = arm.joints()
    arm.move_joints(Joints(start.j1_deg - 60.0, start.j2_deg - 30.0, start.j3_mm - 50.0, start.j4_deg + 90.0),
                    wait=False)
    arm.clock.sleep(0.2)
    arm.stop()
    stopped = drives.positions()
    arm.clock.sleep(0.5)
    assert drives.positions() == stopped  # standing
    assert stopped["j1"] > start.j1_deg - 60.0 + 1.0  # stopped mid-way


def _recovers(arm, drives):
    arm.reset_faults()
    assert arm.faults == {} and {s["state"] for s in arm.state().values()} == {"OPERATION_ENABLED"}
    start = arm.joints()
    arm.move_joints(Joints(start.j1_deg + 3.0, start.j2_deg, start.j3_mm, start.j4_deg))
    assert drives.positions()["j1"] == pytest.approx(start.j1_deg + 3.0, abs=1e-3)


def test_connect_sets_the_option_codes_of_drives_that_ship_others(drives, connect):
    drives.configure_option_codes(values={0x6007: 0, 0x605A: 2, 0x605E: 1})
    arm, warnings = connect()
    assert _codes(drives) == {n: (6, 2) for n in NODES}
    assert all(ax.option_codes == {0x6007: 1, 0x605A: 6, 0x605E: 2} for ax in arm.axes.values())
    assert {d._get(0x6007) for d in drives.drives.values()} == {1}
    assert warnings == []
    _stop_mid_move(arm, drives)
    assert {d.state for d in drives.drives.values()} == {"QUICK_STOP_ACTIVE"}  # 6: it stays there


def test_connect_writes_no_option_code_a_drive_already_has(drives, connect, open_test_bus):
    tap = open_test_bus()
    arm, warnings = connect()
    assert warnings == [] and _codes(drives) == {n: (6, 2) for n in NODES}
    frames = []
    while (msg := tap.recv(0)) is not None:
        frames.append(msg)
    sdo = [bytes(m.data) for m in frames if 0x601 <= m.arbitration_id <= 0x605]
    index = [int.from_bytes(d[1:3], "little") for d in sdo]
    reads = [i for d, i in zip(sdo, index) if d[0] == 0x40]
    writes = [i for d, i in zip(sdo, index) if d[0] & 0xE0 == 0x20]
    assert reads.count(0x6007) == reads.count(0x605A) == reads.count(0x605E) == 5  # one read each: nothing to write
    assert 0x6007 not in writes and 0x605A not in writes and 0x605E not in writes


def test_drives_that_refuse_the_quick_stop_value_stop_in_switch_on_disabled_and_the_host_copes(drives, connect):
    """Factory 0x605A = 2 that will not take 6: bring-up goes on with a warning per node; a stop then ends
    in SWITCH ON DISABLED, the host waits for standstill there, re-enables, and moves again; so does an
    EMCY during a move."""
    drives.configure_option_codes(values={0x605A: 2}, accepted={0x605A: {2}})
    arm, warnings = connect()
    assert len(warnings) == 5
    assert warnings[0] == (
        "j1 (node 1): quick stop option code 0x605A stays 2 (the quick stop ramp, then SWITCH ON DISABLED): "
        "writing 6 was refused with SDO abort 0x06090030; after a quick stop the host waits for standstill "
        "and re-enables from there")
    assert _codes(drives) == {n: (2, 2) for n in NODES}
    assert arm.axes["j3"].option_codes == {0x6007: 1, 0x605A: 2, 0x605E: 2}
    _stop_mid_move(arm, drives)
    assert {d.state for d in drives.drives.values()} == {"SWITCH_ON_DISABLED"}
    assert set(arm.faults) == {"stop"}
    _recovers(arm, drives)
    start = arm.joints()
    drives.inject_fault("emcy", "j2", code=0x2310, after_s=0.1)
    with pytest.raises(DriveFault, match="j2"):
        arm.move_joints(Joints(start.j1_deg - 40.0, start.j2_deg - 30.0, start.j3_mm, start.j4_deg))
    assert drives.drives["j1"].state == "SWITCH_ON_DISABLED" and drives.drives["j2"].state == "FAULT"
    _recovers(arm, drives)
    arm.stop()
    arm.disconnect()  # from SWITCH ON DISABLED: nothing to send, no drive holds torque
    assert {d.state for d in drives.drives.values()} == {"SWITCH_ON_DISABLED"}


def test_drives_without_the_objects_are_driven_with_a_warning(drives, connect):
    drives.configure_option_codes(values={0x605A: 2}, missing={0x605A, 0x605E})
    arm, warnings = connect()
    assert len(warnings) == 10
    assert warnings[0].endswith("; the way check's quick stops (drivers.limits) assume the quick stop ramp 0x6085: "
                                "this axis may stop further off the way")
    assert not any("way check" in w for w in warnings if w.startswith(("j3", "j4", "gripper")))
    assert warnings[0].startswith("j1 (node 1): quick stop option code 0x605A missing (SDO abort 0x06020000, "
                                  "object does not exist): its quick stop is the drive's own")
    assert warnings[1] == ("j1 (node 1): fault reaction option code 0x605E missing (SDO abort 0x06020000, "
                           "object does not exist): a fault on this drive stops its axis as the drive is built; "
                           "the way check's quick stops (drivers.limits) assume the quick stop ramp 0x6085: this "
                           "axis may stop further off the way")
    assert arm.axes["gripper"].option_codes == {0x6007: 1, 0x605A: None, 0x605E: None}
    _stop_mid_move(arm, drives)
    assert {d.state for d in drives.drives.values()} == {"SWITCH_ON_DISABLED"}
    _recovers(arm, drives)


def test_a_drive_whose_quick_stop_lets_the_axis_coast_is_refused_at_bring_up(drives, connect):
    drives.configure_option_codes("j3", values={0x605A: 0}, accepted={0x605A: {0}})
    before = drives.positions()
    with pytest.raises(DriveFault, match=r"^j3 \(node 3\): quick stop option code 0x605A is 0 \(disable drive "
                       r"function: the axis coasts\) and writing 6 was refused with SDO abort 0x06090030: its "
                       r"quick stop would let the axis coast, so the host will not drive it") as e:
        connect()
    assert e.value.node == "j3"  # nothing was enabled, nothing moved
    assert {d.state for d in drives.drives.values()} == {"SWITCH_ON_DISABLED"}
    assert drives.positions() == before


def test_a_refused_fault_reaction_is_a_warning(drives, connect):
    drives.configure_option_codes("gripper", values={0x605E: 0}, accepted={0x605E: {0}})
    arm, warnings = connect()
    assert warnings == [
        "gripper (node 5): fault reaction option code 0x605E stays 0 (disable drive function: the axis coasts): "
        "writing 2 was refused with SDO abort 0x06090030; a fault on this drive stops its axis that way"]
    assert arm.is_connected and arm.axes["gripper"].option_codes == {0x6007: 1, 0x605A: 6, 0x605E: 0}



def _host_dies_mid_move(arm, drives):
    """A long move, then the host falls silent 0.1 s in (its heartbeat stops, nobody stops the drives); returns
    the target and where the axes stand a second later."""
    start = arm.joints()
    target = Joints(start.j1_deg - 60.0, start.j2_deg - 30.0, start.j3_mm - 50.0, start.j4_deg + 90.0)
    arm.move_joints(target, wait=False)
    arm.clock.sleep(0.1)
    arm._host_job.cancel()
    for _ in range(100):  # simulated time without the arm's supervision
        drives.clock.sleep(0.01)
    return target, drives.positions()


@pytest.mark.parametrize(("value", "text", "why"), [
    (0, "no action: the axis runs on", "a host that dies mid-move would leave the axis running its move to the end"),
    (2, "disable voltage: the axis coasts", "a host that dies would let the axis coast"),
])
def test_a_drive_that_would_not_stop_when_the_host_dies_is_refused_at_bring_up(drives, connect, value, text, why):
    drives.configure_option_codes("j2", values={0x6007: value}, accepted={0x6007: {value}})
    with pytest.raises(DriveFault, match=rf"^j2 \(node 2\): abort connection option code 0x6007 is {value} "
                       rf"\({text}\) and writing 1 was refused with SDO abort 0x06090030: {why}, so the host will "
                       r"not drive it \(set 0x6007 to 1 or 3 on the drive\)") as e:
        connect()
    assert e.value.node == "j2"
    assert {d.state for d in drives.drives.values()} == {"SWITCH_ON_DISABLED"}  # nothing was enabled


def test_without_the_hosts_setting_a_drive_with_no_action_runs_its_move_to_the_end(drives, connect):
    """Why the host sets 0x6007: taken over as the drive shipped (0), the host dying mid-move leaves the axis
    running to its target; set (1), it faults and stops mid-way (tests/test_can_faults.py)."""
    arm, _ = connect()
    for d in drives.drives.values():
        d._store(0x6007, 0, 0)  # as if the host had not set it
    target, stood = _host_dies_mid_move(arm, drives)
    assert stood["j1"] == pytest.approx(target.j1_deg, abs=1e-3)  # the whole move, nobody watching
    assert drives.drives["j1"].state == "OPERATION_ENABLED"


def test_a_drive_that_quick_stops_when_the_host_dies_is_driven_with_a_warning(drives, connect):
    drives.configure_option_codes(values={0x6007: 3}, accepted={0x6007: {3}})
    arm, warnings = connect()
    assert len(warnings) == 5 and warnings[0] == (
        "j1 (node 1): abort connection option code 0x6007 stays 3 (quick stop, as 0x605A says): writing 1 was "
        "refused with SDO abort 0x06090030; when the host falls silent the drive quick-stops instead of faulting")
    target, stood = _host_dies_mid_move(arm, drives)
    assert stood["j1"] > target.j1_deg + 1.0  # stopped mid-way, on the quick stop ramp
    assert {d.state for d in drives.drives.values()} == {"QUICK_STOP_ACTIVE"}
    assert all(d.emcy_log[-1:] == [0x8130] for d in drives.drives.values())  # each told why


def test_a_drive_without_the_object_is_driven_with_a_warning_and_stops_as_it_is_built(drives, connect):
    drives.configure_option_codes(missing={0x6007})
    arm, warnings = connect()
    assert warnings[0] == (
        "j1 (node 1): abort connection option code 0x6007 missing (SDO abort 0x06020000, object does not exist): "
        "when the host falls silent this drive does what it is built to do on a heartbeat consumer timeout (its "
        "manual says; many fault, some only send an EMCY)")
    assert len(warnings) == 5 and arm.axes["j1"].option_codes[0x6007] is None
    target, stood = _host_dies_mid_move(arm, drives)
    assert stood["j1"] > target.j1_deg + 1.0
    assert {d.state for d in drives.drives.values()} == {"FAULT"}  # these drives are built to fault
