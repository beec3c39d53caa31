"""Intrinsics from views whose boards cover little of the image: the lens distortion is fitted where the
corners are and extrapolated elsewhere (boards in 5 % of a 1920 x 1080 frame gave k2 -0.35, k3 10.8 for a lens
of 0.05, 0: the model 353 px off in the image's corners), and such a result was written without a warning."""

import json

import cv2
import numpy as np
import pytest
from conftest import EXTERNAL, needs_photos, run_cli

from calibration.intrinsics import MIN_BOARD_COVERAGE_SHARE, board_coverage_share, calibrate_intrinsics

CHESS = EXTERNAL / "opencv-chessboard"
WEBCAM = EXTERNAL / "desk-chessboard-webcam"
VIEWS = ("left01.jpg", "left02.jpg", "left03.jpg", "left06.jpg", "left12.jpg", "left13.jpg")


def test_the_coverage_is_the_share_of_the_image_inside_the_boards_outlines():
    quarter = np.array([[0, 0], [640, 0], [640, 480], [0, 480]], float) + [100, 50]  # a quarter of 1280 x 960
    assert board_coverage_share([quarter], (1280, 960)) == pytest.approx(0.25, abs=0.01)
    # two views over the same place count once; another place adds to it
    assert board_coverage_share([quarter, quarter + 1], (1280, 960)) == pytest.approx(0.25, abs=0.01)
    assert board_coverage_share([quarter, quarter + [500, 400]], (1280, 960)) == pytest.approx(0.491, abs=0.01)
    # the outline, not the corners alone: a 7 x 7 grid of corners spanning the quarter covers it
    grid = np.stack(np.meshgrid(np.linspace(100, 740, 7), np.linspace(50, 530, 7)), -1).reshape(-1, 2)
    assert board_coverage_share([grid], (1280, 960)) == pytest.approx(0.25, abs=0.01)


def _grey(path):
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


@needs_photos
def test_boards_in_the_middle_of_a_large_frame_are_warned_about(tmp_path, capsys):
    """OpenCV's 640 x 480 views pasted in the middle of a 1280 x 960 frame: the same boards, a quarter of the
    image. Each view alone covers 45 % of its 640 x 480 frame and is not warned about."""
    plain = [(n, _grey(CHESS / n)) for n in VIEWS]
    ref = calibrate_intrinsics(plain, (9, 6), 1.0)
    assert ref.coverage_share == pytest.approx(0.40, abs=0.05)
    assert not any("boards cover only" in w for w in ref.warnings)
    paths = []
    for name, g in plain:
        canvas = np.full((960, 1280), 128, np.uint8)
        canvas[240:720, 320:960] = g
        paths.append(tmp_path / name.replace(".jpg", ".png"))
        cv2.imwrite(str(paths[-1]), canvas)
    code, out, err = run_cli("calibrate", "intrinsics", *paths, "--pattern", "9x6", "--square", "25",
                             "--out", tmp_path / "intr.json", capsys=capsys)
    assert code == 0, err
    res = json.loads(out)
    assert res["board_coverage_share"] == pytest.approx(ref.coverage_share / 4, abs=0.01)
    coverage = [w for w in res["warnings"] if "boards cover only" in w]
    assert len(coverage) == 1 and f"{100 * res['board_coverage_share']:.0f} %" in coverage[0]
    assert "distortion" in coverage[0] and "outside" in coverage[0]
    assert f"cell: warning: {coverage[0]}" in err
    assert json.loads((tmp_path / "intr.json").read_text())["report"]["board_coverage_share"] == \
        res["board_coverage_share"]


@needs_photos
@pytest.mark.parametrize("folder, pattern, share", [(CHESS, (9, 6), 0.45), (WEBCAM, (7, 7), 0.38)])
def test_the_shared_sets_are_not_warned_about_coverage(folder, pattern, share):
    r = calibrate_intrinsics([(p.name, _grey(p)) for p in sorted(folder.glob("left*.jpg"))], pattern, 1.0)
    assert r.coverage_share == pytest.approx(share, abs=0.02) and r.coverage_share > MIN_BOARD_COVERAGE_SHARE
    assert not any("boards cover only" in w for w in r.warnings)
