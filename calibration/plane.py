"""The mapping image <-> base frame from points at known base coordinates.

Sources of correspondences (all end in `fit_plane_mapping`):
- ArUco fiducials whose corners' base coordinates are known (`markers_correspondences`);
- points touched with the gripper tip and clicked / detected in the image (a list of
  {"px": [u, v], "mm": [x, y, z]} pairs).

With intrinsics the camera pose is solved (`solvePnP`, IPPE for a plane, then
Levenberg-Marquardt), so pixels map to any plane height z. Without intrinsics a homography
is fitted, exact only on the points' plane. Points on a tilted plane (z spread over
PLANE_TOLERANCE_MM) fit their least-squares plane (calibration/tilted.py), which becomes the
calibration's own plane. The residual is measured where it matters: the
detected pixels mapped back to the plane, against the known base coordinates, in mm.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from calibration.camera import HALF_PX, Calibration, pose_matrix
from calibration.intrinsics import aruco_dictionary
from calibration.tilted import TiltedPlane, fit_plane
from cell.errors import BadInput
from cell.fileio import has_non_number, short_repr, short_text
from cell.scene import MAX_COORD_MM

PLANE_TOLERANCE_MM = 5.0  # the points' z may differ this much and still count as one horizontal plane:
# coordinates touched up with a robot differ by a few mm; the mapping uses their mean z. Beyond, the plane
# is tilted: fitted by least squares (calibration/tilted.py)
FLAT_Z_MM = 1.0  # ... and up to this much without a warning (and with the planar pose solver)
MIN_POINTS = 4
COLLINEAR_RATIO = 1e-3  # the points' second spread direction against the first: below this, a line
WARN_REPROJECTION_PX = 3.0  # the Festo frames fit to 0.9 - 1.1 px; one marker's corners listed one off: 37 px
MIN_MARKER_AREA_MM2 = 1.0  # a marker's square, at least (printed markers are 20-100 mm a side)
CORNER_ORDER_GAIN = 3.0  # another corner order must fit this many times better (and 2 mm) to be named
# A marker's bits are read from the middle of each cell: OpenCV leaves out 0.13 of a cell's side at each
# edge. Out of focus (the Festo frames blurred by sigma 2.5 - 3 px, 13 px cells) the edges carry as much
# of the neighbouring cells as of their own and marker 0 went unread in both frames; leaving out 0.3 (the
# middle 40 % read) reads all four up to sigma 3. A second reading with it adds the ids the first missed:
# a sharp frame's markers are those it read before, and a wrong id still needs a dictionary word within
# OpenCV's error correction, as in the first reading
DEFOCUS_CELL_MARGIN = 0.3
# OpenCV's marker detection thresholds in absolute grey levels (adaptive threshold constant 7, candidate
# contrast): a dim, flat frame loses markers. The Festo frames at 0.35 of their exposure and half their contrast
# (grey 23-54) read 3 and 2 of 4, at 0.25 none; stretched to the full range first, 4 of 4 down to 0.1 of the
# exposure, corners within 0.5 px of the original frame's. Frames whose 0.5-99.5 percentile span is below
# this are read a third time, so stretched (the shared frames span 170 levels: not)
LOW_CONTRAST_SPAN = 128
MAX_VIEW_ANGLE_DEG = 75.0  # a tilted plane seen further from its normal than this is refused as edge-on: a
# pixel spans 3.9 x more across it than along it


def detect_markers(gray: np.ndarray, dictionary: str, duplicates: list[int] | None = None) -> dict[int, np.ndarray]:
    """ArUco markers in the image: id -> corners (4, 2) in CONTRACT-frame pixels, OpenCV's order.

    Markers are read twice: with OpenCV's bit sampling, then, for ids not read so, sampling the middle
    of each bit cell only (DEFOCUS_CELL_MARGIN); a dim or flat frame a third time, its grey levels
    stretched to the full range (LOW_CONTRAST_SPAN). An id seen more than once is left out (which copy lies
    at the known place cannot be told; the last one found used to be taken) and appended to
    `duplicates` when given."""
    corners, flat = [], []
    readings = [(gray, None), (gray, DEFOCUS_CELL_MARGIN)]
    stretched = _stretched_if_flat(gray)
    if stretched is not None:
        readings.append((stretched, None))
    for image, margin in readings:
        params = cv2.aruco.DetectorParameters()
        # corners to sub-pixel: on rendered 60 px markers 0.39 px RMS instead of 0.88 (OpenCV's default: none)
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        if margin is not None:
            params.perspectiveRemoveIgnoredMarginPerCell = margin
        c, ids, _ = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params).detectMarkers(image)
        seen, read = set(flat), list(corners)
        for ci, i in zip(c, [] if ids is None else ids.ravel(), strict=True):
            # a later reading adds only ids the ones before did not read, on markers they did not read: markers
            # both read keep the first's corners (the corners are found from the outline, the same in both; only
            # the bits differ), and a marker read as one id is not taken again as another
            if int(i) not in seen and not _on_a_marker_read(ci, read):
                corners.append(ci)
                flat.append(int(i))
    if not flat:
        return {}
    twice = sorted({i for i in flat if flat.count(i) > 1})
    if duplicates is not None:
        duplicates.extend(twice)
    return {i: c.reshape(4, 2).astype(float) + HALF_PX for i, c in zip(flat, corners, strict=True) if i not in twice}


def _stretched_if_flat(gray: np.ndarray) -> np.ndarray | None:
    """The grey levels between the 0.5th and 99.5th percentiles stretched to 0-255 when they span fewer than
    LOW_CONTRAST_SPAN levels (None: they span more, or nothing to stretch)."""
    lo, hi = np.percentile(gray, (0.5, 99.5))
    if hi - lo >= LOW_CONTRAST_SPAN or hi <= lo:
        return None
    return cv2.convertScaleAbs(gray, alpha=255.0 / (hi - lo), beta=-lo * 255.0 / (hi - lo))


def _on_a_marker_read(quad: np.ndarray, read: list[np.ndarray]) -> bool:
    """Does the centre of `quad` (a marker's corners as OpenCV gives them) lie on one of the markers `read`?"""
    x, y = quad.reshape(4, 2).mean(axis=0)
    return any(cv2.pointPolygonTest(q.reshape(4, 2).astype(np.float32), (float(x), float(y)), False) >= 0
               for q in read)


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
            raise BadInput(f"{source}: marker id {short_repr(key)} is not an integer") from None
        if not 0 <= mid < n_ids:  # it could never be detected: it was reported as 'not found'
            raise BadInput(f"{source}: marker id {short_text(key)} is not in {dictionary} (ids 0..{n_ids - 1})")
        try:
            arr = np.array(corners, dtype=float)
        except OverflowError:  # an integer beyond a float
            raise BadInput(f"{source}: marker {key}: corners must be 4 points [x, y, z] in mm of finite numbers "
                           "(one is too large)") from None
        except (TypeError, ValueError):
            raise BadInput(f"{source}: marker {key}: corners must be 4 points [x, y, z] in mm") from None
        if arr.shape != (4, 3):
            raise BadInput(f"{source}: marker {key}: corners must be 4 points [x, y, z] in mm, got shape "
                           f"{arr.shape}")
        if not np.all(np.isfinite(arr)):  # NaN, Infinity: the file reader takes them
            bad = float(arr[~np.isfinite(arr)][0])
            raise BadInput(f"{source}: marker {key}: corners must be finite numbers (mm), got {short_repr(bad)}")
        if np.abs(arr).max() > MAX_COORD_MM:  # as in scene files; 1e300 overflowed the fit
            raise BadInput(f"{source}: marker {key}: corners must be within {MAX_COORD_MM:g} mm of the base")
        x, y = arr[:, 0], arr[:, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        if area < MIN_MARKER_AREA_MM2:  # four equal corners fitted to nothing (a copy-paste slip)
            raise BadInput(f"{source}: marker {key}: its corners enclose {area:.3g} mm2 on the plane; a marker's "
                           "4 corners are the corners of its square")
        if mid in out:  # "0" and "00": one marker written twice, one of the two silently dropped
            raise BadInput(f"{source}: marker id {short_repr(key)} names marker {mid} a second time")
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


def leave_one_out_fits(detected: dict[int, np.ndarray], known: dict[int, np.ndarray], used: list[int],
                       size: tuple[int, int], camera_matrix=None, dist=None,
                       plane: TiltedPlane | None = None) -> dict[int, Calibration]:
    """Marker -> the mapping fitted to the other markers (`holdout_residuals` and `marker_not_fitting` read the
    same fits). Needs 4 markers (3 left to fit); a marker whose others cannot be fitted has none. `plane`: the
    tilted plane all the markers fit; a pose fitted to the others maps onto it (the others alone may span under
    PLANE_TOLERANCE_MM of z: a horizontal fit at their mean height, which the left-out marker is not at). A
    homography fitted so maps the plane's points to their base (x, y) all the same."""
    fits = {}
    if len(used) < 4:
        return fits
    for i in used:
        uv, xyz, _, _ = markers_correspondences(detected, {j: known[j] for j in used if j != i})
        try:
            cal = fit_plane_mapping(uv, xyz, size, camera_matrix, dist)
        except BadInput:
            continue
        fits[i] = replace(cal, plane=plane, plane_z_mm=None) if plane is not None and cal.has_pose else cal
    return fits


def holdout_residuals(detected: dict[int, np.ndarray], known: dict[int, np.ndarray], used: list[int],
                      size: tuple[int, int], camera_matrix=None, dist=None,
                      plane: TiltedPlane | None = None, fits: dict[int, Calibration] | None = None) -> dict[str, float]:
    """Each marker's RMS error (mm) under the mapping fitted to the other markers (`leave_one_out_fits`, or
    `fits` made so): what a point the fit did not see is off by. The fit's own residual is 2-6 x smaller on the
    Festo frames (0.4-0.6 mm against 1-3.4 mm held out)."""
    if fits is None:
        fits = leave_one_out_fits(detected, known, used, size, camera_matrix, dist, plane)
    out = {}
    for i, cal in fits.items():
        got, want = mapped_and_known(cal, detected[i], known[i])
        err = np.linalg.norm(got - want, axis=1)
        out[str(i)] = round(float(np.sqrt(np.mean(err ** 2))), 3)
    return out


ODD_MARKER_GAIN = 3.0  # leaving one marker out must fit this many times better than all of them, and than
# leaving out any other (and under WARN_REPROJECTION_PX), for it to be named. A homography of the others can
# take up part of a wrong marker's error: the hunter's 5 markers, one 14 mm off, fit to 0.38 px without it,
# 2.4 - 6.0 px without any other, 5.8 px all


def marker_not_fitting(detected: dict[int, np.ndarray], known: dict[int, np.ndarray], used: list[int],
                       size: tuple[int, int], full_rms_px: float, camera_matrix=None, dist=None,
                       plane: TiltedPlane | None = None, fits: dict[int, Calibration] | None = None) -> dict | None:
    """The one marker whose coordinates are wrong, when the fit is bad (over WARN_REPROJECTION_PX) and the
    others fit well without it (`leave_one_out_fits`, or `fits` made so), clearly better than without any other:
    {"id", "others_reprojection_rms_px", "others_residual_mm", "off_mm" (RMS of its corners from where the others'
    fit puts them), "listed_off_mm" (their mean offset, listed minus seen: a marker listed shifted)}; else None.
    One wrong marker spreads its error over the whole fit: the per-marker residuals (5 markers, one listed 14 mm
    off) read 1.0-6.4 mm and did not single it out. Needs 4 markers; two wrong ones name none (leaving out one
    leaves the fit bad)."""
    if full_rms_px <= WARN_REPROJECTION_PX or len(used) < 4:
        return None
    if fits is None:
        fits = leave_one_out_fits(detected, known, used, size, camera_matrix, dist, plane)
    ranked = sorted(fits, key=lambda i: fits[i].report["reprojection_rms_px"])
    if not ranked:
        return None
    best, cal = ranked[0], fits[ranked[0]]
    rms = cal.report["reprojection_rms_px"]
    runner_up = fits[ranked[1]].report["reprojection_rms_px"] if len(ranked) > 1 else np.inf
    if not (rms <= WARN_REPROJECTION_PX and rms * ODD_MARKER_GAIN <= min(full_rms_px, runner_up)):
        return None
    got, want = mapped_and_known(cal, detected[best], known[best])
    off = want - got
    return {"id": best, "others_reprojection_rms_px": round(float(rms), 3),
            "others_residual_mm": round(float(cal.report["residual_mm"]), 3),
            "off_mm": round(float(np.sqrt(np.mean(np.sum(off ** 2, axis=1)))), 3),
            "listed_off_mm": [round(float(v), 3) for v in off.mean(axis=0)]}


def odd_marker_warning(odd: dict, n_used: int) -> str:
    """The warning naming `odd` (marker_not_fitting's answer)."""
    dx, dy = odd["listed_off_mm"][:2]
    return (f"marker {odd['id']} does not fit the others: without it the other {n_used - 1} markers fit to "
            f"{odd['others_reprojection_rms_px']:.1f} px RMS ({odd['others_residual_mm']:.1f} mm), and its corners "
            f"are listed {odd['off_mm']:.1f} mm RMS from where they put them (on average {dx:+.1f}, {dy:+.1f} mm "
            "in x, y); check its coordinates (the calibration still uses it: remove it from the markers file to "
            "leave it out)")


def marker_residuals(cal: Calibration, detected: dict[int, np.ndarray], known: dict[int, np.ndarray],
                     used: list[int]) -> tuple[dict[str, float], list[str]]:
    """Per-marker RMS residual (mm, detected corners mapped to the plane against the known ones) and
    warnings: a fit far worse than a pixel, and markers whose corners fit much better in another
    order (listed from another corner than OpenCV's top-left, or counter-clockwise)."""
    per, warnings = {}, []
    for i in used:
        got, want = mapped_and_known(cal, detected[i], known[i])
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
                      dist: np.ndarray | None = None, name: str = "plane calibration",
                      names: list[str] | None = None) -> Calibration:
    """Fit the image <-> base mapping to correspondences on one plane.

    Parameters
    ----------
    uv_px : array-like of shape (n, 2)
        Pixels, CONTRACT frame.
    xyz_mm : array-like of shape (n, 3)
        The same points in the base frame, mm, on one plane: horizontal (z within PLANE_TOLERANCE_MM; the
        mean is the plane) or tilted (within OFF_PLANE_MM of the least-squares plane; calibration/tilted.py).
    size : (width_px, height_px)
    camera_matrix, dist : optional
        Intrinsics; without them the result is a homography for the points' plane.
    names : optional
        What to call each point in a refusal (default "point #i").

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
    for pts, what in ((uv, "pixels"), (xyz[:, :2], "base points")):
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if not sv[0] > 1e-9 or sv[1] < COLLINEAR_RATIO * sv[0]:
            # findHomography fitted such points with a few mm of residual and the file was written (exit 0)
            raise BadInput(f"the {what} lie on one line (or one point): a plane mapping needs points spread "
                           "over the work area, not along a line")
    z = xyz[:, 2]
    z_spread = float(np.ptp(z))
    k = None if camera_matrix is None else np.asarray(camera_matrix, float)
    d = np.zeros(5) if dist is None or k is None else np.asarray(dist, float).ravel()
    if z_spread > PLANE_TOLERANCE_MM:
        return _fit_tilted(uv, xyz, size, k, d, name, names, z_spread)
    plane_z = float(np.mean(z))
    w, h = size
    if k is not None:
        # IPPE takes coplanar points only; SQPnP any (points a few mm off one plane)
        cam2base = _solve_pose(uv, xyz, k, d, cv2.SOLVEPNP_IPPE if z_spread <= FLAT_Z_MM else cv2.SOLVEPNP_SQPNP)
        cal = Calibration(w, h, k, d, cam2base, None, plane_z, name)
    else:
        cal = Calibration(w, h, None, d, None, _homography(uv, xyz[:, :2]), plane_z, name)
    return _with_report(cal, uv, xyz, {"plane_z_mm": plane_z, "z_spread_mm": z_spread})


def _fit_tilted(uv, xyz, size, k, d, name, names, z_spread: float) -> Calibration:
    """The mapping on the points' least-squares plane, tilted more than the horizontal path takes: the pose
    from the 3D points (intrinsics k, d), or (k None) a homography between the image and the plane's own 2D
    frame."""
    plane, off = fit_plane(xyz, names)
    w, h = size
    if k is not None:
        cal = Calibration(w, h, k, d, _solve_pose(uv, xyz, k, d, cv2.SOLVEPNP_SQPNP), None, None, name, plane=plane)
        to_camera = cal.camera_position_mm() - plane.point_mm
        facing = float(plane.normal @ to_camera / np.linalg.norm(to_camera))  # cos of the view's angle
    else:
        hmat = _homography(uv, plane.to_plane(xyz))
        cal = Calibration(w, h, None, d, None, hmat, None, name, plane=plane)
        facing = _homography_facing(hmat)
    _check_view(plane, facing, cal.has_pose)
    extra = {"plane_z_mm": None, "z_spread_mm": z_spread, "plane": plane.describe(),
             "tilt_deg": round(plane.tilt_deg, 3), "view_angle_deg": round(float(np.degrees(np.arccos(
                 np.clip(abs(facing), 0.0, 1.0)))), 2),
             "off_plane_rms_mm": float(np.sqrt(np.mean(off ** 2))), "off_plane_max_mm": float(np.abs(off).max())}
    return _with_report(cal, uv, xyz, extra)


def _homography(uv: np.ndarray, plane_pts: np.ndarray) -> np.ndarray:
    """The homography from the pixels to their points' 2D coordinates on the plane (all points, no outlier
    rejection: each pair is a measured one)."""
    hmat, _ = cv2.findHomography(uv, plane_pts, 0)
    if hmat is None:
        raise BadInput("no homography fits these points (are they collinear?)")
    return hmat


def _homography_facing(px_to_plane: np.ndarray) -> float:
    """Without intrinsics, the cosine of the angle the plane is seen at, from the homography: the image of a
    small square about the plane's origin (its points' centroid) is foreshortened by about that, and mirrored
    (a positive determinant in the image's y-down frame) when the plane is seen from behind; negative then."""
    to_px = np.linalg.inv(px_to_plane)
    ab = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    ph = np.column_stack([ab, np.ones(3)]) @ to_px.T
    uv = ph[:, :2] / ph[:, 2:3]
    jac = np.column_stack([uv[1] - uv[0], uv[2] - uv[0]])
    sv = np.linalg.svd(jac, compute_uv=False)
    return float(-np.sign(np.linalg.det(jac)) * sv[1] / sv[0])


def _check_view(plane, facing: float, with_pose: bool) -> None:
    """Refuse a tilted plane the camera sees from behind or nearly edge-on (`facing`: the cosine of the angle
    between the plane's normal and the line of sight; negative from behind)."""
    how = "the camera pose" if with_pose else "the homography (no intrinsics)"
    if facing <= 0:
        raise BadInput(f"the camera sees the points' plane ({plane.describe()['equation']}) from behind, by "
                       f"{how}: its front, the upper side, faces away from the camera; base coordinates given in a "
                       "mirrored frame (y down) fit such a view")
    angle = float(np.degrees(np.arccos(min(facing, 1.0))))
    if angle > MAX_VIEW_ANGLE_DEG:
        raise BadInput(f"the camera sees the points' plane nearly edge-on, by {how}: {angle:.1f} deg from "
                       f"its normal (at most {MAX_VIEW_ANGLE_DEG:g}); a pixel spans {1 / facing:.1f} x more "
                       "across the plane than along it, and mapped points would be that much less accurate")


def _solve_pose(uv: np.ndarray, xyz: np.ndarray, k: np.ndarray, d: np.ndarray, solver: int) -> np.ndarray:
    """The camera's pose in the base frame (cam2base, 4 x 4) from the points: `solver`, then
    Levenberg-Marquardt, both on the points about their centroid (the origin is put back in the pose).

    IPPE is given the points flat on z = 0 of that frame: OpenCV's own move of a plane off z = 0 into its
    frame (from the first three points) gave poses hundreds of px off for markers at z = 10 or 45 mm, with
    0.2 px of noise in half the 3-marker fits (refused as "no view of one plane", or written wrong); at
    z = 0, none. The refinement then fits the points as given (their z within FLAT_Z_MM of one another)."""
    origin = xyz.mean(axis=0)
    obj = (xyz - origin).astype(np.float64)
    img = (uv - HALF_PX).astype(np.float64)
    first = obj.copy()
    if solver == cv2.SOLVEPNP_IPPE:
        first[:, 2] = 0.0
    ok, rvec, tvec = cv2.solvePnP(first, img, k, d, flags=solver)
    if not ok:
        raise BadInput("the camera pose could not be solved from these points")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, d, rvec, tvec)
    r, _ = cv2.Rodrigues(rvec)
    cam2centroid = np.linalg.inv(pose_matrix(r, tvec.ravel()))
    return pose_matrix(np.eye(3), origin) @ cam2centroid


