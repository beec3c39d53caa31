"""`cell render SCENE.json --out FRAME.png`: the simulated camera's view of a scene or assembly."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("scene", metavar="SCENE.json", help="scene or assembly file (parts in mm)")
    p.add_argument("--out", required=True, metavar="FRAME.png", help="image file to write")
    p.add_argument("--calibration", metavar="FILE", help="camera calibration (default: the cell's camera)")
    p.add_argument("--cell", metavar="FILE", help="cell file (default: the scene's own, else the default cell): "
                   "without --calibration its camera's size and tray set the view (as `cell run` does)")
    p.add_argument("--seed", type=int, default=0, help="noise and texture seed (default 0; same seed, same frame)")
    p.add_argument("--no-shadows", action="store_true", help="render without shadows (default: with)")
    p.add_argument("--no-highlights", action="store_true",
                   help="render without specular highlights (default: with)")
    p.add_argument("--no-noise", action="store_true", help="render without sensor noise (default: with)")
    p.add_argument("--no-distortion", action="store_true",
                   help="render as if the lens had no distortion (default: the calibration's)")
    p.add_argument("--truth", metavar="FILE", help="also write the parts' projected top outlines (px) as JSON")


def run(args) -> int:
    from dataclasses import replace

    from cell.cellconfig import default_cell_path, load_cell
    from cell.errors import BadInput
    from cell.fileio import read_json, write_json_atomic
    from cell.runtime.session import camera_calibration, refuse_parts_at_the_camera
    from cell.scene import own_cell_path, parse_part
    from cell.vision.simcamera import SimCamera, SimCameraOptions
    from cell.vision.sources import write_image

    raw = read_json(args.scene, "scene file")
    if not isinstance(raw, dict) or not isinstance(raw.get("parts"), list):
        raise BadInput(f"{args.scene}: expected a scene or assembly object with a 'parts' list")
    parts = [parse_part(p, f"{args.scene}: part #{i}") for i, p in enumerate(raw["parts"])]
    cell_path = args.cell or own_cell_path(raw, str(args.scene), Path(args.scene).parent) or default_cell_path()
    cal_path, cal = camera_calibration(load_cell(cell_path), args.calibration)
    # before the rendering, not after; the files read include the shipped defaults when none was named
    _check_outputs(args, [args.scene, cell_path, cal_path])
    refuse_parts_at_the_camera(parts, cal, args.scene)
    opts = SimCameraOptions(seed=args.seed)
    if args.no_shadows:
        opts = replace(opts, shadows=False)
    if args.no_highlights:
        opts = replace(opts, highlights=False)
    if args.no_noise:
        opts = replace(opts, read_noise_dn=0.0, shot_noise=0.0)
    if args.no_distortion:
        opts = replace(opts, distortion=False)
    cam = SimCamera(cal, opts)
    _warn_parts_out_of_view(parts, cam, args.scene)
    frame = cam.render(parts)
    write_image(args.out, frame)
    if args.truth:
        truth = {"image": str(args.out), "parts": [
            {"id": p.id, "top_outline_px": cam.project_ring(p.outline_mm, p.z_top_mm).round(3).tolist(),
             "z_top": p.z_top_mm, "z_bottom": p.z_bottom_mm} for p in parts]}
        write_json_atomic(args.truth, truth)
    print(json.dumps({"out": str(args.out), "parts": len(parts), "width_px": frame.shape[1],
                      "height_px": frame.shape[0], "seed": args.seed}))
    return 0


def _warn_parts_out_of_view(parts, cam, source) -> None:
    """The frame is still rendered (a view of the tray alone has its uses), but a part missing from it
    should not pass unnoticed: an empty frame and exit 0 said nothing."""
    import shapely

    view = shapely.box(0, 0, cam.cal.width_px, cam.cal.height_px)
    for p in parts:
        top = shapely.Polygon(cam.project_points(p.outline_mm, p.z_top_mm))
        if not view.contains(top):
            where = "partly outside" if top.intersects(view) else "outside"
            b = p.polygon.bounds
            print(f"cell: warning: {source}: part {p.id!r} (x {b[0]:.1f}..{b[2]:.1f}, y {b[1]:.1f}..{b[3]:.1f} mm) "
                  f"lies {where} the camera's view ({cam.cal.width_px} x {cam.cal.height_px} px)", file=sys.stderr)


def _check_outputs(args, inputs) -> None:
    """--out and --truth: writable, in an image format OpenCV writes, neither over an input nor each other."""
    import cv2

    from cell.commands._vision_args import refuse_out_over_an_input
    from cell.errors import BadInput
    from cell.fileio import check_writable

    check_writable(args.out, "--out")
    suffix = Path(args.out).suffix or ".png"  # write_image writes PNG when the name has no extension
    if not cv2.haveImageWriter("frame" + suffix):
        raise BadInput(f"--out {args.out}: OpenCV writes no {suffix!r} images; use .png")
    refuse_out_over_an_input(args.out, inputs)
    if args.truth:
        check_writable(args.truth, "--truth")
        refuse_out_over_an_input(args.truth, inputs, "--truth")
        if Path(args.truth).resolve() == Path(args.out).resolve():  # (the other output, not an input)
            raise BadInput(f"--truth {args.truth} is also --out: the image and its outlines need two files")
