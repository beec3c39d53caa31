"""Bad image files given to the commands that read images: a clear message and exit code 2."""

import cv2
import numpy as np
import pytest
from conftest import run_cli
from test_cli_fuzz_recording import _png_header_only


@pytest.mark.parametrize("side_px", [60000, 17000])
def test_a_png_claiming_more_pixels_than_a_frame_is_bad_input(tmp_path, capsys, side_px):
    """60000 x 60000 was exit 1, "internal error: cv2.error ... pixels <= CV_IO_MAX_IMAGE_PIXELS"; 17000 x 17000
    (289 MP), under OpenCV's own limit, was decoded (12000 x 12000 took 0.9 GB to segment, 30000 x 30000 5.3 GB).
    The cell's limit is 268 MP (cell.numerics.MAX_IMAGE_PIXELS), set before cv2 loads."""
    big = tmp_path / "big.png"
    big.write_bytes(_png_header_only(side_px, side_px))
    code, out, err = run_cli("segment", big, "--json", capsys=capsys)
    assert code == 2 and out == ""
    assert f"image {big} has more pixels than OpenCV is set to decode" in err and "internal error" not in err
    assert "the cell's limit is 268 megapixels" in err
    code, _, err = run_cli("calibrate", "intrinsics", big, big, big, "--pattern", "9x6", "--square", "25",
                           "--out", tmp_path / "k.json", capsys=capsys)
    assert code == 2 and "more pixels than OpenCV is set to decode" in err and not (tmp_path / "k.json").exists()


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_float_image_with_pixels_that_are_not_numbers_says_so(tmp_path, capsys, bad):
    # the message read "has float32 pixels; 8- or 16-bit integer or float images are read"
    img = np.full((64, 64, 3), 0.5, np.float32)
    img[3, 4] = bad
    path = tmp_path / "frame.tiff"
    assert cv2.imwrite(str(path), img)
    code, _, err = run_cli("segment", path, "--json", capsys=capsys)
    assert code == 2 and "has float32 pixels that are not finite numbers (nan or inf)" in err


def test_a_grey_float_tiff_is_read_as_grey(tmp_path):
    # OpenCV decodes a one-channel float TIFF only as it is: it was "not a readable image"
    from cell.vision.sources import read_image

    img = np.zeros((40, 60), np.float32)
    img[10:20, 10:30] = 1.0
    path = tmp_path / "grey.tiff"
    assert cv2.imwrite(str(path), img)
    got = read_image(path)
    assert got.shape == (40, 60, 3) and got.dtype == np.uint8
    assert (got[10:20, 10:30] == 255).all() and got.sum() == 255 * 3 * 200


def test_a_file_opencv_cannot_read_leaves_only_our_message_on_stderr(tmp_path):
    import subprocess
    import sys

    # a truncated TIFF: libtiff's complaints came through OpenCV's log as two "[ERROR:0@0.049] ..." lines
    whole = tmp_path / "whole.tiff"
    assert cv2.imwrite(str(whole), np.full((64, 64, 3), 100, np.uint8))
    path = tmp_path / "frame.tiff"
    path.write_bytes(whole.read_bytes()[:200])
    done = subprocess.run([sys.executable, "-m", "cell", "segment", str(path), "--json"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == (f"cell: error: image {path} is not a readable image (corrupt, truncated or not an "
                           "image format)\n")


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("grey", [False, True])
def test_float_tiffs_are_read_in_either_mode(tmp_path, dtype, channels, grey):
    """OpenCV decodes float TIFFs only as they are: a colour one read as grey (calibrate intrinsics) and a
    float64 grey one were 'not a readable image' or an OpenCV error; negative pixels came out as their
    absolute value."""
    from cell.vision.sources import read_image

    img = np.zeros((40, 60), dtype)
    img[10:20, 10:30] = 1.0
    img[30:35, 40:50] = -0.5  # below black
    path = tmp_path / "frame.tiff"
    assert cv2.imwrite(str(path), img if channels == 1 else np.dstack([img] * 3))
    got = read_image(path, grey=grey)
    assert got.dtype == np.uint8 and got.shape == ((40, 60) if grey else (40, 60, 3))
    plane = got if grey else got[..., 0]
    assert (plane[10:20, 10:30] == 255).all() and (plane[30:35, 40:50] == 0).all() and plane.sum() == 255 * 200


@pytest.mark.parametrize("grey", [False, True])
def test_a_float_tiff_with_alpha_is_scaled_by_its_colours_not_its_alpha(tmp_path, grey):
    """Colours in [0, 1] with an alpha of 255: the scale came from the alpha, and the frame read nearly black."""
    from cell.vision.sources import read_image

    bgr = np.zeros((20, 30, 3), np.float32)
    bgr[5:10, 5:10] = 0.9
    path = tmp_path / "alpha.tiff"
    assert cv2.imwrite(str(path), np.dstack([bgr, np.full((20, 30), 255.0, np.float32)]))
    got = read_image(path, grey=grey)
    plane = got if grey else got[..., 2]
    assert plane[5:10, 5:10].min() == round(0.9 * 255) and plane.sum() == 25 * round(0.9 * 255)


def test_an_image_wider_than_opencvs_remap_takes_is_bad_input(tmp_path, capsys):
    # a 33000 x 600 frame with a part in it was exit 1, "internal error: ... dst.cols < SHRT_MAX in function 'remap'"
    img = np.full((600, 33000), 200, np.uint8)
    img[200:400, 1000:1300] = 40
    path = tmp_path / "wide.png"
    assert cv2.imwrite(str(path), img)
    code, out, err = run_cli("segment", path, "--json", "--min-area-px", "100", capsys=capsys)
    assert code == 2 and out == ""
    assert f"image {path} is 33000 x 600 px: a side of more than 32766 px is beyond OpenCV's remap" in err
    assert "internal error" not in err
    ok = tmp_path / "ok.png"
    assert cv2.imwrite(str(ok), img[:, :32766])  # the widest it takes
    code, out, err = run_cli("segment", ok, "--json", "--min-area-px", "100", capsys=capsys)
    assert code == 0, err
