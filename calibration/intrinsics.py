"""Camera intrinsics from photographs of a chessboard or a ChArUco board.

Recipe (chosen to reproduce OpenCV's own published numbers, see docs/vision.md):
- chessboard: `findChessboardCorners` + `cornerSubPix` (half-window 5 on OpenCV's 640 x 480
  boards, EPS + COUNT, 30, 0.1), OpenCV's calibration test recipe. The window grows with the
  board's squares in the image (`SUBPIX_WIN_PER_SQUARE` x the median corner spacing, one window
  for all views): on OpenCV's boards upscaled 3 x, a fixed 5 px window gave 1.83 px RMS, the
  scaled one (15) 0.64 px, about 3 x the original's 0.196. When `findChessboardCornersSB` finds
  boards that this classic detector missed, and more boards in all, every image is detected with
  SB instead (already sub-pixel): one detector per calibration, so that all views have the same
  corner noise.
- ChArUco: `CharucoDetector.detectBoard`, then `board.matchImagePoints`; a view needs at
  least 6 corners. A view with fewer than half of its corners found is detected again at twice
  the size (small markers in low-resolution images), and the larger set is kept. Where the squares
  are large (over 80 px on OpenCV's board), the corners are refined again with a window grown with
  them (`refine_charuco`): OpenCV's own stops at 10 px (3.13 px RMS on its views upscaled to
  4000 x 3000 px, 1.31 px with the grown window, against 6.25 x 0.188 = 1.17).
- `calibrateCamera` with flags 0 (k1, k2, p1, p2, k3); where that model folds the image (a wild k3 from boards
  near the middle: undistorted points out of order), again with k3 = 0, then k2 = k3 = 0, and a warning.

Images where the board is not found are listed and left out. After the fit, a view whose
reprojection RMS is more than `OUTLIER_FACTOR` times the median view RMS (and more than
`OUTLIER_MIN_PX` above it) is flagged as an outlier; with `reject_outliers=True` it is
left out and the fit repeated. Warnings are raised for results a user should not accept
silently (principal point far from the image centre, few views, large RMS).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from cell.errors import BadInput

SUBPIX_WIN_PER_SQUARE = 0.13  # half-window / square side px: 5 on OpenCV's boards (median spacing 37.8 px)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.1)
OUTLIER_FACTOR = 3.0
OUTLIER_MIN_PX = 0.3
LARGE_RMS_PX = 1.0  # a reprojection RMS above this is warned of (expect < 0.5 px)
PRINCIPAL_OFF_CENTRE_WARN = 0.15  # fraction of the image size
# The share of the image inside the used views' board outlines (`board_coverage_share`) below which the lens
# distortion is warned about: it is fitted where the corners are and extrapolated elsewhere. Boards in 5 % of a
# 1920 x 1080 frame: k2 -0.35, k3 10.8 for a lens of 0.05, 0, the model 353 px off in the image's corners; 12 %
# and 17 %: 21 and 49 px. Sets that fit within 0.6-6 px everywhere cover 27-48 %, OpenCV's 13 views 45 %, the
# desk webcam's 38 %
MIN_BOARD_COVERAGE_SHARE = 0.2
COVERAGE_MASK_PX = 512  # the outlines are drawn on a mask of at most this many px a side (a 0.2 % grain)
MIN_VIEWS = 3
MIN_CHARUCO_CORNERS = 6
MIN_SQUARE_PX = 4  # a board square smaller than this cannot be detected
MIN_CHESS_CORNERS_A_SIDE = 3  # OpenCV's chessboard detectors assert on fewer (2x9 was an 'internal error')
MIN_CHARUCO_SQUARES_A_SIDE = 2  # OpenCV takes 2 squares a side; a view still needs MIN_CHARUCO_CORNERS


def check_pattern(pattern: tuple[int, int], charuco: bool) -> None:
    """Refuse a board OpenCV cannot detect, or whose views could never be used, saying the real minimum."""
    cols, rows = pattern
    if not charuco and min(cols, rows) < MIN_CHESS_CORNERS_A_SIDE:
        raise BadInput(f"--pattern {cols}x{rows}: a chessboard needs at least {MIN_CHESS_CORNERS_A_SIDE} inner "
                       "corners a side (COLSxROWS counts the inner corners, where 4 squares meet: 9x6 for a board "
                       "of 10 x 7 squares)")
    if charuco and (min(cols, rows) < MIN_CHARUCO_SQUARES_A_SIDE or (cols - 1) * (rows - 1) < MIN_CHARUCO_CORNERS):
        raise BadInput(f"--pattern {cols}x{rows}: a ChArUco board of {cols} x {rows} squares has "
                       f"{max(cols - 1, 0) * max(rows - 1, 0)} inner corners and a view needs at least "
                       f"{MIN_CHARUCO_CORNERS} (COLSxROWS counts the squares, e.g. 5x7)")


@dataclass
class View:
    """One image of the board: whether it was used and how well it fits."""

    name: str
    found: bool
    n_points: int = 0
    rms_px: float | None = None
    outlier: bool = False
    used: bool = False
    note: str = ""
    detector: str = ""
    subpix_win: int | None = None  # ChArUco: the half-window its corners were refined again with (None: OpenCV's)

    def to_json(self) -> dict:
        return {"image": self.name, "found": self.found, "n_points": self.n_points,
                "rms_px": None if self.rms_px is None else round(self.rms_px, 6),
                "outlier": self.outlier, "used": self.used, "detector": self.detector, "note": self.note,
                "subpix_win": self.subpix_win}


@dataclass
class IntrinsicsResult:
    camera_matrix: np.ndarray  # (3, 3)
    dist: np.ndarray  # (5,)
    rms_px: float
    width_px: int
    height_px: int
    views: list[View]
    warnings: list[str] = field(default_factory=list)
    board: dict = field(default_factory=dict)
    coverage_share: float | None = None  # board_coverage_share of the views used

    @property
    def images_used(self) -> list[str]:
        return [v.name for v in self.views if v.used]

    def to_json(self) -> dict:
        k = self.camera_matrix
        return {"rms_px": self.rms_px, "fx": float(k[0, 0]), "fy": float(k[1, 1]), "cx": float(k[0, 2]),
                "cy": float(k[1, 2]), "dist": [float(x) for x in self.dist.ravel()],
                "width_px": self.width_px, "height_px": self.height_px,
                "images_used": self.images_used,
                "images_not_found": [v.name for v in self.views if not v.found],
                "outliers": [v.name for v in self.views if v.outlier],
                "per_image": [v.to_json() for v in self.views], "warnings": self.warnings, "board": self.board,
                "board_coverage_share": None if self.coverage_share is None else round(self.coverage_share, 4)}

    def to_calibration(self, name: str = "intrinsics"):
        from calibration.camera import Calibration

        report = {"method": "intrinsics", **{k: v for k, v in self.to_json().items()
                                             if k not in ("fx", "fy", "cx", "cy", "dist")}}
        return Calibration(self.width_px, self.height_px, self.camera_matrix.copy(), self.dist.ravel().copy(),
                           name=name, report=report)


def chessboard_object_points(pattern: tuple[int, int], square_mm: float) -> np.ndarray:
    """Board corners (cols * rows, 3) in the board frame, row by row as OpenCV returns them."""
    cols, rows = pattern
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2)
    return np.column_stack([grid * square_mm, np.zeros(len(grid))]).astype(np.float32)


# Large images (a 12 MP phone or DSLR photo) are searched on reduced copies, never at full size: the
# classic detector's time grows with every dark blob of the image, not with the board (a 6000 x 4000 photo of
# a textured table without a board: more than 8 minutes at full size, 32 s at 3200 px, 0.7 s at 1600 px; a
# board pasted small into a 12 MP photo: 20-40 s an image at full size, 0.03 s at 1600 px), and at full size it
# missed 6 of OpenCV's 13 boards upscaled to 4000 x 3000 px (all 13 on the 1600 px copy). The corners found on
# a copy are mapped back and refined at full size with `cornerSubPix` (for both detectors). Images up to
# DETECT_MAX_PX a side are searched at full size, as before.
DETECT_MAX_PX = 1600
# A board too small for the 1600 px copy (squares under about 6 px there: OpenCV's 9 x 6 board 224 px wide in a
# 4032 px photo) is looked for by the sector detector, which stays fast on large images, on a copy of at most
# this size (found there; 0.8 - 1.2 s for both copies of a 12 MP photo without a board, 1.6 - 2.8 s with 3200 px).
# The classic detector is not run on such a copy (32 s at 3200 px on the textured 6000 x 4000 photo).
DETECT_FINE_MAX_PX = 2400


def detection_levels(size: tuple[int, int], detector: str) -> list[int | None]:
    """The long sides of the copies a detector searches, in order (None: the image itself)."""
    long_side = max(size)
    if long_side <= DETECT_MAX_PX:
        return [None]
    if detector == "classic":
        return [DETECT_MAX_PX]
    return [DETECT_MAX_PX, None if long_side <= DETECT_FINE_MAX_PX else DETECT_FINE_MAX_PX]


def find_chessboard(gray: np.ndarray, pattern: tuple[int, int], detector: str = "classic", located=None):
    """(corners (n, 1, 2) float32 at full size or None, a note saying where they were found, None for the image
    itself); corners found on a copy still need refining at full size (`refine_corners`), as the classic
    detector's always do. Classic, large image: `located` is SB's answer on that image where already known."""
    if detector not in ("classic", "sb"):
        raise BadInput(f"unknown chessboard detector {detector!r} (classic, sb, auto)")
    h, w = gray.shape[:2]
    if detector == "classic" and max(w, h) > DETECT_MAX_PX:
        sb_corners, _ = located if located is not None else find_chessboard(gray, pattern, "sb")
        if sb_corners is not None:
            corners, f = _classic_in_region(gray, pattern, sb_corners)
            if corners is not None:
                return corners, ("found in the board's region (located by the sector detector)" if f == 1 else
                                 f"found in the board's region (located by the sector detector), reduced {1 / f:.2f} x")
    for level in detection_levels((w, h), detector):
        if level is None:
            corners = _find_chessboard(gray, pattern, detector)
            if corners is not None:
                return corners, None
            continue
        f = level / max(w, h)
        size = (max(1, round(w * f)), max(1, round(h * f)))
        small = _find_chessboard(cv2.resize(gray, size, interpolation=cv2.INTER_AREA), pattern, detector)
        if small is not None:
            # pixel centres: u at the reduced size is (u + 0.5) * size / w - 0.5
            return (((small + 0.5) / np.array([size[0] / w, size[1] / h], np.float32) - 0.5).astype(np.float32),
                    f"found on a copy reduced to {level} px")
    return None, None


# The classic detector on a 1600 px copy of a 12 MP photo still took 1.3 - 5 s where a textured table surrounds
# a small board (OpenCV's views pasted at their size: 3 of 13 missed after 2 - 5 s each); on the board's region,
# found by the sector detector, it takes 0.01 s. The region: the corners' box grown by this many squares (the
# outer squares and the white border the classic detector needs).
REGION_MARGIN_SQUARES = 2.0


def _classic_in_region(gray: np.ndarray, pattern: tuple[int, int], located: np.ndarray):
    """The classic detector's corners (full size) in the region of the board SB located, at most DETECT_MAX_PX
    a side, and the scale it was searched at; (None, 1) where it does not find the board there."""
    h, w = gray.shape[:2]
    pts = located.reshape(-1, 2)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    square = float(np.max(hi - lo)) / (max(pattern) - 1)
    m = REGION_MARGIN_SQUARES * square
    x0, y0 = max(0, int(np.floor(lo[0] - m))), max(0, int(np.floor(lo[1] - m)))
    x1, y1 = min(w, int(np.ceil(hi[0] + m)) + 1), min(h, int(np.ceil(hi[1] + m)) + 1)
    crop = gray[y0:y1, x0:x1]
    f = min(1.0, DETECT_MAX_PX / max(crop.shape))
    if f < 1:
        size = (max(1, round(crop.shape[1] * f)), max(1, round(crop.shape[0] * f)))
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
        scale = np.array([size[0] / (x1 - x0), size[1] / (y1 - y0)], np.float32)
    else:
        scale = np.ones(2, np.float32)
    corners = _find_chessboard(np.ascontiguousarray(crop), pattern, "classic")
    if corners is None:
        return None, 1.0
    return ((corners + 0.5) / scale - 0.5 + np.array([x0, y0], np.float32)).astype(np.float32), f


def _find_chessboard(gray: np.ndarray, pattern: tuple[int, int], detector: str):
    if detector == "classic":
        found, corners = cv2.findChessboardCorners(gray, pattern)
        return corners if found else None
    found, corners = cv2.findChessboardCornersSB(gray, pattern)
    return corners.astype(np.float32) if found else None


def refine_corners(gray: np.ndarray, corners: np.ndarray, subpix_win: int) -> np.ndarray:
    return cv2.cornerSubPix(gray, corners, (subpix_win, subpix_win), (-1, -1), SUBPIX_CRITERIA)


def subpix_win_for(corners: list[np.ndarray], pattern: tuple[int, int]) -> int:
    """One `cornerSubPix` half-window for a calibration: `SUBPIX_WIN_PER_SQUARE` x the median
    spacing of neighbouring corners along the board's rows over all views, at least 3 px."""
    cols, rows = pattern
    spacing = [np.linalg.norm(np.diff(c.reshape(rows, cols, 2), axis=1), axis=2).ravel() for c in corners]
    return max(3, int(round(SUBPIX_WIN_PER_SQUARE * float(np.median(np.concatenate(spacing))))))


