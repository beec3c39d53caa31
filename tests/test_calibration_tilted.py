"""A calibration plane that is not horizontal: a marker board tilted in front of the default cell's camera,
rendered from a known pose (ArUco markers warped through a pinhole camera), calibrated, mapped and refused
through the CLI; the Festo frames with their markers' coordinates tilted."""

import json

import cv2
import numpy as np
import pytest
from conftest import EXTERNAL, needs_photos, run_cli

from calibration import load_calibration
from calibration.camera import HALF_PX, Calibration, pose_matrix

FESTO = EXTERNAL / "p5binpicking-festo-table"
SIZE = (1280, 1024)
SIDE_MM, PX_PER_MM = 50.0, 4.0  # markers, and the board's texture
BOARD_MM = (300.0, 440.0)  # along the board's x and y axes


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


# the default camera without its lens distortion (a perspective warp renders no distortion)
CAMERA = load_calibration()
K = CAMERA.camera_matrix
PINHOLE = Calibration(*SIZE, K, np.zeros(5), CAMERA.cam2base, None, 0.0, "pinhole")
CAMERA_MATRIX = f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"


class Board:
    """A board of 6 markers (ids 0-5) whose frame is `rotation` (columns: its x and y axes, its normal) at
    `origin_mm` in the base frame."""

    def __init__(self, rotation: np.ndarray, origin_mm):
        self.r, self.o = rotation, np.asarray(origin_mm, float)
        self.corners = {}  # id -> (4, 2) board mm, OpenCV's order as seen from the front
        for i in range(6):
            a0, b0 = 40.0 + 130.0 * (i // 3), 40.0 + 140.0 * (i % 3)
            # the image shows board y to the right and board x down (the default camera: u along base y)
            self.corners[i] = np.array([[a0, b0], [a0, b0 + SIDE_MM], [a0 + SIDE_MM, b0 + SIDE_MM],
                                        [a0 + SIDE_MM, b0]])

    def xyz(self, ab) -> np.ndarray:
        ab = np.asarray(ab, float).reshape(-1, 2)
        return self.o + ab @ self.r[:, :2].T

    @property
    def normal(self) -> np.ndarray:
        return self.r[:, 2]

    def markers_json(self, path, xyz_of=None):
        xyz_of = xyz_of or (lambda i, p: p)
        markers = {str(i): xyz_of(i, self.xyz(c)).tolist() for i, c in self.corners.items()}
        path.write_text(json.dumps({"dictionary": "DICT_4X4_50", "markers": markers}))
        return path

    def render(self, path, scale: int = 2, camera=None):
        """The board on a dark table through `camera` (a pinhole Calibration; default PINHOLE): warped at `scale` x
        the frame's size, then averaged down."""
        camera = camera or PINHOLE
        h_b, w_b = int(BOARD_MM[0] * PX_PER_MM), int(BOARD_MM[1] * PX_PER_MM)
        texture = np.full((h_b, w_b), 235, np.uint8)
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
        side = int(SIDE_MM * PX_PER_MM)
        for i, c in self.corners.items():
            r0, c0 = (c[0] * PX_PER_MM).astype(int)
            texture[r0:r0 + side, c0:c0 + side] = cv2.aruco.generateImageMarker(dictionary, i, side)
        # texture edge coordinates (col, row) -> board mm (a = row, b = col) -> base -> camera -> image edges
        to_ab = np.array([[0, 1 / PX_PER_MM, 0], [1 / PX_PER_MM, 0, 0], [0, 0, 1.0]])
        base2cam = np.linalg.inv(camera.cam2base)
        plane_to_cam = np.column_stack([base2cam[:3, :3] @ self.r[:, 0], base2cam[:3, :3] @ self.r[:, 1],
                                        base2cam[:3, :3] @ self.o + base2cam[:3, 3]])
        k_edges = np.diag([scale, scale, 1.0]) @ (camera.camera_matrix
                                                  + np.array([[0, 0, HALF_PX], [0, 0, HALF_PX], [0, 0, 0]]))
        warp = _shift(-0.5) @ k_edges @ plane_to_cam @ to_ab @ _shift(0.5)  # OpenCV's pixel centres both ends
        big = cv2.warpPerspective(texture, warp, (SIZE[0] * scale, SIZE[1] * scale), flags=cv2.INTER_LINEAR,
                                  borderValue=70)
        frame = cv2.resize(big, SIZE, interpolation=cv2.INTER_AREA)
        noisy = np.clip(frame + np.random.default_rng(1).normal(0, 1.5, frame.shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(path), cv2.cvtColor(noisy, cv2.COLOR_GRAY2BGR))
        return path


def _shift(d: float) -> np.ndarray:
    return np.array([[1, 0, d], [0, 1, d], [0, 0, 1.0]])


# tilted 15 deg about base y and 10 about base x: 18 deg in all, rising towards +x and -y
TILT = _rot("x", 10.0) @ _rot("y", -15.0)
BOARD = Board(TILT, [200.0, -220.0, 20.0])
TRUE_TILT_DEG = float(np.degrees(np.arccos(TILT[2, 2])))


@pytest.fixture(scope="module")
def board_frame(tmp_path_factory):
    d = tmp_path_factory.mktemp("tilted")
    return BOARD.render(d / "board.png"), BOARD.markers_json(d / "markers.json")


def _calibrate(tmp_path, capsys, frame, markers, *extra, name="cal.json"):
    out = tmp_path / name
    code, stdout, err = run_cli("calibrate", "plane", frame, "--markers", markers, "--out", out, *extra,
                                capsys=capsys)
    return code, (json.loads(stdout) if code == 0 else None), err, out


def _map(capsys, cal, *args):
    code, stdout, err = run_cli("map", cal, *args, "--json", capsys=capsys)
    return code, (json.loads(stdout) if code == 0 else None), err


def _pairs(points) -> list[str]:
    return [f"{float(a)!r},{float(b)!r}" for a, b in np.asarray(points, float)]


def test_the_rendered_board_is_where_the_pinhole_puts_it(board_frame):
    """The render itself: the detected corners are the board's corners projected (so the tests below
    measure the calibration, not the drawing)."""
    from calibration.plane import detect_markers

    found = detect_markers(cv2.imread(str(board_frame[0]), cv2.IMREAD_GRAYSCALE), "DICT_4X4_50")
    assert sorted(found) == [0, 1, 2, 3, 4, 5]
    err = np.concatenate([np.linalg.norm(found[i] - PINHOLE.project(BOARD.xyz(c)), axis=1)
                          for i, c in BOARD.corners.items()])
    assert np.sqrt(np.mean(err ** 2)) < 0.3


def test_a_tilted_board_with_intrinsics_gives_its_plane_and_the_camera(tmp_path, capsys, board_frame):
    code, res, err, out = _calibrate(tmp_path, capsys, *board_frame, "--camera-matrix", CAMERA_MATRIX)
    assert code == 0, err
    assert res["method"] == "pose" and res["markers_used"] == [0, 1, 2, 3, 4, 5] and err == ""
    assert res["plane_z_mm"] is None and res["z_spread_mm"] > 100  # was refused: more than 5 mm apart
    assert res["tilt_deg"] == pytest.approx(TRUE_TILT_DEG, abs=1e-3)  # the markers' own plane (their coordinates)
    assert np.allclose(res["plane"]["normal"], BOARD.normal, atol=1e-6)
    assert res["off_plane_max_mm"] < 1e-9 and res["residual_mm"] < 0.2 and res["reprojection_rms_px"] < 0.3
    assert np.linalg.norm(np.subtract(res["camera_position_mm"], CAMERA.camera_position_mm())) < 2.0
    # the line of sight to the markers' centre, against the board's normal
    centre = np.mean([BOARD.xyz(c) for c in BOARD.corners.values()], axis=(0, 1))
    sight = CAMERA.camera_position_mm() - centre
    view_deg = np.degrees(np.arccos(BOARD.normal @ sight / np.linalg.norm(sight)))
    assert res["view_angle_deg"] == pytest.approx(view_deg, abs=0.1)
    saved = json.loads(out.read_text())
    assert saved["version"] == 2 and saved["pose"].keys() == {"cam2base"} and saved["homography"] is None
    assert np.allclose(saved["plane"]["normal"], BOARD.normal, atol=1e-6)


@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_pixels_map_onto_the_tilted_plane_and_back(tmp_path, capsys, board_frame, with_intrinsics):
    extra = ["--camera-matrix", CAMERA_MATRIX] if with_intrinsics else []
    code, res, err, cal = _calibrate(tmp_path, capsys, *board_frame, *extra)
    assert code == 0 and res["method"] == ("pose" if with_intrinsics else "homography"), err
    # points all over the board (not the markers' corners): their pixels through the true camera
    ab = np.random.default_rng(2).uniform([10, 10], [BOARD_MM[0] - 10, BOARD_MM[1] - 10], (20, 2))
    truth = BOARD.xyz(ab)
    px = PINHOLE.project(truth)
    code, got, err = _map(capsys, cal, "--px", *_pairs(px))
    assert code == 0, err
    assert got["z_mm"] is None and got["plane"]["tilt_deg"] == pytest.approx(TRUE_TILT_DEG, abs=1e-3)
    xyz = np.array(got["xyz_mm"])
    assert np.allclose(xyz[:, :2], got["mm"]) and np.abs(xyz - truth).max() < (0.3 if with_intrinsics else 0.5)
    # the other way: base (x, y) on the plane (z from its equation) to the pixels, and round trips
    code, back, _ = _map(capsys, cal, "--mm", *_pairs(truth[:, :2]))
    assert code == 0 and np.abs(np.array(back["px"]) - px).max() < 0.5
    assert np.allclose(np.array(back["xyz_mm"])[:, 2], xyz[:, 2], atol=0.3)
    code, again, _ = _map(capsys, cal, "--px", *_pairs(back["px"]))
    assert np.abs(np.array(again["mm"]) - truth[:, :2]).max() < 1e-3  # mm -> px -> mm (4 decimals printed)


def test_with_intrinsics_pixels_map_onto_horizontal_planes_at_z(tmp_path, capsys, board_frame):
    """What the grasp pipeline needs: the plane at a part's height, whatever plane was calibrated."""
    code, _, err, cal = _calibrate(tmp_path, capsys, *board_frame, "--camera-matrix", CAMERA_MATRIX)
    assert code == 0, err
    xy = np.array([[250.0, -150.0], [420.0, 180.0], [330.0, 20.0]])
    for z in (0.0, 45.0):
        px = PINHOLE.project(np.column_stack([xy, np.full(3, z)]))
        code, got, _ = _map(capsys, cal, "--px", *_pairs(px), "--z", str(z))
        assert code == 0 and got["z_mm"] == z and "xyz_mm" not in got
        assert np.abs(np.array(got["mm"]) - xy).max() < 0.5  # 0.1 - 0.3 mm off the board's own plane
        code, back, _ = _map(capsys, cal, "--mm", *_pairs(xy), "--z", str(z))
        assert np.abs(np.array(back["px"]) - px).max() < 0.5


def test_without_intrinsics_another_height_is_refused(tmp_path, capsys, board_frame):
    code, _, err, cal = _calibrate(tmp_path, capsys, *board_frame)
    assert code == 0, err
    for args in (("map", cal, "--px", "640,512", "--z", "0"), ("map", cal, "--mm", "300,0", "--z", "20"),
                 ("segment", board_frame[0], "--calibration", cal, "--z", "0")):
        code, out, err = run_cli(*args, capsys=capsys)
        assert code == 2 and out == "" and "Traceback" not in err, err
        assert "a homography for its tilted plane (z = " in err and "without a camera model" in err
        assert "calibrate with intrinsics (--camera-matrix or --intrinsics)" in err


@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_segment_maps_outlines_onto_the_tilted_plane(tmp_path, capsys, board_frame, with_intrinsics):
    extra = ["--camera-matrix", CAMERA_MATRIX] if with_intrinsics else []
    code, _, err, cal = _calibrate(tmp_path, capsys, *board_frame, *extra)
    assert code == 0, err
    code, stdout, err = run_cli("segment", board_frame[0], "--calibration", cal, "--json", capsys=capsys)
    assert code == 0, err
    out = json.loads(stdout)
    parts = out["parts"]
    assert parts and all(p["z_mm"] is None for p in parts)  # no one height: the plane's
    loaded = load_calibration(cal)
    assert out["plane"] == json.loads(json.dumps(loaded.plane.describe()))  # each point's z without the file
    code, stdout, err = run_cli("segment", board_frame[0], "--calibration", cal, "--z", "0", "--json",
                                capsys=capsys)
    assert code == (0 if with_intrinsics else 2), err  # --z needs the camera model
    if with_intrinsics:  # on the horizontal plane z = 0: one height, no plane
        assert "plane" not in json.loads(stdout) and json.loads(stdout)["parts"][0]["z_mm"] == 0
    for p in parts:
        # outline_px is printed to 2 decimals: 0.005 px, 0.003 mm
        assert np.allclose(p["outline_mm"], loaded.px_to_xyz(p["outline_px"])[:, :2], atol=0.005)
        xyz = loaded.px_to_xyz(p["outline_px"])
        assert np.abs(loaded.plane.off(xyz)).max() < 1e-6


def test_a_marker_off_the_plane_is_refused_naming_it(tmp_path, capsys, board_frame):
    frame, _ = board_frame
    raised = BOARD.markers_json(tmp_path / "m.json", lambda i, p: p + [0, 0, 10.0 * (i == 4)])
    for extra in ([], ["--camera-matrix", CAMERA_MATRIX]):
        code, _, err, out = _calibrate(tmp_path, capsys, frame, raised, *extra)
        assert code == 2 and not out.exists() and "Traceback" not in err
        assert "the points are not on one plane" in err and "leaves marker 4 corner" in err, err
        assert "mm off it (at most 2.5 mm)" in err


@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_a_tilted_board_given_in_a_mirrored_frame_is_seen_from_behind(tmp_path, capsys, board_frame,
                                                                        with_intrinsics):
    frame, _ = board_frame
    mirrored = BOARD.markers_json(tmp_path / "m.json", lambda i, p: p * [1, -1, 1])
    extra = ["--camera-matrix", CAMERA_MATRIX] if with_intrinsics else []
    code, _, err, out = _calibrate(tmp_path, capsys, frame, mirrored, *extra, "--accept-poor-fit")
    assert code == 2 and not out.exists() and "Traceback" not in err
    assert "sees the points' plane (z = " in err and "from behind, by the " + (
        "camera pose" if with_intrinsics else "homography (no intrinsics)") in err, err
    assert "mirrored frame (y down)" in err


def _points_file(path, uv, xyz):
    path.write_text(json.dumps({"points": [{"px": a, "mm": b} for a, b in zip(np.asarray(uv).tolist(),
                                                                              np.asarray(xyz).tolist())]}))
    return path


@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_a_plane_seen_nearly_edge_on_is_refused(tmp_path, capsys, with_intrinsics):
    """A camera 65 deg from vertical, a plane tilted 6 or 11 deg away from it: 71 or 77 deg from its normal."""
    camera_at = np.array([350 - 800 * np.tan(np.radians(65)), 0.0, 800.0])
    ahead = np.array([350.0, 0.0, 0.0]) - camera_at
    ahead /= np.linalg.norm(ahead)
    r = np.column_stack([[0.0, 1.0, 0.0], np.cross(ahead, [0.0, 1.0, 0.0]), ahead])
    slanted = Calibration(*SIZE, K, np.zeros(5), pose_matrix(r, camera_at), None, 0.0)
    xy = np.random.default_rng(4).uniform([250, -100], [450, 100], size=(16, 2))
    frame = tmp_path / "f.png"
    cv2.imwrite(str(frame), np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    extra = ["--camera-matrix", CAMERA_MATRIX] if with_intrinsics else []
    for slope, ok in ((-0.1, True), (-0.2, False)):
        xyz = np.column_stack([xy, (xy[:, 0] - 350) * slope])
        pts = _points_file(tmp_path / "p.json", slanted.project(xyz), xyz)
        code, out, err = run_cli("calibrate", "plane", frame, "--points", pts, "--out", tmp_path / "c.json",
                                 *extra, capsys=capsys)
        if ok:  # 71 deg: accepted
            assert code == 0 and 70 < json.loads(out)["view_angle_deg"] < 72, err
            continue
        assert code == 2 and out == "" and "Traceback" not in err
        assert "sees the points' plane nearly edge-on" in err and "deg from its normal (at most 75)" in err, err
        assert 76 < float(err.split(" deg from its normal")[0].rsplit(" ", 1)[1]) < 78


def test_a_plane_steeper_than_75_degrees_is_refused(tmp_path, capsys):
    xy = np.random.default_rng(4).uniform([300, -100], [400, 100], size=(12, 2))
    xyz = np.column_stack([xy, 20 + (xy[:, 0] - 300) * 4.0])  # 76 deg
    frame = tmp_path / "f.png"
    cv2.imwrite(str(frame), np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    pts = _points_file(tmp_path / "p.json", PINHOLE.project(xyz), xyz)
    code, out, err = run_cli("calibrate", "plane", frame, "--points", pts, "--out", tmp_path / "c.json",
                             capsys=capsys)
    assert code == 2 and "tilted 76.0 deg from horizontal (at most 75)" in err, err


FESTO_K = "1393.77,1393.14,956.754,545.3"


def _festo_markers(tmp_path, rotation=None):
    ref = json.loads((FESTO / "published_reference.json").read_text())
    markers = dict(ref["marker_corners_robot_frame_mm"])
    markers["1"] = markers["1"][1:] + markers["1"][:1]  # SOURCE.md: the corner order fix
    turn = np.eye(3) if rotation is None else rotation
    m = {k: (np.array(v, float) @ turn.T).tolist() for k, v in markers.items()}
    path = tmp_path / "markers.json"
    path.write_text(json.dumps({"dictionary": ref["aruco_dictionary"], "markers": m}))
    return path


@needs_photos
@pytest.mark.parametrize("image", ["aruco_img.png", "aruco_img2.png"])
def test_festo_markers_on_a_tilted_plane_recover_the_tilt_and_the_camera(tmp_path, capsys, image):
    """The real frames with their markers' coordinates turned onto the plane z = 0.05 x (2.86 deg about y):
    the same camera must come out turned with them, and pixels land on the turned plane."""
    turn = _rot("y", -np.degrees(np.arctan(0.05)))
    code, flat, _, flat_cal = _calibrate(tmp_path, capsys, FESTO / image, _festo_markers(tmp_path),
                                         "--camera-matrix", FESTO_K, name="flat.json")
    code, res, err, cal = _calibrate(tmp_path, capsys, FESTO / image, _festo_markers(tmp_path, turn),
                                     "--camera-matrix", FESTO_K)
    assert code == 0 and res["method"] == "pose" and res["warnings"] == [], err
    assert res["z_spread_mm"] > 5 and res["tilt_deg"] == pytest.approx(2.862, abs=1e-3)
    assert res["plane"]["equation"].startswith("z = 0.05 x + 0 y")
    assert abs(res["residual_mm"] - flat["residual_mm"]) < 0.002  # 0.606 and 0.612 mm, both ways
    assert np.linalg.norm(np.subtract(res["camera_position_mm"], turn @ flat["camera_position_mm"])) < 0.01
    a, b = load_calibration(flat_cal), load_calibration(cal)
    assert _angle_deg(turn @ a.cam2base[:3, :3], b.cam2base[:3, :3]) < 0.001  # turned with the markers
    px = [[300.0, 200.0], [960.0, 540.0], [1700.0, 900.0]]
    assert np.abs(b.px_to_xyz(px) - a.px_to_xyz(px) @ turn.T).max() < 0.01


def _angle_deg(r1: np.ndarray, r2: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r1.T @ r2) - 1) / 2, -1, 1))))


