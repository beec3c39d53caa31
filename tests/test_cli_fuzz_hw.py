"""`cell hw ...` with out-of-range or conflicting values: exit 2 and one clear line, or (a long wait) no crash."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from conftest import ROOT, run_cli


@pytest.mark.parametrize("argv, message", [
    # a part that is not there, or wider than the jaws open, was "gripped" (exit 0)
    (["gripper", "grip", "--width", "20", "--part", "nan", "--simulated-time"], "--part nan: the width of a part"),
    (["gripper", "grip", "--width", "20", "--part", "-3", "--simulated-time"], "--part -3: the width of a part"),
    (["gripper", "grip", "--width", "20", "--part", "0", "--simulated-time"], "--part 0: the width of a part"),
    (["gripper", "grip", "--width", "20", "--part", "1e9", "--simulated-time"], "at most the opening, 80 mm"),
    # options of grip given to open were dropped without a word
    (["gripper", "open", "--width", "20", "--simulated-time"], "--width and --force are for grip"),
    (["gripper", "open", "--force", "20", "--simulated-time"], "--width and --force are for grip"),
    # a SimClock stepped through every heartbeat of 1e300 s (no end); real time: OverflowError, exit 1
    (["corner", "--dwell", "1e300", "--simulated-time"], "--dwell 1e+300: at most 600 s"),
    (["corner", "--dwell", "1e300"], "--dwell 1e+300: at most 600 s"),
    # ignored on a real bus (it runs in real time), where the bus could not be opened anyway here
    (["status", "--interface", "socketcan", "--channel", "vcan-none-77", "--simulated-time"],
     "--simulated-time is for the simulated drives (--interface virtual), not socketcan"),
])
def test_hw_refuses_values_out_of_range(capsys, argv, message):
    code, out, err = run_cli("hw", *argv, capsys=capsys)
    assert code == 2 and message in err and "internal error" not in err, err
    assert len(err.strip().splitlines()) == 1 and out == ""


def test_a_part_as_wide_as_the_opening_may_be_placed(capsys):
    code, out, err = run_cli("hw", "gripper", "grip", "--width", "80", "--part", "80", "--simulated-time",
                             capsys=capsys)
    assert code == 0 and "holding" in out, err


def test_hw_sim_serves_for_a_time_longer_than_a_timeout_can_be():
    """--seconds 1e300 was 'internal error: OverflowError: timestamp out of range'; now it serves until stopped."""
    proc = subprocess.Popen([sys.executable, "-m", "cell", "hw", "sim", "--seconds", "1e300"], cwd=ROOT,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)), text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        line = proc.stderr.readline()
        assert "simulated drives" in line
        time.sleep(0.5)
        assert proc.poll() is None  # still serving
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0 and "stopped" in err and "internal error" not in err, err
