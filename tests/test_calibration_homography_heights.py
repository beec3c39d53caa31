"""A homography-only plane calibration mapped at other heights (`cell map --z`, calibration/offplane.py): a board
of markers on the table rendered through known cameras (straight down, tilted 5 deg, tilted 25 deg), calibrated
without intrinsics and mapped against the truth; the Festo frames against their pose calibration with the
published intrinsics. Figures in docs/vision.md."""

import json

import numpy as np
import pytest
from conftest import EXTERNAL, needs_photos, run_cli
from test_calibration_tilted import PINHOLE, SIZE, Board, K, _rot

from calibration import default_calibration_path, load_calibration
from calibration.camera import Calibration, pose_matrix
from calibration.default import _R_DOWN

FESTO = EXTERNAL / "p5binpicking-festo-table"
# rendered frames, the camera's height right: at most 0.32 mm (px -> mm) and 0.79 px (mm -> px) off at z = 100
# over the whole image and the tray; these allow about twice that
TOLERANCE_MM, TOLERANCE_PX = 0.65, 1.6


def _camera(tilt_x_deg: float, tilt_y_deg: float, position_mm) -> Calibration:
    """The default camera's lens without distortion (principal point 3.2, -2.4 px off the centre), turned
    `tilt_x_deg` about base x and `tilt_y_deg` about y from straight down, at `position_mm`."""
    r = _rot("y", tilt_y_deg) @ _rot("x", tilt_x_deg) @ _R_DOWN
    return Calibration(*SIZE, K, np.zeros(5), pose_matrix(r, position_mm), None, 0.0, "truth")


CAMERAS = {"down": PINHOLE,  # the default cell's camera: a few tenths of a degree off straight down
           "tilted 5 deg": _camera(3.0, 4.0, (300.0, 40.0, 800.0)),
           "tilted 25 deg": _camera(0.0, 25.0, (700.0, 0.0, 750.0))}
GRID_PX = np.column_stack([g.ravel() for g in np.meshgrid(np.linspace(0, SIZE[0], 9), np.linspace(0, SIZE[1], 7))])
TRAY_MM = np.column_stack([g.ravel() for g in np.meshgrid(np.linspace(200, 500, 5), np.linspace(-250, 250, 7))])


@pytest.fixture(scope="module")
def homographies(tmp_path_factory):
    """camera name -> the calibration file `cell calibrate plane` writes without intrinsics from the board on the
    table (z = 0) seen by that camera."""
    d = tmp_path_factory.mktemp("homography_heights")
    board = Board(np.eye(3), [200.0, -220.0, 0.0])
    markers = board.markers_json(d / "markers.json")
    out = {}
    for i, (name, camera) in enumerate(CAMERAS.items()):
        out[name] = d / f"h{i}.json"
        frame = board.render(d / f"board{i}.png", camera=camera)
        assert run_cli("calibrate", "plane", frame, "--markers", markers, "--out", out[name]) == 0
        assert json.loads(out[name].read_text())["pose"] is None  # a homography only
    return out


def _pairs(points) -> list[str]:
    return [f"{float(a)!r},{float(b)!r}" for a, b in np.asarray(points, float)]


def _map(capsys, cal, way, points, *extra):
    code, out, err = run_cli("map", cal, way, *_pairs(points), *extra, "--json", capsys=capsys)
    assert code == 0, err
    res = json.loads(out)
    return np.array(res["mm" if way == "--px" else "px"]), res, err


@pytest.mark.parametrize("name", ["down", "tilted 5 deg"])
@pytest.mark.parametrize("z", [20.0, 50.0, 100.0])
def test_a_homography_maps_at_a_part_top_within_a_fraction_of_a_millimetre(homographies, capsys, name, z):
    """The camera 800 mm up, as the default cell says: both directions within the tolerance of the truth."""
    truth = CAMERAS[name]
    got, res, err = _map(capsys, homographies[name], "--px", GRID_PX, "--z", str(z))
    assert np.linalg.norm(got - truth.px_to_mm(GRID_PX, z), axis=1).max() < TOLERANCE_MM
    px, _, _ = _map(capsys, homographies[name], "--mm", TRAY_MM, "--z", str(z))
    assert np.linalg.norm(px - truth.project(np.column_stack([TRAY_MM, np.full(len(TRAY_MM), z)])),
                          axis=1).max() < TOLERANCE_PX
    back, _, _ = _map(capsys, homographies[name], "--mm", got, "--z", str(z))
    assert np.abs(back - GRID_PX).max() < 1e-3  # one mapping, both ways (the output is rounded to 1e-4)
    off = res["off_plane"]
    assert off["estimate"] is True and off["focal_from"] == "height" and off["camera_mm"][2] == 800.0
    assert np.linalg.norm(np.subtract(off["camera_mm"], truth.camera_position_mm())) < 5.0
    assert off["error_bound_mm"] > 0 and res["z_mm"] == z
    # said on stderr: an estimate, what it assumed, how far the assumptions' tolerances move the points
    assert err.count("\n") == 1 and f"on z = {z:g} mm the points are an estimate" in err
    assert "principal point at the image centre" in err and "z = 800 mm (the default cell's camera.height_mm)" in err
    assert f"move up to {off['error_bound_mm']:.2f} mm if that height is off by 50 mm" in err