@needs_photos
@pytest.mark.parametrize("image", ["aruco_img.png", "aruco_img2.png"])
def test_festo_markers_sheared_onto_a_tilted_plane_keep_the_view_of_it(tmp_path, capsys, image):
    """z += 0.05 x (a shear: lengths along x grow 0.125 %, 1 mm across the markers): the plane as the camera
    sees it (its normal in the camera's frame) comes out within 0.08 deg of the table's, the camera 1.3 mm
    from the turned one."""
    code, flat, _, flat_cal = _calibrate(tmp_path, capsys, FESTO / image, _festo_markers(tmp_path),
                                         "--camera-matrix", FESTO_K, name="flat.json")
    sheared = np.array([[1, 0, 0], [0, 1, 0], [0.05, 0, 1.0]])
    code, res, err, cal = _calibrate(tmp_path, capsys, FESTO / image, _festo_markers(tmp_path, sheared),
                                     "--camera-matrix", FESTO_K)
    assert code == 0 and res["tilt_deg"] == pytest.approx(2.862, abs=1e-3) and res["residual_mm"] < 0.65, err
    a, b = load_calibration(flat_cal), load_calibration(cal)
    seen_flat = np.linalg.inv(a.cam2base[:3, :3]) @ [0.0, 0.0, 1.0]
    seen_tilted = np.linalg.inv(b.cam2base[:3, :3]) @ b.plane.normal
    assert np.degrees(np.arccos(np.clip(seen_flat @ seen_tilted, -1, 1))) < 0.1
    turn = _rot("y", -np.degrees(np.arctan(0.05)))
    assert np.linalg.norm(np.subtract(res["camera_position_mm"], turn @ flat["camera_position_mm"])) < 2.0


