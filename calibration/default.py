"""The default cell's camera: nominal values behind calibration/data/default.json.

CONTRACT.md: 1280 x 1024 px, looking straight down from about z = 800 over the tray
centre (x 350, y 0). The tray (x 300 mm by y 500 mm) is taller than wide, so the image's
long side (u) runs along base +y and v along base +x (the robot is at the top of the
image). f = 1600 px gives 0.5 mm/px on the table: 640 x 512 mm in view, the tray plus a
margin. The lens has mild barrel distortion (about 13 px at the corners) and the mount a
few tenths of a degree of tilt, as a real one would; the simulated camera renders with
exactly this file, so ground truth and calibration agree.

`python -m calibration.default` rewrites the JSON file from these numbers.
"""

from __future__ import annotations

import math

import numpy as np

from calibration.camera import Calibration, pose_matrix

WIDTH_PX, HEIGHT_PX = 1280, 1024
FOCAL_PX = 1600.0
PRINCIPAL_PX = (642.7, 509.1)  # OpenCV convention; a real sensor is never centred exactly
DIST = (-0.06, 0.09, 0.0004, -0.0003, 0.0)  # k1, k2, p1, p2, k3
CAMERA_MM = (350.0, 0.0, 800.0)
TILT_DEG = (0.3, -0.2, 0.4)  # small rotations about base x, y, z of a mount that is not perfect

# Camera axes in the base frame for a camera looking straight down: x_cam = +y_base (u along
# the tray's long side), y_cam = +x_base (v away from the robot), z_cam = -z_base (down).
_R_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def _rot(axis: int, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def default_cell_calibration() -> Calibration:
    tilt = _rot(2, TILT_DEG[2]) @ _rot(1, TILT_DEG[1]) @ _rot(0, TILT_DEG[0])
    k = np.array([[FOCAL_PX, 0.0, PRINCIPAL_PX[0]], [0.0, FOCAL_PX, PRINCIPAL_PX[1]], [0.0, 0.0, 1.0]])
    report = {"method": "nominal", "note": "the default cell's nominal camera (calibration/default.py); "
              "replace with `cell calibrate plane` on a real cell"}
    return Calibration(WIDTH_PX, HEIGHT_PX, k, np.array(DIST), pose_matrix(tilt @ _R_DOWN, CAMERA_MM), None,
                       0.0, "default cell camera", report)


VIEW_MARGIN = 1.28  # the view is this much wider than the tray: the default's 640 mm over 500 mm


def nominal_calibration(width_px: int, height_px: int, camera_z_mm: float, tray_x_mm, tray_y_mm) -> Calibration:
    """An ideal camera (no tilt, no distortion) looking straight down from `camera_z_mm` over the
    centre of the tray, u along base +y as in the default, the focal length the largest that keeps
    the tray and a margin in view: what the simulated cell uses for a cell file whose camera or
    tray is not the default's (the shipped calibration would render another image size or miss
    the tray)."""
    span_x, span_y = tray_x_mm[1] - tray_x_mm[0], tray_y_mm[1] - tray_y_mm[0]
    focal = camera_z_mm * min(width_px / (VIEW_MARGIN * span_y), height_px / (VIEW_MARGIN * span_x))
    k = np.array([[focal, 0.0, (width_px - 1) / 2], [0.0, focal, (height_px - 1) / 2], [0.0, 0.0, 1.0]])
    centre = (sum(tray_x_mm) / 2, sum(tray_y_mm) / 2, camera_z_mm)
    report = {"method": "nominal", "note": "an ideal camera over the cell file's tray "
              "(calibration.default.nominal_calibration); replace with `cell calibrate plane` on a real cell"}
    return Calibration(width_px, height_px, k, np.zeros(5), pose_matrix(_R_DOWN, centre), None, 0.0,
                       f"nominal {width_px} x {height_px} camera at z {camera_z_mm:g}", report)


if __name__ == "__main__":
    from calibration.calfile import default_calibration_path, save_calibration

    save_calibration(default_cell_calibration(), default_calibration_path())
    print(default_calibration_path())
