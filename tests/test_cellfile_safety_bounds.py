"""Cell file values that switched a safety check off or broke the drivers, refused when the file is read (exit 2,
one line naming the key and why), and the values on the bounds taken: the drives' and the host's heartbeat
periods, the error-frame burst limit, the gripper's forces against the drive's 0.1 N force limit 0x2100."""

from __future__ import annotations

import json

import pytest
from cell_files import edited_cell
from conftest import run_cli
from drivers_fixtures import needs_sim

from cell.cellconfig import HEARTBEAT_FRAME_BITS, parse_cell
from cell.errors import BadInput

_raw = edited_cell  # the default cell file's JSON with each edit set: `can__heartbeat_ms=5`


def _cell(**edits):
    return parse_cell(_raw(**edits), "cell.json")


def _refused(message: str, **edits) -> str:
    with pytest.raises(BadInput) as e:
        _cell(**edits)
    assert message in str(e.value), str(e.value)
    return str(e.value)


def _refused_by_the_cli(tmp_path, capsys, message: str, **edits) -> None:
    """`cell hw status --cell FILE`: exit 2, one line on stderr, nothing sent (nothing on stdout)."""
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(_raw(**edits)))
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", path, capsys=capsys)
    assert code == 2 and out == "", err
    assert err.count("\n") == 1 and err.startswith(f"cell: error: cell file {path}: ") and message in err, err


# --- can.heartbeat_ms: the drives' heartbeat (0x1017), watched by the host ------------------------------------
@pytest.mark.parametrize("hb", [10, 100, 1000])
def test_drive_heartbeats_from_the_hosts_poll_to_a_second_are_taken(hb):
    assert _cell(can__heartbeat_ms=hb).can.heartbeat_ms == hb


@pytest.mark.parametrize("hb, message", [
    # at 6 ms and under, every run of the host's watch (every 10 ms) was more than half a deadline after the
    # previous one: taken for a held-up host, silence was counted afresh each time and no drive was ever silent
    (9, "can.heartbeat_ms = 9 is less than 10 ms: the host looks at the drives every 10 ms"),
    (1, "the 5 drives' heartbeats alone would be 5000 frames/s, 32.5 % of can.bitrate 1000000 bit/s"),
    # at 65535 (the 16-bit object's top, all that was checked) a dead drive went unnoticed for 197 s
    (1001, "can.heartbeat_ms = 1001 is more than 1000 ms: the host would find a silent drive only 3 periods after "
           "its last heartbeat, 3.003 s"),
    (65535, "196.605 s, where a move takes a second or two"),
])
def test_drive_heartbeats_outside_them_are_refused(hb, message):
    _refused(message, can__heartbeat_ms=hb)


def test_a_drive_heartbeat_out_of_bounds_is_one_line_and_exit_2(tmp_path, capsys):
    _refused_by_the_cli(tmp_path, capsys, "can.heartbeat_ms = 5 is less than 10 ms", can__heartbeat_ms=5)
    _refused_by_the_cli(tmp_path, capsys, "can.heartbeat_ms = 65535 is more than 1000 ms", can__heartbeat_ms=65535)


def test_the_heartbeat_load_is_the_drivers_frame_size():
    from drivers.codec import frame_bits

    assert HEARTBEAT_FRAME_BITS == frame_bits(1)


@needs_sim
@pytest.mark.parametrize("hb", [10, 1000])
def test_at_either_bound_a_silent_drive_is_found_within_three_periods(hb):
    """The bounds are periods the host's watch works with: j2 falls silent, and is found silent after its last
    heartbeat plus the deadline (3 periods) and a poll or two, not before two periods."""
    from drivers import simulated_cell

    with simulated_cell(_cell(can__heartbeat_ms=hb)) as (arm, drives):
        period_s = hb / 1000.0
        drives.inject_fault("silent", "j2")
        t0 = arm.clock.now()  # j2's last heartbeat came within a period before
        arm.clock.sleep(2 * period_s - 0.001)
        assert not arm.faults
        arm.clock.sleep(period_s + 2 * arm.poll_s)
        assert arm.faults.get("j2", "").startswith("j2 (node 2): no heartbeat for"), arm.faults
        assert arm.clock.now() - t0 <= 3 * period_s + 2 * arm.poll_s + 1e-9


