"""Intrinsics on inputs built at run time from the shared real photographs (never copied into the project):
boards small in 12 MP photos, photos without a board, portrait and EXIF-turned views, 16-bit PNGs, cut-off
boards, mixed sizes. The figures are compared with the same views' calibration at 640 x 480."""

import json

import cv2
import numpy as np
import pytest
from conftest import EXTERNAL, run_cli

from calibration.intrinsics import DETECT_FINE_MAX_PX, DETECT_MAX_PX, calibrate_intrinsics, find_chessboard

CHESS = EXTERNAL / "opencv-chessboard"
CHARUCO = EXTERNAL / "opencv-charuco"
FESTO = EXTERNAL / "p5binpicking-festo-table"
CHARUCO_BOARD = {"marker_mm": 0.02, "dictionary": "DICT_6X6_250"}
W12, H12 = 4032, 3024
VIEWS = ("left01.jpg", "left03.jpg", "left06.jpg", "left12.jpg")

pytestmark = pytest.mark.skipif(not (CHESS.is_dir() and CHARUCO.is_dir() and FESTO.is_dir()),
                                reason="the shared photographs (../shared/external) are not here")


def _grey(path):
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


@pytest.fixture(scope="module")
def table_12mp():
    """A 12 MP grey photo of a textured table without a board: the Festo cell frame upscaled, with noise."""
    img = cv2.resize(_grey(FESTO / "aruco_img.png"), (W12, H12), interpolation=cv2.INTER_CUBIC).astype(np.float32)
    return np.clip(img + np.random.default_rng(0).normal(0, 6, img.shape), 0, 255).astype(np.uint8)


def _pasted(canvas, img, x0, y0, scale=1.0):
    small = img if scale == 1.0 else cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    out = canvas.copy()
    out[y0:y0 + small.shape[0], x0:x0 + small.shape[1]] = small
    return out


@pytest.fixture
def searches(monkeypatch):
    """(detector, long side) of every image a chessboard detector searched, the real detector still running.
    What took minutes was the classic detector on the 12 MP photo itself; the tests used to bound wall time
    instead, and a loaded 2-core machine took 7-8 s for the 0.6-1.1 s of the boardless photo (limit 6 s)."""
    import calibration.intrinsics as intrinsics

    seen, real = [], intrinsics._find_chessboard

    def spy(gray, pattern, detector):
        seen.append((detector, max(gray.shape[:2])))
        return real(gray, pattern, detector)

    monkeypatch.setattr(intrinsics, "_find_chessboard", spy)
    return seen


@pytest.fixture
def charuco_detections(monkeypatch):
    """(long side, smallest marker perimeter in px) of every image the ChArUco detector ran on (it still runs)."""
    import calibration.intrinsics as intrinsics

    seen, real = [], intrinsics._charuco_corners

    class Recorded:
        def __init__(self, det):
            self.det = det

        def detectBoard(self, gray):  # noqa: N802 - OpenCV's name
            side = max(gray.shape[:2])
            seen.append((side, self.det.getDetectorParameters().minMarkerPerimeterRate * side))
            return self.det.detectBoard(gray)

    monkeypatch.setattr(intrinsics, "_charuco_corners", lambda det, gray, n_all: real(Recorded(det), gray, n_all))
    return seen


def _k(r):
    k = r.camera_matrix
    return np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]])


def test_small_chessboards_in_12mp_photos_give_the_640_calibration_quickly(table_12mp, searches):
    # OpenCV's 640 x 480 views pasted at their size into a 12 MP photo of a textured table, plus one photo
    # without a board. At full size the classic detector took 20-41 s a view (the table's texture), and the
    # boardless photo at 6000 x 4000 px more than 8 minutes; on a 1600 px copy 2-5 s for some views, and it
    # missed 3 of 13. In the board's region, located by SB on the copy, it takes 0.01 s, and the corners refined
    # at full size are those of the 640 x 480 views shifted by the paste offset
    plain = [(n, _grey(CHESS / n)) for n in VIEWS]
    ref = calibrate_intrinsics(plain, (9, 6), 1.0)
    big = [(n, _pasted(table_12mp, g, 1700, 1300)) for n, g in plain] + [("table.png", table_12mp)]
    searches.clear()
    r = calibrate_intrinsics(big, (9, 6), 1.0)
    assert sorted(r.images_used) == sorted(VIEWS) and [v.name for v in r.views if not v.found] == ["table.png"]
    assert r.board["detector"] == "classic" and r.board["subpix_win"] == ref.board["subpix_win"] == 5
    assert all(v.note.startswith("found in the board's region (located by the sector detector)") for v in r.views[:4])
    assert "seen whole" not in r.views[4].note and "all its inner corners" in r.views[4].note
    assert _k(r) == pytest.approx(_k(ref) + [0, 0, 1700, 1300], abs=0.2)
    assert r.rms_px == pytest.approx(ref.rms_px, abs=0.01)
    # quickly (1.5-3 s here; before, minutes): no detector on a 12 MP photo itself, the classic one only in the
    # four boards' regions and on the boardless photo's 1600 px copy
    assert max(side for _, side in searches) <= DETECT_FINE_MAX_PX
    classic = [side for d, side in searches if d == "classic"]
    assert len(classic) == 5 and classic.count(DETECT_MAX_PX) == 1 and max(classic) == DETECT_MAX_PX


