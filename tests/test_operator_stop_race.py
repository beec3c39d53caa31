"""The operator's stop comes from another thread (the station's stop button) while the command thread starts a
move. Every frame of a move that enables operation (a set-point's controlwords, the halt's release) is sent
under the lock the stop latches under: the stop lands before such a frame, which is then not sent, or after
it, and its quick stops follow it on the bus. Before, a release already past the move's last look re-enabled
(CiA 402 transition 16) an axis the stop had just stopped. Through the real stack: python-can's virtual bus
and the simulated drives."""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time

import pytest
from drivers_fixtures import *  # noqa: F403 - the bus, drives and arm fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints
from drivers import Arm, DriverError, codec
from drivers.axis import Axis

pytestmark = needs_sim

STOP = "quick stop requested by the operator"


def _target(start: Joints) -> Joints:
    return Joints(start.j1_deg - 30.0, start.j2_deg - 20.0, start.j3_mm, start.j4_deg + 20.0)


def _stopper(arm):
    """The operator's stop in a thread of its own, as the station's stop button sends it."""
    t = threading.Thread(target=arm.stop, name="operator-stop", daemon=True)
    t.start()
    return t


def _stop_when(monkeypatch, arm, method: str, node: str | None = None):
    """The operator's stop, pressed (and finished) once as `node` (any node: None) enters `Axis.<method>`.
    Returns the method as it was."""
    real, done = getattr(Axis, method), []

    def hooked(ax, *a, **kw):
        if node in (None, ax.name) and not done:
            done.append(_stopper(arm).join(5.0))
        return real(ax, *a, **kw)

    monkeypatch.setattr(Axis, method, hooked)
    return real


def _controlwords(spy, cell):
    """(node name, controlword) of every RPDO1 on the bus so far, in order."""
    by_rpdo1 = {codec.RPDO1_BASE + n.node_id: name for name, n in cell.can.nodes.items()}
    return [(by_rpdo1[m.arbitration_id], int.from_bytes(m.data[:2], "little"))
            for m in iter(lambda: spy.recv(0), None) if m.arbitration_id in by_rpdo1]


def _nothing_enabled_after_the_first_quick_stop(words) -> None:
    first = next(i for i, (_, cw) in enumerate(words) if cw == codec.CW_QUICK_STOP)
    late = [(n, hex(cw)) for n, cw in words[first:] if cw & 0x000F == codec.CW_ENABLE_OPERATION]
    assert late == [], f"enable operation sent after the operator's quick stops: {late}"


def test_a_stop_landing_after_the_last_look_keeps_the_release_from_going_out(arm, sim_drives, open_test_bus,
                                                                             cell_cfg, monkeypatch):
    """Every axis holds its set-point and the last look found nothing; the stop then comes before the releases."""
    _stop_when(monkeypatch, arm, "release")
    spy = open_test_bus()
    start = sim_drives.positions()
    with pytest.raises(DriverError, match=STOP):
        arm.move_joints(_target(arm.joints()))
    arm.clock.sleep(0.5)
    words = _controlwords(spy, cell_cfg)
    assert not any(cw == codec.CW_ENABLE_OPERATION for _, cw in words)  # no release went out
    _nothing_enabled_after_the_first_quick_stop(words)
    assert sim_drives.positions() == pytest.approx(start, abs=1e-9)
    assert {sim_drives.drives[n].state for n in ("j1", "j2", "j4")} == {"QUICK_STOP_ACTIVE"}
    assert list(arm.faults) == ["stop"]


