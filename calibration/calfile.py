"""The calibration file: readable, versioned JSON, validated on read, written atomically.

```json
{
  "format": "disassembly-cell/calibration",
  "version": 1,
  "name": "default cell camera",
  "image": {"width_px": 1280, "height_px": 1024},
  "intrinsics": {"fx": 1600.0, "fy": 1600.0, "cx": 642.7, "cy": 509.1, "skew": 0.0,
                 "dist": [k1, k2, p1, p2, k3], "rms_px": 0.2},        // or null
  "pose": {"cam2base": [[r, r, r, x], [r, r, r, y], [r, r, r, z], [0, 0, 0, 1]],
           "plane_z_mm": 0.0},                                       // or null
  "homography": {"px_to_mm": [[...], [...], [...]], "plane_z_mm": 0.0},  // or null
  "report": {...}                                                     // free-form, kept
}
```
A calibration on a tilted plane (calibration/tilted.py) is version 2 (a reader of version 1 would
map on a horizontal plane): `"plane": {"point_mm": [x, y, z], "x_axis": [...], "y_axis": [...],
"normal": [...]}`, `pose` without `plane_z_mm`, `homography` as `{"px_to_plane_mm": [[3 x 3]]}`
(pixels to the plane's own 2D frame). Horizontal calibrations are written as version 1, as before.
`cx`, `cy` are OpenCV's (pixel centres at integers); mapping functions take and give
CONTRACT-frame pixels (see calibration/camera.py). Lengths in mm.
"""

from __future__ import annotations

from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np

from calibration.camera import Calibration
from calibration.tilted import MAX_TILT_DEG, TiltedPlane
from cell.cellconfig import CAMERA_PX
from cell.errors import BadInput
from cell.fileio import has_non_number, is_finite_number, read_json, short_repr, to_jsonable, write_json_atomic

FORMAT = "disassembly-cell/calibration"
VERSION = 1  # a horizontal plane's (and intrinsics only): written as before
PLANE_VERSION = 2  # a tilted plane's: a reader of version 1 only would map it on a horizontal plane
UNIT_TOLERANCE = 1e-6  # the tilted plane's axes: unit, at right angles, normal = x_axis x y_axis
MAX_HOMOGRAPHY_COND = 1e12  # a fitted px -> mm homography of a 1920 x 1080 frame: about 1e5
MAX_PX = 1e6  # fx, fy and the principal point: a real lens's fx is hundreds to tens of thousands of px
MAX_MM = 1e6  # camera position and plane height, as coordinates in scene files


def default_calibration_path() -> Path:
    return Path(str(resources.files("calibration") / "data" / "default.json"))


def load_calibration(path: str | Path | None = None, *, size: tuple[int, int] | None = None) -> Calibration:
    """Read and validate a calibration file (None: the default cell's).

    `size` = (width_px, height_px) refuses a file made for another resolution.
    """
    path = default_calibration_path() if path is None else Path(path)
    raw = read_json(path, "calibration file")
    cal = replace(parse_calibration(raw, str(path)), source=str(path))
    if size is not None and tuple(size) != cal.size:
        raise BadInput(f"calibration file {path} is for {cal.width_px} x {cal.height_px} px images, "
                       f"not {size[0]} x {size[1]} px")
    return cal


def save_calibration(cal: Calibration, path: str | Path) -> None:
    """Write `cal` atomically (a crash leaves the old file or the new one, never half). Nothing that
    `load_calibration` would refuse is written (BadInput, the file left as it was): the reader's own checks
    run on what is about to be written. A lens model that folds the image (a fit of too few or too similar
    views) and a camera that does not look down on its plane are named first, with what to do."""
    def refuse(why: str):
        raise BadInput(f"{why}: {path} not written")

    if cal.camera_matrix is not None and cal.cam2base is not None:  # what load_calibration would refuse
        _check_sees_plane(cal.camera_matrix, np.asarray(cal.cam2base, float), cal.plane_z_mm,
                          int(cal.width_px), int(cal.height_px), refuse, cal.plane)
    if cal.camera_matrix is not None and not is_lens_model(cal.camera_matrix, np.ravel(cal.dist),
                                                               int(cal.width_px), int(cal.height_px)):
        coefficients = np.round(np.ravel(cal.dist), 4).tolist()
        raise BadInput(f"the fitted distortion {coefficients} folds or collapses the image: {path} not written; "
                       "more views, tilted in several directions, give a lens model")
    raw = checked_json(cal, refuse)  # and whatever else the reader would refuse: `cell map` would say so only later
    try:
        write_json_atomic(path, raw)
    except OSError as e:  # a directory, a read-only place, a full disk: the user's to fix
        raise BadInput(f"cannot write the calibration file {path}: {e.strerror or e}") from None