def test_a_12mp_photo_without_a_board_is_searched_in_seconds(table_12mp, searches):
    # about 0.6 and 1.1 s here, 2.6 s and more at full size: only the copies are searched, the classic detector
    # on the 1600 px one only (32 s at 3200 px on a textured 6000 x 4000 photo)
    copies = [("sb", DETECT_MAX_PX), ("sb", DETECT_FINE_MAX_PX)]
    for detector, searched in (("classic", [*copies, ("classic", DETECT_MAX_PX)]), ("sb", copies)):
        searches.clear()
        corners, note = find_chessboard(table_12mp, (9, 6), detector)
        assert corners is None and note is None
        assert searches == searched, detector


def test_a_tiny_board_is_found_by_the_sector_detector_on_the_finer_copy(table_12mp):
    # left01 at 0.35 x: a board 224 px wide (squares of 13 px) in a 4032 px photo, 5 px squares on the
    # 1600 px copy: SB finds it on the 2400 px copy, and the corners refined
    # at full size are those of the 640 x 480 view scaled (pixel centres: (u + 0.5) * 0.35 - 0.5 + offset)
    g = _grey(CHESS / "left01.jpg")
    img = _pasted(table_12mp, g, 2100, 900, 0.35)
    # the classic detector misses it on the 1600 px copy; it finds it in the region SB located
    classic, note = find_chessboard(img, (9, 6), "classic")
    assert classic is not None and note == "found in the board's region (located by the sector detector)"
    corners, level = find_chessboard(img, (9, 6), "sb")
    assert level == "found on a copy reduced to 2400 px"
    _, found = cv2.findChessboardCorners(g, (9, 6))
    found = cv2.cornerSubPix(g, found, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.1))
    truth = (found.reshape(-1, 2) + 0.5) * 0.35 - 0.5 + [2100, 900]
    from calibration.intrinsics import refine_corners, subpix_win_for

    win = subpix_win_for([corners], (9, 6))
    assert win == 3  # squares of 13 px
    refined = refine_corners(img, corners, win).reshape(-1, 2)
    # (SB may number the corners from the other end of the board)
    off = np.linalg.norm(refined[:, None] - truth[None], axis=2).min(axis=1)
    coarse = np.linalg.norm(corners.reshape(-1, 2)[:, None] - truth[None], axis=2).min(axis=1)
    assert np.sqrt(np.mean(off ** 2)) < 0.15 and off.max() < 0.4 and np.sqrt(np.mean(coarse ** 2)) < 0.3


def test_a_small_charuco_board_in_a_12mp_photo_is_found(table_12mp, charuco_detections):
    # OpenCV's drops markers under 0.03 x the long side in perimeter (121 px at 4032 px): the tutorial's board
    # at its size in a 12 MP photo (markers of 25 px) was found in none of the 4 views
    plain = [(p.name, _grey(p)) for p in sorted(CHARUCO.glob("img_0*.jpg"))]
    ref = calibrate_intrinsics(plain, (5, 7), 0.04, charuco=CHARUCO_BOARD)
    big = [(n, _pasted(table_12mp, g, 1700, 1300)) for n, g in plain]
    charuco_detections.clear()
    r = calibrate_intrinsics(big, (5, 7), 0.04, charuco=CHARUCO_BOARD)
    # about 2 s here (a wall-time bound of 10 s failed on one loaded core: 22 s): one detection a view at the
    # photo's size, no upscaled retry, marker candidates down to a 30 px perimeter and no smaller
    assert charuco_detections == [(W12, pytest.approx(30.0))] * 4
    assert len(r.images_used) == 4 and all(v.n_points == 24 for v in r.views)
    assert _k(r) == pytest.approx(_k(ref) + [0, 0, 1700, 1300], abs=0.05)
    assert r.rms_px == pytest.approx(ref.rms_px, abs=0.005)


