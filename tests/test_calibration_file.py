"""The calibration model and file: round trips, heights, validation, the default cell's camera."""

import json
import re

import numpy as np
import pytest
from conftest import run_cli

from calibration import Calibration, default_calibration_path, load_calibration, save_calibration
from calibration.calfile import calibration_to_json
from calibration.default import default_cell_calibration
from cell.errors import BadInput


@pytest.fixture(scope="module")
def cal():
    return load_calibration()


@pytest.mark.parametrize("z_mm", [0.0, 12.5, 40.0])
def test_mm_px_mm_round_trip(cal, z_mm):
    rng = np.random.default_rng(7)
    xy = rng.uniform([120, -300], [580, 300], size=(500, 2))
    uv = cal.mm_to_px(xy, z_mm)
    assert np.abs(cal.px_to_mm(uv, z_mm) - xy).max() < 1e-6


def test_px_mm_px_round_trip_over_the_whole_image(cal):
    rng = np.random.default_rng(8)
    uv = rng.uniform([0, 0], [cal.width_px, cal.height_px], size=(500, 2))
    assert np.abs(cal.mm_to_px(cal.px_to_mm(uv, 20.0), 20.0) - uv).max() < 1e-6


def test_lens_distortion_is_handled(cal):
    # a straight line on the table bends in the image (barrel distortion), and maps back straight
    xy = np.column_stack([np.full(50, 110.0), np.linspace(-300, 300, 50)])
    uv = cal.mm_to_px(xy)
    chord = np.polyfit(uv[:, 0], uv[:, 1], 1)
    assert np.abs(np.polyval(chord, uv[:, 0]) - uv[:, 1]).max() > 1.0  # visibly curved in pixels
    back = cal.px_to_mm(uv)
    assert np.abs(back[:, 0] - 110.0).max() < 1e-6
    ideal = cal.undistort_px(uv)
    fit = np.polyfit(ideal[:, 0], ideal[:, 1], 1)
    assert np.abs(np.polyval(fit, ideal[:, 0]) - ideal[:, 1]).max() < 1e-6


def test_parallax_part_tops_map_differently(cal):
    # a pixel near the image corner sees the table and a 30 mm high part top at different x, y
    uv = [[60.0, 60.0]]
    d = np.linalg.norm(cal.px_to_mm(uv, 0.0) - cal.px_to_mm(uv, 30.0))
    assert d > 8.0
    centre = [cal.vertical_vanishing_px()]
    assert np.linalg.norm(cal.px_to_mm(centre, 0.0) - cal.px_to_mm(centre, 30.0)) < 1e-6


def test_default_cell_camera_matches_the_contract(cal):
    assert (cal.width_px, cal.height_px) == (1280, 1024)
    assert cal.mm_per_px() == pytest.approx(0.5, abs=0.01)
    assert 780 < cal.camera_position_mm()[2] < 820
    tray = np.array([[200, -250], [500, -250], [500, 250], [200, 250]], float)
    uv = cal.mm_to_px(tray)
    assert np.all((uv > 20) & (uv < [cal.width_px - 20, cal.height_px - 20]))
    # the image's long side (u) runs along the tray's long side (y)
    span = uv.max(axis=0) - uv.min(axis=0)
    assert span[0] > span[1]
    assert np.ptp(cal.mm_to_px([[350, -250], [350, 250]])[:, 0]) > 900


def test_shipped_file_equals_the_nominal_values():
    shipped = json.loads(default_calibration_path().read_text())
    assert shipped == json.loads(json.dumps(calibration_to_json(default_cell_calibration())))


def test_save_load_round_trip(tmp_path, cal):
    path = tmp_path / "sub" / "cal.json"
    save_calibration(cal, path)
    again = load_calibration(path)
    uv = np.array([[10.0, 20.0], [640.0, 512.0], [1270.0, 1000.0]])
    assert np.allclose(again.px_to_mm(uv, 15.0), cal.px_to_mm(uv, 15.0), atol=1e-9)
    assert [p.name for p in path.parent.iterdir()] == ["cal.json"]  # no temp file left behind
    assert json.loads(path.read_text())["format"] == "disassembly-cell/calibration"