def _tilted_file(tmp_path, with_intrinsics=True):
    from calibration import save_calibration
    from calibration.plane import fit_plane_mapping

    ab = np.random.default_rng(6).uniform([0, 0], BOARD_MM, (12, 2))
    xyz = BOARD.xyz(ab)
    k = K if with_intrinsics else None
    cal = fit_plane_mapping(PINHOLE.project(xyz), xyz, SIZE, k, np.zeros(5) if with_intrinsics else None)
    path = tmp_path / "tilted.json"
    save_calibration(cal, path)
    return cal, path


@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_a_tilted_calibration_file_reads_back_the_same_mapping(tmp_path, with_intrinsics):
    cal, path = _tilted_file(tmp_path, with_intrinsics)
    raw = json.loads(path.read_text())
    assert raw["version"] == 2 and set(raw["plane"]) == {"point_mm", "x_axis", "y_axis", "normal"}
    assert (raw["homography"] is None) == with_intrinsics
    if not with_intrinsics:
        assert set(raw["homography"]) == {"px_to_plane_mm"}  # to the plane's own 2D frame
    back = load_calibration(path, size=SIZE)
    px = [[100.0, 80.0], [640.0, 512.0], [1200.0, 950.0]]
    assert back.plane_z_mm is None and np.array_equal(back.px_to_xyz(px), cal.px_to_xyz(px))
    assert np.array_equal(back.mm_to_px([[300.0, 0.0]]), cal.mm_to_px([[300.0, 0.0]]))
    assert back.mm_per_px() == cal.mm_per_px()
    resized = back.resized(2560, 2048)  # a frame upscaled as a whole keeps its plane
    assert np.allclose(resized.px_to_xyz(np.multiply(px, 2)), cal.px_to_xyz(px), atol=1e-6)