def charuco_board(squares: tuple[int, int], square_mm: float, marker_mm: float, dictionary: str):
    d = aruco_dictionary(dictionary)
    return cv2.aruco.CharucoBoard(squares, square_mm, marker_mm, d)


def aruco_dictionary(name: str):
    code = getattr(cv2.aruco, name, None) if isinstance(name, str) and name.startswith("DICT_") else None
    if code is None:
        raise BadInput(f"unknown ArUco dictionary {name!r} (e.g. DICT_4X4_50, DICT_6X6_250)")
    return cv2.aruco.getPredefinedDictionary(code)


# A ChArUco view with fewer than half of its corners found is looked at again at twice the size (images
# up to this many pixels a side): OpenCV's marker detector loses small markers (its tutorial's board at
# 320 x 240 px: 4-10 of 24 corners, 13-22 at twice the size), the corners are refined on either.
CHARUCO_UPSCALE_MAX_PX = 2000


# OpenCV drops marker candidates whose perimeter is under 0.03 x the image's long side: 19 px at 640 px, but
# 121 px at 4032 px, so OpenCV's own board pasted at its size into a 12 MP photo was found in none of 4 views
# (markers of 25 px a side). Images larger than this get the rate that keeps the smallest perimeter at 0.03 x
# this many px (30 px, markers of 7.5 px a side, which no dictionary's cells can be read below); the 4 views then
# give all 24 corners each, in 0.5 s a 12 MP view (0.6 - 0.8 s on a 24 MP photo without a board). Images up to
# this size are detected as before.
CHARUCO_MIN_PERIMETER_REF_PX = 1000


