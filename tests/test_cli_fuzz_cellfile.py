"""Cell files with numbers no cell has: refused when read, naming the key, not a hang or an internal error later."""

import json

import pytest
from conftest import run_cli

from cell.cellconfig import default_cell_path


def _cell_file(tmp_path, edits):
    raw = json.loads(default_cell_path().read_text())
    for path, value in edits:
        d = raw
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
    cell = tmp_path / "cell.json"
    cell.write_text(json.dumps(raw))
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
    ([(("camera", "height_mm"), 1e308)], "camera.height_mm must be within"),  # was ZeroDivisionError
    # `cell hw status`: internal errors at bring-up (the drives' objects are 16 and 32 bits)
    ([(("can", "heartbeat_ms"), 1e6)], "can.heartbeat_ms = 1000000 is more than 65535 ms"),
    ([(("can", "host_heartbeat_ms"), 30000)], "can.host_heartbeat_ms = 30000 is more than 21845 ms"),
    ([(("scara", "j4_deg"), [-360, 3000]), (CPU, 1e6)], "scara.j4_deg = 3000 is 3e+09 counts"),
    ([(CPU, 1e6)], "scara.max_acceleration.j4 = 2400 is 2.4e+09 counts"),
    ([(("can", "nodes", "gripper", "counts_per_unit"), 1e308)], "must be within +-1e+06"),
])
def test_a_cell_file_with_out_of_range_numbers_is_refused(tmp_path, capsys, edits, message):
    cell = _cell_file(tmp_path, edits)
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", cell, capsys=capsys)
    assert code == 2 and message in err and "internal error" not in err and out == "", err
    assert f"cell file {cell}" in err


def test_counts_that_fit_32_bits_are_taken(tmp_path, capsys):
    cell = _cell_file(tmp_path, [(("can", "nodes", "j1", "counts_per_unit"), 1e6)])  # 132 deg: 1.32e8 counts
    code, out, err = run_cli("hw", "status", "--simulated-time", "--cell", cell, capsys=capsys)
    assert code == 0, err