def test_a_charuco_board_cut_off_by_the_frame_is_still_used():
    # half of the board outside a close-up view: the corners that are in are used, a chessboard would be lost
    plain = [(p.name, _grey(p)) for p in sorted(CHARUCO.glob("img_0*.jpg"))]
    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(plain[0][1])
    left = corners.reshape(-1, 2)[:, 0] < np.median(corners.reshape(-1, 2)[:, 0])
    x_cut = int(np.ceil(corners.reshape(-1, 2)[left, 0].max())) + 25  # half of the board's corners stay in
    covered = [(n, g.copy()) for n, g in plain]
    covered[0][1][:, x_cut:] = 200  # the frame's edge, kept at the set's size: nothing of the board beyond
    r = calibrate_intrinsics(covered, (5, 7), 0.04, charuco=CHARUCO_BOARD)
    assert len(r.images_used) == 4 and 6 <= r.views[0].n_points < 24 and r.views[1].n_points == 24


def _exif_orientation_6(path, grey_img, fmt="PNG"):
    """Save the grey image with EXIF orientation 6 (display turned 90 degrees clockwise), as phones do."""
    image_mod = pytest.importorskip("PIL.Image")
    im = image_mod.fromarray(grey_img)
    exif = image_mod.Exif()
    exif[0x0112] = 6
    im.save(path, format=fmt, exif=exif)


def test_cli_portrait_16bit_and_exif_turned_views_give_the_turned_camera(tmp_path, capsys):
    # the same views turned 90 degrees clockwise, as 16-bit PNGs, and as PNGs whose EXIF orientation turns
    # them: read as displayed (as `cell segment` reads frames), both give the turned camera: fx and fy
    # swapped, cx' = h - 1 - cy, cy' = cx (OpenCV's pixel centres). All 13 views: 4 give a lens model refused
    plain = [(p.name, _grey(p)) for p in sorted(CHESS.glob("left*.jpg"))]
    ref = _k(calibrate_intrinsics(plain, (9, 6), 1.0))
    turned = np.array([ref[1], ref[0], 480 - 1 - ref[3], ref[2]])
    sixteen, exif = [], []
    for n, g in plain:
        sixteen.append(tmp_path / f"{n}-16.png")
        cv2.imwrite(str(sixteen[-1]), cv2.rotate(g, cv2.ROTATE_90_CLOCKWISE).astype(np.uint16) * 257)
        exif.append(tmp_path / f"{n}-exif.png")
        _exif_orientation_6(exif[-1], g)
    for files in (sixteen, exif):
        code, out, err = run_cli("calibrate", "intrinsics", *files, "--pattern", "9x6", "--square", "1", "--out",
                                 tmp_path / "cam.json", capsys=capsys)
        assert code == 0, err
        res = json.loads(out)
        assert (res["width_px"], res["height_px"]) == (480, 640) and len(res["images_used"]) == 13
        assert [res["fx"], res["fy"], res["cx"], res["cy"]] == pytest.approx(turned, abs=0.3)


def test_cli_portrait_mixed_with_landscape_is_refused_naming_the_images(tmp_path, capsys):
    plain = [(n, _grey(CHESS / n)) for n in VIEWS]
    files = []
    for i, (n, g) in enumerate(plain):
        files.append(tmp_path / n.replace(".jpg", ".png"))
        if i == 2:
            _exif_orientation_6(files[-1], g)  # a phone turned for one shot
        else:
            cv2.imwrite(str(files[-1]), g)
    code, out, err = run_cli("calibrate", "intrinsics", *files, "--pattern", "9x6", "--square", "1", "--out",
                             tmp_path / "cam.json", capsys=capsys)
    assert code == 2 and out == "" and "Traceback" not in err and err.count("\n") == 1
    assert "640x480 (3)" in err and f"480x640 (1): {files[2]}" in err and "EXIF orientation" in err
    assert not (tmp_path / "cam.json").exists()


def test_cli_images_of_two_sizes_are_refused_naming_them(tmp_path, capsys):
    files = []
    for i, n in enumerate(VIEWS):
        g = _grey(CHESS / n)
        files.append(tmp_path / n)
        cv2.imwrite(str(files[-1]), cv2.resize(g, (1280, 960)) if i == 0 else g)
    code, out, err = run_cli("calibrate", "intrinsics", *files, "--pattern", "9x6", "--square", "1", "--out",
                             tmp_path / "cam.json", capsys=capsys)
    assert code == 2 and out == "" and "Traceback" not in err
    assert f"640x480 (3): {files[1]}, {files[2]}, {files[3]}; 1280x960 (1): {files[0]}" in err
    assert "one camera matrix holds for one image size" in err
