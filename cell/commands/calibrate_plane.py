"""`cell calibrate plane IMAGE --markers MARKERS.json --out FILE [--camera-matrix ... | --intrinsics FILE]`.

Also `--points POINTS.json` instead of markers: points touched with the gripper tip,
`{"points": [{"px": [u, v], "mm": [x, y, z]}, ...]}` (u, v in the CONTRACT pixel frame, within the image).
"""

from __future__ import annotations

import json
import sys

from cell.commands._vision_args import numbers, refuse_out_over_an_input

MIN_MARKERS = 3
# A fit this bad is an error in the inputs, not a poor camera: the Festo frames fit to 1.1-1.5 px, and
# one marker's corners listed one off gave 31-38 px (21 mm on the table). Such a file is not written
# unless --accept-poor-fit says so: `cell run` would pick 20 mm beside the parts.
REFUSE_REPROJECTION_PX = 10.0


def add_arguments(p) -> None:
    p.add_argument("image", metavar="IMAGE", help="camera frame showing the fiducials")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--markers", metavar="MARKERS.json", help="ArUco markers at known base coordinates")
    src.add_argument("--points", metavar="POINTS.json", help="pixel / base-frame pairs (touched points)")
    p.add_argument("--out", required=True, metavar="FILE", help="calibration file to write")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--camera-matrix", metavar="FX,FY,CX,CY", help="intrinsics (OpenCV's cx, cy), no distortion")
    g.add_argument("--intrinsics", metavar="FILE", help="a calibration file with intrinsics")
    p.add_argument("--name", default=None, help="name stored in the calibration file")
    p.add_argument("--accept-poor-fit", action="store_true",
                   help=f"write the file even with a fit worse than {REFUSE_REPROJECTION_PX:g} px RMS reprojection")
    p.add_argument("--json", action="store_true", help="accepted for symmetry: the result is always JSON")


def principal_point_off_centre(k, w: int, h: int) -> str | None:
    """Where a camera matrix's principal point lies, when far from the image's centre (more than
    PRINCIPAL_OFF_CENTRE_WARN of its size, as `cell calibrate intrinsics` warns) or outside it; else None."""
    from calibration.intrinsics import PRINCIPAL_OFF_CENTRE_WARN, principal_point_offset

    cx, cy = float(k[0, 2]), float(k[1, 2])
    if not (0 <= cx <= w and 0 <= cy <= h):
        return "outside the image"
    dx, dy = principal_point_offset(k, w, h)
    if max(dx, dy) > PRINCIPAL_OFF_CENTRE_WARN:
        return f"{100 * dx:.0f}% / {100 * dy:.0f}% of the image's size off its centre"
    return None


def run(args) -> int:
    import numpy as np

    from calibration import load_calibration, save_calibration
    from calibration.calfile import check_camera_matrix
    from calibration.plane import (
        FLAT_Z_MM,
        detect_markers,
        fit_plane_mapping,
        holdout_residuals,
        leave_one_out_fits,
        marker_not_fitting,
        marker_residuals,
        markers_correspondences,
        odd_marker_warning,
        parse_markers,
    )
    from cell.errors import BadInput
    from cell.fileio import check_writable, read_json
    from cell.vision.sources import read_image

    refuse_out_over_an_input(args.out, [args.image, args.markers, args.points, args.intrinsics])
    check_writable(args.out, "--out")  # before the fit, not after
    frame = read_image(args.image)
    h, w = frame.shape[:2]
    k = dist = None
    if args.camera_matrix:
        fx, fy, cx, cy = numbers(args.camera_matrix, 4, "--camera-matrix")
        if fx <= 0 or fy <= 0:
            raise BadInput("--camera-matrix: fx and fy must be positive")
        if max(fx, fy, abs(cx), abs(cy)) > 1e6:  # 1e300 was 'the plane z = 0.0 mm is not in front of the camera'
            raise BadInput(f"--camera-matrix {args.camera_matrix}: pixels, each within 1e6 (fx, fy of a real lens "
                           "are hundreds to tens of thousands)")

        def refuse_matrix(why: str):
            raise BadInput(f"--camera-matrix {args.camera_matrix}: {why}")

        # as the calibration file's reader checks them: fx 0.5 or cx 100000 was written (exit 0) into a file
        # that `cell map` then refused
        check_camera_matrix(fx, fy, cx, cy, 0.0, w, h, refuse_matrix, where="")
        k, dist = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.zeros(5)
    elif args.intrinsics:
        intr = load_calibration(args.intrinsics, size=(w, h))
        if not intr.has_intrinsics:
            raise BadInput(f"{args.intrinsics} holds no intrinsics")
        k, dist = intr.camera_matrix, intr.dist
    out: dict = {}
    if args.markers:
        dictionary, known = parse_markers(read_json(args.markers, "markers file"), args.markers)
        if len(known) < MIN_MARKERS:  # no image could help: was "2 of the markers ... were found"
            raise BadInput(f"--markers {args.markers} lists only {len(known)} marker{'s' * (len(known) > 1)} "
                           f"({sorted(known)}); at least {MIN_MARKERS} are needed")
        duplicated: list[int] = []
        detected = detect_markers(cv_grey(frame), dictionary, duplicated)
        uv, xyz, used, missing = markers_correspondences(detected, known)
        missing = [i for i in missing if i not in duplicated]  # seen, but ambiguous: reported as such
        out.update({"markers_used": used, "markers_missing": missing,
                    "markers_detected": sorted(detected), "markers_duplicated": duplicated})
        if len(used) < MIN_MARKERS:
            raise BadInput(f"{len(used)} of the markers in {args.markers} were found in {args.image} "
                           f"(found ids {sorted(detected)}, need at least {MIN_MARKERS} of {sorted(known)}"
                           + (f"; seen more than once, left out: {duplicated}" if duplicated else "") + ")")
        names = [f"marker {i} corner {j}" for i in used for j in range(4)]
    else:
        uv, xyz = parse_points(read_json(args.points, "points file"), args.points, (w, h), args.image)
        names = None  # "point #i", as the points file numbers them
    cal = fit_plane_mapping(uv, xyz, (w, h), k, dist, args.name or "plane calibration", names)
    warnings: list[str] = []
    if args.markers:
        per_marker, warnings = marker_residuals(cal, detected, known, used)
        if duplicated:
            warnings.insert(0, f"markers seen more than once in the image, left out: {duplicated}")
        fits = leave_one_out_fits(detected, known, used, (w, h), k, dist, cal.plane)  # (read by both below)
        held_out = holdout_residuals(detected, known, used, (w, h), fits=fits)
        # named, not left out: the file is the calibration asked for (the markers as listed), and the
        # refusal over REFUSE_REPROJECTION_PX still holds; the user removes the marker, or corrects it
        odd = marker_not_fitting(detected, known, used, (w, h), cal.report["reprojection_rms_px"], fits=fits)
        # after "the markers fit badly", which it explains; a marker already named for its corner order has
        # the better hint
        if odd is not None and not any(say.startswith(f"marker {odd['id']}:") for say in warnings):
            at = next((n + 1 for n, say in enumerate(warnings) if say.startswith("the markers fit badly")), 0)
            warnings.insert(at, odd_marker_warning(odd, len(used)))
        cal.report.update({"markers_used": out["markers_used"], "markers_missing": out["markers_missing"],
                           "markers_duplicated": duplicated, "marker_not_fitting": odd,
                           "per_marker_residual_mm": per_marker, "warnings": warnings,
                           "holdout_residual_mm": held_out,
                           "holdout_residual_max_mm": max(held_out.values()) if held_out else None})
    if k is not None and (fov := wide_view_deg(k, w, h)) is not None:  # a digit lost from fx, fy
        warnings.append(f"the camera matrix gives a {fov:.0f} degree field of view across the image (fx "
                        f"{k[0, 0]:g}, fy {k[1, 1]:g} px for {w} x {h} px), wider than almost any lens: is a digit "
                        "missing? (the fit can follow a wrong focal length with a wrong camera height)")
        cal.report["warnings"] = warnings
    if k is not None and (off := principal_point_off_centre(k, w, h)) is not None:
        # intrinsics made for another resolution (the full frame's matrix on a half-size image: its principal
        # point at the corner) were taken without a word: the camera 1553 mm up instead of 779, maps 3 mm off
        warnings.append(f"the camera matrix's principal point ({k[0, 2]:.1f}, {k[1, 2]:.1f}) lies {off} ({w} x {h} "
                        "px): are the intrinsics for another resolution? (scale fx, fy, cx and cy with the image)")
        cal.report["warnings"] = warnings
    if cal.has_pose:
        distance_mm = float(np.linalg.norm(cal.camera_position_mm() - xyz.mean(axis=0)))
        cal.report["camera_distance_mm"] = round(distance_mm, 3)
        if distance_mm > FAR_CAMERA_MM:  # a digit too many in fx, fy
            fov = 2 * np.degrees(np.arctan(w / (2 * k[0, 0])))
            warnings.append(f"the fit puts the camera {distance_mm:.0f} mm from the points, more than "
                            f"{FAR_CAMERA_MM:g} mm (a cell's camera hangs within a few metres of its table): with "
                            f"fx {k[0, 0]:g}, fy {k[1, 1]:g} px the view is {fov:.1f} degrees across {w} px; is the "
                            "focal length a digit too long? (the fit follows a wrong focal length with a wrong "
                            "camera distance)")
            cal.report["warnings"] = warnings
    if cal.plane is None and cal.report["z_spread_mm"] > FLAT_Z_MM:
        warnings.append(f"the {'markers' if args.markers else 'points'}' z spans {cal.report['z_spread_mm']:.1f} mm: "
                        f"the mapping is for their mean plane, z = {cal.report['plane_z_mm']:.2f} mm")
        cal.report["warnings"] = warnings
    cal.report["image"] = str(args.image)
    rms = cal.report.get("reprojection_rms_px")
    if rms is not None and rms > REFUSE_REPROJECTION_PX and not args.accept_poor_fit:
        hints = [w for w in warnings if not w.startswith("the markers fit badly")]
        raise BadInput(f"the {'markers' if args.markers else 'points'} fit {rms:.1f} px RMS reprojection "
                       f"({cal.report['residual_mm']:.1f} mm RMS on the plane; more than {REFUSE_REPROJECTION_PX:g} px "
                       f"is an error in the coordinates or the corner order): {args.out} not written"
                       + ("; " + "; ".join(hints) if hints else "")
                       + " (--accept-poor-fit writes it anyway)")
    save_calibration(cal, args.out)
    out = {**cal.report, **out, "out": str(args.out)}
    print(json.dumps(out))
    if out.get("markers_missing"):
        print(f"cell: warning: markers not found in the image: {out['markers_missing']}", file=sys.stderr)
    for w in warnings:
        print(f"cell: warning: {w}", file=sys.stderr)
    return 0


WIDE_VIEW_DEG = 120.0  # wider than this across the image: a fisheye, or a focal length 10 x too short
# A camera the fit puts farther than this from the points' centroid: no cell hangs its camera so high (the
# default cell's is 0.8 m over the tray), but a focal length 10 x too long puts it there (fx 16000 for a
# 1280 px frame: 8 m), and a narrow view alone does not tell (telephoto lenses of 5 - 10 degrees exist)
FAR_CAMERA_MM = 3000.0


def wide_view_deg(k, w: int, h: int) -> float | None:
    """The widest field of view across the image (deg) that the camera matrix `k` gives, when it is more than
    WIDE_VIEW_DEG; else None."""
    import math

    fov = max(2 * math.degrees(math.atan(w / (2 * k[0, 0]))), 2 * math.degrees(math.atan(h / (2 * k[1, 1]))))
    return fov if fov > WIDE_VIEW_DEG else None


def cv_grey(frame):
    import cv2

    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)


