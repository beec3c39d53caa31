"""The simulated camera, frame sources and the segment / render commands, with bad input."""

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import EXTERNAL, needs_photos, run_cli
from test_fileio_atomic import fifo  # noqa: F401 - the fixture

from calibration import Calibration, default_calibration_path, save_calibration
from cell.errors import BadInput
from cell.vision import FileCamera, SimCamera, SimCameraOptions, read_image
from cell.vision.sample_parts import make_part

PARTS = [make_part("gear", "gear", 300, -120), make_part("cover", "cover", 420, 100, 30)]


def test_sim_camera_is_deterministic_for_a_seed():
    a = SimCamera(options=SimCameraOptions(seed=4)).render(PARTS)
    b = SimCamera(options=SimCameraOptions(seed=4)).render(PARTS)
    c = SimCamera(options=SimCameraOptions(seed=5)).render(PARTS)
    assert a.shape == (1024, 1280, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    cam = SimCamera(options=SimCameraOptions(seed=4))
    assert np.array_equal(cam.read(PARTS), a) and not np.array_equal(cam.read(PARTS), a)  # next frame


def test_empty_tray_is_lit_and_noisy_but_plain():
    frame = SimCamera(options=SimCameraOptions(seed=2)).render([]).astype(float)
    grey = frame.mean(axis=2)
    assert 90 < grey.mean() < 170
    centre, corner = grey[400:600, 500:800].mean(), grey[:100, :100].mean()
    assert centre > corner  # vignetting
    assert 0.5 < np.std(grey[500:520, 600:620] - cv2.GaussianBlur(grey, (0, 0), 3)[500:520, 600:620]) < 6


def test_parts_appear_where_the_calibration_says():
    cam = SimCamera(options=SimCameraOptions(seed=1, shadows=False, highlights=False))
    part = make_part("disc", "d", 380, 150, material="dark_plastic")
    frame = cam.render([part])
    u, v = np.round(cam.cal.mm_to_px([[380.0, 150.0]], part.z_top_mm)[0]).astype(int)
    assert frame[v, u].mean() < 70  # the dark part's top
    u2, v2 = np.round(cam.cal.mm_to_px([[380.0, 150.0 + 30]], 0.0)[0]).astype(int)
    assert frame[v2, u2].mean() > 100  # the tray beside it


def test_file_camera(tmp_path):
    paths = []
    for i in range(2):
        p = tmp_path / f"f{i}.png"
        cv2.imwrite(str(p), np.full((20, 30, 3), 40 * i, np.uint8))
        paths.append(p)
    with FileCamera(paths) as cam:
        assert cam.is_connected
        assert cam.read().mean() == 0 and cam.read().mean() == 40
        with pytest.raises(BadInput, match="no more frames"):
            cam.read()
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    with pytest.raises(BadInput, match="bad.png is not a readable image"):
        FileCamera([bad]).read()


@pytest.fixture
def frame_file(tmp_path):
    p = tmp_path / "frame.png"
    cv2.imwrite(str(p), SimCamera(options=SimCameraOptions(seed=3)).render(PARTS))
    return p


def test_segment_cli_with_calibration_gives_mm(frame_file, capsys):
    code, out, _ = run_cli("segment", frame_file, "--calibration", default_calibration_path(), "--z", "8",
                           "--json", capsys=capsys)
    assert code == 0
    parts = json.loads(out)["parts"]
    assert len(parts) == 2
    cover = min(parts, key=lambda p: abs(p["centroid_mm"][0] - 420) + abs(p["centroid_mm"][1] - 100))
    assert np.allclose(cover["centroid_mm"], [420, 100], atol=1.0)
    assert len(cover["holes_mm"]) == 2 and len(cover["outline_mm"]) == len(cover["outline_px"])


def test_segment_cli_with_calibration_prints_mm_without_json_too(frame_file, capsys):
    """Was: pixel figures only, though the calibration was given to have millimetres."""
    code, out, _ = run_cli("segment", frame_file, "--calibration", default_calibration_path(), "--z", "8",
                           capsys=capsys)
    assert code == 0
    cover = next(line for line in out.splitlines() if "2 hole(s)" in line)
    px_area, mm2, x, y = (float(v) for v in re.search(
        r"area (\d+) px = ([\d.]+) mm2, centroid \([\d.]+, [\d.]+\) px = \(([\d.]+), ([\d.]+)\) mm", cover).groups())
    truth = PARTS[1].polygon.area  # (the silhouette, mapped at the top, takes in a little of the walls: +3 %)
    assert abs(mm2 - truth) < 0.05 * truth and np.allclose([x, y], [420, 100], atol=1.0)
    code, out, _ = run_cli("segment", frame_file, "--calibration", default_calibration_path(), "--z", "8", "--json",
                           capsys=capsys)
    assert any(p["area_mm2"] == mm2 for p in json.loads(out)["parts"])


def test_segment_cli_empty_tray(tmp_path, capsys):
    p = tmp_path / "empty.png"
    cv2.imwrite(str(p), SimCamera(options=SimCameraOptions(seed=8)).render([]))
    code, out, _ = run_cli("segment", p, "--json", capsys=capsys)
    assert code == 0 and json.loads(out)["parts"] == []


def test_segment_cli_refuses_other_resolution(tmp_path, frame_file, capsys):
    small = Calibration(640, 480, homography=np.diag([1.0, -1.0, 1.0]), name="small")
    save_calibration(small, tmp_path / "small.json")
    code, _, err = run_cli("segment", frame_file, "--calibration", tmp_path / "small.json", "--json", capsys=capsys)
    assert code == 2 and f"1280 x 1024 px but calibration file {tmp_path / 'small.json'} is for 640 x 480" in err


def test_segment_cli_refuses_a_frame_of_another_size_before_any_output(tmp_path, frame_file, capsys):
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), cv2.imread(str(frame_file))[::2, ::2])
    code, out, err = run_cli("segment", frame_file, small, "--calibration", default_calibration_path(), "--json",
                             capsys=capsys)
    assert code == 2 and out == "" and "is 640 x 512 px but calibration" in err  # the first frame's line was printed