def test_homography_only_refuses_other_heights():
    h = np.array([[0.5, 0, 100], [0, 0.5, -200], [0, 0, 1.0]])
    cal = Calibration(640, 480, homography=h, plane_z_mm=5.0, name="h")
    assert np.allclose(cal.px_to_mm([[10, 20]]), [[105, -190]])
    assert np.allclose(cal.mm_to_px(cal.px_to_mm([[10, 20]])), [[10, 20]])
    with pytest.raises(BadInput, match="homography for the plane z = 5.0"):
        cal.px_to_mm([[10, 20]], 0.0)


def _write(tmp_path, obj, name="c.json"):
    p = tmp_path / name
    p.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return p


def test_missing_file_is_refused(tmp_path):
    with pytest.raises(BadInput, match="does not exist"):
        load_calibration(tmp_path / "nope.json")


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(format="something else"), "'format' must be"),
    (lambda d: d.update(version=99), "version 99 is not supported"),
    (lambda d: d["image"].update(width_px=-3), "image.width_px must be a positive integer"),
    (lambda d: d["intrinsics"].update(fx="big"), "intrinsics.fx must be a finite number"),
    (lambda d: d["intrinsics"].update(dist=[1, 2, 3]), "intrinsics.dist must be a list"),
    (lambda d: d["pose"]["cam2base"][0].__setitem__(0, 3.0), "not a rotation matrix"),
    (lambda d: d["pose"].update(cam2base=[[1, 0], [0, 1]]), "pose.cam2base must be a 4 x 4"),
    (lambda d: d.update(intrinsics=None, pose=None), "neither 'intrinsics' nor 'homography'"),
])
def test_malformed_files_are_refused(tmp_path, mutate, match):
    d = json.loads(default_calibration_path().read_text())
    mutate(d)
    with pytest.raises(BadInput, match=match):
        load_calibration(_write(tmp_path, d))


BIG_INT = "1" + "0" * 400  # an integer no float holds


@pytest.mark.parametrize("mutate, match", [
    # each was an internal error (OverflowError) or refused as a distortion that 'folds the image'
    (lambda d: d["intrinsics"].update(fx="BIG"), "intrinsics.fx must be a finite number"),
    (lambda d: d["pose"]["cam2base"][0].__setitem__(3, "BIG"), "pose.cam2base must be a 4 x 4 list of numbers"),
    (lambda d: d["homography"].update(px_to_mm=[[1, 0, 0], [0, 1, 0], [0, 0, "BIG"]]),
     "homography.px_to_mm must be a 3 x 3 list of numbers"),
    (lambda d: d["image"].update(width_px=10**9), "image 1000000000 x 1024 px: each side at least 16 px"),
    (lambda d: d["image"].update(height_px=8), "each side at least 16 px"),
    (lambda d: d["intrinsics"].update(fx=1e300), "fx and fy must be between 1 and 1e+06 px"),
    (lambda d: d["intrinsics"].update(fy=1e-300), "fx and fy must be between 1 and 1e+06 px"),
    (lambda d: d["intrinsics"].update(cx=1e200), "intrinsics.cx = 1e+200 px is not near the 1280 px image"),
    (lambda d: d["intrinsics"].update(skew=1e9), "intrinsics.skew = 1e+09 px: at most fx"),
    (lambda d: d["pose"]["cam2base"][1].__setitem__(3, 1e200), "position and plane_z_mm must be within 1e+06 mm"),
    (lambda d: d["pose"].update(plane_z_mm=-1e7), "position and plane_z_mm must be within 1e+06 mm"),
    # a camera under the table; one turned to look up (x and z axes flipped: still a rotation)
    (lambda d: d["pose"]["cam2base"][2].__setitem__(3, -800.0), "the camera at z = -800 mm"),
    (lambda d: d["pose"].update(cam2base=[[-r[0], r[1], -r[2], r[3]] for r in d["pose"]["cam2base"][:3]]
                                + [[0, 0, 0, 1]]), "does not look down onto the plane z = 0 mm"),
])
def test_out_of_range_files_are_refused_naming_the_key(tmp_path, capsys, mutate, match):
    d = json.loads(default_calibration_path().read_text())
    d["homography"] = {"px_to_mm": [[0.3, 0, 0], [0, 0.3, 0], [0, 0, 1]], "plane_z_mm": 0.0}
    mutate(d)
    path = _write(tmp_path, json.dumps(d).replace('"BIG"', BIG_INT))
    with pytest.raises(BadInput, match=re.escape(match)):
        load_calibration(path)
    code, stdout, err = run_cli("map", path, "--px", "640,512", capsys=capsys)  # the CLI: exit 2, one line
    assert code == 2 and stdout == "" and err.startswith(f"cell: error: calibration file {path}:")
    assert err.count("\n") == 1