def parse_points(raw, source: str, size: tuple[int, int], image) -> tuple:
    """The points file's pixel / base-frame pairs. A pixel outside `image` of `size` (w, h) is refused: no
    point touched on the table can be seen there. The image covers [0, w] x [0, h] in the CONTRACT frame
    (origin at the top-left pixel's top-left corner), border included."""
    import numpy as np

    from cell.errors import BadInput
    from cell.fileio import has_non_number
    from cell.scene import MAX_COORD_MM

    pts = raw.get("points") if isinstance(raw, dict) else None
    if not isinstance(pts, list) or not pts:
        raise BadInput(f"{source}: expected {{\"points\": [{{\"px\": [u, v], \"mm\": [x, y, z]}}, ...]}}")
    uv, xyz = [], []
    for i, p in enumerate(pts):
        if isinstance(p, dict) and (has_non_number(p.get("px")) or has_non_number(p.get("mm"))):
            raise BadInput(f"{source}: point #{i} needs 'px': [u, v] and 'mm': [x, y, z] (true/false and strings "
                           "are not numbers)")
        try:
            a = np.array(p["px"], float)
            b = np.array(p["mm"], float)
        except OverflowError:  # an integer literal too large for a float (JSON allows any length)
            raise BadInput(f"{source}: point #{i} needs 'px': [u, v] and 'mm': [x, y, z] (finite numbers; one is "
                           "too large)") from None
        except (KeyError, TypeError, ValueError):
            raise BadInput(f"{source}: point #{i} needs 'px': [u, v] and 'mm': [x, y, z]") from None
        if a.shape != (2,) or b.shape != (3,) or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise BadInput(f"{source}: point #{i} needs 'px': [u, v] and 'mm': [x, y, z] (finite numbers)")
        if np.abs(b).max() > MAX_COORD_MM:
            raise BadInput(f"{source}: point #{i} 'mm' must be within {MAX_COORD_MM:g} mm of the base (the units "
                           "are mm)")
        if not (0 <= a[0] <= size[0] and 0 <= a[1] <= size[1]):
            raise BadInput(f"{source}: point #{i} 'px' [{a[0]:g}, {a[1]:g}] lies outside the image {image} "
                           f"({size[0]} x {size[1]} px: u within 0..{size[0]}, v within 0..{size[1]}, from the "
                           "top-left pixel's top-left corner)")
        uv.append(a)
        xyz.append(b)
    return np.array(uv), np.array(xyz)