# --- can.host_heartbeat_ms: the host's heartbeat, watched by the drives (0x1016, 3 periods) ----------------------
@pytest.mark.parametrize("hb", [10, 100, 1000])
def test_host_heartbeats_from_the_hosts_poll_to_a_second_are_taken(hb):
    assert _cell(can__host_heartbeat_ms=hb).can.host_heartbeat_ms == hb


@pytest.mark.parametrize("hb, message", [
    (9, "can.host_heartbeat_ms = 9 is less than 10 ms: the drives would fault on a host heartbeat 27 ms late (3 "
        "periods), under three of the host's looks at the drives (every 10 ms"),
    (1, "3 ms late"),
    # at 21845 (the 16-bit deadline's top, all that was checked) a dead host left every drive enabled for 65 s
    (1001, "can.host_heartbeat_ms = 1001 is more than 1000 ms: a drive would find a dead host only 3 periods after "
           "its last heartbeat, 3.003 s, and run on enabled meanwhile"),
    (21845, "65.535 s"),
])
def test_host_heartbeats_outside_them_are_refused(hb, message):
    _refused(message, can__host_heartbeat_ms=hb)


def test_a_host_heartbeat_out_of_bounds_is_one_line_and_exit_2(tmp_path, capsys):
    _refused_by_the_cli(tmp_path, capsys, "can.host_heartbeat_ms = 5 is less than 10 ms", can__host_heartbeat_ms=5)
    _refused_by_the_cli(tmp_path, capsys, "can.host_heartbeat_ms = 21845 is more than 1000 ms",
                        can__host_heartbeat_ms=21845)


@needs_sim
@pytest.mark.parametrize("hb", [10, 1000])
def test_at_either_bound_the_drives_find_a_dead_host_within_three_periods(hb):
    """The bounds are periods the drives' watch works with: alive, no drive faults; the host's heartbeat stops,
    and every drive faults (EMCY 0x8130) within 3 periods and a tick of the drives, not within two."""
    from drivers import simulated_cell

    with simulated_cell(_cell(can__host_heartbeat_ms=hb)) as (arm, drives):
        period_s = hb / 1000.0
        arm.clock.sleep(2.0)
        assert not arm.faults and all(d.error_code == 0 for d in drives.drives.values())
        arm._host_job.cancel()  # the host is gone: its last heartbeat went out within a period before
        arm.clock.sleep(2 * period_s - 0.001)
        assert all(d.error_code == 0 for d in drives.drives.values())
        arm.clock.sleep(period_s + 0.02)
        assert {n: d.error_code for n, d in drives.drives.items()} == dict.fromkeys(drives.drives, 0x8130)


# --- can.error_frames_max: the burst limit, a rate within can.error_window_ms -------------------------------------
@pytest.mark.parametrize("most, window_ms", [(10, 100), (10, 1000), (100, 1000), (6000, 60_000), (0, 100), (10, 109)])
def test_burst_limits_up_to_100_error_frames_a_second_are_taken(most, window_ms):
    c = _cell(can__error_frames_max=most, can__error_window_ms=window_ms).can
    assert (c.error_frames_max, c.error_window_ms) == (most, window_ms)


@pytest.mark.parametrize("most, window_ms, message", [
    # 1000000 was taken: the burst check was off
    (1_000_000, 1000, "can.error_frames_max = 1000000 is more than 100 for can.error_window_ms = 1000: at most 100 "
                      "error frames a second of the window"),
    (101, 1000, "can.error_frames_max = 101 is more than 100 for can.error_window_ms = 1000"),
    (11, 100, "can.error_frames_max = 11 is more than 10 for can.error_window_ms = 100"),
    (11, 109, "can.error_frames_max = 11 is more than 10 for can.error_window_ms = 109"),
    (6001, 60_000, "can.error_frames_max = 6001 is more than 6000 for can.error_window_ms = 60000"),
])
def test_burst_limits_past_it_are_refused(most, window_ms, message):
    _refused(message, can__error_frames_max=most, can__error_window_ms=window_ms)


