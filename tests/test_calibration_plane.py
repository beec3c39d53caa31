"""Image <-> base frame on a plane: real ArUco frames of a robot cell, synthetic points, the CLI."""

import json

import numpy as np
import pytest
from conftest import EXTERNAL, needs_photos, run_cli

from calibration import default_calibration_path, load_calibration
from calibration.plane import fit_plane_mapping

FESTO = EXTERNAL / "p5binpicking-festo-table"
DEFAULT = default_calibration_path()


def _markers(tmp_path, shift_marker1=True, extra=None):
    ref = json.loads((FESTO / "published_reference.json").read_text())
    markers = {k: v for k, v in ref["marker_corners_robot_frame_mm"].items()}
    if shift_marker1:  # SOURCE.md: OpenCV corner j of marker 1 is the published entry (j + 1) mod 4
        markers["1"] = markers["1"][1:] + markers["1"][:1]
    markers.update(extra or {})
    p = tmp_path / "markers.json"
    p.write_text(json.dumps({"dictionary": ref["aruco_dictionary"], "markers": markers}))
    return p, ref


@needs_photos
@pytest.mark.parametrize("image", ["aruco_img.png", "aruco_img2.png"])
@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_festo_frames_fit_to_about_a_millimetre(tmp_path, capsys, image, with_intrinsics):
    markers, ref = _markers(tmp_path)
    k = np.array(ref["camera_matrix_realsense_sdk"])
    extra = ["--camera-matrix", f"{k[0, 0]},{k[1, 1]},{k[0, 2]},{k[1, 2]}"] if with_intrinsics else []
    out = tmp_path / "plane.json"
    code, stdout, _ = run_cli("calibrate", "plane", FESTO / image, "--markers", markers, "--out", out, *extra,
                              capsys=capsys)
    assert code == 0
    res = json.loads(stdout)
    assert res["markers_used"] == [0, 1, 2, 3]
    # sub-pixel marker corners: 0.51 - 0.61 mm (0.64 - 0.85 mm with OpenCV's unrefined corners)
    assert res["residual_mm"] < 0.7
    assert res["mm_per_px"] == pytest.approx(0.56, abs=0.01)
    # each marker under the fit to the other three: what an unseen point is off by, above the fit's own
    held, own = res["holdout_residual_mm"], res["per_marker_residual_mm"]
    assert sorted(held) == ["0", "1", "2", "3"] and all(held[m] > own[m] for m in held)
    assert res["holdout_residual_max_mm"] == max(held.values()) < 5.0
    if with_intrinsics:
        assert res["method"] == "pose"
        assert np.allclose(res["camera_position_mm"], [74, -395, 779], atol=3.0)
        assert res["reprojection_rms_px"] < 1.2  # SOURCE.md's solvePnP on unrefined corners: 1.34 - 1.50
    else:
        assert res["method"] == "homography"
    cal = load_calibration(out, size=(1920, 1080))
    # a marker corner maps back to its published base coordinates within a few mm
    code, stdout, _ = run_cli("map", out, "--mm", "175.7,-90.0", "--json", capsys=capsys)
    uv = json.loads(stdout)["px"][0]
    assert np.allclose(cal.px_to_mm([uv])[0], [175.7, -90.0], atol=1e-6)


def test_marker_corners_are_found_to_sub_pixel_accuracy():
    """Markers drawn on a plane and imaged through a known homography, blurred, with noise."""
    import cv2

    from calibration.plane import detect_markers

    rng = np.random.default_rng(3)
    side, supersample = 60, 4
    errors = []
    for _ in range(8):
        plane = np.full((600, 800), 230, np.uint8)
        truth = {}
        for i, (x, y) in enumerate([(100, 100), (600, 100), (100, 420), (600, 420)]):
            plane[y:y + side, x:x + side] = cv2.aruco.generateImageMarker(
                cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), i, side)
            truth[i] = np.array([[x, y], [x + side, y], [x + side, y + side], [x, y + side]], float)  # edges
        corners = np.float32([[0, 0], [800, 0], [800, 600], [0, 600]])
        h = cv2.getPerspectiveTransform(corners, corners + rng.uniform(-50, 50, (4, 2)).astype(np.float32))
        # warp a supersampled copy (pixel-centre coordinates at both ends), then average it down
        s, t = supersample, (lambda d: np.array([[1, 0, d], [0, 1, d], [0, 0, 1.0]]))
        big = cv2.resize(plane, None, fx=s, fy=s, interpolation=cv2.INTER_NEAREST)
        hs = t(-0.5) @ np.diag([s, s, 1.0]) @ h @ np.diag([1 / s, 1 / s, 1.0]) @ t(0.5)
        warped = cv2.warpPerspective(big, hs, (800 * s, 600 * s), borderValue=230)
        img = cv2.GaussianBlur(cv2.resize(warped, (800, 600), interpolation=cv2.INTER_AREA).astype(np.float32),
                               (0, 0), 1.0) + rng.normal(0, 2.0, (600, 800))
        found = detect_markers(np.clip(img, 0, 255).astype(np.uint8), "DICT_4X4_50")
        assert sorted(found) == [0, 1, 2, 3]
        for i, uv in found.items():  # CONTRACT frame: pixel edges, as the truth
            errors.append(np.linalg.norm(uv - cv2.perspectiveTransform(truth[i].reshape(-1, 1, 2), h).reshape(4, 2),
                                         axis=1))
    assert np.sqrt(np.mean(np.concatenate(errors) ** 2)) < 0.5  # OpenCV's unrefined corners: ~0.9 px


