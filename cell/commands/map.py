"""`cell map CALIBRATION --px U,V ... [--z MM] --json` (or `--mm X,Y ...`): pixels <-> base frame.

On a tilted calibration plane (calibration/tilted.py) without --z the points are on that plane: x, y as
always, and `xyz_mm` gives each point's z too (`z_mm` is null: the plane has no one height).

A homography-only calibration of a horizontal plane maps at another --z through the camera it implies
(calibration/offplane.py): an estimate, said so on stderr with what it assumed and how far those assumptions'
tolerances move the points, and given in the JSON as `off_plane`."""

from __future__ import annotations

import json

from cell.commands._vision_args import allow_negative_pairs, pair, plane_z


def add_arguments(p) -> None:
    allow_negative_pairs(p)
    p.add_argument("calibration", metavar="CALIBRATION", help="calibration file")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--px", nargs="+", metavar="U,V", help="pixels (origin at the top-left pixel's corner)")
    g.add_argument("--mm", nargs="+", metavar="X,Y", help="base-frame points, mm")
    p.add_argument("--z", type=float, default=None, metavar="MM",
                   help="height of a horizontal plane (default: the calibration's plane, tilted or not)")
    p.add_argument("--camera-height", type=float, default=None, metavar="MM",
                   help="a homography-only calibration at another --z: the camera's optical centre's z, mm (default: "
                        "the default cell's camera.height_mm)")
    p.add_argument("--json", action="store_true", help="print a JSON object")


def run(args) -> int:
    from calibration import load_calibration
    from calibration.offplane import MIN_CAMERA_ABOVE_MM
    from cell.errors import BadInput
    from cell.fileio import short_text
    from cell.scene import MAX_COORD_MM

    plane_z(args.z)
    plane_z(args.camera_height, "--camera-height")
    cal = load_calibration(args.calibration)
    horizontal_homography = cal.homography is not None and not cal.has_pose and cal.plane is None
    if args.camera_height is not None and not horizontal_homography:
        raise BadInput(f"--camera-height is for a homography-only calibration of a horizontal plane; {cal.label} "
                       + ("has a camera pose" if cal.has_pose else "cannot map off its tilted plane"
                          if cal.plane is not None else "has no mapping to the base frame"))
    if args.camera_height is not None and args.camera_height - cal.plane_z_mm < MIN_CAMERA_ABOVE_MM:
        raise BadInput(f"--camera-height {args.camera_height:g}: the camera's optical centre must be at least "
                       f"{MIN_CAMERA_ABOVE_MM:g} mm above the calibration's plane z = {cal.plane_z_mm:g} mm")
    off_plane = None
    if horizontal_homography and args.z is not None and abs(args.z - cal.plane_z_mm) > 1e-6:
        from calibration.offplane import OffPlaneMapping
        from cell.cellconfig import default_cell

        if args.camera_height is None:
            height = default_cell().camera.height_mm
            off_plane = OffPlaneMapping(cal, height, f"the default cell's camera.height_mm, {height:g} mm "
                                        "(--camera-height gives another)")
        else:
            off_plane = OffPlaneMapping(cal, args.camera_height, f"--camera-height {args.camera_height:g}")
    to_mm = off_plane.px_to_mm if off_plane else cal.px_to_mm
    if args.px:
        pts = [pair(t, "--px") for t in args.px]
        w, h = cal.width_px, cal.height_px
        far = [t for t, (u, v) in zip(args.px, pts, strict=True) if not (-w <= u <= 2 * w and -h <= v <= 2 * h)]
        if far:  # 1e300,1e300 was mapped through the homography to a point (-489, -27417) mm, exit 0
            raise BadInput(f"--px {short_text(far[0])}: pixels must be within one image size of the "
                           f"calibration's {w} x {h} px images (u {-w}..{2 * w}, v {-h}..{2 * h})")
        try:
            res = to_mm(pts, args.z)
        except BadInput as e:  # beyond the plane's horizon: name the pixel
            to_mm([(w / 2, h / 2)], args.z)  # unless the image centre fails too (the calibration, --z)
            for t, p in zip(args.px, pts, strict=True):
                try:
                    to_mm([p], args.z)
                except BadInput:
                    raise BadInput(f"--px {short_text(t)}: {e}") from None
            raise
        far = [t for t, p in zip(args.px, res, strict=True) if max(map(abs, p)) > MAX_COORD_MM]
        if far:  # a pixel just short of the horizon: a point kilometres away
            raise BadInput(f"--px {short_text(far[0])}: the pixel maps to a point more than "
                           f"{MAX_COORD_MM:g} mm from the base (at the plane's horizon)")
        key = "mm"
    else:
        pts = [pair(t, "--mm") for t in args.mm]
        far = [t for t, p in zip(args.mm, pts, strict=True) if max(map(abs, p)) > MAX_COORD_MM]
        if far:  # 1e30,1e30 was mapped to 1.1e13 px, exit 0
            raise BadInput(f"--mm {far[0]}: coordinates must be within {MAX_COORD_MM:g} mm of the base "
                           "(the units are mm)")
        res = (off_plane.mm_to_px if off_plane else cal.mm_to_px)(pts, args.z)
        key = "px"
    out = {key: [[round(float(a), 4), round(float(b), 4)] for a, b in res],
           "z_mm": cal.plane_z_mm if args.z is None else args.z}
    if off_plane:
        out["off_plane"] = say_off_plane(off_plane, pts, args.z, key, args.camera_height is None)
    on_tilt = cal.plane is not None and args.z is None
    if on_tilt:  # each point's z on the plane: from the mapped x, y, or the given ones
        xyz = cal.plane.lift(res if args.px else pts)
        out.update(xyz_mm=[[round(float(v), 4) for v in p] for p in xyz], plane=cal.plane.describe())
    if args.json:
        print(json.dumps(out))
    else:
        for i, (src, (a, b)) in enumerate(zip(pts, out[key], strict=True)):
            print(f"{src[0]:g},{src[1]:g} -> {a:.3f},{b:.3f} {key}"
                  + (f" (z {out['xyz_mm'][i][2]:.3f} mm on the tilted plane)" if on_tilt else ""))
    return 0


def say_off_plane(mapping, pts, z_mm: float, key: str, default_height: bool) -> dict:
    """The JSON's `off_plane` for an estimated mapping, and the warning on stderr saying what it assumed."""
    import sys

    from calibration.offplane import ASSUMED, HEIGHT_TOLERANCE_MM, PRINCIPAL_TOLERANCE

    cal, cam = mapping.cal, mapping.camera
    bound = mapping.error_bound(pts, z_mm, key)
    unit = "mm" if key == "mm" else "px"
    w, h = cal.size
    du, dv = PRINCIPAL_TOLERANCE * w, PRINCIPAL_TOLERANCE * h
    where = (f"the camera it implies at ({cam.camera_mm[0]:.1f}, {cam.camera_mm[1]:.1f}, {cam.camera_mm[2]:.1f}) mm, "
             f"f {cam.focal_px:.0f} px, {cam.tilt_deg:.1f} deg from straight down")
    if cam.focal_from == "height":
        given = "the default cell's camera.height_mm" if default_height else "--camera-height"
        source = f"with its optical centre at z = {mapping.camera_z_mm:g} mm ({given})"
        tolerances = f"that height is off by {HEIGHT_TOLERANCE_MM:g} mm and the principal point by"
    else:
        source = (f"with the focal length the view gives (the plane seen {cam.tilt_deg:.0f} deg from straight down; "
                  f"the camera's height {mapping.camera_z_mm:g} mm is not used)")
        tolerances = "the principal point is off by"
    moved = ("; cannot bound how far" if bound is None else
             f"; these points move up to {bound:.2f} {unit} if {tolerances} {PRINCIPAL_TOLERANCE:.0%} of the image "
             f"({du:.0f} x {dv:.0f} px)")
    residual = cal.report.get("residual_mm")
    print(f"cell: warning: {cal.label} is a homography for the plane z = {cal.plane_z_mm:g} mm: on z = {z_mm:g} mm "
          f"the points are an estimate, through {where}, assuming {ASSUMED}, {source}{moved}"
          + (f" (on its own plane it fits its points to {residual:.2f} mm RMS)" if isinstance(residual, float) else ""),
          file=sys.stderr)
    return {**mapping.describe(), f"error_bound_{unit}": None if bound is None else round(bound, 3),
            "bound_assumes": {"camera_height_within_mm": HEIGHT_TOLERANCE_MM if cam.focal_from == "height" else None,
                              "principal_point_within_px": [round(du, 1), round(dv, 1)]}}