def calibration_to_json(cal: Calibration) -> dict:
    d: dict = {"format": FORMAT, "version": VERSION, "name": cal.name,
               "image": {"width_px": int(cal.width_px), "height_px": int(cal.height_px)},
               "intrinsics": None, "pose": None, "homography": None}
    if cal.camera_matrix is not None:
        k = cal.camera_matrix
        d["intrinsics"] = {"fx": float(k[0, 0]), "fy": float(k[1, 1]), "cx": float(k[0, 2]),
                           "cy": float(k[1, 2]), "skew": float(k[0, 1]),
                           "dist": [float(x) for x in np.ravel(cal.dist)]}
    if cal.plane is not None:
        d["version"] = PLANE_VERSION
        p = cal.plane
        d["plane"] = {key: [float(v) for v in vec] for key, vec in
                      (("point_mm", p.point_mm), ("x_axis", p.x_axis), ("y_axis", p.y_axis), ("normal", p.normal))}
    height = {} if cal.plane is not None else {"plane_z_mm": float(cal.plane_z_mm)}
    if cal.cam2base is not None:
        d["pose"] = {"cam2base": np.asarray(cal.cam2base, float).tolist(), **height}
    if cal.homography is not None:
        key = "px_to_mm" if cal.plane is None else "px_to_plane_mm"
        d["homography"] = {key: np.asarray(cal.homography, float).tolist(), **height}
    d["report"] = to_jsonable(cal.report, nonfinite="null")
    return d


def checked_json(cal: Calibration, fail) -> dict:
    """`cal` as its file holds it, with the file's reader's checks run on it: `fail(why)` where it would be
    refused (every writer of a calibration file: nothing is written that cannot be read back)."""
    raw = calibration_to_json(cal)
    parse_calibration(raw, fail=fail)
    return raw


