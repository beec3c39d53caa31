"""Cell files with numbers no cell has: refused when read, naming the key, not a hang or an internal error later."""

import json

import pytest
from conftest import run_cli

from cell.cellconfig import default_cell_path


def _edited(edits) -> dict:
    """The default cell file's JSON with each (key path, value) of `edits` set."""
    raw = json.loads(default_cell_path().read_text())
    for path, value in edits:
        d = raw
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
    return raw


def _cell_file(tmp_path, edits):
    cell = tmp_path / "cell.json"
    cell.write_text(json.dumps(_edited(edits)))
    return cell


CPU = ("can", "nodes", "j4", "counts_per_unit")


@pytest.mark.parametrize("edits, message", [
    # `cell grasp` ran without end (1e9) or was an internal error (1e308: OverflowError)
    ([(("gripper", "pad_width_mm"), 1e9)], "gripper.pad_width_mm must be within +-1e+06"),
    ([(("gripper", "pad_width_mm"), 1e308)], "gripper.pad_width_mm must be within +-1e+06"),
    ([(("scara", "j4_deg"), [-360, 1e9])], "scara.j4_deg[1] must be within +-1e+06"),
    # `cell render` asked for terabytes (MemoryError) or numpy refused the shape (ValueError): internal errors
    ([(("camera", "width_px"), 1e9)], "camera.width_px must be within +-1e+06"),
    ([(("camera", "width_px"), 1e6)], "camera 1000000 x 1024 px"),
    ([(("camera", "height_px"), 100000)], "at most 100 MP in all"),
    ([(("camera", "width_px"), 8)], "each side at least 16 px"),
    # `cell run` was an internal error in segmentation (cv2.error: dst.cols < SHRT_MAX in function 'remap')
    ([(("camera", "width_px"), 40000), (("camera", "height_px"), 1000)],
     "camera 40000 x 1000 px: each side must be less than 32767 px (OpenCV's remap limit"),
    ([(("camera", "height_mm"), 1e308)], "camera.height_mm must be within"),  # was ZeroDivisionError
    # `cell hw status`: internal errors at bring-up (the drives' objects are 16 and 32 bits)
    ([(("can", "heartbeat_ms"), 1e6)], "can.heartbeat_ms = 1000000 is more than 1000 ms"),
    ([(("can", "host_heartbeat_ms"), 30000)], "can.host_heartbeat_ms = 30000 is more than 1000 ms"),
    ([(("scara", "j4_deg"), [-360, 3000]), (CPU, 1e6)], "scara.j4_deg = 3000 is 3e+09 counts"),
    ([(CPU, 1.2e6)], "the quick stop's deceleration (2 x scara.max_acceleration.j4) = 4800 is 5.76e+09 counts"),
    ([(CPU, 1e7)], "scara.j4_deg = 360 is 3.6e+09 counts (can.nodes.j4.counts_per_unit = 1e+07): more than a "
                   "drive's INTEGER32 position holds"),
    ([(("can", "nodes", "gripper", "counts_per_unit"), 1e308)], "gripper.opening_mm = 80 is inf counts"),
    # the gripper's acceleration, 10 x its speed, was not checked: "internal error: ValueError" at bring-up
    ([(("gripper", "speed_mm_s"), 1000), (("can", "nodes", "gripper", "counts_per_unit"), 1e6)],
     "gripper's acceleration (10 x speed_mm_s) = 10000 is 1e+10 counts"),
])
def test_a_cell_file_with_out_of_range_numbers_is_refused(tmp_path, capsys, edits, message):
    cell = _cell_file(tmp_path, edits)
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", cell, capsys=capsys)
    assert code == 2 and message in err and "internal error" not in err and out == "", err
    assert f"cell file {cell}" in err