def test_the_default_window_bounds_the_burst_limit_too(tmp_path, capsys):
    """error_frames_max without error_window_ms: the limit is taken against the default window, 1000 ms."""
    raw = _raw(can__error_frames_max=101)
    del raw["can"]["error_window_ms"]
    with pytest.raises(BadInput, match="can.error_frames_max = 101 is more than 100 for can.error_window_ms = 1000"):
        parse_cell(raw, "cell.json")
    _refused_by_the_cli(tmp_path, capsys, "can.error_frames_max = 1000000 is more than 100",
                        can__error_frames_max=1_000_000)


@needs_sim
def test_at_the_bound_the_burst_check_still_stops_the_arm():
    """100 error frames within 1000 ms are counted; the 101st latches a bus fault."""
    from drivers import simulated_cell

    with simulated_cell(_cell(can__error_frames_max=100)) as (arm, drives):
        drives.inject_fault("error_frames", count=100, error_class="bus_error")
        arm.clock.sleep(0.1)
        assert arm.bus_state()["error_frames"] == 100 and arm.bus_state()["fault"] is None
        drives.inject_fault("error_frames", count=1, error_class="bus_error")
        arm.clock.sleep(0.1)
        assert arm.bus_state()["fault"].startswith("bus: 101 error frames within 1000 ms"), arm.bus_state()


# --- gripper.grip_force_n and max_force_n: the drive's force limit 0x2100, UNSIGNED16 in 0.1 N, sent rounded ------
@pytest.mark.parametrize("grip, most", [
    (40.0, 140.0),
    (140.0, 140.0),  # the grip force may be the most
    (0.051, 140.0),  # 0.51 -> 1: 0.1 N
    (6553.5, 6553.5),  # 65535: the top of 16 bits
    (40.0, 6553.54),  # 65535.4 -> 65535 as the drivers round it
])
def test_grip_forces_the_drive_holds_are_taken(grip, most):
    g = _cell(gripper__grip_force_n=grip, gripper__max_force_n=most).gripper
    assert (g.grip_force_n, g.max_force_n) == (grip, most)


@pytest.mark.parametrize("grip, most, message", [
    # connect wrote 500 N into 0x2100 of a gripper whose most is 140 N; every grip at the cell's force was refused
    (500.0, 140.0, "gripper.grip_force_n = 500 N is more than gripper.max_force_n = 140 N: connect would set the "
                   "drive's force limit 0x2100 past the gripper's most"),
    (140.01, 140.0, "gripper.grip_force_n = 140.01 N is more than gripper.max_force_n = 140 N"),
    # 0.5 -> 0 (Python rounds half to even, as the drivers do): a force limit of 0 N
    (0.05, 140.0, "gripper.grip_force_n = 0.05 N is 0 in the drive's force limit 0x2100 (0.1 N, sent rounded): the "
                  "jaws would close with no force; more than 0.05 N"),
    (0.01, 140.0, "gripper.grip_force_n = 0.01 N is 0 in the drive's force limit 0x2100"),
    (0.01, 0.01, "gripper.grip_force_n = 0.01 N is 0 in the drive's force limit 0x2100"),
    # grip(force_n=7000) reached canopen's UNSIGNED16 encoder: an internal error, not a refusal
    (40.0, 10_000.0, "gripper.max_force_n = 10000 N is 100000 in the drive's force limit 0x2100 (0.1 N, sent "
                     "rounded): more than its UNSIGNED16 holds (at most 6553.5 N)"),
    (40.0, 6553.55, "gripper.max_force_n = 6553.55 N is 65536 in the drive's force limit 0x2100"),  # 65535.5 -> 65536
])
def test_grip_forces_the_drive_does_not_hold_are_refused(grip, most, message):
    _refused(message, gripper__grip_force_n=grip, gripper__max_force_n=most)