def parse_calibration(raw, source: str = "<calibration>", fail=None) -> Calibration:
    """Validate the JSON object of a calibration file; every problem names the key. `fail(why)` raises (by
    default BadInput naming `source`; the writer passes its own, to refuse what it was about to write)."""

    def fail_in_file(why: str):
        raise BadInput(f"calibration file {source}: {why}")

    fail = fail or fail_in_file

    if not isinstance(raw, dict):
        fail("top level must be a JSON object")
    if raw.get("format") != FORMAT:
        fail(f"'format' must be {FORMAT!r}, got {short_repr(raw.get('format'))} (not a calibration file?)")
    version = raw.get("version")
    if not isinstance(version, int) or isinstance(version, bool):
        fail(f"'version' must be an integer, got {short_repr(version)}")
    if version > PLANE_VERSION or version < 1:
        fail(f"version {version} is not supported (this program reads version {VERSION}, and {PLANE_VERSION} for a "
             "tilted plane)")
    img = raw.get("image")
    if not isinstance(img, dict):
        fail("'image' must be an object with width_px and height_px")
    w, h = img.get("width_px"), img.get("height_px")
    for key, v in (("width_px", w), ("height_px", h)):
        if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
            fail(f"image.{key} must be a positive integer, got {short_repr(v)}")
    if min(w, h) < CAMERA_PX[0] or w * h > CAMERA_PX[1]:  # checked before the lens model, which samples the image
        fail(f"image {w} x {h} px: each side at least {CAMERA_PX[0]} px, at most {CAMERA_PX[1] / 1e6:g} MP in all")

    k = dist = cam2base = hom = None
    plane = _tilted_plane(raw.get("plane"), version, fail)
    plane_z = 0.0 if plane is None else None
    intr = raw.get("intrinsics")
    if intr is not None:
        if not isinstance(intr, dict):
            fail("'intrinsics' must be an object or null")
        vals = {}
        for key in ("fx", "fy", "cx", "cy"):
            vals[key] = _finite(intr.get(key), f"intrinsics.{key}", fail)
        skew = _finite(intr.get("skew", 0.0), "intrinsics.skew", fail)
        check_camera_matrix(vals["fx"], vals["fy"], vals["cx"], vals["cy"], skew, w, h, fail)
        dist_raw = intr.get("dist", [0.0] * 5)
        if not isinstance(dist_raw, list) or len(dist_raw) not in (4, 5, 8, 12, 14):
            fail("intrinsics.dist must be a list of 4, 5, 8, 12 or 14 numbers (OpenCV's order)")
        dist = np.array([_finite(x, "intrinsics.dist", fail) for x in dist_raw])
        k = np.array([[vals["fx"], skew, vals["cx"]], [0.0, vals["fy"], vals["cy"]], [0.0, 0.0, 1.0]])
        if not is_lens_model(k, dist, w, h):
            fail("intrinsics.dist folds or collapses the image: points along its rows or columns come out of "
                 "order, or far closer or further apart than a pinhole camera's, when undistorted; that is no lens "
                 "(check the coefficients' order: k1, k2, p1, p2, k3, ...)")
    pose = raw.get("pose")
    if pose is not None:
        if k is None:
            fail("'pose' needs 'intrinsics'")
        if not isinstance(pose, dict):
            fail("'pose' must be an object or null")
        cam2base = _matrix(pose.get("cam2base"), (4, 4), "pose.cam2base", fail)
        r = cam2base[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            fail("pose.cam2base rotation part is not a rotation matrix")
        if not np.allclose(cam2base[3], [0, 0, 0, 1]):
            fail("pose.cam2base last row must be [0, 0, 0, 1]")
        if plane is None:
            plane_z = _finite(pose.get("plane_z_mm", 0.0), "pose.plane_z_mm", fail)
        elif pose.get("plane_z_mm") is not None:
            fail("pose.plane_z_mm: a calibration on a tilted 'plane' has no one height")
        if np.abs(cam2base[:3, 3]).max() > MAX_MM or abs(plane_z or 0.0) > MAX_MM:
            fail(f"pose.cam2base's position and plane_z_mm must be within {MAX_MM:g} mm of the base")
        _check_sees_plane(k, cam2base, plane_z, w, h, fail, plane)
    homr = raw.get("homography")
    if homr is not None:
        if not isinstance(homr, dict):
            fail("'homography' must be an object or null")
        key = "px_to_mm" if plane is None else "px_to_plane_mm"  # to the plane's own 2D frame
        if plane is not None and ("px_to_mm" in homr or homr.get("plane_z_mm") is not None):
            fail("homography: on a tilted 'plane' it is 'px_to_plane_mm', without px_to_mm or plane_z_mm")
        hom = _matrix(homr.get(key), (3, 3), f"homography.{key}", fail)
        with np.errstate(over="ignore", invalid="ignore"):
            cond = np.linalg.cond(hom)  # scale-free: a homography times any factor is the same mapping
        if not np.isfinite(cond) or cond > MAX_HOMOGRAPHY_COND:
            fail(f"homography.{key} is singular (or too badly conditioned to invert)")
        if plane is None:
            plane_z = _finite(homr.get("plane_z_mm", plane_z), "homography.plane_z_mm", fail)
            if abs(plane_z) > MAX_MM:
                fail(f"homography.plane_z_mm must be within {MAX_MM:g} mm of the base")
        _check_homography_looks_down(hom, plane_z, w, h, fail, plane)
    if k is None and hom is None:
        fail("the file has neither 'intrinsics' nor 'homography'")
    report = raw.get("report", {})
    if not isinstance(report, dict):
        fail("'report' must be an object")
    if plane is not None and cam2base is None and hom is None:
        fail("'plane' needs a 'pose' or a 'homography' that maps onto it")
    return Calibration(w, h, k, dist if dist is not None else np.zeros(5), cam2base, hom, plane_z,
                       str(raw.get("name", Path(source).stem)), report, plane)


def check_camera_matrix(fx: float, fy: float, cx: float, cy: float, skew: float, w: int, h: int, fail,
                        where: str = "intrinsics.") -> None:
    """The camera matrix's numbers as the reader takes them, for `w` x `h` px images: `fail(why)` otherwise
    (`where` prefixes the names: the file's keys, or "" for a command-line option's)."""
    if not (1.0 <= fx <= MAX_PX and 1.0 <= fy <= MAX_PX):
        # 1e300 or 1e-300 were refused as a distortion that 'folds the image': name the key instead
        fail(f"{where}fx and fy must be between 1 and {MAX_PX:g} px (a real lens: hundreds to tens of "
             f"thousands), got {fx:g} and {fy:g}")
    for key, value, size in (("cx", cx, w), ("cy", cy, h)):
        if abs(value - size / 2) > 10 * size:
            fail(f"{where}{key} = {value:g} px is not near the {size} px image (the principal point "
                 "lies in or close to the image)")
    if abs(skew) > fx:
        fail(f"{where}skew = {skew:g} px: at most fx ({fx:g}); it is about 0 for a real camera")


def _tilted_plane(raw, version: int, fail) -> TiltedPlane | None:
    """The file's tilted plane (version 2), validated: a point, unit axes at right angles, the normal their
    cross product and pointing up, not steeper than MAX_TILT_DEG."""
    if raw is None:
        if version >= PLANE_VERSION:  # else a pose would map on z = 0, the default height: silently wrong
            fail(f"version {version} is a tilted plane's calibration, but 'plane' is missing or null")
        return None
    if version < PLANE_VERSION:
        fail(f"'plane' (a tilted calibration plane) needs version {PLANE_VERSION}; version {version} files map on "
             "a horizontal plane")
    if not isinstance(raw, dict):
        fail("'plane' must be an object {point_mm, x_axis, y_axis, normal} or null")
    vec = {key: _matrix(raw.get(key), (3,), f"plane.{key}", fail) for key in ("point_mm", "x_axis", "y_axis",
                                                                            "normal")}
    if np.abs(vec["point_mm"]).max() > MAX_MM:
        fail(f"plane.point_mm must be within {MAX_MM:g} mm of the base")
    axes = np.array([vec["x_axis"], vec["y_axis"], vec["normal"]])
    if not (np.allclose(axes @ axes.T, np.eye(3), atol=UNIT_TOLERANCE)
            and np.allclose(np.cross(vec["x_axis"], vec["y_axis"]), vec["normal"], atol=UNIT_TOLERANCE)):
        fail("plane.x_axis, y_axis and normal must be unit vectors at right angles, normal = x_axis x y_axis")
    plane = TiltedPlane(vec["point_mm"], vec["x_axis"], vec["y_axis"])
    if plane.tilt_deg > MAX_TILT_DEG:  # the normal pointing down is a tilt over 90 degrees
        fail(f"plane.normal {np.round(vec['normal'], 4).tolist()} is tilted {plane.tilt_deg:.1f} deg from straight "
             f"up; a calibration plane's normal points up, at most {MAX_TILT_DEG:g} deg from it")
    return plane


LENS_SPREAD_RANGE = (0.1, 10.0)  # undistorted image extent / pinhole extent that a lens can give
LENS_ROUND_TRIP_PX = 0.5


def is_lens_model(k: np.ndarray, dist: np.ndarray, w: int, h: int, n: int = 9) -> bool:
    """Do points along the image's borders and middle lines stay in order, finite and about as far apart
    as a pinhole camera's, when undistorted?
    A real lens maps the image one to one; dist = [1e10, 0, ...] sent every pixel to about one point
    (every part outline collapsed), a large k2 folds the corners back."""
    import cv2

    us, vs = np.linspace(0.0, w - 1.0, n), np.linspace(0.0, h - 1.0, n)
    lines = [np.stack([us, np.full(n, v)], 1) for v in (0.0, (h - 1) / 2, h - 1.0)]
    lines += [np.stack([np.full(n, u), vs], 1) for u in (0.0, (w - 1) / 2, w - 1.0)]
    pts = np.concatenate(lines).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)  # converged, not OpenCV's 5 steps
    with np.errstate(all="ignore"):
        und = cv2.undistortPoints(pts, k, dist, None, None, None, criteria).reshape(6, n, 2)
    if not np.all(np.isfinite(und)):
        return False
    # the undistorted points must distort back onto the pixels (OpenCV's iteration gives up on a
    # diverging model, e.g. k1 = -50, and hands the pinhole points back unchanged)
    rays = np.concatenate([und.reshape(-1, 2), np.ones((und.size // 2, 1))], axis=1)
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, dist)
    if not np.all(np.abs(back.reshape(-1, 2) - pts.reshape(-1, 2)) < LENS_ROUND_TRIP_PX):
        return False
    along = np.concatenate([und[:3, :, 0], und[3:, :, 1]])  # x along the rows, y along the columns
    if not np.all(np.diff(along, axis=1) > 0):
        return False
    # ... and spread about as far as the pinhole image's (wide-angle barrel: a few times; 1e10: 1e-3)
    pinhole = np.array([(w - 1) / k[0, 0]] * 3 + [(h - 1) / k[1, 1]] * 3)
    ratio = (along[:, -1] - along[:, 0]) / pinhole
    return bool(np.all((ratio > LENS_SPREAD_RANGE[0]) & (ratio < LENS_SPREAD_RANGE[1])))


def _check_sees_plane(k: np.ndarray, cam2base: np.ndarray, plane_z_mm: float | None, w: int, h: int, fail,
                      plane: TiltedPlane | None = None) -> None:
    """The camera must be above the plane the pose was made for (in front of a tilted `plane`) and its image
    centre look down onto it: a camera under the table, or one looking up at it (markers given in a
    mirrored, y-down frame fit such a pose), sees no part from above. (A steeply tilted camera may see past
    the plane's horizon at an edge; such pixels are refused when mapped.)"""
    centre = np.array([(w / 2 - k[0, 2]) / k[0, 0], (h / 2 - k[1, 2]) / k[1, 1], 1.0])
    ray = cam2base[:3, :3] @ centre
    if plane is not None:
        if not (plane.off(cam2base[:3, 3])[0] > 0 and ray @ plane.normal < 0):
            fail(f"pose: the camera at {np.round(cam2base[:3, 3], 1).tolist()} mm, looking along "
                 f"{np.round(ray / np.linalg.norm(ray), 3).tolist()}, does not look onto the front (upper side) of "
                 f"the plane {plane.describe()['equation']}")
        return
    height_mm = cam2base[2, 3] - plane_z_mm
    if not (height_mm > 0 and ray[2] < 0):
        fail(f"pose: the camera at z = {cam2base[2, 3]:g} mm, looking along "
             f"{np.round(ray / np.linalg.norm(ray), 3).tolist()}, does not look down onto the plane z = "
             f"{plane_z_mm:g} mm from above (the pose is the camera's in the base frame, z up; base "
             "coordinates given in a mirrored frame, y down, fit a camera below the plane)")


def _check_homography_looks_down(px_to_mm: np.ndarray, plane_z_mm: float | None, w: int, h: int, fail,
                                 plane: TiltedPlane | None = None) -> None:
    """A homography must map the image onto its plane as a camera above it sees it: turned, not mirrored. Seen
    from above (z up, right-handed base frame; a tilted plane's front, with its own right-handed 2D frame), the
    map from the image (u right, v down) to the plane has a negative Jacobian determinant; from below, or with
    base coordinates given in a mirrored frame (y down), a positive one. That determinant is
    det(H) / w(u, v)^3 (w the third row of H times (u, v, 1)): its sign changes only across the plane's horizon,
    w = 0, and every pixel the calibration maps lies on the image centre's side of it (calibration/camera.py
    refuses the others), so its sign at the image centre is its sign at every such pixel, markers included."""
    with np.errstate(over="ignore", invalid="ignore"):
        w_centre = float(px_to_mm[2] @ [w / 2.0, h / 2.0, 1.0])
        det = float(np.linalg.det(px_to_mm))
    if np.sign(det) * np.sign(w_centre) < 0:
        return
    if plane is not None:
        fail(f"homography: it maps the image onto the plane {plane.describe()['equation']} mirrored, as a camera "
             "behind the plane would see it: it does not look onto the front (upper side) of the plane (base "
             "coordinates given in a mirrored frame, y down, fit a mirrored mapping)")
    fail(f"homography: it maps the image onto the plane z = {plane_z_mm:g} mm mirrored, as a camera below the "
         f"plane would see it: it does not look down onto the plane z = {plane_z_mm:g} mm from above (the "
         "mapping is to the base frame, z up; base coordinates given in a mirrored frame, y down, fit a "
         "mirrored mapping)")


def _finite(v, where, fail) -> float:
    if not is_finite_number(v):
        fail(f"{where} must be a finite number, got {short_repr(v)}")
    return float(v)


def _matrix(v, shape, where, fail) -> np.ndarray:
    kind = f"a {shape[0]} x {shape[1]} list of" if len(shape) == 2 else f"a list of {shape[0]}"
    if has_non_number(v):
        fail(f"{where} must be {kind} numbers (true/false and strings are not numbers)")
    try:
        arr = np.array(v, dtype=float)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond a float
        fail(f"{where} must be {kind} numbers")
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        fail(f"{where} must be {kind} finite numbers")
    return arr
