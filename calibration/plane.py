"""The mapping image <-> base frame from points at known base coordinates.

Sources of correspondences (all end in `fit_plane_mapping`):
- ArUco fiducials whose corners' base coordinates are known (`markers_correspondences`);
- points touched with the gripper tip and clicked / detected in the image (a list of
  {"px": [u, v], "mm": [x, y, z]} pairs).

With intrinsics the camera pose is solved (`solvePnP`, IPPE for a plane, then
Levenberg-Marquardt), so pixels map to any plane height z. Without intrinsics a homography
is fitted, exact only on the points' plane. The residual is measured where it matters: the
detected pixels mapped back to the plane, against the known base coordinates, in mm.
"""

from __future__ import annotations

import cv2
import numpy as np

from calibration.camera import HALF_PX, Calibration, pose_matrix
from calibration.intrinsics import aruco_dictionary
from cell.errors import BadInput
from cell.fileio import has_non_number
from cell.scene import MAX_COORD_MM

PLANE_TOLERANCE_MM = 5.0  # the points' z may differ this much and still count as one (horizontal) plane:
# coordinates touched up with a robot differ by a few mm; the mapping uses their mean z
FLAT_Z_MM = 1.0  # ... and up to this much without a warning (and with the planar pose solver)
MIN_POINTS = 4
COLLINEAR_RATIO = 1e-3  # the points' second spread direction against the first: below this, a line
WARN_REPROJECTION_PX = 3.0  # the Festo frames fit to 0.9 - 1.1 px; one marker's corners listed one off: 37 px
MIN_MARKER_AREA_MM2 = 1.0  # a marker's square, at least (printed markers are 20-100 mm a side)
CORNER_ORDER_GAIN = 3.0  # another corner order must fit this many times better (and 2 mm) to be named


def detect_markers(gray: np.ndarray, dictionary: str, duplicates: list[int] | None = None) -> dict[int, np.ndarray]:
    """ArUco markers in the image: id -> corners (4, 2) in CONTRACT-frame pixels, OpenCV's order.

    An id seen more than once is left out (which copy lies at the known place cannot be told; the last
    one found used to be taken) and appended to `duplicates` when given."""
    params = cv2.aruco.DetectorParameters()
    # corners to sub-pixel: on rendered 60 px markers 0.39 px RMS instead of 0.88 (OpenCV's default: none)
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)
    corners, ids, _ = det.detectMarkers(gray)
    if ids is None:
        return {}
    flat = [int(i) for i in ids.ravel()]
    twice = sorted({i for i in flat if flat.count(i) > 1})
    if duplicates is not None:
        duplicates.extend(twice)
    return {i: c.reshape(4, 2).astype(float) + HALF_PX for i, c in zip(flat, corners, strict=True) if i not in twice}