def test_a_plane_beyond_the_horizon_names_the_calibration():
    cal = load_calibration()
    with pytest.raises(BadInput, match=r"calibration file \S+default\.json: the plane z = 900 mm is not below the "
                                       r"camera: the camera's optical centre is at z = 800 mm, looking down"):
        cal.px_to_mm([[640, 512]], 900.0)  # above the camera, at 800 mm


def test_not_json_is_refused(tmp_path):
    with pytest.raises(BadInput, match="not valid JSON"):
        load_calibration(_write(tmp_path, '{"format": "disassembly-cell/calibration", '))


def test_other_resolution_is_refused(tmp_path, cal):
    with pytest.raises(BadInput, match="for 1280 x 1024 px images, not 640 x 480"):
        load_calibration(None, size=(640, 480))
    with pytest.raises(BadInput, match="is 640 x 480 px but calibration"):
        cal.check_frame(np.zeros((480, 640, 3), np.uint8))


def test_intrinsics_only_cannot_map():
    cal = Calibration(640, 480, camera_matrix=np.array([[500, 0, 320], [0, 500, 240], [0, 0, 1.0]]))
    with pytest.raises(BadInput, match="intrinsics only"):
        cal.px_to_mm([[1, 2]])


def _homography_file(tmp_path, h, name="h.json"):
    cal = Calibration(640, 480, homography=np.eye(3), name="h")
    d = calibration_to_json(cal)
    d["homography"]["px_to_mm"] = h
    return _write(tmp_path, d, name)


def test_homography_is_validated_whatever_its_scale(tmp_path):
    h = np.array([[0.5, 0, 100], [0, -0.5, 200], [0, 0, 1.0]])
    # a homography times any factor is the same mapping: 1e-6 x h used to be refused as "singular"
    small = load_calibration(_homography_file(tmp_path, (1e-6 * h).tolist()))
    assert np.allclose(small.px_to_mm([[10, 20]]), [[105, 190]])
    # entries near the float limit: det() overflowed to a huge number and the file was accepted
    with pytest.raises(BadInput, match="homography.px_to_mm is singular"):
        load_calibration(_homography_file(tmp_path, [[1e308, 1e308, 0], [0, 1, 0], [0, 0, 1]]))
    with pytest.raises(BadInput, match="true/false and strings are not numbers"):
        load_calibration(_homography_file(tmp_path, [[True, 0, 0], [0, 1, 0], [0, 0, 1]]))
    d = json.loads(default_calibration_path().read_text())
    d["pose"]["cam2base"][3][3] = True
    with pytest.raises(BadInput, match="true/false and strings are not numbers"):
        load_calibration(_write(tmp_path, d))
    d = json.loads(default_calibration_path().read_text())
    d["pose"]["cam2base"] = [[str(v) for v in row] for row in d["pose"]["cam2base"]]  # read as numbers before
    with pytest.raises(BadInput, match="pose.cam2base.*strings are not numbers"):
        load_calibration(_write(tmp_path, d))


def test_map_never_prints_infinity(tmp_path, capsys):
    # a valid homography (y turned over, x 1e307) whose products overflow: used to print {"mm": [[Infinity, ...]]}
    path = _homography_file(tmp_path, (1e307 * np.diag([1.0, -1.0, 1.0])).tolist())
    code, out, err = run_cli("map", path, "--px", "100,100", "--json", capsys=capsys)
    assert code == 2 and out == "" and err.count("\n") == 1 and "infinity or NaN" in err
    code, out, _ = run_cli("map", path, "--px", "0.5,0.25", "--json", capsys=capsys)
    assert code == 0 and json.loads(out, parse_constant=lambda c: pytest.fail(c))["mm"] == [[0.5, -0.25]]


def test_homography_refuses_points_beyond_the_horizon():
    # a tilted view: the plane's horizon is the image line v = -1000 (w = 0 there)
    h = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0.001, 1.0]])
    cal = Calibration(640, 480, homography=h, name="tilted")
    inside = cal.px_to_mm([[10, 20], [600, -900]])
    assert np.allclose(cal.mm_to_px(inside), [[10, 20], [600, -900]])
    assert np.allclose(cal.mm_to_px([[0, -2000]]), [[0, -2000 / 3]])  # far on the plane: still in front
    with pytest.raises(BadInput, match="beyond the plane's horizon"):
        cal.px_to_mm([[10, -2000]])  # used to come back as the point (-10, 2000) on the plane
    with pytest.raises(BadInput, match="beyond the plane's horizon"):
        cal.mm_to_px([[0, 2000]])  # the point it maps to: its "image" (0, -2000) lies beyond the horizon


