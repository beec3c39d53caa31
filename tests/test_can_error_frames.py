"""The error frame policy (drivers.errorframes) on the virtual bus against the simulated drives, in simulated
time: a sporadic error frame is counted and the move goes on; more than can.error_frames_max within
can.error_window_ms stop it; a frame saying the host is off the bus stops it at once; a reset starts the
window afresh; the cell file's values are checked when read."""

from __future__ import annotations

import copy
import dataclasses
import json
import logging
import re
from pathlib import Path

import can
import pytest
from conftest import run_cli
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.cellconfig import default_cell_path, load_cell, parse_cell
from cell.errors import BadInput
from cell.kinematics import Joints
from drivers import Arm, BusFault, FaultLatched, errorframes, sim
from drivers.errorframes import classify

pytestmark = needs_sim

ERROR_H = Path("/usr/include/linux/can/error.h")
CAN_H = Path("/usr/include/linux/can.h")


def _header_values(path: Path) -> dict[str, int]:
    pattern = r"#define\s+(CAN_ERR_\w+)\s+(0x[0-9A-Fa-f]+|\d+)U?\b"
    return {m[1]: int(m[2], 0) for m in re.finditer(pattern, path.read_text())}


@pytest.mark.skipif(not ERROR_H.is_file(), reason="no linux/can/error.h on this machine")
def test_the_error_classes_are_the_kernels():
    """Every bit the policy reads, and every name it gives, is the value of the system's linux/can/error.h
    (and can.h; python-can's CAN_ERR_FLAG too)."""
    h = {**_header_values(ERROR_H), **_header_values(CAN_H)}
    ours = {k: v for k, v in vars(errorframes).items() if k.startswith("CAN_ERR_")}
    assert len(ours) > 15 and {k: h[k] for k in ours} == ours
    crtl = {"rx-overflow": "RX_OVERFLOW", "tx-overflow": "TX_OVERFLOW", "rx-error-warning": "RX_WARNING",
            "tx-error-warning": "TX_WARNING", "rx-error-passive": "RX_PASSIVE", "tx-error-passive": "TX_PASSIVE",
            "back-to-error-active": "ACTIVE"}
    assert {name: h[f"CAN_ERR_CRTL_{crtl[name]}"] for name in crtl} == {
        name: bit for bit, name in errorframes.CONTROLLER_NAMES.items()}
    prot = {"single-bit-error": "BIT", "frame-format-error": "FORM", "bit-stuffing-error": "STUFF",
            "tx-dominant-bit-error": "BIT0", "tx-recessive-bit-error": "BIT1", "bus-overload": "OVERLOAD",
            "active-error": "ACTIVE", "error-on-tx": "TX"}
    assert {name: h[f"CAN_ERR_PROT_{prot[name]}"] for name in prot} == {
        name: bit for bit, name in errorframes.PROTOCOL_NAMES.items()}
    from can.interfaces.socketcan import constants

    assert constants.CAN_ERR_FLAG == h["CAN_ERR_FLAG"] == 0x20000000


@pytest.mark.parametrize(
    ("error_class", "action", "names"),
    [
        ("bus_error", "count", "protocol-violation{single-bit-error}, bus-error"),
        ("error_warning", "count", "controller-problem{tx-error-warning}"),
        ("unclassified", "count", "error frame of no class"),
        ("lost_arbitration", "note", "lost-arbitration"),
        ("back_to_error_active", "note", "controller-problem{back-to-error-active}"),
        ("bus_off", "stop", "bus-off"),
        ("tx_timeout", "stop", "tx-timeout"),
        ("no_ack", "stop", "no-acknowledgement-on-tx"),  # with protocol-violation and bus-error: the stop wins
        ("error_passive", "stop", "controller-problem{tx-error-passive}, error-counter-tx-rx{tx 128, rx 0}"),
        ("restarted", "stop", "restarted-after-bus-off"),
    ],
)
def test_each_class_as_socketcan_presents_it(error_class, action, names):
    v = classify(sim.error_frame(error_class))
    assert v.action == action and names in v.text


def test_an_interface_that_gives_no_class_is_counted_whatever_its_id_says():
    """PCAN's error frame id is PCAN-Basic's own (0x40 there is no bus-off) and Kvaser's says nothing: from such
    a bus every error frame goes into the window, none stops at once on a misread class."""
    msg = sim.error_frame("bus_off")
    assert classify(msg, readable=False).action == "count"
    assert "no class" in classify(msg, readable=False).text
    bus = can.Bus(interface="virtual", channel="classes-readable")
    try:
        assert errorframes.classes_readable(bus)  # the simulation's bus presents them as SocketCAN does
    finally:
        bus.shutdown()


