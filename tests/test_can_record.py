"""Bus recording round trip with python-can's loggers: record a simulated session, read it
back with can.LogReader, get the identical frames; replay it onto a bus."""

from __future__ import annotations

import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from cell.errors import BadInput
from cell.kinematics import Joints
from drivers import Arm, sim
from drivers.errorframes import classify
from drivers.pump import BusPump
from drivers.record import BusRecorder, read_log, replay, same_frame

pytestmark = needs_sim


@pytest.mark.parametrize("suffix", [".asc", ".log", ".blf"])
def test_session_recording_reads_back_identical(tmp_path, open_test_bus, sim_clock, cell_cfg, suffix):
    heard = []
    tap = BusPump(open_test_bus(), [heard.append], name="test-tap")
    sim_clock.add_settler(tap.settle)
    path = tmp_path / f"session{suffix}"
    with BusRecorder(open_test_bus(), path, clock=sim_clock) as rec:
        with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as drives:
            with Arm(open_test_bus(), cell_cfg, clock=sim_clock) as arm:
                s = arm.joints()
                arm.move_joints(Joints(s.j1_deg + 2, s.j2_deg, s.j3_mm - 10, s.j4_deg))
                drives.gripper_object_width_mm = 20.0
                assert arm.gripper.grip(20.0).holding
            drives.inject_fault("error_frames", count=1, error_class="bus_off")
            sim_clock.sleep(0.01)
    tap.settle()
    tap.stop()
    frames = read_log(path)
    assert rec.frames == len(frames) == len(heard) > 100
    assert all(same_frame(a, b) for a, b in zip(frames, heard, strict=True))
    ids = {m.arbitration_id for m in frames}
    assert {0x181, 0x201, 0x301, 0x601, 0x581, 0x701, 0x77F, 0x000} <= ids  # PDOs, SDO, heartbeats, NMT
    errors = [m for m in frames if m.is_error_frame]
    assert len(errors) == 1
    if suffix == ".blf":  # of python-can's formats the one that keeps the error class and its details
        assert classify(errors[0]).text.startswith("bus-off, error-counter-tx-rx{tx 255, rx 0}: ")
    # simulated time stamps: the session took seconds of simulated time
    assert frames[-1].timestamp - frames[0].timestamp > 1.0


def test_replay_sends_the_recorded_frames(tmp_path, open_test_bus):
    import can

    path = tmp_path / "fixture.log"
    sender, rec_bus = open_test_bus(), open_test_bus()
    sent = [can.Message(arbitration_id=0x200 + i, data=bytes([i, 0x0F]), is_extended_id=False) for i in range(1, 6)]
    with BusRecorder(rec_bus, path) as rec:
        for m in sent:
            sender.send(m)
    assert rec.frames == 5
    listener = open_test_bus()
    assert replay(path, sender) == 5
    got = [listener.recv(timeout=1.0) for _ in sent]
    assert all(same_frame(a, b) for a, b in zip(got, sent, strict=True))


@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_a_channel_named_with_spaces_is_recorded_readably(tmp_path, suffix):
    """A candump line is split at spaces: a bus on a channel named with one (a test's, `--channel 'test bus'`)
    left a recording whose can.log did not read back ("too many values to unpack")."""
    import can

    from drivers import open_bus

    path = tmp_path / f"spaces{suffix}"
    sender, rec_bus = open_bus("virtual", "a bus [with spaces]: x"), open_bus("virtual", "a bus [with spaces]: x")
    try:
        sent = [can.Message(arbitration_id=0x181, data=bytes([i]), is_extended_id=False) for i in range(3)]
        with BusRecorder(rec_bus, path) as rec:
            for m in sent:
                sender.send(m)
        assert rec.frames == 3
        got = read_log(path)
        assert len(got) == 3 and all(same_frame(a, b) for a, b in zip(got, sent, strict=True))
    finally:
        sender.shutdown()
        rec_bus.shutdown()


def test_unknown_log_format_and_missing_log_are_bad_input(tmp_path, open_test_bus):
    with pytest.raises(BadInput, match="python-can"):
        BusRecorder(open_test_bus(), tmp_path / "x.json")
    with pytest.raises(BadInput, match="does not exist"):
        read_log(tmp_path / "missing.asc")


def test_golden_session_fixture_is_reproduced_frame_for_frame(tmp_path):
    from drivers.golden import fixture_path, record_golden_session

    path = tmp_path / "session.log"
    record_golden_session(path)
    got, want = read_log(path), read_log(fixture_path())
    assert len(got) == len(want) > 200
    for i, (a, b) in enumerate(zip(got, want, strict=True)):
        assert same_frame(a, b) and a.timestamp == pytest.approx(b.timestamp), f"frame {i}: {a} != {b}"


def test_the_golden_fixture_is_remade_in_place(tmp_path):
    """`python -m drivers.golden` (docs/drivers.md) ended in a traceback: a CAN log is never written over."""
    from drivers.golden import fixture_path, remake_fixture

    out = tmp_path / "enable_move_grip.log"
    out.write_text("an older session\n")
    remake_fixture(out)
    assert out.read_bytes() == fixture_path().read_bytes() and [p.name for p in tmp_path.iterdir()] == [out.name]


@pytest.mark.parametrize("argv", [["status", "--json"], ["jog", "j3", "10"]])
def test_hw_record_never_writes_over_a_file(tmp_path, capsys, argv):
    """`cell hw ... --record FILE` onto an existing file (another log, a recording's can.log, the command's own
    cell file) is refused before anything is sent, and the file is as it was (before, it was replaced, even by a
    jog refused with exit 2)."""
    from cell.cli import main

    for name, content in (("old.log", b"precious\n"), ("cell.log", None)):
        path = tmp_path / name
        if content is None:  # the cell file itself, under a log's name
            from cell.cellconfig import default_cell_path

            content = default_cell_path().read_bytes()
        path.write_bytes(content)
        extra = ["--cell", str(path)] if name == "cell.log" else []
        code = main(["hw", *argv, "--simulated-time", "--record", str(path), *extra])
        err = capsys.readouterr().err
        assert code == 2 and f"CAN log {path} exists: a CAN log is never written over" in err
        assert "Traceback" not in err and path.read_bytes() == content