def test_a_stop_pressed_while_a_release_goes_out_sends_its_quick_stops_after_it(arm, sim_drives, open_test_bus,
                                                                                cell_cfg, monkeypatch):
    """The stop's latch waits for the release frame on its way: the quick stops follow it, and no release goes
    out after them (before, the stop's quick stops could go first and the release re-enable the axis they
    stopped)."""
    real, seen, latching = Axis.send_controlword, {}, threading.Event()
    latch = Arm._latch

    def _latch(self, err, key=None):
        if key == "stop":
            latching.set()
        return latch(self, err, key)

    def send_controlword(ax, cw):
        if cw == codec.CW_ENABLE_OPERATION and "thread" not in seen:  # the first release, inside the gate
            seen["thread"] = _stopper(arm)
            assert latching.wait(5.0)
            time.sleep(0.05)  # wall time for a stop not held at its latch to send its quick stops
            seen["stop held"] = seen["thread"].is_alive()
            seen["on the bus"] = _controlwords(spy, cell_cfg)
        return real(ax, cw)

    def gate_then_the_stop():
        """The move's gate; once the stop is on its way, the command thread goes on only after it has latched: in
        simulated time a stop thread starved of the CPU (a loaded machine) lost the race to the whole move, which
        then ended without the stop (once, with 4 test processes on 2 cores)."""
        with gate():
            yield
        if "thread" in seen:
            deadline = time.monotonic() + 5.0
            while "stop" not in arm.faults and time.monotonic() < deadline:
                time.sleep(0.001)

    gate = arm._unless_latched
    for ax in arm.axes.values():
        monkeypatch.setattr(ax, "move_gate", contextlib.contextmanager(gate_then_the_stop))
    monkeypatch.setattr(Arm, "_latch", _latch)
    monkeypatch.setattr(Axis, "send_controlword", send_controlword)
    spy = open_test_bus()
    with pytest.raises(DriverError, match=STOP):
        arm.move_joints(_target(arm.joints()))
    seen["thread"].join(5.0)
    arm.clock.sleep(0.5)
    assert seen["stop held"]
    assert not any(cw == codec.CW_QUICK_STOP for _, cw in seen["on the bus"])
    words = seen["on the bus"] + _controlwords(spy, cell_cfg)
    releases = [n for n, cw in words if cw == codec.CW_ENABLE_OPERATION]
    assert releases[0] == "j1"  # the one on its way when the stop came (the next ones may win the lock too)
    _nothing_enabled_after_the_first_quick_stop(words)
    assert {sim_drives.drives[n].state for n in ("j1", "j2", "j4")} == {"QUICK_STOP_ACTIVE"}
    assert list(arm.faults) == ["stop"]


def test_a_stop_between_two_one_by_one_starts_keeps_the_next_axis_standing(sim_drives, open_test_bus, sim_clock,
                                                                           cell_cfg, monkeypatch):
    """Without coordinated start: j1 runs when the stop comes, after the look before j2's handshake; j2's
    set-point frame is not sent (before, it re-enabled j2 from QUICK STOP ACTIVE and j2 started its move)."""
    cell = dataclasses.replace(cell_cfg, can=dataclasses.replace(cell_cfg.can, coordinated_start=False))
    arm = Arm(open_test_bus(), cell, clock=sim_clock, sdo_timeout_s=1.0)
    arm.connect()
    try:
        _stop_when(monkeypatch, arm, "send_target", "j2")
        spy = open_test_bus()
        start = sim_drives.positions()
        _moved_into_the_stop(arm, spy, cell)
        assert sim_drives.positions()["j2"] == pytest.approx(start["j2"], abs=1e-9)
        assert sim_drives.drives["j2"].state == "QUICK_STOP_ACTIVE"
        assert list(arm.faults) == ["stop"]
    finally:
        arm.disconnect()


def _moved_into_the_stop(arm, spy, cell) -> None:
    """A move that ends in the operator's stop, with no enable operation on the bus after the stop's quick stops."""
    with pytest.raises(DriverError, match=STOP):
        arm.move_joints(_target(arm.joints()))
    arm.clock.sleep(0.5)
    _nothing_enabled_after_the_first_quick_stop(_controlwords(spy, cell))


def _hook_wait(monkeypatch, node: str, what: str, action):
    """Run `action` once as `node` starts a wait whose text starts with `what`."""
    real, done = Axis.wait_status, []

    def wait_status(ax, pred, seq, text, *a, **kw):
        if ax.name == node and text.startswith(what) and not done:
            done.append(action())
        return real(ax, pred, seq, text, *a, **kw)

    monkeypatch.setattr(Axis, "wait_status", wait_status)