def test_one_sporadic_error_frame_during_a_move_does_not_stop_it(arm, sim_drives):
    start = arm.joints()
    target = Joints(start.j1_deg - 40.0, start.j2_deg - 30.0, start.j3_mm - 50.0, start.j4_deg + 90.0)
    arm.move_joints(target, wait=False)
    arm.clock.sleep(0.1)
    sim_drives.inject_fault("error_frames", count=1, error_class="bus_error")
    arm.wait_idle()
    assert sim_drives.positions()["j1"] == pytest.approx(target.j1_deg, abs=1e-3)
    assert arm.faults == {} and arm.error_frames == 1
    bus = arm.bus_state()
    assert bus["by_class"] == {"protocol-violation": 1, "bus-error": 1, "error-counter-tx-rx": 1}
    assert bus["in_window"] == 1 and bus["fault"] is None and "single-bit-error" in bus["last"]
    arm.clock.sleep(1.0)
    assert arm.bus_state()["in_window"] == 0 and arm.error_frames == 1  # out of the window, still counted


def test_error_frames_spread_wider_than_the_window_never_stop_the_arm(arm, sim_drives):
    """Thirty frames, the limit's in every window but never more: a bus that works. Then one more within the
    window of the last ten stops it, the message naming the count and the window."""
    most, window_s = arm.cell.can.error_frames_max, arm.cell.can.error_window_ms / 1000.0
    for _ in range(3):
        sim_drives.inject_fault("error_frames", count=most, error_class="error_warning")
        arm.clock.sleep(window_s + 0.01)
    assert arm.faults == {} and arm.error_frames == 3 * most
    sim_drives.inject_fault("error_frames", count=most, error_class="bus_error")
    arm.clock.sleep(window_s - 0.05)
    assert arm.faults == {}
    sim_drives.inject_fault("error_frames", count=1, error_class="unclassified")
    arm.clock.sleep(0.01)
    assert arm.faults["bus"].startswith(f"bus: {most + 1} error frames within 1000 ms (more than can.error_frames_max")
    assert "the last: error frame of no class" in arm.faults["bus"]


def test_lost_arbitration_is_no_error(arm, sim_drives, caplog):
    """Arbitration is how CAN shares the bus, back to error-active the recovery: seen, never a stop, and
    no warning (a controller reporting every lost arbitration would flood the log of a healthy bus)."""
    with caplog.at_level(logging.DEBUG, logger="drivers.arm"):
        for kind in ("lost_arbitration", "back_to_error_active"):
            sim_drives.inject_fault("error_frames", count=3 * arm.cell.can.error_frames_max, error_class=kind)
        arm.clock.sleep(0.02)
    assert arm.faults == {} and arm.bus_state()["in_window"] == 0
    assert arm.bus_state()["by_class"] == {"lost-arbitration": 30, "controller-problem": 30, "error-counter-tx-rx": 30}
    assert (arm.bus_state()["error_frames"], arm.bus_state()["errors"]) == (60, 0)
    seen = [r for r in caplog.records if "error frame" in r.getMessage()]
    assert len(seen) == 60 and {r.levelno for r in seen} == {logging.DEBUG}
    assert all(r.getMessage().endswith("(seen, not counted)") for r in seen)
    sim_drives.inject_fault("error_frames", count=1, error_class="bus_error")
    arm.clock.sleep(0.02)
    assert arm.bus_state()["errors"] == 1 and arm.faults == {}


@pytest.mark.parametrize(("error_class", "name"), [
    ("bus_off", "bus-off"), ("tx_timeout", "tx-timeout"), ("no_ack", "no-acknowledgement-on-tx"),
    ("error_passive", "tx-error-passive"), ("restarted", "restarted-after-bus-off"),
])
def test_a_frame_saying_the_host_is_off_the_bus_stops_the_move_at_once(arm, sim_drives, error_class, name):
    start = arm.joints()
    target = Joints(start.j1_deg - 40.0, start.j2_deg, start.j3_mm, start.j4_deg)
    arm.move_joints(target, wait=False)
    arm.clock.sleep(0.1)
    sim_drives.inject_fault("error_frames", count=1, error_class=error_class)
    t0 = arm.clock.now()
    with pytest.raises(BusFault, match=rf"^bus: error frame .*{name}.*: (the host's CAN controller|no node ack)"):
        arm.wait_idle()
    assert sim_drives.drives["j1"].state == "QUICK_STOP_ACTIVE"
    assert sim_drives.positions()["j1"] > target.j1_deg + 20.0  # stopped a third of the way
    assert arm.clock.now() - t0 < 1.0  # the quick stop ramp, not a window
    assert arm.error_frames == 1