@needs_photos
def test_published_corner_order_without_the_fix_is_refused(tmp_path, capsys):
    # 31-38 px, 21 mm on the table: an error in the marker list, not a poor camera; nothing is written
    markers, _ = _markers(tmp_path, shift_marker1=False)
    code, stdout, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", markers, "--out",
                                tmp_path / "p.json", "--json", capsys=capsys)
    assert code == 2 and stdout == "" and not (tmp_path / "p.json").exists()
    assert "px RMS reprojection" in err and "marker 1:" in err and "--accept-poor-fit" in err
    assert "Traceback" not in err


@needs_photos
@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_a_marker_listed_in_another_corner_order_is_named(tmp_path, capsys, with_intrinsics):
    markers, ref = _markers(tmp_path, shift_marker1=False)  # the published list, marker 1 one corner off
    k = np.array(ref["camera_matrix_realsense_sdk"])
    extra = ["--camera-matrix", f"{k[0, 0]},{k[1, 1]},{k[0, 2]},{k[1, 2]}"] if with_intrinsics else []
    code, stdout, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", markers, "--out",
                                tmp_path / "p.json", *extra, "--accept-poor-fit", capsys=capsys)
    res = json.loads(stdout)
    assert code == 0 and res["residual_mm"] > 5.0  # written when the user says so, but not silently:
    assert any("fit badly" in w for w in res["warnings"]) and "fit badly" in err
    named = [w for w in res["warnings"] if w.startswith("marker ")]
    assert len(named) == 1 and named[0].startswith("marker 1:")
    assert "as listed" in named[0] and "read from its 2nd listed corner (index 1); check the corner order" in named[0]
    assert res["per_marker_residual_mm"]["1"] > 20 * res["per_marker_residual_mm"]["0"]
    saved = json.loads((tmp_path / "p.json").read_text())["report"]
    assert saved["warnings"] == res["warnings"]
    # with the fix there is nothing to warn about, in both frames
    markers, _ = _markers(tmp_path)
    for image in ("aruco_img.png", "aruco_img2.png"):
        code, stdout, err = run_cli("calibrate", "plane", FESTO / image, "--markers", markers, "--out",
                                    tmp_path / "p.json", *extra, capsys=capsys)
        res = json.loads(stdout)
        assert code == 0 and res["warnings"] == [] and err == ""
        assert max(res["per_marker_residual_mm"].values()) < 1.0


@needs_photos
def test_a_marker_seen_twice_is_left_out(tmp_path, capsys):
    import cv2

    from calibration.plane import detect_markers

    frame = cv2.imread(str(FESTO / "aruco_img.png"))
    corners = detect_markers(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), "DICT_4X4_50")[2]
    (x0, y0), (x1, y1) = (corners.min(0) - 15).astype(int), (corners.max(0) + 15).astype(int)
    copy = frame.copy()
    copy[100:100 + y1 - y0, 900:900 + x1 - x0] = frame[y0:y1, x0:x1]  # a second marker 2, elsewhere
    path = tmp_path / "two_of_marker_2.png"
    cv2.imwrite(str(path), copy)
    markers, _ = _markers(tmp_path)
    code, stdout, err = run_cli("calibrate", "plane", path, "--markers", markers, "--out", tmp_path / "p.json",
                                capsys=capsys)
    res = json.loads(stdout)  # the last copy found used to be taken as the marker at the known place
    assert code == 0 and res["markers_used"] == [0, 1, 3] and res["markers_duplicated"] == [2]
    assert res["markers_missing"] == [] and "seen more than once" in err and res["residual_mm"] < 1.0


@needs_photos
def test_markers_missing_from_the_image_are_skipped_and_reported(tmp_path, capsys):
    extra = {"7": [[0, 0, 0], [40, 0, 0], [40, 40, 0], [0, 40, 0]]}
    markers, _ = _markers(tmp_path, extra=extra)
    code, stdout, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", markers, "--out",
                                tmp_path / "p.json", capsys=capsys)
    res = json.loads(stdout)
    assert code == 0 and res["markers_missing"] == [7] and res["markers_used"] == [0, 1, 2, 3]
    assert "7" in err