def test_a_grip_force_out_of_bounds_is_one_line_and_exit_2(tmp_path, capsys):
    _refused_by_the_cli(tmp_path, capsys, "gripper.grip_force_n = 500 N is more than gripper.max_force_n = 140 N",
                        gripper__grip_force_n=500.0)
    _refused_by_the_cli(tmp_path, capsys, "gripper.max_force_n = 10000 N is 100000", gripper__max_force_n=10_000.0)


@needs_sim
@pytest.mark.parametrize("grip, most, grip_units, most_units", [
    (0.051, 0.1, 1, 1), (0.051, 6553.5, 1, 65535), (40.0, 6553.54, 400, 65535)])
def test_forces_on_the_bounds_reach_the_drive_as_checked(grip, most, grip_units, most_units):
    """The bounds are the drivers' encoding: connect writes the cell's grip force into 0x2100, grip() the most."""
    from drivers import simulated_cell
    from drivers.eds import GRIP_FORCE_INDEX

    with simulated_cell(_cell(gripper__grip_force_n=grip, gripper__max_force_n=most)) as (arm, drives):
        force_limit = drives.drives["gripper"].node.sdo[GRIP_FORCE_INDEX]
        assert force_limit.raw == grip_units
        drives.gripper_object_width_mm = 30.0
        assert arm.gripper.grip(30.0, force_n=most).holding and not arm.faults
        assert force_limit.raw == most_units


# --- speeds: a move across an axis' range ends within a minute --------------------------------------------------
def test_speeds_under_which_a_move_across_an_axis_takes_more_than_a_minute_are_refused(tmp_path, capsys):
    """Was: taken, and the first move of `cell run` took about 4000 s with no word (0.01 deg/s)."""
    _refused_by_the_cli(tmp_path, capsys, "scara.max_velocity.j1 = 0.01 and max_acceleration.j1 = 720: a move "
                        "across J1's range", scara__max_velocity__j1=0.01)
    _refused("gripper.speed_mm_s = 0.1: a move across the gripper's range (80 mm) would take 800 s, more than 60 s",
             gripper__speed_mm_s=0.1)
    _refused("max_acceleration.j3 = 0.001", scara__max_acceleration__j3=0.001)
    j3 = _cell().scara.j3_mm
    span = j3[1] - j3[0]
    fast = 1e5  # (the ramps take no time: the move is its distance over its speed)
    assert _cell(scara__max_velocity__j3=span / 59.9, scara__max_acceleration__j3=fast)
    _refused("would take 60.1 s", scara__max_velocity__j3=span / 60.1, scara__max_acceleration__j3=fast)


def test_a_wrist_without_end_is_timed_over_one_turn():
    """J4 given limits of a million degrees (a wrist that turns without end) at 600 deg/s: a turn takes 0.85 s."""
    assert _cell(scara__j4_deg=[-1e6, 1e6]).scara.j4_deg == (-1e6, 1e6)
    _refused("a move across J4's range (360 deg) would take", scara__j4_deg=[-1e6, 1e6], scara__max_velocity__j4=5.0)


@pytest.mark.parametrize("distance, v, a", [(264.0, 180.0, 720.0), (1.0, 180.0, 720.0), (200.0, 0.01, 720.0),
                                            (80.0, 60.0, 600.0), (360.0, 5.0, 1e5)])
def test_the_move_time_the_cell_file_bounds_is_the_drives_profile(distance, v, a):
    """cellconfig times a move itself (importing drivers there costs every `cell grasp` 0.2 s): it must stay
    the drives' own trapezoid."""
    from cell.cellconfig import _full_range_move_s
    from drivers.profile import trapezoid

    assert _full_range_move_s(distance, v, a) == pytest.approx(trapezoid(distance, v, a).duration_s, rel=1e-12)
