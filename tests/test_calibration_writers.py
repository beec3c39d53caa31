"""The calibration file's writers refuse whatever its reader would refuse, before anything is written: a
calibration that `cell calibrate` wrote (exit 0) and `cell map` then refused replaced a good one."""

import json

import cv2
import numpy as np
import pytest
from conftest import run_cli

from calibration import Calibration, load_calibration, save_calibration
from calibration.calfile import calibration_to_json, parse_calibration
from cell.errors import BadInput

W, H = 1280, 1024
GOOD_MATRIX = "1000,1000,640,512"


@pytest.fixture
def frame(tmp_path):
    """A 1280 x 1024 frame with 4 ArUco markers, and their corners in a base frame as a camera looking down
    on the table sees it (x along u, y against v: 0.25 mm/px), and in that frame mirrored (y down)."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    img = np.full((H, W), 255, np.uint8)
    right, mirrored = {}, {}
    for i, (u, v) in enumerate([(100, 100), (1000, 100), (100, 800), (1000, 800)]):
        img[v:v + 120, u:u + 120] = cv2.aruco.generateImageMarker(d, i, 120)
        corners = [(u, v), (u + 120, v), (u + 120, v + 120), (u, v + 120)]
        right[str(i)] = [[200 + 0.25 * cu, 125 - 0.25 * cv, 0.0] for cu, cv in corners]
        mirrored[str(i)] = [[x, -y, z] for x, y, z in right[str(i)]]
    cv2.imwrite(str(tmp_path / "m.png"), img)
    for name, markers in (("right.json", right), ("mirrored.json", mirrored)):
        (tmp_path / name).write_text(json.dumps({"dictionary": "DICT_4X4_50", "markers": markers}))
    return tmp_path


def _calibrate(frame, capsys, markers, *extra):
    return run_cli("calibrate", "plane", frame / "m.png", "--markers", frame / markers, "--out", frame / "cal.json",
                   *extra, capsys=capsys)


@pytest.mark.parametrize("matrix, message", [
    ("0.5,0.5,640,512", "fx and fy must be between 1 and 1e+06 px (a real lens: hundreds to tens of thousands), "
                        "got 0.5 and 0.5"),
    ("1000,1000,100000,512", "cx = 100000 px is not near the 1280 px image"),
    ("1000,1000,640,-20000", "cy = -20000 px is not near the 1024 px image"),
    ("1e-9,1e-9,640,512", "fx and fy must be between 1 and 1e+06 px"),  # a camera on the plane
])
def test_a_camera_matrix_the_reader_refuses_is_refused_and_the_good_file_kept(frame, capsys, matrix, message):
    """It was written (exit 0) over the good calibration, and `cell map` then refused the file."""
    code, _, err = _calibrate(frame, capsys, "right.json", "--camera-matrix", GOOD_MATRIX)
    assert code == 0, err
    good = (frame / "cal.json").read_bytes()
    code, out, err = _calibrate(frame, capsys, "right.json", "--camera-matrix", matrix)
    assert code == 2 and out == "", err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"cell: error: --camera-matrix {matrix}: {message}"), err
    assert (frame / "cal.json").read_bytes() == good
    load_calibration(frame / "cal.json")  # still the good one


def _k(fx, fy, cx, cy, skew=0.0):
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("cal, message", [
    (Calibration(W, H, _k(0.5, 0.5, 640, 512)), "intrinsics.fx and fy must be between 1 and 1e+06 px"),
    (Calibration(W, H, _k(1000, 1000, 1e5, 512)), "intrinsics.cx = 100000 px is not near the 1280 px image"),
    (Calibration(W, H, _k(1000, 1000, 640, 512, skew=2000)), "intrinsics.skew = 2000 px: at most fx"),
    (Calibration(8, 8, _k(10, 10, 4, 4)), "image 8 x 8 px: each side at least 16 px"),
    (Calibration(W, H, homography=np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])),
     "homography.px_to_mm is singular"),
    (Calibration(W, H, homography=np.diag([0.25, -0.25, 1.0]), plane_z_mm=2e6),
     "homography.plane_z_mm must be within 1e+06 mm of the base"),
])
def test_save_calibration_refuses_what_load_calibration_refuses(tmp_path, cal, message):
    """The writer checked the pose and the lens model only: any other calibration the reader refuses was written,
    replacing the file there, and found out only when it was read."""
    with pytest.raises(BadInput, match="calibration file x.json: " + _re(message)):
        parse_calibration(calibration_to_json(cal), "x.json")  # the reader refuses it ...
    path = tmp_path / "cal.json"
    path.write_text("the good calibration\n")
    with pytest.raises(BadInput, match=_re(message) + f".*: {_re(str(path))} not written"):
        save_calibration(cal, path)  # ... so the writer does, leaving the file there as it was
    assert path.read_text() == "the good calibration\n"


def _re(text: str) -> str:
    import re

    return re.escape(text)


def test_a_recording_is_not_made_with_a_calibration_its_replay_would_refuse(tmp_path, capsys):
    """A cell file's camera 900 m above the tray gave the simulated camera a nominal fx of 1.8e6 px: `cell run
    --record` wrote it as calibration.json (exit 0) and `cell replay` then refused the recording as corrupt."""
    from cell.cellconfig import default_cell_path

    cell = json.loads(default_cell_path().read_text())
    cell["camera"]["height_mm"] = 900_000.0
    (tmp_path / "cell.json").write_text(json.dumps(cell))
    code, out, err = run_cli("run", "--cell", tmp_path / "cell.json", "--record", tmp_path / "rec", "--json",
                             capsys=capsys)
    assert code == 2 and out == "", err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "intrinsics.fx and fy must be between 1 and 1e+06 px" in lines[0], err
    assert f"the recording {tmp_path / 'rec'} is not written" in lines[0]
    assert not (tmp_path / "rec").exists()


MIRRORED = "does not look down onto the plane z = 0 mm from above"


def test_a_homography_of_markers_in_a_mirrored_frame_is_refused_as_with_intrinsics(frame, capsys):
    """Without intrinsics the markers given y down were fitted by a mirrored homography and written (exit 0),
    while with --camera-matrix the same markers were refused: now both are, for the same reason."""
    code, out, err = _calibrate(frame, capsys, "right.json")
    assert code == 0 and json.loads(out)["method"] == "homography", err
    good = (frame / "cal.json").read_bytes()
    assert np.allclose(load_calibration(frame / "cal.json").px_to_mm([[160, 160]]), [[240, 85]], atol=0.1)
    for extra in ([], ["--camera-matrix", GOOD_MATRIX]):
        code, out, err = _calibrate(frame, capsys, "mirrored.json", *extra)
        lines = err.strip().splitlines()
        assert code == 2 and out == "" and len(lines) == 1, err
        assert MIRRORED in lines[0] and "base coordinates given in a mirrored frame, y down" in lines[0], err
        assert lines[0].endswith(f"{frame / 'cal.json'} not written")
        assert (frame / "cal.json").read_bytes() == good


@pytest.mark.parametrize("h, mirrored", [
    (np.diag([0.25, -0.25, 1.0]), False),
    (-np.diag([0.25, -0.25, 1.0]), False),  # the same mapping: det(H) > 0, but so is w at every pixel
    (np.diag([0.25, 0.25, 1.0]), True),
    (-np.diag([0.25, 0.25, 1.0]), True),
    # a tilted view, its horizon above the image (v = -2000): mirrored or not over the whole image
    (np.array([[0.25, 0.0, 0.0], [0.0, -0.25, 0.0], [0.0, 0.0005, 1.0]]), False),
    (np.array([[0.25, 0.0, 0.0], [0.0, 0.25, 0.0], [0.0, 0.0005, 1.0]]), True),
])
def test_the_reader_refuses_a_mirrored_homography(tmp_path, h, mirrored):
    path = tmp_path / "h.json"
    raw = calibration_to_json(Calibration(W, H, homography=np.diag([1.0, -1.0, 1.0]), name="h"))
    raw["homography"]["px_to_mm"] = h.tolist()
    path.write_text(json.dumps(raw))
    if mirrored:
        with pytest.raises(BadInput, match=f"calibration file {_re(str(path))}: homography: .*{MIRRORED}.*mirrored "
                                           "frame, y down"):
            load_calibration(path)
    else:
        cal = load_calibration(path)
        # turned, not mirrored: base x along u, y against v, at every pixel
        a, b, c = cal.px_to_mm([[100, 100], [200, 100], [100, 200]])
        assert b[0] > a[0] and c[1] < a[1]


def test_the_reader_refuses_a_mirrored_homography_on_a_tilted_plane():
    from calibration.tilted import TiltedPlane

    t = np.radians(10.0)
    plane = TiltedPlane(np.array([350.0, 0.0, 20.0]), np.array([1.0, 0.0, 0.0]),
                        np.array([0.0, np.cos(t), np.sin(t)]))
    for h, refused in ((np.diag([0.25, -0.25, 1.0]), False), (np.diag([0.25, 0.25, 1.0]), True)):
        raw = calibration_to_json(Calibration(W, H, homography=h, plane_z_mm=None, name="t", plane=plane))
        if refused:
            with pytest.raises(BadInput, match="homography: .* mirrored.*does not look onto the front"):
                parse_calibration(raw, "t.json")
        else:
            parse_calibration(raw, "t.json")
