"""Camera calibration: intrinsics from boards, the image <-> base-frame mapping, the file.

    camera.py      Calibration: px_to_mm / mm_to_px on the plane at any height z
    calfile.py     the calibration file (JSON, versioned, validated, atomic)
    intrinsics.py  camera matrix and distortion from chessboard / ChArUco images
    plane.py       image <-> base frame from fiducials or points at known base coordinates
    default.py     the default cell's nominal camera (data/default.json)
"""

import cell  # noqa: F401  (first: it pins numpy's BLAS kernels before numpy loads, cell/numerics.py)
from calibration.calfile import default_calibration_path, load_calibration, save_calibration
from calibration.camera import Calibration

__all__ = ["Calibration", "default_calibration_path", "load_calibration", "save_calibration"]