@pytest.mark.parametrize("content, match", [
    (b"", "is empty"),
    (b"this is not an image", "not a readable image"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00", "not a readable image"),
])
def test_segment_cli_corrupt_images(tmp_path, capsys, content, match):
    p = tmp_path / "frame.png"
    p.write_bytes(content)
    code, out, err = run_cli("segment", p, "--json", capsys=capsys)
    assert code == 2 and match in err and out == "" and "Traceback" not in err


@pytest.mark.parametrize("option, value", [
    ("--min-area-px", "nan"),   # used to print "parts": [] and exit 0 (no area compares above NaN)
    ("--min-area-px", "-5"),    # used to keep every speck
    ("--min-area-mm2", "nan"),
    ("--min-area-mm2", "-1"),
    ("--z", "inf"),             # used to say "the plane z = inf mm is not in front of the camera"
    ("--z", "nan"),
])
def test_segment_cli_refuses_non_finite_and_negative_numbers(capsys, option, value):
    image = EXTERNAL / "simplecv-coins" / "pills.png"
    extra = ["--calibration", default_calibration_path()] if option != "--min-area-px" else []
    code, out, err = run_cli("segment", image, *extra, option, value, "--json", capsys=capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and option in err and "Traceback" not in err


def test_segment_cli_missing_and_directory(tmp_path, capsys):
    code, _, err = run_cli("segment", tmp_path / "nope.png", "--json", capsys=capsys)
    assert code == 2 and "does not exist" in err
    code, _, err = run_cli("segment", tmp_path, "--json", capsys=capsys)
    assert code == 2 and "is a directory" in err


@pytest.mark.parametrize("command", [["segment"], ["calibrate", "intrinsics", "--pattern", "9x6", "--square", "1"]])
def test_an_image_that_is_a_fifo_is_bad_input(fifo, tmp_path, capsys, command):  # noqa: F811 - the fixture
    # (the image was read like a file: `cell segment` waited for ever for a writer)
    extra = ["--out", tmp_path / "cal.json"] if "intrinsics" in command else ["--json"]
    code, out, err = run_cli(*command, *[fifo] * (3 if "intrinsics" in command else 1), *extra, capsys=capsys)
    assert code == 2 and f"image {fifo} is not a regular file" in err and out == ""


def test_render_cli_writes_frame_and_truth(tmp_path, capsys):
    scene = {"units": "mm", "parts": [p.to_json() for p in PARTS], "target": "gear"}
    sp = tmp_path / "scene.json"
    sp.write_text(json.dumps(scene))
    out = tmp_path / "frame.png"
    code, stdout, _ = run_cli("render", sp, "--out", out, "--seed", "2", "--truth", tmp_path / "t.json",
                              capsys=capsys)
    assert code == 0 and json.loads(stdout)["parts"] == 2
    frame = read_image(out)
    assert frame.shape == (1024, 1280, 3)
    direct = SimCamera(options=SimCameraOptions(seed=2)).render(PARTS)  # the file rounds outlines to 1e-4 mm
    assert np.abs(frame.astype(int) - direct).mean() < 0.05
    truth = json.loads((tmp_path / "t.json").read_text())
    assert [p["id"] for p in truth["parts"]] == ["gear", "cover"]


def test_render_cli_bad_scene(tmp_path, capsys):
    sp = tmp_path / "scene.json"
    sp.write_text(json.dumps({"parts": [{"id": "x", "outline": [[0, 0], [1, 1]], "z_top": 3}]}))
    code, _, err = run_cli("render", sp, "--out", tmp_path / "f.png", capsys=capsys)
    assert code == 2 and "at least 3" in err
    assert not (tmp_path / "f.png").exists()


def test_bench_vision_prints_figures(capsys):
    code, out, _ = run_cli("bench", "vision", "--frames", "1", "--parts", "3", "--repeats", "2", "--conditions",
                           "all effects", "--json", capsys=capsys)
    assert code == 0
    rows = [json.loads(line) for line in out.splitlines()]
    acc, timing, large, large_cal = rows[0], rows[-3], rows[-2], rows[-1]
    assert acc["condition"] == "all effects" and acc["found"] == acc["parts"] == 3
    assert 0.0 < acc["outline_rms_mm"] < 0.6 and acc["centroid_mean_mm"] < 0.5
    assert timing["median_ms"] > 0 and timing["frame"] == "1280x1024" and timing["regions"] == 8
    assert large["frame"] == "4000x3200" and large["regions"] == 8  # the same 8 parts at 12 MP, no specks
    assert timing["detection_scale"] == 2 and large["detection_scale"] == 6
    # with its calibration resized to it: the same parts, detected as coarsely (was 1 / 2 whatever the frame)
    assert large_cal["frame"] == "4000x3200" and large_cal["regions"] == 8 and large_cal["detection_scale"] == 6
    code, _, err = run_cli("bench", "vision", "--conditions", "foggy", capsys=capsys)
    assert code == 2 and "unknown condition" in err


@needs_photos
def test_bench_vision_times_real_photos_given(tmp_path, capsys):
    photo = EXTERNAL / "simplecv-coins" / "wshed.jpg"
    args = ["bench", "vision", "--frames", "1", "--parts", "1", "--repeats", "1", "--conditions", "plain (no effects)"]
    code, out, _ = run_cli(*args, "--photos", photo, "--json", capsys=capsys)
    assert code == 0
    last = json.loads(out.splitlines()[-1])
    assert str(photo) in last["timing"] and last["frame"] == "256x192" and last["median_ms"] > 0
    code, out, err = run_cli(*args, "--photos", tmp_path / "none.png", capsys=capsys)
    assert code == 2 and out == "" and "does not exist" in err


def test_truncated_image_gives_one_clear_line_without_decoder_noise(tmp_path, frame_file):
    # OpenCV's decoder warns on the process's own stderr (not Python's): only a subprocess sees it
    import subprocess
    import sys

    p = tmp_path / "cut.png"
    p.write_bytes(frame_file.read_bytes()[:5000])
    r = subprocess.run([sys.executable, "-m", "cell", "segment", str(p), "--json"], capture_output=True, text=True,
                       cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines() == [f"cell: error: image {p} is not a readable image "
                                             "(corrupt, truncated or not an image format)"]


@needs_photos
def test_high_bit_depth_frames_are_read_at_their_depth(tmp_path, capsys):
    """A 10 - 14 bit camera's frame in a 16-bit PNG: OpenCV's default decode kept the top 8 bits (a
    12-bit frame came out with values 0 - 15) and pills.png segmented into 4 regions instead of 2."""
    photo = EXTERNAL / "simplecv-coins" / "pills.png"
    bgr = cv2.imread(str(photo))
    full = tmp_path / "full16.png"
    cv2.imwrite(str(full), bgr.astype(np.uint16) * 257)
    assert np.array_equal(read_image(full), bgr)  # a full-range 16-bit copy reads back exactly
    twelve = tmp_path / "twelve.png"
    cv2.imwrite(str(twelve), bgr.astype(np.uint16) * 16 + (bgr >> 4))  # 0 - 4095
    assert np.abs(read_image(twelve).astype(int) - bgr).max() <= 1
    grey = cv2.imread(str(EXTERNAL / "opencv-chessboard" / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(tmp_path / "g10.png"), grey.astype(np.uint16) * 4)  # 10 bits, the intrinsics' grey path
    assert np.abs(read_image(tmp_path / "g10.png", grey=True).astype(int) - grey).max() <= 1
    outs = []
    for p in (photo, twelve):
        code, out, _ = run_cli("segment", p, "--json", capsys=capsys)
        assert code == 0
        outs.append(sorted((round(q["area_px"]), len(q["holes_px"])) for q in json.loads(out)["parts"]))
    assert len(outs[1]) == 2 and outs[1] == outs[0]


@needs_photos
@pytest.mark.parametrize("photo, damage, message", [
    # cut in the middle of the image data: libpng printed "libpng error: PNG input buffer is incomplete" too
    ("p5binpicking-festo-table/aruco_img.png", lambda b: b[:700000], "is not a readable image"),
    # bytes flipped inside the scan: libjpeg decoded a smeared frame (exit 0) and printed "Corrupt JPEG data"
    ("opencv-objects/stuff.jpg", lambda b: b[:5000] + bytes(x ^ 0x55 for x in b[5000:5100]) + b[5100:],
     "is corrupt (the decoder says: Corrupt JPEG data"),
    # 200 bytes of the scan zeroed: 45 % of the pixels wrong, and libjpeg's only word is "173 extraneous
    # bytes before marker 0xd9" (the scan's blocks ran out before its data): read as intact before
    ("simplecv-coins/wshed.jpg", lambda b: b[:13432] + bytes(200) + b[13632:], "extraneous bytes before marker 0xd9"),
])
def test_damaged_photographs_give_one_clear_line(tmp_path, photo, damage, message):
    import subprocess
    import sys

    p = tmp_path / Path(photo).name
    p.write_bytes(damage((EXTERNAL / photo).read_bytes()))
    r = subprocess.run([sys.executable, "-m", "cell", "segment", str(p), "--json"], capture_output=True, text=True,
                       cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"cell: error: image {p} ") and message in lines[0]
    with pytest.raises(BadInput, match="image"):
        FileCamera([p]).read()  # the cell loop's frames go the same way


@needs_photos
def test_junk_between_jpeg_markers_is_read(tmp_path, capsys):
    # libjpeg says "Corrupt JPEG data: 3 extraneous bytes before marker 0xdb" and skips them: the pixels are
    # those of the clean file, so the frame is segmented, not refused as corrupt
    b = (EXTERNAL / "opencv-objects/stuff.jpg").read_bytes()
    end_of_app0 = 4 + int.from_bytes(b[4:6], "big")
    p = tmp_path / "junk.jpg"
    p.write_bytes(b[:end_of_app0] + b"\x00\x11\x22" + b[end_of_app0:])
    assert np.array_equal(read_image(p), read_image(EXTERNAL / "opencv-objects/stuff.jpg"))
    code, out, err = run_cli("segment", p, "--json", capsys=capsys)
    assert code == 0 and len(json.loads(out)["parts"]) >= 5, err


@needs_photos
def test_segment_z_needs_a_calibration_and_out_never_overwrites_an_input(tmp_path, capsys):
    photo = tmp_path / "left01.jpg"
    photo.write_bytes((EXTERNAL / "opencv-chessboard/left01.jpg").read_bytes())
    code, out, err = run_cli("segment", photo, "--z", "10", "--json", capsys=capsys)
    assert code == 2 and out == "" and "--z" in err and "--calibration" in err
    before = photo.read_bytes()
    code, out, err = run_cli("calibrate", "intrinsics", photo, "--pattern", "9x6", "--square", "1", "--out", photo,
                             capsys=capsys)
    assert code == 2 and "one of the inputs" in err and photo.read_bytes() == before