def mapped_and_known(cal: Calibration, uv: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels mapped onto the calibration's plane and the known points they should land on: base (x, y) on a
    horizontal plane (the points' z is the plane's within its tolerance); on a tilted one the points in 3D
    and the known ones' feet on the plane (their distance off it is reported apart)."""
    if cal.plane is None:
        return cal.px_to_mm(uv), xyz[:, :2]
    return cal.px_to_xyz(uv), cal.plane.foot(xyz)


def _with_report(cal: Calibration, uv: np.ndarray, xyz: np.ndarray, plane_keys: dict) -> Calibration:
    """`cal` with its report: the residual on the plane (mm) and the reprojection (px)."""
    method = "pose" if cal.has_pose else "homography"
    try:
        if cal.has_pose:
            proj = cal.project(xyz)
        elif cal.plane is None:
            proj = cal.mm_to_px(xyz[:, :2])
        else:
            proj = cal.plane_points_to_px(cal.plane.foot(xyz))
        got, want = mapped_and_known(cal, uv, xyz)
    except BadInput:  # the fit's horizon runs through its own points: no camera sees them so
        raise BadInput(f"the {len(uv)} points fit no view of one plane: the best {method} puts some of them "
                       "beyond the plane's horizon; a pixel or a base coordinate is wrong (check each pair)") from None
    err_mm = np.linalg.norm(got - want, axis=1)
    err_px = np.linalg.norm(proj - uv, axis=1)
    report = {"method": method, "points": len(uv), **plane_keys,
              "residual_mm": float(np.sqrt(np.mean(err_mm ** 2))), "residual_max_mm": float(err_mm.max()),
              "reprojection_rms_px": float(np.sqrt(np.mean(err_px ** 2))),
              "mm_per_px": cal.mm_per_px()}
    if cal.has_pose:
        report["camera_position_mm"] = [round(float(x), 3) for x in cal.camera_position_mm()]
    return replace(cal, report=report)
