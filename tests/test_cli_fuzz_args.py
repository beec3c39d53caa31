"""Command-line values that argparse or numpy mishandled: found by trying bad inputs on every command."""

import pytest
from conftest import run_cli


@pytest.mark.parametrize("argv, message", [
    # a negative number in exponent form was taken for an option
    (["segment", "nowhere.png", "--z", "-1e5"], "--z is the height"),
    (["calibrate", "plane", "nowhere.png", "--markers", "m.json", "--out", "o.json", "--camera-matrix", "-1,-1,5,5"],
     "fx and fy must be positive"),
])
def test_negative_values_in_exponent_form_are_values_not_options(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    if argv[0] == "calibrate":
        import cv2
        import numpy as np

        cv2.imwrite("nowhere.png", np.zeros((48, 64, 3), np.uint8))
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and message in err and "expected one argument" not in err, err
    assert not (tmp_path / "o.json").exists()


def test_a_negative_jog_in_exponent_form_moves(capsys):
    code, out, err = run_cli("hw", "jog", "j1", "-1e0", "--simulated-time", capsys=capsys)
    assert code == 0 and "j1:" in out, err


@pytest.mark.parametrize("argv", [
    ["render", "scene.json", "--out", "o.png", "--seed", "-1"],
    ["examples", "generate", "--out", "e.jsonl", "--count", "1", "--seed", "-1"],
    ["study", "--budget", "tiny", "--out", "st", "--seed", "-1"],
    ["bench", "vision", "--frames", "1", "--repeats", "1", "--seed", "-1"],
    ["bench", "stability", "--poses", "1", "--seed", "-1"],
])
def test_a_negative_seed_is_bad_input_not_an_internal_error(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and "--seed must be 0 or more" in err and "internal error" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["map", "CAL", "--mm", "300,0", "1e30,1e30"], "--mm 1e30,1e30: coordinates must be within 1e+06 mm"),  # was:
    # mapped to 1.1e13 px, exit 0
    (["map", "CAL", "--px", "100,100", "--z", "-1e300"], "--z must be within 1e+06 mm of the table"),
    (["segment", "nowhere.png", "--calibration", "CAL", "--z", "1e300"], "--z must be within 1e+06 mm"),
])
def test_heights_and_points_a_kilometre_off_are_bad_input(capsys, argv, message):
    from calibration import default_calibration_path

    argv = [default_calibration_path() if a == "CAL" else a for a in argv]
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and message in err and out == "", err
