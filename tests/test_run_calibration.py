"""`cell run`'s calibration (cell.runtime.session._calibration): a real cell whose camera or tray is not the
default's needs --calibration (the shipped one silently placed its parts for a camera at 800 mm); any run's
calibration must show the whole tray."""

from __future__ import annotations

import numpy as np
import pytest
from cell_files import cell_file_with
from conftest import run_cli

from calibration import default_calibration_path
from cell.cellconfig import load_cell
from cell.runtime.session import RealCell, RunConfig, _calibration
from cell.vision.sources import write_image


def _cell_file(tmp_path, name, **sections):
    return cell_file_with(tmp_path / f"{name}.json", **sections)


@pytest.fixture
def frame(tmp_path):
    path = tmp_path / "frame.png"
    write_image(path, np.full((1024, 1280, 3), 200, np.uint8))
    return path


def _real_run(capsys, tmp_path, frame, *argv):
    rec = tmp_path / "rec"
    code, out, err = run_cli("run", "--interface", "virtual", "--channel", f"calib-{tmp_path.name}", "--camera",
                             frame, "--yes", "--record", rec, *argv, capsys=capsys)
    return code, err, rec


@pytest.mark.parametrize("section, values", [("camera", {"height_mm": 1200.0}),
                                             ("tray", {"x_mm": [200.0, 420.0], "y_mm": [-400.0, -50.0]})])
def test_a_real_cell_of_another_camera_or_tray_needs_its_calibration(tmp_path, capsys, frame, section, values):
    cell = _cell_file(tmp_path, "other", **{section: values})
    code, err, rec = _real_run(capsys, tmp_path, frame, "--cell", cell)
    assert code == 2 and "Traceback" not in err, err
    assert "pass --calibration" in err and "calibrate" in err and str(cell) in err and "nothing moved" in err
    assert not rec.exists()  # refused before the recording (and the bus) was opened


def test_a_calibration_that_does_not_show_the_whole_tray_is_refused(tmp_path, capsys, frame):
    """The shipped calibration sees x 200..500, y -250..250; a tray at y -400..-50 lies partly beyond its image (x to
    420 mm: the arm reaches all of it)."""
    cell = _cell_file(tmp_path, "negy", tray={"x_mm": [200.0, 420.0], "y_mm": [-400.0, -50.0]})
    for argv in (["--cell", cell, "--calibration", default_calibration_path()],):  # the real cell
        code, err, rec = _real_run(capsys, tmp_path, frame, *argv)
        assert code == 2 and "does not show all of the cell's tray" in err and "(200, -400) mm" in err, err
        assert "Traceback" not in err and not rec.exists()
    # the simulated cell as well, the calibration given: a tray wider than its view (the parts in view, on the tray)
    wide = _cell_file(tmp_path, "wide", tray={"y_mm": [-330.0, 330.0]})
    code, out, err = run_cli("run", "--cell", wide, "--calibration", default_calibration_path(),
                             "--record", tmp_path / "sim", capsys=capsys)
    assert code == 2 and "does not show all of the cell's tray (x 200 to 500, y -330 to 330 mm)" in err, err
    assert f"calibration file {default_calibration_path()}" in err and not (tmp_path / "sim").exists()


def test_which_calibration_a_run_takes(tmp_path):
    real = RealCell("virtual", "unused", "0")
    default = load_cell(None)
    high = load_cell(_cell_file(tmp_path, "high", camera={"height_mm": 1200.0}))
    # the default cell: the shipped calibration, simulated or real
    assert _calibration(RunConfig(), default)[0] == default_calibration_path()
    assert _calibration(RunConfig(real_cell=real), default)[0] == default_calibration_path()
    # the simulated cell of another camera: a nominal one of its own at its height (no file)
    path, cal = _calibration(RunConfig(), high)
    assert path is None and cal.cam2base[2, 3] == pytest.approx(1200.0)
    # the real one takes the calibration it is given
    assert _calibration(RunConfig(real_cell=real, calibration=default_calibration_path()), high)[0] == \
        default_calibration_path()
