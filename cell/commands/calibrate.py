"""`cell calibrate intrinsics IMAGES... --pattern COLSxROWS --square MM --out FILE`."""

from __future__ import annotations

import json
import sys

from cell.commands._vision_args import grid, refuse_out_over_an_input

# OpenCV's calibration asserts, or overflows, on squares of 1e-30 or 1e38, and loses accuracy at 1e6
# (fx 533 -> 596 on OpenCV's boards); any real board in mm, m or inches is well inside
SQUARE_RANGE = (1e-4, 1e5)


def add_arguments(p) -> None:
    p.add_argument("images", nargs="+", metavar="IMAGE", help="photographs of the board")
    p.add_argument("--pattern", required=True, metavar="COLSxROWS",
                   help="chessboard: inner corners, at least 3 a side (e.g. 9x6); ChArUco: squares, with at "
                        "least 6 inner corners (e.g. 5x7)")
    p.add_argument("--square", required=True, type=float, metavar="MM", help="side of one square")
    p.add_argument("--out", required=True, metavar="FILE", help="calibration file to write")
    p.add_argument("--detector", choices=("auto", "classic", "sb"), default="auto",
                   help="chessboard detector: classic + cornerSubPix, the sector-based SB one, or auto "
                        "(classic when it finds every board, else SB for all; default auto)")
    p.add_argument("--subpix-win", type=int, default=None, metavar="N",
                   help="cornerSubPix half window of the classic detector, and of ChArUco corners refined "
                        "again (default: 0.13 x the squares' size in px, 5 on OpenCV's 640 x 480 boards; "
                        "ChArUco: OpenCV's own window of up to 10 px, or 0.13 x the squares, at most 0.7 x the "
                        "white margin to the markers, once that is wider)")
    p.add_argument("--reject-outliers", action="store_true",
                   help="leave out views that do not fit and calibrate again")
    p.add_argument("--charuco", action="store_true", help="the board is a ChArUco board")
    p.add_argument("--marker", type=float, metavar="MM", help="ChArUco marker side (same unit as --square)")
    p.add_argument("--dictionary", default=None, help="ChArUco dictionary (default DICT_6X6_250)")
    p.add_argument("--name", default=None, help="name stored in the calibration file")
    p.add_argument("--json", action="store_true", help="accepted for symmetry: the result is always JSON")


def _views_found(result, n_images: int, charuco: bool) -> str:
    """In how many views the board was found; in under half, the board given is likely not the one shown."""
    from calibration.intrinsics import pattern_hint

    found = sum(v.found for v in result.views)
    few = f"; {pattern_hint(charuco)}" if found < n_images / 2 else ""
    return f"the board was found in {found} of {n_images} images{few}"


def run(args) -> int:
    from calibration import save_calibration
    from calibration.intrinsics import MIN_CHESS_CORNERS_A_SIDE, calibrate_intrinsics, check_pattern
    from cell.errors import BadInput
    from cell.fileio import check_writable, short_repr
    from cell.vision.sources import read_image

    try:
        pattern = grid(args.pattern, "--pattern")
    except BadInput as e:  # its 'both at least 2' holds for ChArUco squares; a chessboard needs 3 corners
        if args.charuco:
            raise
        raise BadInput(f"--pattern must be COLSxROWS with at least {MIN_CHESS_CORNERS_A_SIDE} inner corners a side, "
                       f"e.g. 9x6 (got {short_repr(args.pattern)})") from e
    check_pattern(pattern, args.charuco)
    if not (SQUARE_RANGE[0] <= args.square <= SQUARE_RANGE[1]):  # NaN fails too
        raise BadInput(f"--square must be a finite positive length from {SQUARE_RANGE[0]:g} to {SQUARE_RANGE[1]:g} "
                       f"(the unit of the result's translations), got {args.square:g}")
    charuco = None
    if args.charuco:
        if args.marker is None or not 0 < args.marker < args.square:  # NaN fails both
            raise BadInput("--charuco needs --marker MM, smaller than --square")
        charuco = {"marker_mm": args.marker, "dictionary": args.dictionary or "DICT_6X6_250"}
    elif args.marker is not None or args.dictionary is not None:  # a chessboard has neither: dropped silently
        raise BadInput("--marker and --dictionary describe a ChArUco board: give --charuco too")
    if args.subpix_win is not None and args.subpix_win < 1:
        raise BadInput("--subpix-win must be at least 1")
    refuse_out_over_an_input(args.out, args.images)
    check_writable(args.out, "--out")  # before the calibration, not after
    images = [(str(path), read_image(path, grey=True)) for path in args.images]
    result = calibrate_intrinsics(images, pattern, args.square, detector=args.detector, charuco=charuco,
                                  reject_outliers=args.reject_outliers, subpix_win=args.subpix_win)
    cal = result.to_calibration(args.name or "intrinsics")
    try:
        save_calibration(cal, args.out)
    except BadInput as e:  # a lens model that folds the image: often a board of another size, found by mistake
        raise BadInput(f"{e} ({_views_found(result, len(images), charuco is not None)})") from None
    out = result.to_json()
    out["out"] = str(args.out)
    print(json.dumps(out))
    for w in result.warnings:
        print(f"cell: warning: {w}", file=sys.stderr)
    return 0