@needs_photos
def test_fewer_than_three_markers_is_bad_input(tmp_path, capsys):
    ref = json.loads((FESTO / "published_reference.json").read_text())
    m = {k: ref["marker_corners_robot_frame_mm"][k] for k in ("0", "2")}
    p = tmp_path / "m.json"
    p.write_text(json.dumps({"dictionary": "DICT_4X4_50", "markers": m}))
    code, _, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", p, "--out",
                           tmp_path / "p.json", capsys=capsys)
    assert code == 2 and err == f"cell: error: --markers {p} lists only 2 markers ([0, 2]); at least 3 are needed\n"
    assert not (tmp_path / "p.json").exists()


@needs_photos
def test_markers_in_a_mirrored_frame_give_no_calibration(tmp_path, capsys):
    """Base coordinates given y down (a board's own frame) fit a camera under the table looking up: it
    was written and mapped pixels; now it is refused and nothing is written."""
    markers, ref = _markers(tmp_path)
    m = json.loads(markers.read_text())
    m["markers"] = {key: [[x, -y, z] for x, y, z in corners] for key, corners in m["markers"].items()}
    markers.write_text(json.dumps(m))
    k = np.array(ref["camera_matrix_realsense_sdk"])
    out = tmp_path / "plane.json"
    code, stdout, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", markers, "--out", out,
                                "--camera-matrix", f"{k[0, 0]},{k[1, 1]},{k[0, 2]},{k[1, 2]}", "--accept-poor-fit",
                                capsys=capsys)
    assert code == 2 and stdout == "" and not out.exists()
    assert "does not look down onto the plane z = 0 mm from above" in err and "mirrored frame, y down" in err