def test_a_stop_during_a_set_point_handshake_ends_its_wait_at_once(arm, sim_drives, open_test_bus, cell_cfg,
                                                                   monkeypatch):
    """The stop lands while j2 waits for its set-point's acknowledge: a quick-stopped drive takes no set-point, so
    the wait ends on its status, in the stop's error, and the next frame of the handshake is not sent (before,
    the host waited out the answer's second and blamed j2 for not answering, with a hint about coordinated
    start)."""
    _hook_wait(monkeypatch, "j2", "set-point acknowledge", lambda: _stopper(arm).join(5.0))
    spy = open_test_bus()
    start = sim_drives.positions()
    _moved_into_the_stop(arm, spy, cell_cfg)
    assert sim_drives.positions() == pytest.approx(start, abs=1e-9)
    assert list(arm.faults) == ["stop"]  # the host's own stop, not blamed on j2


def test_a_fault_during_a_set_point_handshake_is_the_fault_with_its_emcy(arm, sim_drives, monkeypatch):
    """j2 faults (EMCY over-current) as its acknowledge is cleared: the status in FAULT has the acknowledge bit
    clear, and still the wait ends in the fault's error with its code, not in a drive that left operation."""
    from drivers import DriveDisabled, DriveFault

    _hook_wait(monkeypatch, "j2", "set-point acknowledge cleared", lambda: sim_drives.inject_fault("emcy", "j2"))
    with pytest.raises(DriveFault, match=r"j2 \(node 2\)") as err:
        arm.move_joints(_target(arm.joints()))
    assert not isinstance(err.value, DriveDisabled)
    assert err.value.emcy_code == 0x2310 and "EMCY 0x2310 continuous over-current" in arm.faults["j2"]


@pytest.mark.parametrize(("first", "during"), [("emcy", "fault_reset"), ("emcy", "enable"), ("stop", "fault_reset")])
def test_a_stop_during_a_fault_reset_is_not_cleared_by_it(arm, sim_drives, monkeypatch, first, during):
    """j3 faulted (or an earlier stop is latched); the operator presses stop while the host resets the drives
    (j3's fault reset) or enables them again (j2's enable): the reset raises the stop, nothing is enabled after
    it, and the next move is refused. Before, the reset cleared the stop with the faults it began with and
    enabled every axis, and the next move ran."""
    from drivers import FaultLatched

    if first == "emcy":
        sim_drives.inject_fault("emcy", "j3")
        arm.clock.sleep(0.1)
    else:
        arm.stop()
    assert ("j3" if first == "emcy" else "stop") in arm.faults
    real = _stop_when(monkeypatch, arm, during, "j3" if during == "fault_reset" else "j2")
    joints = arm.joints()
    with pytest.raises(DriverError, match=STOP):
        arm.reset_faults()
    assert "stop" in arm.faults
    arm.clock.sleep(0.5)
    assert not [n for n, d in sim_drives.drives.items() if d.state == "OPERATION_ENABLED"]
    with pytest.raises(FaultLatched):
        arm.move_joints(_target(joints))
    monkeypatch.setattr(Axis, during, real)
    arm.reset_faults()  # the next reset clears it
    assert arm.faults == {}


@pytest.mark.parametrize("first", ["stop", "emcy"])
def test_a_stop_after_an_enable_frame_left_quick_stops_that_axis_too(arm, sim_drives, monkeypatch, first):
    """The stop lands after j2's enable operation went out during a reset, before j2 answered: j2 (still
    reported QUICK STOP ACTIVE or SWITCHED ON) gets its quick stop too. Before, the stop skipped it as not
    enabled, and j2 then stood in OPERATION ENABLED with the stop latched."""
    if first == "stop":
        arm.stop()
    else:
        sim_drives.inject_fault("emcy", "j2")
        arm.clock.sleep(0.1)
    _stop_when(monkeypatch, arm, "_wait_enabled", "j2")  # j2's enable sent, its answer not yet heard
    with pytest.raises(DriverError):
        arm.reset_faults()
    arm.clock.sleep(0.5)
    assert "stop" in arm.faults
    assert not [n for n, d in sim_drives.drives.items() if d.state == "OPERATION_ENABLED"]
