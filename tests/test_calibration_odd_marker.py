"""One marker listed at wrong coordinates among right ones: the fit is poor everywhere and the per-marker
residuals spread the error over all of them (the hunter's 5 markers, one 14 mm off: 1.0-6.4 mm each, the wrong
one not the worst by much), so the warning names the marker without which the others fit."""

import json

import numpy as np
import pytest
from conftest import run_cli
from test_calibration_tilted import CAMERA_MATRIX, Board


@pytest.fixture(scope="module")
def flat_board(tmp_path_factory):
    d = tmp_path_factory.mktemp("odd")
    board = Board(np.eye(3), [200.0, -220.0, 0.0])
    return board.render(d / "board.png"), board


def _calibrate(tmp_path, capsys, frame, board, off_mm: dict, *extra):
    markers = board.markers_json(tmp_path / "markers.json",
                                 lambda i, p: p + [*off_mm[i], 0.0] if i in off_mm else p)
    out = tmp_path / "cal.json"
    code, stdout, err = run_cli("calibrate", "plane", frame, "--markers", markers, "--out", out, *extra,
                                capsys=capsys)
    assert code == 0, err
    return json.loads(stdout), err, out


@pytest.mark.parametrize("extra", [["--camera-matrix", CAMERA_MATRIX], []], ids=["pose", "homography"])
def test_one_marker_listed_7_mm_off_is_named(tmp_path, capsys, flat_board, extra):
    frame, board = flat_board
    res, err, out = _calibrate(tmp_path, capsys, frame, board, {4: (6.0, -4.0)}, *extra)
    assert res["reprojection_rms_px"] > 3  # "the markers fit badly", as before
    assert res["markers_used"] == [0, 1, 2, 3, 4, 5]  # kept: the calibration is the one asked for
    odd = res["marker_not_fitting"]
    assert odd["id"] == 4 and odd["others_reprojection_rms_px"] < 1.0
    # where the others put it: the listed corners 6, -4 mm from the detected ones
    assert np.allclose(odd["listed_off_mm"], [6.0, -4.0], atol=0.5)
    named = [w for w in res["warnings"] if w.startswith("marker 4 ")]
    assert len(named) == 1 and "7.2 mm" in named[0] and "without it the other 5 markers fit" in named[0]
    assert f"cell: warning: {named[0]}" in err
    assert json.loads(out.read_text())["report"]["marker_not_fitting"]["id"] == 4


def test_markers_that_fit_name_none(tmp_path, capsys, flat_board):
    frame, board = flat_board
    res, err, _ = _calibrate(tmp_path, capsys, frame, board, {}, "--camera-matrix", CAMERA_MATRIX)
    assert res["marker_not_fitting"] is None and err == ""


def test_two_markers_off_name_none(tmp_path, capsys, flat_board):
    """Leaving out one does not bring the rest to a good fit: no marker is singled out, the generic warning
    stays."""
    frame, board = flat_board
    res, err, _ = _calibrate(tmp_path, capsys, frame, board, {4: (6.0, -4.0), 0: (-5.0, 4.5)},
                             "--camera-matrix", CAMERA_MATRIX)
    assert res["marker_not_fitting"] is None
    assert any(w.startswith("the markers fit badly") for w in res["warnings"])


def test_a_marker_off_enough_to_refuse_the_fit_is_named_in_the_refusal(tmp_path, capsys, flat_board):
    """14 mm off: over 10 px, refused (nothing written) as before, the message naming the marker."""
    frame, board = flat_board
    markers = board.markers_json(tmp_path / "markers.json", lambda i, p: p + [12.0, -8.0, 0.0] if i == 4 else p)
    code, out, err = run_cli("calibrate", "plane", frame, "--markers", markers, "--out", tmp_path / "cal.json",
                             "--camera-matrix", CAMERA_MATRIX, capsys=capsys)
    assert code == 2 and out == "" and err.count("\n") == 1 and not (tmp_path / "cal.json").exists()
    assert "not written" in err and "marker 4 " in err and "14.4 mm" in err
