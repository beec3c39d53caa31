"""`cell map CALIBRATION --px U,V ... [--z MM] --json` (or `--mm X,Y ...`): pixels <-> base frame.

On a tilted calibration plane (calibration/tilted.py) without --z the points are on that plane: x, y as
always, and `xyz_mm` gives each point's z too (`z_mm` is null: the plane has no one height)."""

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
    p.add_argument("--json", action="store_true", help="print a JSON object")


def run(args) -> int:
    from calibration import load_calibration
    from cell.errors import BadInput
    from cell.fileio import short_text
    from cell.scene import MAX_COORD_MM

    plane_z(args.z)
    cal = load_calibration(args.calibration)
    if args.px:
        pts = [pair(t, "--px") for t in args.px]
        w, h = cal.width_px, cal.height_px
        far = [t for t, (u, v) in zip(args.px, pts, strict=True) if not (-w <= u <= 2 * w and -h <= v <= 2 * h)]
        if far:  # 1e300,1e300 was mapped through the homography to a point (-489, -27417) mm, exit 0
            raise BadInput(f"--px {short_text(far[0])}: pixels must be within one image size of the "
                           f"calibration's {w} x {h} px images (u {-w}..{2 * w}, v {-h}..{2 * h})")
        try:
            res = cal.px_to_mm(pts, args.z)
        except BadInput as e:  # beyond the plane's horizon: name the pixel
            cal.px_to_mm([(w / 2, h / 2)], args.z)  # unless the image centre fails too (the calibration, --z)
            for t, p in zip(args.px, pts, strict=True):
                try:
                    cal.px_to_mm([p], args.z)
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
        res = cal.mm_to_px(pts, args.z)
        key = "px"
    out = {key: [[round(float(a), 4), round(float(b), 4)] for a, b in res],
           "z_mm": cal.plane_z_mm if args.z is None else args.z}
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
