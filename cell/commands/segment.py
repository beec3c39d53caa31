"""`cell segment IMAGE... --json [--calibration FILE] [--z MM]`: frames -> part contours."""

from __future__ import annotations

import json
import sys

from cell.commands._vision_args import finite, plane_z

MIN_AREA_MM2 = 75.0  # with a calibration: regions smaller than this are specks


def add_arguments(p) -> None:
    p.add_argument("images", nargs="+", metavar="IMAGE", help="image file(s) to segment")
    p.add_argument("--json", action="store_true", help="print JSON (one object per image, one per line)")
    p.add_argument("--calibration", metavar="FILE",
                   help="calibration file: adds outline_mm (base frame) to every part")
    p.add_argument("--z", type=float, default=None, metavar="MM",
                   help="height of the parts' tops for the mm mapping (default: the calibration's plane)")
    p.add_argument("--reference", metavar="IMAGE", help="image of the empty tray under the same light")
    p.add_argument("--min-area-mm2", type=float, default=None,
                   help=f"with a calibration: regions smaller than this are specks (default {MIN_AREA_MM2:g})")
    p.add_argument("--min-area-px", type=float, default=None,
                   help="regions smaller than this many pixels are specks (default: from --min-area-mm2 with "
                        "a calibration, else 300 on a frame up to 1280 px long, x (long side / 1280)^2 above); "
                        "counted on the region's pixels, so a kept part's area_px (its outline's area) may be smaller")
    p.add_argument("--backlit", action="store_true",
                   help="the tray is the bright side of the frame (a back-lit panel in a dark surround)")
    p.add_argument("--no-shadow-aware", action="store_true",
                   help="treat any darkening as a part (for back-lit trays or frames without shadows)")


def run(args) -> int:
    from dataclasses import replace

    from calibration import load_calibration
    from cell.vision.segment import SegmentParams, segment_frame, segment_to_mm
    from cell.vision.sources import read_image

    plane_z(args.z)
    finite(args.min_area_mm2, "--min-area-mm2", 0.0)
    finite(args.min_area_px, "--min-area-px", 0.0)
    cal = None
    if args.z is not None and not args.calibration:
        from cell.errors import BadInput

        raise BadInput("--z is the height the outlines are mapped to in mm: it needs --calibration")
    if args.min_area_mm2 is not None and not args.calibration:  # it was ignored without a word
        from cell.errors import BadInput

        raise BadInput("--min-area-mm2 is an area on the table: it needs --calibration (without one, --min-area-px)")
    if args.calibration:
        cal = load_calibration(args.calibration)
        if not cal.can_map:
            from cell.errors import BadInput

            raise BadInput(f"calibration {args.calibration} has no image -> base-frame mapping "
                           "(it holds intrinsics only; run `cell calibrate plane`)")
    z = args.z if args.z is not None else (cal.plane_z_mm if cal else 0.0)
    params = SegmentParams.for_calibration(
        cal, MIN_AREA_MM2 if args.min_area_mm2 is None else args.min_area_mm2, z) if cal else SegmentParams()
    if args.min_area_px is not None:
        params = replace(params, min_area_px=args.min_area_px)
    if args.backlit:
        params = replace(params, tray="bright")
    if args.no_shadow_aware:
        params = replace(params, shadow_aware=False)
    frames = [(path, read_image(path)) for path in args.images]  # all bad files refused before any output
    reference = read_image(args.reference) if args.reference else None
    if cal is not None:  # like unreadable files: refused before any output, not after the first lines
        for path, frame in frames:
            cal.check_frame(frame, f"image {path}")
    for path, frame in frames:
        segs = segment_frame(frame, params, reference_bgr=reference)
        parts = []
        for seg in segs:
            d = seg.to_json()
            if cal is not None:
                outline_mm, holes_mm = segment_to_mm(seg, cal, z)
                d["outline_mm"] = [[round(float(x), 3), round(float(y), 3)] for x, y in outline_mm]
                d["holes_mm"] = [[[round(float(x), 3), round(float(y), 3)] for x, y in h] for h in holes_mm]
                d["centroid_mm"] = [round(float(v), 3) for v in cal.px_to_mm(seg.centroid_px, z)[0]]
                d["area_mm2"] = round(_area_mm2(outline_mm, holes_mm), 1)
                d["z_mm"] = z
            parts.append(d)
        h, w = frame.shape[:2]
        # regions cut by the border that lie outside the tray (its surround), left out of `parts`
        outside = len(segs.outside_tray)
        out = {"image": str(path), "width_px": w, "height_px": h, "parts": parts, "outside_tray": outside}
        if cal is not None and z is None:  # on a tilted plane (no one height): the plane, as `cell map` gives it
            out["plane"] = cal.plane.describe()
        if args.json:
            print(json.dumps(out))
        else:
            print(f"{path}: {len(parts)} part(s)" + (f"; {outside} region(s) outside the tray left out" if outside
                                                      else ""))
            for i, d in enumerate(parts):
                print(f"  #{i}: {_part_line(d)}")
    sys.stdout.flush()
    return 0


def _area_mm2(outline_mm, holes_mm) -> float:
    """The part's area seen from above: its outline's less its holes'."""
    import shapely

    return shapely.Polygon(outline_mm, holes_mm).area


def _part_line(d: dict) -> str:
    """One part in pixels and, with a calibration, in mm on the table: what a user checks the mapping by."""
    (u, v), flags = d["centroid_px"], ", ".join(f for f in ("merged", "cut_off") if d[f])
    area = f"area {d['area_px']:.0f} px" + (f" = {d['area_mm2']:.1f} mm2" if "area_mm2" in d else "")
    centroid = f"centroid ({u:.1f}, {v:.1f}) px" + (
        " = ({:.1f}, {:.1f}) mm".format(*d["centroid_mm"]) if "centroid_mm" in d else "")
    return f"{area}, {centroid}, {len(d['holes_px'])} hole(s)" + (f" [{flags}]" if flags else "")