def charuco_marker_params(size: tuple[int, int]):
    """ArUco detector parameters for ChArUco boards in images of `size` (see CHARUCO_MIN_PERIMETER_REF_PX)."""
    params = cv2.aruco.DetectorParameters()
    long_side = max(size)
    if long_side > CHARUCO_MIN_PERIMETER_REF_PX:
        params.minMarkerPerimeterRate = params.minMarkerPerimeterRate * CHARUCO_MIN_PERIMETER_REF_PX / long_side
    return params


def _charuco_corners(det, gray: np.ndarray, n_all: int):
    """ChArUco corners (k, 1, 2), their ids and k; at twice the size where that finds more (module note)."""
    corners, ids, _, _ = det.detectBoard(gray)
    n = 0 if ids is None else len(ids)
    if 2 * n < n_all and max(gray.shape[:2]) <= CHARUCO_UPSCALE_MAX_PX:
        big_corners, big_ids, _, _ = det.detectBoard(cv2.resize(gray, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC))
        if big_ids is not None and len(big_ids) > n:
            # pixel centres: u at twice the size is 2 u + 0.5
            return ((big_corners - 0.5) / 2).astype(np.float32), big_ids, len(big_ids)
    return corners, ids, n


# OpenCV refines ChArUco corners with `cornerSubPix` in a half-window of at most 10 px (its own cap), so on a
# 12 MP camera the window sees a few per cent of a square: OpenCV's tutorial views upscaled to 4000 x 3000 px
# gave 3.13 px RMS (0.50 px at 640 x 480 scale, against 0.188 there). Where the squares are large enough for a
# wider window (more than OPENCV_CHARUCO_WIN_MAX_PX), the corners are refined again with one grown with them.
OPENCV_CHARUCO_WIN_MAX_PX = 10
# ... but kept inside the white margin between a corner and the markers beside it: a window reaching the
# markers' edges pulls the corner (boards rendered at 4000 x 3000 px with markers 0.8 of a square, squares of
# 320 px: OpenCV's corners 0.15-0.16 px RMS off the truth, 0.13-0.17 with a 42 px window (0.13 square), 0.05
# with 23 px (0.7 x the margin of 0.1 square))
CHARUCO_MARGIN_USE = 0.7