def _edit(key, value):
    def change(raw):
        where = raw
        *path, last = key.split(".")
        for k in path:
            where = where[k]
        where[last] = value
    return change


@pytest.mark.parametrize("change, message", [
    (_edit("version", 1), "'plane' (a tilted calibration plane) needs version 2; version 1 files map on a "
                          "horizontal plane"),
    (_edit("plane.x_axis", [1.0, 0.0, 0.0]), "plane.x_axis, y_axis and normal must be unit vectors at right angles"),
    (_edit("plane.normal", [0.0, 0.0, 1.0]), "plane.x_axis, y_axis and normal must be unit vectors at right angles"),
    (_edit("plane.point_mm", [1.0, 2.0]), "plane.point_mm must be a list of 3 finite numbers"),
    (_edit("plane.point_mm", [1.0, True, 2.0]), "plane.point_mm must be a list of 3 numbers (true/false"),
    (_edit("plane.point_mm", [1e7, 0.0, 0.0]), "plane.point_mm must be within 1e+06 mm of the base"),
    (_edit("plane", [1, 2, 3]), "'plane' must be an object {point_mm, x_axis, y_axis, normal} or null"),
    (_edit("pose.plane_z_mm", 0.0), "pose.plane_z_mm: a calibration on a tilted 'plane' has no one height"),
    (_edit("pose", None), "'plane' needs a 'pose' or a 'homography' that maps onto it"),
    (_edit("version", 3), "version 3 is not supported (this program reads version 1, and 2 for a tilted plane)"),
    (_edit("plane", None), "version 2 is a tilted plane's calibration, but 'plane' is missing or null"),
    (lambda raw: raw.pop("plane"), "version 2 is a tilted plane's calibration, but 'plane' is missing or null"),
])
def test_a_bad_tilted_calibration_file_is_refused_naming_the_key(tmp_path, capsys, change, message):
    _, path = _tilted_file(tmp_path)
    raw = json.loads(path.read_text())
    change(raw)
    path.write_text(json.dumps(raw))
    code, out, err = run_cli("map", path, "--px", "640,512", capsys=capsys)
    assert code == 2 and out == "" and f"calibration file {path}: {message}" in err, err