def test_a_camera_height_50_mm_off_moves_points_within_the_bound_it_prints(homographies, capsys):
    """The camera is 800 mm up; told 850: points at z = 100 move about r z dH / H^2 (3.3 mm at the image's corners,
    r = 410 mm), within the printed bound; at z = 20 a fifth of that."""
    truth = CAMERAS["down"]
    errors = {}
    for z in (20.0, 100.0):
        got, res, _ = _map(capsys, homographies["down"], "--px", GRID_PX, "--z", str(z), "--camera-height", "850")
        errors[z] = np.linalg.norm(got - truth.px_to_mm(GRID_PX, z), axis=1).max()
        assert res["off_plane"]["camera_height_mm"] == 850.0 and errors[z] < res["off_plane"]["error_bound_mm"]
    r_mm = np.linalg.norm(truth.px_to_mm(GRID_PX, 100.0) - truth.camera_position_mm()[:2], axis=1).max()
    assert errors[100.0] == pytest.approx(r_mm * 100.0 * 50.0 / 800.0 ** 2, rel=0.25)
    assert errors[20.0] < errors[100.0] / 3


def test_a_steeply_tilted_camera_takes_the_focal_length_from_the_view(homographies, capsys):
    """25 deg from straight down the view gives f (Zhang): the camera's height is not used."""
    truth = CAMERAS["tilted 25 deg"]
    got, res, err = _map(capsys, homographies["tilted 25 deg"], "--px", GRID_PX, "--z", "100")
    assert res["off_plane"]["focal_from"] == "view" and "the camera's height 800 mm is not used" in err
    assert res["off_plane"]["focal_px"] == pytest.approx(K[0, 0], rel=0.01)
    assert np.linalg.norm(got - truth.px_to_mm(GRID_PX, 100.0), axis=1).max() < TOLERANCE_MM
    other, _, _ = _map(capsys, homographies["tilted 25 deg"], "--px", GRID_PX, "--z", "100", "--camera-height", "600")
    assert np.array_equal(other, got)


def test_on_its_own_plane_a_homography_maps_as_before(homographies, capsys):
    cal = load_calibration(homographies["down"])
    for extra in ([], ["--z", "0"]):
        got, res, err = _map(capsys, homographies["down"], "--px", GRID_PX, *extra)
        assert "off_plane" not in res and err == ""
        assert np.allclose(got, cal.px_to_mm(GRID_PX), atol=1e-4)


@pytest.mark.parametrize("args, message", [
    (["--z", "900"], "the plane z = 900 mm is not below the camera the homography implies (its optical centre at "
                     "z = 800.0 mm"),
    (["--z", "20", "--camera-height", "5"], "--camera-height 5: the camera's optical centre must be at least 10 mm "
                                            "above the calibration's plane z = 0 mm"),
    (["--z", "20", "--camera-height", "nan"], "--camera-height must be a finite number"),
])
def test_bad_heights_are_refused(homographies, capsys, args, message):
    code, out, err = run_cli("map", homographies["down"], "--px", "640,512", *args, "--json", capsys=capsys)
    assert code == 2 and out == "" and message in err and err.count("\n") == 1, err


def test_a_camera_height_with_a_pose_calibration_is_refused(capsys):
    code, _, err = run_cli("map", default_calibration_path(), "--px", "640,512", "--z", "20", "--camera-height", "800",
                           capsys=capsys)
    assert code == 2 and "--camera-height is for a homography-only calibration" in err and "has a camera pose" in err


def test_cell_run_still_refuses_a_homography(homographies, capsys):
    """`cell map` estimates; the cell loop plans on a calibration with intrinsics only."""
    code, _, err = run_cli("run", "--calibration", homographies["down"], capsys=capsys)
    assert code == 2 and "needs intrinsics and a camera pose" in err


@needs_photos
@pytest.mark.parametrize("image", ["aruco_img.png", "aruco_img2.png"])
def test_festo_homography_maps_at_heights_as_the_pose_with_published_intrinsics(tmp_path, capsys, image):
    """Over the whole 1920 x 1080 frame (markers in a part of it): at z = 0 the two calibrations differ up to 1.39
    mm; at z = 20 - 100 with the pose's camera height (779 mm) up to 1.37 mm, with the default cell's 800 mm up to
    3.4 mm at z = 100, within the printed bound."""
    ref = json.loads((FESTO / "published_reference.json").read_text())
    markers = dict(ref["marker_corners_robot_frame_mm"])
    markers["1"] = markers["1"][1:] + markers["1"][:1]  # SOURCE.md's corner-order fix
    (tmp_path / "m.json").write_text(json.dumps({"dictionary": ref["aruco_dictionary"], "markers": markers}))
    k = np.array(ref["camera_matrix_realsense_sdk"])
    common = ("calibrate", "plane", FESTO / image, "--markers", tmp_path / "m.json", "--out")
    assert run_cli(*common, tmp_path / "h.json") == 0
    assert run_cli(*common, tmp_path / "p.json", "--camera-matrix", f"{k[0, 0]},{k[1, 1]},{k[0, 2]},{k[1, 2]}") == 0
    capsys.readouterr()
    pose = load_calibration(tmp_path / "p.json")
    grid = np.column_stack([g.ravel() for g in np.meshgrid(np.linspace(0, 1920, 13), np.linspace(0, 1080, 8))])
    camera_z = pose.camera_position_mm()[2]
    for z in (20.0, 50.0, 100.0):
        got, _, _ = _map(capsys, tmp_path / "h.json", "--px", grid, "--z", str(z), "--camera-height", str(camera_z))
        assert np.linalg.norm(got - pose.px_to_mm(grid, z), axis=1).max() < 1.5
    got, res, _ = _map(capsys, tmp_path / "h.json", "--px", grid, "--z", "100")
    diff = np.linalg.norm(got - pose.px_to_mm(grid, 100.0), axis=1).max()
    assert 2.5 < diff < 3.6 and diff < res["off_plane"]["error_bound_mm"]