@pytest.mark.parametrize("content, match", [
    ({"dictionary": "DICT_9X9_1", "markers": {"0": [[0, 0, 0]] * 4}}, "unknown ArUco dictionary"),
    ({"dictionary": "DICT_4X4_50", "markers": {"0": [[0, 0]] * 4}}, "4 points"),
    ({"dictionary": "DICT_4X4_50", "markers": {"x": [[0, 0, 0]] * 4}}, "not an integer"),
    # true taken for 1.0: the frame was calibrated (52 mm residual) and exit 0
    ({"dictionary": "DICT_4X4_50", "markers": {"0": [[True, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}},
     "true/false and strings are not numbers"),
    # numbers written as strings: numpy read "0" as 0.0 and the frame was calibrated, exit 0
    ({"dictionary": "DICT_4X4_50", "markers": {"0": [["0", "0", "0"], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}},
     "true/false and strings are not numbers"),
    ({"dictionary": "DICT_4X4_50", "markers": {"0": [[5, 5, 0]] * 4}}, "its corners enclose 0 mm2"),
    # ids the dictionary has not: they could never be detected and were reported as 'not found'
    *[({"dictionary": "DICT_4X4_50", "markers": {mid: [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}},
       f"marker id {mid} is not in DICT_4X4_50 (ids 0..49)") for mid in ("-1", "50", "99999999999999999999")],
    ("{not json", "not valid JSON"),
    # an integer no float holds was an internal error (OverflowError); 1e300 mm is no place in the cell
    ('{"dictionary": "DICT_4X4_50", "markers": {"0": [[1%s, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}}' % ("0" * 400),
     "corners must be 4 points [x, y, z] in mm of finite numbers (one is too large)"),
    ({"dictionary": "DICT_4X4_50", "markers": {"0": [[1e300, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}},
     "within 1e+06 mm of the base"),
    # was: "corners must be 4 points [x, y, z] in mm, got shape (4, 3)" (the shape is right)
    ('{"dictionary": "DICT_4X4_50", "markers": {"0": [[NaN, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}}',
     "marker 0: corners must be finite numbers (mm), got NaN"),
    ('{"dictionary": "DICT_4X4_50", "markers": {"0": [[0, 0, 0], [1, 0, 0], [1, 1, -Infinity], [0, 1, 0]]}}',
     "marker 0: corners must be finite numbers (mm), got -Infinity"),
    ({"dictionary": "DICT_4X4_50", "markers": {"x" * 1000: [[0, 0, 0]] * 4}},
     "marker id '" + "x" * 36 + "... is not an integer"),
    # "0" and "00" are one marker: one of the two was silently dropped
    ({"dictionary": "DICT_4X4_50", "markers": {"0": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                                               "00": [[5, 0, 0], [6, 0, 0], [6, 1, 0], [5, 1, 0]]}},
     "marker id '00' names marker 0 a second time"),
])
@needs_photos
def test_bad_markers_files(tmp_path, capsys, content, match):
    p = tmp_path / "m.json"
    p.write_text(content if isinstance(content, str) else json.dumps(content))
    code, _, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", p, "--out",
                           tmp_path / "p.json", capsys=capsys)
    assert code == 2 and match in err


@needs_photos
def test_out_that_cannot_be_written_is_bad_input(tmp_path, capsys):
    markers, _ = _markers(tmp_path)
    blocker = tmp_path / "file"
    blocker.write_text("")
    for out in (tmp_path, blocker / "p.json"):  # a directory; a path under a plain file
        code, stdout, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", markers, "--out",
                                    out, capsys=capsys)
        assert code == 2 and stdout == "" and err.count("\n") == 1
        assert err.startswith(f"cell: error: --out {out}") and "Traceback" not in err  # before the fit, not after
    code, _, err = run_cli("calibrate", "intrinsics", *sorted((EXTERNAL / "opencv-chessboard").glob("left0*.jpg")),
                           "--pattern", "9x6", "--square", "1", "--out", tmp_path, capsys=capsys)
    assert code == 2 and err == f"cell: error: --out {tmp_path} is a directory, not a file\n"


def test_touched_points_recover_the_default_camera(tmp_path, capsys):
    """Points touched with the gripper on a plane at z = 15: the pose comes back, residual tiny."""
    truth = load_calibration()
    rng = np.random.default_rng(3)
    xy = rng.uniform([210, -240], [490, 240], size=(12, 2))
    uv = truth.mm_to_px(xy, 15.0) + rng.normal(0, 0.1, size=(12, 2))  # click noise, 0.1 px
    cal = fit_plane_mapping(uv, np.column_stack([xy, np.full(12, 15.0)]), truth.size, truth.camera_matrix,
                            truth.dist)
    assert cal.report["residual_mm"] < 0.1
    grid = np.array([[300.0, -100.0], [450.0, 200.0]])
    assert np.abs(cal.px_to_mm(truth.mm_to_px(grid, 0.0), 0.0) - grid).max() < 0.3  # another height too
    pts = tmp_path / "points.json"
    pts.write_text(json.dumps({"points": [{"px": list(a), "mm": [b[0], b[1], 15.0]} for a, b in zip(uv, xy)]}))
    frame = tmp_path / "frame.png"
    import cv2

    cv2.imwrite(str(frame), np.zeros((1024, 1280, 3), np.uint8))
    code, stdout, _ = run_cli("calibrate", "plane", frame, "--points", pts, "--intrinsics",
                              DEFAULT, "--out", tmp_path / "c.json", capsys=capsys)
    assert code == 0 and json.loads(stdout)["residual_mm"] < 0.1


def _points_15mm_up(tmp_path):
    """A blank frame, 12 points 15 mm over the tray as the default camera sees them, their xy (mm) and its focal
    length (px)."""
    import cv2

    truth = load_calibration()
    xy = np.random.default_rng(3).uniform([210, -240], [490, 240], size=(12, 2))
    uv = truth.mm_to_px(xy, 15.0)
    pts = tmp_path / "points.json"
    pts.write_text(json.dumps({"points": [{"px": list(a), "mm": [b[0], b[1], 15.0]} for a, b in zip(uv, xy)]}))
    frame = tmp_path / "frame.png"
    cv2.imwrite(str(frame), np.zeros((1024, 1280, 3), np.uint8))
    return frame, pts, xy, float(truth.camera_matrix[0, 0])


def test_a_focal_length_a_digit_short_is_warned_about(tmp_path, capsys):
    """fx 160 px for a 1280 px image (the default camera's is about 1000): a 152 degree view. The plane fit can
    follow it with a camera 10 x too close, and nothing else would say so."""
    frame, pts, xy, fx = _points_15mm_up(tmp_path)
    for matrix, warned in ((f"{fx / 10:g},{fx / 10:g},640,512", True), (f"{fx:g},{fx:g},640,512", False)):
        code, out, err = run_cli("calibrate", "plane", frame, "--points", pts, "--camera-matrix", matrix,
                                 "--out", tmp_path / f"c{warned}.json", "--accept-poor-fit", capsys=capsys)
        assert code == 0, err
        says = [w for w in json.loads(out).get("warnings", []) if "field of view" in w]
        assert bool(says) is warned and ("is a digit missing?" in err) is warned


def test_intrinsics_for_another_resolution_are_warned_about(tmp_path, capsys):
    """The full frame's camera matrix given for a half-size image puts its principal point at the image's corner:
    taken without a word, it put the camera twice as high and `cell map` 3 mm off. A principal point outside the
    image, or far off its centre (as `calibrate intrinsics` warns), is named; the image's own is not."""
    frame, pts, xy, fx = _points_15mm_up(tmp_path)
    for centre, warned in (("1300,1023.5", "outside the image"), ("900,512", "20% / 0% of the image's size off"),
                           ("640,512", None)):
        code, out, err = run_cli("calibrate", "plane", frame, "--points", pts, "--camera-matrix", f"{fx:g},{fx:g},"
                                 f"{centre}", "--out", tmp_path / f"c{centre}.json", "--accept-poor-fit", capsys=capsys)
        assert code == 0, err
        says = [w for w in json.loads(out).get("warnings", []) if "principal point" in w]
        if warned is None:
            assert says == []
        else:
            assert len(says) == 1 and warned in says[0] and "intrinsics for another resolution?" in err


def test_a_focal_length_a_digit_too_long_is_warned_about_by_the_camera_distance(tmp_path, capsys):
    """fx 16000 px for a 1280 px image: the fit follows it with the camera 10 x too far, 8 m over the tray, and
    only a focal length too short (a view over 120 degrees) was warned about. A camera more than 3 m from the
    points is named; the default camera, 0.8 m over them, is not."""
    frame, pts, xy, fx = _points_15mm_up(tmp_path)
    for scale, warned in ((10, True), (1, False)):
        matrix = f"{fx * scale:g},{fx * scale:g},640,512"
        code, out, err = run_cli("calibrate", "plane", frame, "--points", pts, "--camera-matrix", matrix,
                                 "--out", tmp_path / f"c{warned}.json", capsys=capsys)
        assert code == 0, err
        res = json.loads(out)
        says = [w for w in res.get("warnings", []) if "from the points" in w]
        assert bool(says) is warned and ("a digit too long?" in err) is warned, err
        distance = np.linalg.norm(np.subtract(res["camera_position_mm"], [*xy.mean(axis=0), 15.0]))
        assert res["camera_distance_mm"] == pytest.approx(distance, abs=0.01)
        if warned:
            assert distance > 7000 and f"{distance:.0f} mm" in says[0] and "more than 3000 mm" in says[0]


@needs_photos
@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_points_a_few_mm_off_one_plane_fit_their_mean_plane_with_a_warning(tmp_path, capsys, with_intrinsics):
    """Coordinates touched up with a robot differ in z by a few mm: they were refused as 'not on one
    horizontal plane' beyond 1 mm (and the planar pose solver cannot take them). Up to 5 mm they fit
    the mean plane, with the pose close to the truth and a warning; beyond, a tilted fixture fits its own
    tilted plane (it was refused), with no mean-plane warning."""
    truth = load_calibration()
    rng = np.random.default_rng(5)
    xy = rng.uniform([210, -240], [490, 240], size=(16, 2))
    z = 10.0 + rng.uniform(-1.5, 1.5, size=16)  # 3 mm of spread about z = 10
    uv = truth.project(np.column_stack([xy, z]))
    frame = tmp_path / "frame.png"
    import cv2

    cv2.imwrite(str(frame), np.zeros((1024, 1280, 3), np.uint8))
    extra = ["--intrinsics", DEFAULT] if with_intrinsics else []
    for name, zs, ok in (("spread", z, True), ("tilted", 10.0 + (xy[:, 1] + 240) * 0.02, False)):
        pts = tmp_path / f"{name}.json"
        pts.write_text(json.dumps({"points": [{"px": list(a), "mm": [b[0], b[1], c]}
                                              for a, b, c in zip(uv.tolist(), xy.tolist(), zs.tolist())]}))
        code, out, err = run_cli("calibrate", "plane", frame, "--points", pts, *extra,
                                 "--out", tmp_path / f"{name}-cal.json", capsys=capsys)
        if not ok:  # 9.6 mm from one side of the tray to the other: the points' own plane, 1.15 deg
            res = json.loads(out)
            assert code == 0 and res["plane_z_mm"] is None and res["tilt_deg"] == pytest.approx(1.146, abs=0.01)
            assert not res.get("warnings") and err == "" and res["off_plane_max_mm"] < 1e-9
            continue
        res = json.loads(out)
        assert code == 0 and abs(res["plane_z_mm"] - float(z.mean())) < 1e-9
        assert f"z spans {np.ptp(z):.1f} mm" in err and any("mean plane" in w for w in res["warnings"])
        assert res["residual_mm"] < 1.0  # 1.5 mm off the plane moves a point < 0.6 mm at the tray's edge
        if with_intrinsics:
            assert np.linalg.norm(np.subtract(res["camera_position_mm"], truth.camera_position_mm())) < 3.0


def test_touched_points_with_true_for_a_number_are_bad_input(tmp_path, capsys):
    pts = tmp_path / "points.json"
    good = [{"px": [100.0 * i, 50.0 * i * i], "mm": [10.0 * i, 7.0 * i * i, 0.0]} for i in range(1, 6)]
    pts.write_text(json.dumps({"points": good[:4] + [{"px": [True, 3.0], "mm": [1.0, 2.0, 0.0]}]}))
    code, _, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--points", pts,
                           "--out", tmp_path / "c.json", capsys=capsys)
    assert code == 2 and "point #4" in err and "true/false" in err
    assert not (tmp_path / "c.json").exists()


@needs_photos
@pytest.mark.parametrize("px, mm", [
    (lambda i: [100 * i, 100 * i], lambda i: [10 * i, 10 * i, 0]),       # all on one line: was exit 0, 6.6 mm
    (lambda i: [100, 100], lambda i: [10 * i, 5 * i * i, 0]),            # one pixel
    (lambda i: [100 * i, 40 * i * i], lambda i: [0, 0, 0]),              # one base point (pixels in the frame)
])
@pytest.mark.parametrize("with_intrinsics", [True, False])
def test_points_on_a_line_are_bad_input(tmp_path, capsys, px, mm, with_intrinsics):
    pts = tmp_path / "points.json"
    pts.write_text(json.dumps({"points": [{"px": px(i), "mm": mm(i)} for i in range(1, 6)]}))
    extra = ["--camera-matrix", "1393.77,1393.14,956.754,545.3"] if with_intrinsics else []
    code, out, err = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--points", pts,
                             "--out", tmp_path / "c.json", *extra, capsys=capsys)
    assert code == 2 and out == "" and "lie on one line" in err
    assert not (tmp_path / "c.json").exists()


def _linear_points(uvs):
    """Pixel / base pairs of one exact linear mapping (0.1 mm a pixel, as a camera looking down sees the base
    frame: v against y): any subset fits to nothing."""
    return {"points": [{"px": [u, v], "mm": [200 + u / 10, 50 - v / 10, 0]} for u, v in uvs]}


INSIDE = [(50 + 100 * i, 40 + 80 * j) for i in range(3) for j in range(3)]


@pytest.mark.parametrize("px", [(-50, 40), (50, -0.5), (640.5, 40), (50, 481), (-1e3, 1e4)])
def test_touched_points_outside_the_image_are_bad_input(tmp_path, capsys, px):
    """A pixel outside the frame cannot be where a touched point was seen; it fitted (exit 0, the file written)
    when it lay on the same mapping as the others."""
    import cv2

    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((480, 640, 3), np.uint8))
    pts = tmp_path / "points.json"
    pts.write_text(json.dumps(_linear_points(INSIDE + [px])))
    code, out, err = run_cli("calibrate", "plane", tmp_path / "f.png", "--points", pts,
                             "--out", tmp_path / "c.json", capsys=capsys)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and "internal error" not in err, err
    assert f"point #9 'px' [{px[0]:g}, {px[1]:g}] lies outside the image {tmp_path / 'f.png'} (640 x 480 px" in err
    assert not (tmp_path / "c.json").exists()


def test_touched_points_on_the_image_border_are_accepted(tmp_path, capsys):
    """The frame covers [0, w] x [0, h] (CONTRACT: origin at the top-left pixel's top-left corner)."""
    import cv2

    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((480, 640, 3), np.uint8))
    pts = tmp_path / "points.json"
    pts.write_text(json.dumps(_linear_points(INSIDE + [(0, 0), (640, 0), (0, 480), (640, 480), (320, 480)])))
    code, out, err = run_cli("calibrate", "plane", tmp_path / "f.png", "--points", pts,
                             "--out", tmp_path / "c.json", capsys=capsys)
    assert code == 0, err
    assert json.loads(out)["points"] == 14 and (tmp_path / "c.json").exists()