def test_after_a_reset_the_window_starts_afresh(open_test_bus, sim_clock, cell_cfg, sim_drives):
    """A long window (constructor override): the burst that stopped the arm is forgotten by reset_faults(),
    so as many frames again right after it do not stop it a second time."""
    with Arm(open_test_bus(), cell_cfg, clock=sim_clock, error_frames_max=3, error_window_ms=60_000) as arm:
        sim_drives.inject_fault("error_frames", count=4)
        sim_clock.sleep(0.02)
        assert arm.faults["bus"].startswith("bus: 4 error frames within 60000 ms")
        arm.reset_faults()
        assert arm.faults == {} and arm.bus_state()["in_window"] == 0
        sim_drives.inject_fault("error_frames", count=3)
        sim_clock.sleep(0.02)
        assert arm.faults == {} and arm.error_frames == 7
        sim_drives.inject_fault("error_frames", count=1)
        sim_clock.sleep(0.02)
        assert arm.faults["bus"].startswith("bus: 4 error frames within 60000 ms")


def test_the_cell_files_window_is_the_arms(open_test_bus, sim_clock, cell_cfg, sim_drives):
    """error_frames_max = 0: the first error frame of any class stops the arm (the strictest setting)."""
    cell = dataclasses.replace(cell_cfg, can=dataclasses.replace(cell_cfg.can, error_frames_max=0))
    with Arm(open_test_bus(), cell, clock=sim_clock) as arm:
        sim_drives.inject_fault("error_frames", count=1, error_class="error_warning")
        sim_clock.sleep(0.02)
        assert arm.faults["bus"].startswith("bus: 1 error frame within 1000 ms (more than can.error_frames_max = 0")
        with pytest.raises(FaultLatched):
            arm.move_joints(arm.joints())


def _cell_with(**can_keys) -> dict:
    raw = json.loads(default_cell_path().read_text())
    raw = copy.deepcopy(raw)
    raw["can"].update(can_keys)
    return raw


def test_the_window_is_optional_in_the_cell_file():
    raw = _cell_with()
    del raw["can"]["error_frames_max"], raw["can"]["error_window_ms"]
    c = parse_cell(raw).can
    assert (c.error_frames_max, c.error_window_ms) == (10, 1000) == (load_cell().can.error_frames_max, 1000)
    c = parse_cell(_cell_with(error_frames_max=0, error_window_ms=250)).can
    assert (c.error_frames_max, c.error_window_ms) == (0, 250)


@pytest.mark.parametrize(
    ("keys", "message"),
    [
        ({"error_frames_max": -1}, "can.error_frames_max must be 0 or more error frames, got -1"),
        ({"error_frames_max": 2.5}, "can.error_frames_max must be a whole number, got 2.5"),
        ({"error_frames_max": "10"}, "can.error_frames_max must be a finite number, got '10'"),
        ({"error_frames_max": None}, "can.error_frames_max must be a finite number, got null"),
        ({"error_window_ms": 0}, "can.error_window_ms must be positive, got 0"),
        ({"error_window_ms": 100.5}, "can.error_window_ms must be a whole number, got 100.5"),
        ({"error_window_ms": 120_000}, "can.error_window_ms = 120000 is more than 60000 ms"),
        ({"error_window_ms": 5}, "can.error_window_ms = 5 is less than 100 ms"),
        ({"error_frame_max": 3}, "unknown key can.error_frame_max"),
    ],
)
def test_a_bad_window_in_the_cell_file_is_refused(tmp_path, capsys, keys, message):
    with pytest.raises(BadInput, match=re.escape(message)):
        parse_cell(_cell_with(**keys))
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(_cell_with(**keys)))
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", str(path), capsys=capsys)
    assert code == 2 and message in err and "Traceback" not in err and out == ""


def test_hw_status_shows_the_bus(capsys):
    code, out, err = run_cli("hw", "status", "--simulated-time", capsys=capsys)
    assert code == 0, err
    assert out.splitlines()[-1].startswith("bus      error frames 0; more than 10 within 1000 ms")
    code, out, err = run_cli("hw", "status", "--simulated-time", "--json", capsys=capsys)
    assert code == 0 and len(out.splitlines()) == 5 and "bus      error frames 0" in err  # stdout: the nodes only


def test_hw_status_and_the_run_summary_name_the_classes_alike():
    import io

    from cell.commands.hw import _bus_text
    from cell.commands.run import _print_summary

    bus = {"error_frames": 5, "errors": 4, "by_class": {"rx-overflow": 1, "bus-error": 3, "lost-arbitration": 1},
           "error_frames_max": 10, "error_window_ms": 1000, "fault": None}
    assert "error frames 5 (3 bus-error, 1 lost-arbitration, 1 rx-overflow);" in _bus_text(bus)
    out = io.StringIO()
    _print_summary({"assembly": "a", "parts_removed": 0, "parts_total": 1, "status": "stopped", "grasps": 0,
                    "parts": [], "can_bus": bus}, out)
    assert "CAN bus: 5 error frame(s) (3 bus-error, 1 lost-arbitration, 1 rx-overflow), 4 counted" in out.getvalue()