def charuco_spacing_px(board, corners: np.ndarray, ids: np.ndarray) -> float | None:
    """Median image distance between detected ChArUco corners that are neighbours on the board (None: none are)."""
    obj = board.getChessboardCorners()[ids.ravel()][:, :2]
    img = corners.reshape(-1, 2)
    i, j = np.triu_indices(len(img), 1)
    neighbours = np.isclose(np.linalg.norm(obj[i] - obj[j], axis=1), board.getSquareLength(), rtol=1e-3)
    if not neighbours.any():
        return None
    return float(np.median(np.linalg.norm(img[i[neighbours]] - img[j[neighbours]], axis=1)))


def charuco_subpix_win(board, spacing_px: float) -> int:
    """`cornerSubPix` half-window for squares of `spacing_px`: `SUBPIX_WIN_PER_SQUARE` of a square, at most
    `CHARUCO_MARGIN_USE` of the white margin between a corner and its markers."""
    margin = (board.getSquareLength() - board.getMarkerLength()) / 2 / board.getSquareLength()
    return max(1, int(round(min(SUBPIX_WIN_PER_SQUARE, CHARUCO_MARGIN_USE * margin) * spacing_px)))


def refine_charuco(board, gray: np.ndarray, corners: np.ndarray, ids: np.ndarray, subpix_win: int | None = None):
    """(corners, the half-window they were refined again with, or None where OpenCV's own was kept)."""
    if subpix_win is None:
        spacing = charuco_spacing_px(board, corners, ids)
        subpix_win = None if spacing is None else charuco_subpix_win(board, spacing)
        if subpix_win is None or subpix_win <= OPENCV_CHARUCO_WIN_MAX_PX:
            return corners, None
    return refine_corners(gray, corners.astype(np.float32), subpix_win), subpix_win