def test_map_cli_both_ways_with_negative_coordinates(capsys):
    code, stdout, _ = run_cli("map", DEFAULT, "--mm", "350,-120.5", "-0,0", "--z", "10",
                              "--json", capsys=capsys)
    assert code == 0
    px = json.loads(stdout)["px"]
    code, stdout, _ = run_cli("map", DEFAULT, "--px", *[f"{u},{v}" for u, v in px],
                              "--z", "10", "--json", capsys=capsys)
    assert np.allclose(json.loads(stdout)["mm"], [[350, -120.5], [0, 0]], atol=1e-3)
    # negative values in scientific notation are values too (argparse took "-1.205e2" for an option)
    code, stdout, err = run_cli("map", DEFAULT, "--mm", "3.5e2,-1.205e2", "-1e2,5", "--z", "10", "--json",
                                capsys=capsys)
    assert code == 0, err
    assert np.allclose(json.loads(stdout)["px"][0], px[0], atol=1e-6)


@pytest.mark.parametrize("args, match", [
    (["--px", "1,2,3"], "two numbers"),
    (["--px", "a,b"], "two numbers"),
    (["--px", "1" * 100000 + ",x"], "two numbers A,B (got '" + "1" * 36 + "...)"),  # was all 100 kB of it
    (["--mm", "1,nan"], "finite"),
    (["--px", "1,2", "--z", "nan"], "--z must be a finite number"),
    (["--px", "1,2", "--z", "inf"], "--z must be a finite number"),
])
def test_map_cli_bad_points(capsys, args, match):
    code, _, err = run_cli("map", DEFAULT, *args, "--json", capsys=capsys)
    assert code == 2 and match in err