def test_a_tilted_plane_facing_down_or_seen_from_behind_is_refused_on_read(tmp_path, capsys):
    _, path = _tilted_file(tmp_path)
    raw = json.loads(path.read_text())
    p = raw["plane"]
    p["y_axis"], p["normal"] = [-v for v in p["y_axis"]], [-v for v in p["normal"]]  # the same plane, upside down
    path.write_text(json.dumps(raw))
    code, _, err = run_cli("map", path, "--px", "640,512", capsys=capsys)
    assert code == 2 and "deg from straight up; a calibration plane's normal points up, at most 75" in err, err
    raw["plane"]["point_mm"][2] += 1000.0  # the camera (800 mm up) under the plane
    p["y_axis"], p["normal"] = [-v for v in p["y_axis"]], [-v for v in p["normal"]]
    path.write_text(json.dumps(raw))
    code, _, err = run_cli("map", path, "--px", "640,512", capsys=capsys)
    assert code == 2 and "does not look onto the front (upper side) of the plane z = " in err, err


def test_horizontal_calibrations_are_written_as_before(tmp_path):
    """Version 1, no plane key, plane_z_mm kept: readers of version 1 read them as they did."""
    from calibration import save_calibration

    path = tmp_path / "c.json"
    save_calibration(CAMERA, path)
    raw = json.loads(path.read_text())
    assert raw["version"] == 1 and "plane" not in raw and raw["pose"]["plane_z_mm"] == 0.0