def calibrate_intrinsics(images: list[tuple[str, np.ndarray]], pattern: tuple[int, int], square_mm: float,
                         *, detector: str = "auto", charuco: dict | None = None,
                         reject_outliers: bool = False, subpix_win: int | None = None) -> IntrinsicsResult:
    """Calibrate from named grey images.

    Parameters
    ----------
    images : list of (name, ndarray of shape (h, w) uint8)
        All images must have the same size.
    pattern : (cols, rows)
        Chessboard inner corners; for ChArUco the squares (x, y) of the board.
    square_mm : float
        Side of one square (any unit; the intrinsics do not depend on it).
    detector : {"auto", "classic", "sb"}
        Chessboard detector (see the module docstring); ignored for ChArUco.
    charuco : dict, optional
        {"marker_mm": float, "dictionary": "DICT_6X6_250"}: the board is ChArUco.
    reject_outliers : bool
        Leave out views flagged as outliers and fit again.
    subpix_win : int, optional
        Half-size of the `cornerSubPix` window of the classic detector. None: from the squares'
        size in the images (`subpix_win_for`; 5 on OpenCV's own images, as its test uses; its C++
        sample's 11 roughly doubles the RMS there). ChArUco: every view's corners are refined again
        with it; None: OpenCV's own window, or one grown with the squares where they are large
        (`refine_charuco`).
    """
    if not images:
        raise BadInput("no images given")
    if not (np.isfinite(square_mm) and square_mm > 0):
        raise BadInput(f"the square side must be a finite positive length, got {square_mm!r}")
    check_pattern(pattern, charuco is not None)
    _refuse_mixed_sizes(images)
    h, w = images[0][1].shape[:2]
    squares = pattern if charuco is not None else (pattern[0] + 1, pattern[1] + 1)
    if max(squares) * MIN_SQUARE_PX > max(w, h) or min(squares) * MIN_SQUARE_PX > min(w, h):
        # OpenCV's detectors fail with assertions on such images (1 x 1 px) or allocate without end (99999x99999)
        raise BadInput(f"a board of {squares[0]} x {squares[1]} squares cannot be seen in {w} x {h} px images "
                       f"(at least {MIN_SQUARE_PX} px a square); check --pattern")
    if subpix_win is not None and not (1 <= subpix_win and 2 * subpix_win + 5 <= min(w, h)):
        raise BadInput(f"the cornerSubPix half-window {subpix_win} does not fit in {w} x {h} px images "
                       f"(at most {(min(w, h) - 5) // 2})")
    views = [View(name, False) for name, _ in images]
    obj_pts: list[np.ndarray | None] = [None] * len(images)
    img_pts: list[np.ndarray | None] = [None] * len(images)

    if charuco is not None:
        board = charuco_board(pattern, square_mm, float(charuco["marker_mm"]), charuco.get("dictionary",
                                                                                           "DICT_6X6_250"))
        det = cv2.aruco.CharucoDetector(board, cv2.aruco.CharucoParameters(), charuco_marker_params((w, h)))
        n_all = (pattern[0] - 1) * (pattern[1] - 1)
        for i, (_, gray) in enumerate(images):
            corners, ids, n = _charuco_corners(det, gray, n_all)
            views[i].detector = "charuco"
            if n < MIN_CHARUCO_CORNERS:
                views[i].note = f"only {n} ChArUco corners found (need {MIN_CHARUCO_CORNERS})"
                continue
            corners, views[i].subpix_win = refine_charuco(board, gray, corners, ids, subpix_win)
            op, ip = board.matchImagePoints(corners, ids)
            obj_pts[i], img_pts[i] = op.astype(np.float32), ip.astype(np.float32)
            views[i].found, views[i].n_points = True, n
        board_info = {"type": "charuco", "squares": list(pattern), "square": square_mm, **charuco}
    else:
        order = {"auto": ["classic", "sb"], "classic": ["classic"], "sb": ["sb"]}.get(detector)
        if order is None:
            raise BadInput(f"unknown chessboard detector {detector!r} (auto, classic, sb)")
        objp = chessboard_object_points(pattern, square_mm)
        name = order[0]
        located = {}  # SB's answer on large images, asked once (the classic detector searches the region it found)
        if name == "classic" and max(w, h) > DETECT_MAX_PX:
            located = {i: find_chessboard(g, pattern, "sb") for i, (_, g) in enumerate(images)}
        found, reduced = zip(*(find_chessboard(g, pattern, name, located.get(i)) for i, (_, g) in enumerate(images)),
                             strict=True)
        classic_win = subpix_win
        if name == "classic":
            found, classic_win = _refine_views(images, found, [True] * len(found), pattern, subpix_win, (w, h))
        sb_win = None
        missed = [i for i, c in enumerate(found) if c is None]
        if len(order) > 1 and missed:
            # switch to SB for every view only if it finds boards the classic detector missed (an image
            # without a board must not change the detector of the others), and more of them in all: SB
            # misses boards the classic one finds (left04 and left05 of OpenCV's set), and one hard view
            # must not cost two good ones
            missed_by_sb = {i: located.get(i) or find_chessboard(images[i][1], pattern, "sb") for i in missed}
            if any(c is not None for c, _ in missed_by_sb.values()):  # (each view looked at once by SB)
                by_sb, sb_reduced = zip(*(missed_by_sb.get(i) or located.get(i) or find_chessboard(g, pattern, "sb")
                                          for i, (_, g) in enumerate(images)), strict=True)
                if sum(c is not None for c in by_sb) > sum(c is not None for c in found):
                    name, found, reduced = "sb", by_sb, sb_reduced
        if name == "sb":  # SB's corners are sub-pixel at the size it saw: those of a reduced copy are refined
            found, sb_win = _refine_views(images, found, [r is not None for r in reduced], pattern, subpix_win,
                                          (w, h))
        for i, corners in enumerate(found):
            views[i].detector = name
            if corners is None:
                views[i].note = (f"board {pattern[0]}x{pattern[1]} not found (a chessboard is found only when all "
                                 "its inner corners are in the image; a ChArUco board may be cut off)")
                continue
            if reduced[i]:
                views[i].note = f"{reduced[i]}, corners refined at full size"
            obj_pts[i], img_pts[i] = objp, corners
            views[i].found, views[i].n_points = True, len(corners)
        board_info = {"type": "chessboard", "inner_corners": list(pattern), "square": square_mm,
                      "detector": name, "subpix_win": classic_win if name == "classic" else sb_win}

    use = [i for i, v in enumerate(views) if v.found]
    if len(use) < MIN_VIEWS:
        raise BadInput(f"the board was found in {len(use)} of {len(images)} images; at least {MIN_VIEWS} "
                       f"are needed ({pattern_hint(charuco is not None)})")
    k, dist, rms, per_view, simpler = _fit(obj_pts, img_pts, use, (w, h))
    _flag_outliers(views, use, per_view)
    if reject_outliers and any(views[i].outlier for i in use):
        kept = [i for i in use if not views[i].outlier]
        if len(kept) >= MIN_VIEWS:
            k, dist, rms, per_view, simpler = _fit(obj_pts, img_pts, kept, (w, h))
            for i, e in zip(kept, per_view, strict=True):
                views[i].rms_px = e
            for i in use:
                if views[i].outlier:
                    views[i].note = "outlier: left out"
            use = kept
    for i in use:
        views[i].used = True
    result = IntrinsicsResult(k, dist.ravel()[:5] if dist.size >= 5 else dist.ravel(), float(rms), w, h, views,
                              board=board_info, coverage_share=board_coverage_share([img_pts[i] for i in use],
                                                                                    (w, h)))
    result.warnings = _warnings(result) + ([simpler] if simpler else [])
    return result