def test_map_cli_missing_calibration(tmp_path, capsys):
    code, _, err = run_cli("map", tmp_path / "none.json", "--px", "1,2", capsys=capsys)
    assert code == 2 and "does not exist" in err


@pytest.mark.parametrize("way", ["--px", "--mm"])
def test_map_cli_refuses_a_plane_at_or_above_the_camera(capsys, way):
    """The default camera is 800 mm up: --z 799.9999 (its height as a calibration prints it, rounded) mapped every
    pixel to the camera's own x, y (350, 0), exit 0; --mm gave pixels thousands of px off. A plane within 10 mm
    of the camera's optical centre (inside its lens) or above it is refused, saying how high the camera is."""
    point = "640,512" if way == "--px" else "350,0"
    for z in ("799.9999", "800", "795", "5000"):
        code, out, err = run_cli("map", default_calibration_path(), way, point, "--z", z, "--json", capsys=capsys)
        assert code == 2 and out == "" and err.count("\n") == 1, (z, err)
        assert "the camera's optical centre is at z = 800 mm" in err and "Traceback" not in err
    code, out, err = run_cli("map", default_calibration_path(), way, point, "--z", "700", "--json", capsys=capsys)
    assert code == 0, err


@needs_photos
def test_no_holdout_with_three_markers(tmp_path, capsys):
    markers, ref = _markers(tmp_path)
    m = json.loads(markers.read_text())
    del m["markers"]["3"]
    markers.write_text(json.dumps(m))
    code, stdout, _ = run_cli("calibrate", "plane", FESTO / "aruco_img.png", "--markers", markers, "--out",
                              tmp_path / "p.json", capsys=capsys)
    res = json.loads(stdout)
    assert code == 0 and res["markers_used"] == [0, 1, 2]
    assert res["holdout_residual_mm"] == {} and res["holdout_residual_max_mm"] is None