def _ramp_markers(slope: float) -> tuple[dict, dict]:
    """Four 50 mm markers on the plane z = slope x, three near x = 150 - 230 and one at x = 480, with their
    pixels through PINHOLE (exact corners): (detected, known)."""
    known, detected = {}, {}
    for i, (x0, y0) in enumerate([(150, -250), (150, 150), (180, -50), (480, 0)]):
        square = np.array([[x0, y0], [x0, y0 + 50], [x0 + 50, y0 + 50], [x0 + 50, y0]], float)
        known[i] = np.column_stack([square, slope * square[:, 0]])
        detected[i] = PINHOLE.project(known[i])
    return detected, known


@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_a_held_out_marker_is_measured_on_the_tilted_plane(with_intrinsics):
    """Markers 0 - 2 span 4.5 mm of z (a horizontal fit), all four 19 mm: the pose fitted to the three maps
    marker 3 onto the tilted plane, not their mean height (3.4 mm of parallax on exact corners)."""
    from calibration.plane import fit_plane_mapping, holdout_residuals, markers_correspondences

    detected, known = _ramp_markers(0.05)
    uv, xyz, used, _ = markers_correspondences(detected, known)
    k, d = (K, np.zeros(5)) if with_intrinsics else (None, None)
    cal = fit_plane_mapping(uv, xyz, SIZE, k, d)
    assert cal.plane is not None and np.ptp(np.concatenate([known[i] for i in (0, 1, 2)])[:, 2]) <= 5.0
    held = holdout_residuals(detected, known, used, SIZE, k, d, cal.plane)
    assert sorted(held) == ["0", "1", "2", "3"] and max(held.values()) < 0.01, held