def board_coverage_share(corners: list[np.ndarray], size: tuple[int, int]) -> float:
    """The share of the image (0-1) inside the union of the views' board outlines: each view's detected corners'
    convex hull (the board between its corners, not the corners alone)."""
    w, h = size
    scale = min(1.0, COVERAGE_MASK_PX / max(w, h))
    mw, mh = max(1, round(w * scale)), max(1, round(h * scale))
    mask = np.zeros((mh, mw), np.uint8)
    for c in corners:
        hull = cv2.convexHull(np.asarray(c, np.float32).reshape(-1, 2) * np.float32(scale))
        cv2.fillConvexPoly(mask, np.round(hull * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    return float(mask.mean())


def pattern_hint(charuco: bool) -> str:
    """What to check when the board is found in few views (or in some, falsely: a 9x7 in a 9x6 board)."""
    return ("check --pattern, which counts the squares COLSxROWS for ChArUco, and --dictionary" if charuco
            else "check --pattern, which counts inner corners COLSxROWS")


def _refuse_mixed_sizes(images) -> None:
    """One camera matrix holds for one image size: a set of several sizes is refused, naming the images of each
    (a resized or cropped copy, or a turned camera, has another matrix)."""
    by_size: dict[tuple[int, int], list[str]] = {}
    for name, img in images:
        by_size.setdefault((img.shape[1], img.shape[0]), []).append(str(name))
    if len(by_size) == 1:
        return

    def names(ns):
        return ", ".join(ns[:3]) + (f" and {len(ns) - 3} more" if len(ns) > 3 else "")

    listed = "; ".join(f"{w}x{h} ({len(ns)}): {names(ns)}"
                       for (w, h), ns in sorted(by_size.items(), key=lambda kv: (-len(kv[1]), kv[0])))
    if any((h, w) in by_size for w, h in by_size):
        hint = ("portrait and landscape views are mixed: images are read as they are displayed (a JPEG's EXIF "
                "orientation applied, as `cell segment` reads frames), so a camera turned between shots, or "
                "photos whose EXIF orientation differs, give both; turn them all to the orientation the camera "
                "will be used in, or calibrate each orientation apart")
    else:
        hint = ("one camera matrix holds for one image size: calibrate each size apart (a resized or cropped "
                "copy has another camera matrix)")
    raise BadInput(f"the images have different sizes: {listed}; {hint}")


def _refine_views(images, found, refine, pattern, subpix_win, size):
    """(the found corners, those flagged in `refine` refined at full size with `cornerSubPix`, the half-window
    used: `subpix_win` or one for all views from their squares, `subpix_win_for`; None when nothing was refined)."""
    todo = [c is not None and r for c, r in zip(found, refine, strict=True)]
    if not any(todo):
        return list(found), subpix_win
    if subpix_win is None:
        subpix_win = min(subpix_win_for([c for c in found if c is not None], pattern), (min(size) - 5) // 2)
    return [refine_corners(g, c, subpix_win) if t else c
            for c, t, (_, g) in zip(found, todo, images, strict=True)], subpix_win


# Where the full model folds the image (a wild k3 fitted from boards near the middle), the fit is made again
# with fewer radial terms, as OpenCV advises for lenses that are not fisheye: k3 = 0, then k2 = k3 = 0; taken
# only where the corners fit it well (a wrong --pattern found in a few views folds the image too, at 1.9 px).
SIMPLER_MODELS = ((cv2.CALIB_FIX_K3, "k3 = 0"), (cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3, "k2 = k3 = 0"))


def _fit(obj_pts, img_pts, use, size):
    """k, dist, rms, per-view RMS and, where a simpler model was needed, a warning saying so."""
    from calibration.calfile import is_lens_model

    fit = _fit_model(obj_pts, img_pts, use, size, 0)
    if is_lens_model(fit[0], fit[1].ravel(), *size):
        return (*fit, None)
    folded = ", ".join(f"{x:.3g}" for x in fit[1].ravel())
    for flags, what in SIMPLER_MODELS:
        simpler = _fit_model(obj_pts, img_pts, use, size, flags)
        if simpler[2] <= LARGE_RMS_PX and is_lens_model(simpler[0], simpler[1].ravel(), *size):
            return (*simpler, f"the full distortion model (k1, k2, p1, p2, k3 = {folded}) folds the image where "
                              f"no board was; fitted with {what} instead (RMS {simpler[2]:.3f} px against "
                              f"{fit[2]:.3f}): views with the board near the image's edges and corners fit the "
                              "whole model")
    return (*fit, None)  # the calibration file's check refuses it and says what to do


def _fit_model(obj_pts, img_pts, use, size, flags: int):
    ops = [obj_pts[i] for i in use]
    ips = [img_pts[i] for i in use]
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(ops, ips, size, None, None, flags=flags)
    per_view = []
    for op, ip, rv, tv in zip(ops, ips, rvecs, tvecs, strict=True):
        proj, _ = cv2.projectPoints(op, rv, tv, k, dist)
        per_view.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - ip.reshape(-1, 2)) ** 2, axis=1)))))
    return k, dist, float(rms), per_view