def test_touched_points_with_one_wrong_pair_say_a_pair_is_wrong(tmp_path, capsys):
    """One pair far off the others' mapping bends the homography until its horizon runs through the points.
    The message was "some points lie beyond the plane's horizon (not on the plane in front of the camera)",
    which says nothing of what to fix."""
    import cv2

    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((480, 640, 3), np.uint8))
    pts = _linear_points(INSIDE)
    pts["points"].append({"px": [640, 0], "mm": [0, 0, 0]})  # the mapping puts (640, 0) at (264, -50)
    (tmp_path / "points.json").write_text(json.dumps(pts))
    code, out, err = run_cli("calibrate", "plane", tmp_path / "f.png", "--points", tmp_path / "points.json",
                             "--out", tmp_path / "c.json", capsys=capsys)
    assert code == 2 and out == "" and not (tmp_path / "c.json").exists()
    assert "the 10 points fit no view of one plane" in err and "a pixel or a base coordinate is wrong" in err, err


@needs_photos
@pytest.mark.parametrize("image", ["aruco_img.png", "aruco_img2.png"])
def test_markers_of_a_defocused_frame_are_all_found_and_fit_as_sharp(tmp_path, capsys, image):
    """The Festo frames out of focus (Gaussian blur, sigma 2.5 - 3 px at 1920 x 1080: markers of about
    77 px, 13 px a bit cell). OpenCV's default bit sampling reads each cell up to 0.13 of its side from
    its edges, where the blur mixes in the neighbouring cells: marker 0 went unread in both frames, so
    the calibration used 3 markers (held out 1.2 - 1.6 mm off at marker 0's centre) or, one more lost,
    refused the frame. All four are read now and fit as the sharp frame does."""
    import cv2

    markers, ref = _markers(tmp_path)
    sharp = tmp_path / "sharp.json"
    assert run_cli("calibrate", "plane", FESTO / image, "--markers", markers, "--out", sharp, capsys=capsys)[0] == 0
    for sigma in (2.5, 3.0):
        blurred = tmp_path / f"blur{sigma}.png"
        cv2.imwrite(str(blurred), cv2.GaussianBlur(cv2.imread(str(FESTO / image)), (0, 0), sigma))
        out = tmp_path / f"plane{sigma}.json"
        code, stdout, _ = run_cli("calibrate", "plane", blurred, "--markers", markers, "--out", out, capsys=capsys)
        assert code == 0
        res = json.loads(stdout)
        assert res["markers_used"] == [0, 1, 2, 3], sigma
        assert res["residual_mm"] < 1.0  # blurred corners: 0.69 - 0.96 mm against 0.51 - 0.53 sharp
        # the marker centres (and every table point between them) land where the sharp frame puts them:
        # 0.01 - 0.39 mm off
        centres = [np.mean(c, axis=0)[:2] for c in json.loads(markers.read_text())["markers"].values()]
        uv = load_calibration(sharp).mm_to_px(np.array(centres))
        assert np.hypot(*(load_calibration(out).px_to_mm(uv) - centres).T).max() < 0.5, sigma