@needs_photos
def test_festo_markers_turned_a_little_keep_their_held_out_residuals(tmp_path, capsys):
    """Turned onto z = 0.008 x (6.5 mm of z: tilted; without marker 0 or 1 the rest spans under 5 mm) the
    held-out residuals are the flat table's (marker 0 was 3.64 mm against 1.74)."""
    turn = _rot("y", -np.degrees(np.arctan(0.008)))
    image = FESTO / "aruco_img.png"
    _, flat, _, _ = _calibrate(tmp_path, capsys, image, _festo_markers(tmp_path), "--camera-matrix", FESTO_K,
                               name="flat.json")
    code, res, err, _ = _calibrate(tmp_path, capsys, image, _festo_markers(tmp_path, turn), "--camera-matrix",
                                   FESTO_K)
    assert code == 0 and res["plane_z_mm"] is None, err
    assert res["holdout_residual_mm"] == pytest.approx(flat["holdout_residual_mm"], abs=0.002)


@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_mm_per_px_on_a_steep_plane_is_a_pixels_footprint(with_intrinsics):
    """A plane tilted 60 deg along the image's v (the default camera looks down, v along base x): a pixel
    covers about 2 x more of it along v than along u. mm_per_px is the side of the square of a pixel's area
    on the plane (what mm^2 thresholds in pixels need: `segment --min-area-mm2`), not the span along u
    (which gave half the area)."""
    from calibration.plane import fit_plane_mapping
    from cell.vision.segment import SegmentParams

    xy = np.random.default_rng(8).uniform([330, -150], [370, 150], (16, 2))
    xyz = np.column_stack([xy, np.tan(np.radians(60)) * (xy[:, 0] - 350) + 40])
    k, d = (K, np.zeros(5)) if with_intrinsics else (None, None)
    cal = fit_plane_mapping(PINHOLE.project(xyz), xyz, SIZE, k, d)
    assert cal.plane.tilt_deg == pytest.approx(60.0, abs=1e-6)
    centre = np.array([SIZE[0] / 2.0, SIZE[1] / 2.0])
    corners = cal.px_to_xyz(centre + [[-1, -1], [1, -1], [1, 1], [-1, 1]])
    area_mm2_per_px = np.linalg.norm(np.cross(corners[2] - corners[0], corners[3] - corners[1])) / 2 / 4
    assert cal.mm_per_px() ** 2 == pytest.approx(area_mm2_per_px, rel=1e-3)
    params = SegmentParams.for_calibration(cal, 75.0, None)
    assert params.min_area_px == pytest.approx(75.0 / area_mm2_per_px, rel=1e-3)