def _flag_outliers(views: list[View], use: list[int], per_view: list[float]) -> None:
    med = float(np.median(per_view))
    for i, e in zip(use, per_view, strict=True):
        views[i].rms_px = e
        if e > OUTLIER_FACTOR * med and e > med + OUTLIER_MIN_PX:
            views[i].outlier = True
            views[i].note = f"outlier: view RMS {e:.3f} px vs median {med:.3f} px"


def principal_point_offset(k, w: int, h: int) -> tuple[float, float]:
    """How far a camera matrix's principal point lies from the centre of a `w` x `h` px image, as shares of its
    width and height (PRINCIPAL_OFF_CENTRE_WARN is where a warning starts)."""
    return abs(float(k[0, 2]) - (w - 1) / 2) / w, abs(float(k[1, 2]) - (h - 1) / 2) / h


def _warnings(r: IntrinsicsResult) -> list[str]:
    out = []
    cx, cy = r.camera_matrix[0, 2], r.camera_matrix[1, 2]
    dx, dy = principal_point_offset(r.camera_matrix, r.width_px, r.height_px)
    if max(dx, dy) > PRINCIPAL_OFF_CENTRE_WARN:
        out.append(f"principal point ({cx:.1f}, {cy:.1f}) is far from the image centre "
                   f"({(r.width_px - 1) / 2:.1f}, {(r.height_px - 1) / 2:.1f}): {100 * dx:.0f}% / "
                   f"{100 * dy:.0f}% of the image size; the views probably do not constrain the model "
                   "(tilt the board more, cover the corners) - do not use this result as is")
    n = len(r.images_used)
    if n < 8:
        out.append(f"only {n} views used; 10-20 views at varied tilts give a stable calibration")
    if r.rms_px > LARGE_RMS_PX:
        out.append(f"RMS reprojection error {r.rms_px:.2f} px is large (expect < 0.5 px)")
    if r.coverage_share is not None and r.coverage_share < MIN_BOARD_COVERAGE_SHARE:
        out.append(f"the boards cover only {100 * r.coverage_share:.0f} % of the image (the used views' board "
                   f"outlines together; at least {100 * MIN_BOARD_COVERAGE_SHARE:.0f} % expected): the lens distortion "
                   "is fitted there and is not trustworthy outside it (dist "
                   f"{', '.join(f'{x:.3g}' for x in r.dist.ravel())}); take views with the board near the image's "
                   "edges and corners")
    outl = [v.name for v in r.views if v.outlier]
    if outl:
        out.append("views that do not fit the model: " + ", ".join(outl))
    return out