@needs_photos
@pytest.mark.parametrize("image", ["aruco_img.png", "aruco_img2.png"])
def test_markers_of_a_dim_flat_frame_are_all_found_and_fit_as_the_original(tmp_path, capsys, image):
    """The Festo frames at half their contrast and a third of their exposure down to a tenth (a dim
    cell, a camera set too short: grey 23-54 at most). OpenCV's marker detection thresholds in absolute
    grey levels: 3 and 2 of the 4 markers were read at a third of the exposure, none below, and the
    plane was fitted through 3 or refused. Read again with the grey levels stretched, all four fit as the
    original frame does."""
    import cv2

    markers, _ = _markers(tmp_path)
    sharp = tmp_path / "original.json"
    assert run_cli("calibrate", "plane", FESTO / image, "--markers", markers, "--out", sharp, capsys=capsys)[0] == 0
    original = cv2.imread(str(FESTO / image)).astype(np.float32)
    for exposure in (0.35, 0.25, 0.1):
        dim = tmp_path / f"dim{exposure}.png"
        cv2.imwrite(str(dim), np.clip(((original - 128) * 0.5 + 128) * exposure, 0, 255).astype(np.uint8))
        out = tmp_path / f"plane{exposure}.json"
        code, stdout, _ = run_cli("calibrate", "plane", dim, "--markers", markers, "--out", out, capsys=capsys)
        assert code == 0, exposure
        res = json.loads(stdout)
        assert res["markers_used"] == [0, 1, 2, 3], exposure
        assert res["residual_mm"] < 1.0
        centres = [np.mean(c, axis=0)[:2] for c in json.loads(markers.read_text())["markers"].values()]
        uv = load_calibration(sharp).mm_to_px(np.array(centres))
        assert np.hypot(*(load_calibration(out).px_to_mm(uv) - centres).T).max() < 0.5, exposure


def test_a_frame_with_the_full_range_of_grey_is_not_read_a_third_time():
    """The stretched reading is for dim or flat frames only: a frame spanning the grey levels is read as before."""
    from calibration import plane

    ramp = np.tile(np.linspace(0, 255, 400).astype(np.uint8), (300, 1))
    assert plane._stretched_if_flat(ramp) is None
    flat = (ramp // 8 + 20).astype(np.uint8)  # grey 20-51
    stretched = plane._stretched_if_flat(flat)
    assert stretched.min() <= 2 and stretched.max() >= 253
    assert plane._stretched_if_flat(np.full((10, 10), 7, np.uint8)) is None  # one grey level: nothing to stretch


def test_the_second_reading_takes_no_marker_the_first_read_under_another_id(monkeypatch):
    """The middle-of-the-cells reading (for out-of-focus frames) adds ids the first reading missed. A marker
    the first read as 3 and the second misread as 4 (were 4 listed but not in view) must not come back as
    marker 4 at marker 3's place: the plane would be fitted through a wrong point."""
    import cv2

    from calibration import plane

    image = np.full((300, 300), 255, np.uint8)
    image[90:210, 90:210] = cv2.aruco.generateImageMarker(plane.aruco_dictionary("DICT_4X4_50"), 3, 120)
    detector = cv2.aruco.ArucoDetector

    class MisreadingInTheMiddle:
        def __init__(self, dictionary, params):
            self.det, self.second = detector(dictionary, params), params.perspectiveRemoveIgnoredMarginPerCell > 0.2

        def detectMarkers(self, gray):
            c, ids, rejected = self.det.detectMarkers(gray)
            return c, (ids + 1 if self.second and ids is not None else ids), rejected

    monkeypatch.setattr(cv2.aruco, "ArucoDetector", MisreadingInTheMiddle)
    found = plane.detect_markers(image, "DICT_4X4_50")
    assert list(found) == [3]