@pytest.mark.parametrize("counts_per_deg", [1e6, 1.86e6])
def test_a_fine_encoder_is_taken(tmp_path, capsys, counts_per_deg):
    """A 23-bit encoder behind an 80:1 harmonic drive: 1.86e6 counts per degree. The blanket +-1e6 bound on
    every number refused it; its rates fit the drives' UNSIGNED32 objects (the quick stop's 1440 deg/s^2 is
    2.7e9 counts/s^2, past INTEGER32)."""
    cell = _cell_file(tmp_path, [(("can", "nodes", j, "counts_per_unit"), counts_per_deg) for j in ("j1", "j2")])
    code, out, err = run_cli("hw", "status", "--simulated-time", "--json", "--cell", cell, capsys=capsys)
    assert code == 0, err
    nodes = [json.loads(line) for line in out.splitlines()]
    assert [n["state"] for n in nodes] == ["OPERATION_ENABLED"] * 5


def test_counts_that_fit_32_bits_are_taken(tmp_path, capsys):
    cell = _cell_file(tmp_path, [(("can", "nodes", "j1", "counts_per_unit"), 1e6)])  # 132 deg: 1.32e8 counts
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", cell, capsys=capsys)
    assert code == 0, err


# ------------------------------------------------------------------ the bounds pinned (mutation pass)
def _parse(edits):
    from cell.cellconfig import parse_cell

    return parse_cell(_edited(edits), "cell.json")


def _refused(edits, message):
    from cell.errors import BadInput

    with pytest.raises(BadInput) as e:
        _parse(edits)
    assert message in str(e.value), str(e.value)


@pytest.mark.parametrize("edits", [
    [(("camera", "width_px"), 10_000), (("camera", "height_px"), 10_000)],  # 100 MP exactly
    [(("camera", "width_px"), 16), (("camera", "height_px"), 16)],  # the smallest side
    [(("camera", "width_px"), 32766), (("camera", "height_px"), 1000)],  # the longest side OpenCV's remap takes
    [(("camera", "width_px"), 1000), (("camera", "height_px"), 32766)],
    [(("can", "heartbeat_ms"), 1000), (("can", "host_heartbeat_ms"), 1000)],  # a second
    [(("can", "heartbeat_ms"), 10), (("can", "host_heartbeat_ms"), 10)],  # the host's poll
    # exactly one count/s (0.5 counts per mm; 0.001 mm/s at 1000 counts per mm would take 22 hours to open)
    [(("gripper", "speed_mm_s"), 2.0), (("can", "nodes", "gripper", "counts_per_unit"), 0.5)],
    [(("scara", "j4_deg"), [-1e6, 1e6])],  # the bound of any number
])
def test_numbers_on_the_bounds_are_taken(edits):
    _parse(edits)


@pytest.mark.parametrize("edits, message", [
    ([(("camera", "width_px"), 10_000), (("camera", "height_px"), 10_001)], "at most 100 MP in all"),
    ([(("camera", "width_px"), 1280), (("camera", "height_px"), 15)], "each side at least 16 px"),
    ([(("camera", "width_px"), 15), (("camera", "height_px"), 1024)], "each side at least 16 px"),
    ([(("camera", "width_px"), 32767), (("camera", "height_px"), 1000)], "each side must be less than 32767 px"),
    ([(("camera", "width_px"), 1000), (("camera", "height_px"), 32767)], "each side must be less than 32767 px"),
    ([(("can", "heartbeat_ms"), 1001)], "can.heartbeat_ms = 1001 is more than 1000 ms"),
    ([(("can", "heartbeat_ms"), 9)], "can.heartbeat_ms = 9 is less than 10 ms"),
    ([(("can", "host_heartbeat_ms"), 1001)], "can.host_heartbeat_ms = 1001 is more than 1000 ms"),
    ([(("can", "host_heartbeat_ms"), 9)], "can.host_heartbeat_ms = 9 is less than 10 ms"),
    ([(("scara", "j4_deg"), [-1e9, 360])], "scara.j4_deg[0] must be within +-1e+06"),  # negative too
    ([(("scara", "j4_deg"), [-3000, 360]), (CPU, 1e6)], "scara.j4_deg = 3000 is 3e+09 counts"),  # the lower limit
])
def test_numbers_just_past_the_bounds_are_refused(edits, message):
    _refused(edits, message)