@pytest.mark.parametrize("px", ["1e300,1e300", "-100000,5", "-641,0", "0,961", "1281,0"])
def test_map_refuses_pixels_more_than_an_image_size_outside_the_image(tmp_path, capsys, px):
    """With a homography (no pose to say a pixel looks past the plane) 1e300,1e300 printed a point
    (-489, -27417) mm, exit 0; -100000,5 too."""
    path = _homography_file(tmp_path, [[0.5, 0, 100], [0, -0.5, 200], [0, 0, 1.0]])
    code, out, err = run_cli("map", path, "--px", "320,240", px, "--json", capsys=capsys)
    assert code == 2 and out == "", err
    assert err.strip() == (f"cell: error: --px {px}: pixels must be within one image size of the calibration's "
                           "640 x 480 px images (u -640..1280, v -480..960)")


def test_map_takes_pixels_up_to_an_image_size_outside_the_image(tmp_path, capsys):
    path = _homography_file(tmp_path, np.diag([1.0, -1.0, 1.0]).tolist())
    code, out, err = run_cli("map", path, "--px", "-640,-480", "1280,960", "--json", capsys=capsys)
    assert code == 0, err
    assert json.loads(out)["mm"] == [[-640, 480], [1280, -960]]


@pytest.mark.parametrize("px, message", [
    ("10,-400", "--px 10,-400: calibration file {path}: some points lie beyond the plane's horizon"),
    ("10,-333.3333", "--px 10,-333.3333: the pixel maps to a point more than 1e+06 mm from the base (at the "
                     "plane's horizon)"),
])
def test_map_refuses_pixels_at_or_beyond_the_homography_horizon(tmp_path, capsys, px, message):
    """A tilted view whose horizon is the image line v = -333.3 (w = 0), inside the bound of an image size."""
    path = _homography_file(tmp_path, [[1.0, 0, 0], [0, -1.0, 0], [0, 0.003, 1.0]])
    code, out, err = run_cli("map", path, "--px", "320,240", px, "--json", capsys=capsys)
    assert code == 2 and out == "" and message.format(path=path) in err and err.count("\n") == 1, err


def test_map_puts_a_plane_the_calibration_cannot_map_on_no_pixel(tmp_path, capsys):
    """A --z the homography has no mapping for fails at every pixel: the message names no pixel. (A --z off its
    plane is mapped through the camera it implies, tests/test_calibration_homography_heights.py; one above that
    camera, 800 mm up by the default cell, is not.)"""
    path = _homography_file(tmp_path, np.diag([1.0, -1.0, 1.0]).tolist())
    code, out, err = run_cli("map", path, "--px", "320,240", "--z", "900", "--json", capsys=capsys)
    assert code == 2 and err.startswith(f"cell: error: calibration file {path}: the plane z = 900 mm is not below "
                                        "the camera the homography implies"), err


@pytest.mark.parametrize("dist", [[1e10, 0, 0, 0, 0], [0, 0, 0, 0, -1e6]])
def test_a_distortion_that_no_lens_has_is_refused(tmp_path, dist):
    # dist[0] = 1e10 was read, and mapped every pixel to about one point on the table
    d = json.loads(default_calibration_path().read_text())
    d["intrinsics"]["dist"] = dist
    with pytest.raises(BadInput, match="intrinsics.dist folds or collapses the image"):
        load_calibration(_write(tmp_path, d))
    d["intrinsics"]["dist"] = [-0.2813, 0.0291, 0.0012, -0.0001, 0.1549]  # OpenCV's own boards' lens
    assert load_calibration(_write(tmp_path, d)).dist[0] == pytest.approx(-0.2813)
    from dataclasses import replace

    from calibration import save_calibration

    bad = replace(load_calibration(_write(tmp_path, d)), dist=np.array(dist, float))
    with pytest.raises(BadInput, match="folds or collapses the image.*not written"):
        save_calibration(bad, tmp_path / "never.json")
    assert not (tmp_path / "never.json").exists()