def parse_markers(raw, source: str) -> tuple[str, dict[int, np.ndarray]]:
    """Validate a MARKERS.json object (CONTRACT.md); returns (dictionary, id -> corners (4, 3) mm)."""
    if not isinstance(raw, dict):
        raise BadInput(f"{source}: top level must be a JSON object")
    dictionary = raw.get("dictionary")
    if not isinstance(dictionary, str):
        raise BadInput(f"{source}: 'dictionary' must name an ArUco dictionary, e.g. \"DICT_4X4_50\"")
    n_ids = aruco_dictionary(dictionary).bytesList.shape[0]
    markers = raw.get("markers")
    if not isinstance(markers, dict) or not markers:
        raise BadInput(f"{source}: 'markers' must be an object {{\"ID\": [[x, y, z] x 4], ...}}")
    out = {}
    for key, corners in markers.items():
        if has_non_number(corners):
            raise BadInput(f"{source}: marker {key}: corners must be 4 points [x, y, z] in mm (true/false and "
                           "strings are not numbers)")
        try:
            mid = int(key)
        except ValueError:
            raise BadInput(f"{source}: marker id {key!r} is not an integer") from None
        if not 0 <= mid < n_ids:  # it could never be detected: it was reported as 'not found'
            raise BadInput(f"{source}: marker id {key} is not in {dictionary} (ids 0..{n_ids - 1})")
        try:
            arr = np.array(corners, dtype=float)
        except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond a float
            raise BadInput(f"{source}: marker {key}: corners must be 4 points [x, y, z] in mm") from None
        if arr.shape != (4, 3) or not np.all(np.isfinite(arr)):
            raise BadInput(f"{source}: marker {key}: corners must be 4 points [x, y, z] in mm, got shape "
                           f"{arr.shape}")
        if np.abs(arr).max() > MAX_COORD_MM:  # as in scene files; 1e300 overflowed the fit
            raise BadInput(f"{source}: marker {key}: corners must be within {MAX_COORD_MM:g} mm of the base")
        x, y = arr[:, 0], arr[:, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        if area < MIN_MARKER_AREA_MM2:  # four equal corners fitted to nothing (a copy-paste slip)
            raise BadInput(f"{source}: marker {key}: its corners enclose {area:.3g} mm2 on the plane; a marker's "
                           "4 corners are the corners of its square")
        out[mid] = arr
    return dictionary, out


def markers_correspondences(detected: dict[int, np.ndarray], known: dict[int, np.ndarray]):
    """Pair detected and known corners: (uv (n, 2), xyz (n, 3), used ids, missing ids)."""
    used = sorted(set(detected) & set(known))
    missing = sorted(set(known) - set(detected))
    if not used:
        return np.zeros((0, 2)), np.zeros((0, 3)), used, missing
    uv = np.concatenate([detected[i] for i in used])
    xyz = np.concatenate([known[i] for i in used])
    return uv, xyz, used, missing


def holdout_residuals(detected: dict[int, np.ndarray], known: dict[int, np.ndarray], used: list[int],
                      size: tuple[int, int], camera_matrix=None, dist=None) -> dict[str, float]:
    """Each marker's RMS error (mm) under the mapping fitted to the other markers: what a point the fit
    did not see is off by. The fit's own residual is 2-6 x smaller on the Festo frames (0.4-0.6 mm
    against 1-3.4 mm held out). Needs 4 markers (3 left to fit); a marker whose others cannot be
    fitted is left out."""
    out = {}
    if len(used) < 4:
        return out
    for i in used:
        rest = {j: known[j] for j in used if j != i}
        uv, xyz, _, _ = markers_correspondences(detected, rest)
        try:
            cal = fit_plane_mapping(uv, xyz, size, camera_matrix, dist)
        except BadInput:
            continue
        err = np.linalg.norm(cal.px_to_mm(detected[i]) - known[i][:, :2], axis=1)
        out[str(i)] = round(float(np.sqrt(np.mean(err ** 2))), 3)
    return out


def marker_residuals(cal: Calibration, detected: dict[int, np.ndarray], known: dict[int, np.ndarray],
                     used: list[int]) -> tuple[dict[str, float], list[str]]:
    """Per-marker RMS residual (mm, detected corners mapped to the plane against the known ones) and
    warnings: a fit far worse than a pixel, and markers whose corners fit much better in another
    order (listed from another corner than OpenCV's top-left, or counter-clockwise)."""
    per, warnings = {}, []
    for i in used:
        got = cal.px_to_mm(detected[i])
        want = known[i][:, :2]
        orders = [np.roll(want, -k, axis=0) for k in range(4)] + [np.roll(want[::-1], -k, axis=0) for k in range(4)]
        errs = [float(np.sqrt(np.mean(np.sum((got - o) ** 2, axis=1)))) for o in orders]
        per[str(i)] = round(errs[0], 3)
        best = int(np.argmin(errs))
        if best and errs[best] * CORNER_ORDER_GAIN < errs[0] and errs[0] - errs[best] > 2.0:
            first = best if best < 4 else (3 - (best - 4)) % 4  # index of the listed corner to start from
            how = (f"{'backwards ' if best >= 4 else ''}from its {('1st', '2nd', '3rd', '4th')[first]} listed "
                   f"corner (index {first})")
            warnings.append(f"marker {i}: its corners are {errs[0]:.1f} mm RMS off as listed, {errs[best]:.1f} mm "
                            f"read {how}; check the corner order (OpenCV's: clockwise from the marker's own top-left)")
    rms = cal.report.get("reprojection_rms_px")
    if rms is not None and rms > WARN_REPROJECTION_PX:
        warnings.insert(0, f"the markers fit badly: {rms:.1f} px RMS reprojection, {cal.report['residual_mm']:.1f} mm "
                           "RMS on the plane (expect about 1 px); check the markers' coordinates and corner order")
    return per, warnings


def fit_plane_mapping(uv_px, xyz_mm, size: tuple[int, int], camera_matrix: np.ndarray | None = None,
                      dist: np.ndarray | None = None, name: str = "plane calibration") -> Calibration:
    """Fit the image <-> base mapping to correspondences on one plane.

    Parameters
    ----------
    uv_px : array-like of shape (n, 2)
        Pixels, CONTRACT frame.
    xyz_mm : array-like of shape (n, 3)
        The same points in the base frame, mm; all at one height (within PLANE_TOLERANCE_MM; the mean is the plane).
    size : (width_px, height_px)
    camera_matrix, dist : optional
        Intrinsics; without them the result is a homography for the points' plane.

    Returns
    -------
    Calibration whose `report` holds `residual_mm` (RMS), `residual_max_mm`,
    `reprojection_rms_px` and the method.
    """
    uv = np.asarray(uv_px, float).reshape(-1, 2)
    xyz = np.asarray(xyz_mm, float).reshape(-1, 3)
    if len(uv) != len(xyz):
        raise BadInput(f"{len(uv)} pixels but {len(xyz)} base points")
    if len(uv) < MIN_POINTS:
        raise BadInput(f"{len(uv)} points given; at least {MIN_POINTS} (one marker) are needed, "
                       "better 12 (three markers) spread over the work area")
    z = xyz[:, 2]
    z_spread = float(np.ptp(z))
    if z_spread > PLANE_TOLERANCE_MM:
        raise BadInput(f"the points are not on one horizontal plane (z from {z.min():.2f} to {z.max():.2f} mm, "
                       f"more than {PLANE_TOLERANCE_MM:g} mm apart)")
    for pts, what in ((uv, "pixels"), (xyz[:, :2], "base points")):
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if not sv[0] > 1e-9 or sv[1] < COLLINEAR_RATIO * sv[0]:
            # findHomography fitted such points with a few mm of residual and the file was written (exit 0)
            raise BadInput(f"the {what} lie on one line (or one point): a plane mapping needs points spread "
                           "over the work area, not along a line")
    plane_z = float(np.mean(z))
    w, h = size
    if camera_matrix is not None:
        k = np.asarray(camera_matrix, float)
        d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
        obj = xyz.astype(np.float64)
        img = (uv - HALF_PX).astype(np.float64)
        # IPPE takes coplanar points only; SQPnP any (points a few mm off one plane)
        solver = cv2.SOLVEPNP_IPPE if z_spread <= FLAT_Z_MM else cv2.SOLVEPNP_SQPNP
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, d, flags=solver)
        if not ok:
            raise BadInput("the camera pose could not be solved from these points")
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, d, rvec, tvec)
        r, _ = cv2.Rodrigues(rvec)
        base2cam = pose_matrix(r, tvec.ravel())
        cal = Calibration(w, h, k, d, np.linalg.inv(base2cam), None, plane_z, name)
        proj = cal.project(xyz)
        method = "pose"
    else:
        hmat, _ = cv2.findHomography(uv, xyz[:, :2], 0)
        if hmat is None:
            raise BadInput("no homography fits these points (are they collinear?)")
        cal = Calibration(w, h, None, np.zeros(5), None, hmat, plane_z, name)
        proj = None
        method = "homography"
    try:
        if proj is None:
            proj = cal.mm_to_px(xyz[:, :2])
        err_mm = np.linalg.norm(cal.px_to_mm(uv) - xyz[:, :2], axis=1)
    except BadInput:  # the fit's horizon runs through its own points: no camera sees them so
        raise BadInput(f"the {len(uv)} points fit no view of one plane: the best {method} puts some of them "
                       "beyond the plane's horizon; a pixel or a base coordinate is wrong (check each pair)") from None
    err_px = np.linalg.norm(proj - uv, axis=1)
    report = {"method": method, "points": len(uv), "plane_z_mm": plane_z, "z_spread_mm": z_spread,
              "residual_mm": float(np.sqrt(np.mean(err_mm ** 2))), "residual_max_mm": float(err_mm.max()),
              "reprojection_rms_px": float(np.sqrt(np.mean(err_px ** 2))),
              "mm_per_px": cal.mm_per_px()}
    if cal.has_pose:
        report["camera_position_mm"] = [round(float(x), 3) for x in cal.camera_position_mm()]
    return Calibration(cal.width_px, cal.height_px, cal.camera_matrix, cal.dist, cal.cam2base, cal.homography,
                       plane_z, name, report)