# Counts as the drivers send them, on a power-of-two encoder (the products are exact): positions and the
# quick stop's deceleration 0x6085 are rounded to the nearest count, the other rates rounded down. A limit
# within half a count under 2^31 (2^32) passed the check and was an internal error at bring-up:
# "ValueError: position 2147483648 counts does not fit INTEGER32", "Value does not fit in specified type".
J4 = ("scara", "j4_deg")
J4_ACCEL = ("scara", "max_acceleration", "j4")
J4_VELOCITY = ("scara", "max_velocity", "j4")


@pytest.mark.parametrize("edits, message", [
    ([(J4, [-360, 2147483647.5 / 4096]), (CPU, 4096)], "scara.j4_deg = 524288 is 2.15e+09 counts"),
    ([(J4_ACCEL, 4294967295.5 / 8192), (CPU, 4096)],
     "the quick stop's deceleration (2 x scara.max_acceleration.j4) = 1.04858e+06 is 4.29e+09 counts"),
    ([(J4_VELOCITY, 2**32 / 8192), (CPU, 8192)], "scara.max_velocity.j4 = 524288 is 4.29e+09 counts"),
])
def test_counts_that_round_past_32_bits_are_refused(tmp_path, capsys, edits, message):
    cell = _cell_file(tmp_path, edits)
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", cell, capsys=capsys)
    assert code == 2 and message in err and "internal error" not in err and out == "", err


@pytest.mark.parametrize("edits", [
    [(J4, [-360, 2147483647.25 / 4096]), (CPU, 4096)],  # 2147483647 counts
    [(J4_ACCEL, 4294967295.25 / 8192), (CPU, 4096)],  # 0x6085: 4294967295 counts/s^2
    [(J4_VELOCITY, (2**32 - 0.75) / 8192), (CPU, 8192)],  # 0x6081: 4294967295 counts/s
    # rounded down, 4294967295 counts/s; the simulated drives' power-on 0x6081 rounded it up to 2^32 and
    # bring-up was an internal error
    [(J4_VELOCITY, (2**32 - 0.25) / 8192), (CPU, 8192)],
])
def test_counts_that_round_to_32_bits_are_taken(tmp_path, capsys, edits):
    cell = _cell_file(tmp_path, edits)
    code, out, err = run_cli("hw", "status", "--simulated-time", "--json", "--cell", cell, capsys=capsys)
    assert code == 0, err
    assert [json.loads(line)["state"] for line in out.splitlines()] == ["OPERATION_ENABLED"] * 5



# ------------------------------------------------------------------ long values quoted short
LONG = list(range(100_000))


@pytest.mark.parametrize("edits, message", [
    ([(("motion", "dropoff_mm"), LONG)], "motion.dropoff_mm must be a list of 3 numbers, got [0, 1, 2, 3, 4, 5, 6"),
    ([(("scara", "j4_deg"), LONG)], "scara.j4_deg must be a list of 2 numbers, got [0, 1, 2, 3, 4, 5, 6, 7"),
    ([(("can", "nodes", "j1", "unit"), "deg" * 100_000)], "can.nodes.j1.unit must be 'deg' (a revolute joint), "
                                                           "got 'degdegdeg"),
    ([(("motion", "x" * 100_000), 1)], "unknown key motion.'xxxxxxxx"),
])
def test_a_long_value_is_quoted_short(tmp_path, capsys, edits, message):
    """The reader echoed the whole value: a dropoff_mm of 100000 numbers printed a 689 KB message."""
    cell = _cell_file(tmp_path, edits)
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", cell, capsys=capsys)
    assert code == 2 and message in err and out == "", err[:300]
    assert len(err) < len(f"cell: error: cell file {cell}: ") + 250, err[:300]
