"""Mapping off its plane with a homography-only calibration: an estimate of where the camera is.

A pixel's ray runs from the camera's optical centre C through the point P0 the homography gives it on its
plane z0; on the horizontal plane z it meets P = C + (P0 - C) s, s = (C_z - z) / (C_z - z0): the plane's
points scaled about the camera's nadir (C's foot) by s. So the homography maps at any height once C is
known, and still exactly on its own plane (s = 1).

C follows from the homography (Zhang, one view) for a pinhole camera with its principal point at the image
centre, square pixels and no skew: the plane -> image homography is K [r1 r2 t] up to scale, K = [[f, 0, w/2],
[0, f, h/2], [0, 0, 1]] (CONTRACT pixels), and the pose follows once f is known. f comes
- from the view: r1 . r2 = 0 and |r1| = |r2| give f when the plane is seen tilted enough (`FOCAL_FROM_VIEW_TILT_DEG`);
- else from the camera's height: seen straight down the scale gives only f / height (both constraints
  degenerate), so f is the one that puts C at the given camera z.
A straight-down camera's height error dH moves a point r from the nadir by about r |z - z0| dH / H^2 (H the
camera's height over the plane): 0.5 mm at r = 500, z - z0 = 30, dH = 20, H = 800.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.errors import BadInput

# The view's focal length is used when the camera looks at least this far from straight down (by the view's
# f, and half that placed at the given height): below, Zhang's f is too noisy. Measured on synthetic views of
# 24 corners with 1 px of noise and the principal point 15, -10 px off the centre: at 10 deg its f is 4 % off
# (median), points at z = 100 mm 2.8 mm, against 4.0 mm from a height 50 mm off; at 20 deg 2.3 % and 2.3 mm
# against 5.0 mm
FOCAL_FROM_VIEW_TILT_DEG = 20.0
FOCAL_RANGE_PX = (1.0, 1e6)  # as the calibration file's reader takes fx, fy
MIN_CAMERA_ABOVE_MM = 10.0  # as calibration/camera.py's MIN_PLANE_BELOW_CAMERA_MM
# What the error bound assumes: the camera's height known to this, the principal point this share of the
# image's size from its centre (a lens centred on the sensor to 2 %; the Festo RealSense: 0.2 % and 0.5 %)
HEIGHT_TOLERANCE_MM = 50.0
PRINCIPAL_TOLERANCE = 0.02


@dataclass(frozen=True)
class CameraEstimate:
    """The camera a homography implies: optical centre `camera_mm` (base frame), focal length `focal_px`,
    the optical axis' tilt from straight down `tilt_deg`, and `focal_from` ("view" or "height")."""

    camera_mm: np.ndarray
    focal_px: float
    tilt_deg: float
    focal_from: str


def _plane_to_centred_px(px_to_mm: np.ndarray, size: tuple[int, int], offset_px=(0.0, 0.0)) -> np.ndarray:
    """The plane (x, y, 1) -> pixels homography with the pixels taken about the assumed principal point (the
    image centre, moved by `offset_px`), scaled to unit norm."""
    cu, cv = size[0] / 2.0 + offset_px[0], size[1] / 2.0 + offset_px[1]
    a = np.array([[1.0, 0.0, -cu], [0.0, 1.0, -cv], [0.0, 0.0, 1.0]]) @ np.linalg.inv(px_to_mm)
    return a / np.linalg.norm(a)


def _pose(a: np.ndarray, focal_px: float, plane_z_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(rotation base -> camera (3, 3), optical centre in the base frame (3,)) for the focal length."""
    m = np.diag([1.0 / focal_px, 1.0 / focal_px, 1.0]) @ a
    scale = math.sqrt(np.linalg.norm(m[:, 0]) * np.linalg.norm(m[:, 1]))
    seen = np.linalg.solve(a, [0.0, 0.0, 1.0])  # the plane's point at the image centre, homogeneous
    if (m @ seen)[2] / seen[2] < 0:  # ... in front of the camera (the base origin may be beyond the horizon)
        scale = -scale
    r1, r2, t = m[:, 0] / scale, m[:, 1] / scale, m[:, 2] / scale
    u, _, vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    r = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt  # the nearest rotation
    centre = -r.T @ t
    return r, centre + [0.0, 0.0, plane_z_mm]


def _focal_from_view(a: np.ndarray) -> float | None:
    """Zhang's focal length from one view of a plane (r1 . r2 = 0, |r1| = |r2|, least squares in f^2); None
    when they give none (a plane seen straight down: both read 0 = 0 at every f)."""
    p = np.array([a[0, 0] * a[0, 1] + a[1, 0] * a[1, 1], a[0, 0] ** 2 + a[1, 0] ** 2 - a[0, 1] ** 2 - a[1, 1] ** 2])
    q = np.array([a[2, 0] * a[2, 1], a[2, 0] ** 2 - a[2, 1] ** 2])  # p / f^2 + q = 0
    denom = float(q @ q)
    if denom == 0.0:
        return None
    f2 = -float(p @ q) / denom  # p + q f^2 = 0: least squares in f^2 over the two
    if not f2 > 0:
        return None
    f = math.sqrt(f2)
    return f if FOCAL_RANGE_PX[0] <= f <= FOCAL_RANGE_PX[1] else None


def _focal_for_camera_z(a: np.ndarray, plane_z_mm: float, camera_z_mm: float) -> float | None:
    """The smallest focal length whose pose puts the optical centre at `camera_z_mm` (None: none does). The
    camera's height over the plane grows with f from 0, in proportion seen straight down; a tilted view's peaks
    (a longer f reads the same perspective as a steeper view, the camera moving out sideways): the first
    crossing on a log grid, then bisection."""
    def above(log_f: float) -> float:
        return _pose(a, math.exp(log_f), plane_z_mm)[1][2] - camera_z_mm

    grid = np.linspace(math.log(FOCAL_RANGE_PX[0]), math.log(FOCAL_RANGE_PX[1]), 241)
    first = next((i for i, g in enumerate(grid) if above(g) >= 0), None)
    if not first:  # none, or the camera above it already at f = 1 px
        return None
    lo, hi = grid[first - 1], grid[first]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if above(mid) < 0 else (lo, mid)
    return math.exp(0.5 * (lo + hi))


def estimate_camera(px_to_mm: np.ndarray, size: tuple[int, int], plane_z_mm: float, camera_z_mm: float,
                    offset_px=(0.0, 0.0), focal_from: str | None = None) -> CameraEstimate:
    """The camera the homography implies, its principal point at the image centre (moved by `offset_px`): f
    from the view when the pose it gives looks at least FOCAL_FROM_VIEW_TILT_DEG from straight down and the
    camera placed at `camera_z_mm` at least half that (seen nearly straight down the view's f is noise, and so
    is the tilt it gives), else the f that places the camera at `camera_z_mm`. `focal_from` ("view",
    "height") forces one."""
    if camera_z_mm - plane_z_mm < MIN_CAMERA_ABOVE_MM:
        raise BadInput(f"the camera at z = {camera_z_mm:g} mm is not above the calibration's plane z = "
                       f"{plane_z_mm:g} mm (at least {MIN_CAMERA_ABOVE_MM:g} mm above it)")
    a = _plane_to_centred_px(px_to_mm, size, offset_px)
    by_height = by_view = None
    f = _focal_for_camera_z(a, plane_z_mm, camera_z_mm) if focal_from != "view" else None
    if f is not None:
        r, centre = _pose(a, f, plane_z_mm)
        by_height = CameraEstimate(centre, f, _tilt_deg(r), "height")
    f = _focal_from_view(a) if focal_from != "height" else None
    if f is not None:
        r, centre = _pose(a, f, plane_z_mm)
        if centre[2] - plane_z_mm >= MIN_CAMERA_ABOVE_MM:
            by_view = CameraEstimate(centre, f, _tilt_deg(r), "view")
    if focal_from is None and by_view is not None and by_height is not None and not (
            by_view.tilt_deg >= FOCAL_FROM_VIEW_TILT_DEG and by_height.tilt_deg >= FOCAL_FROM_VIEW_TILT_DEG / 2):
        by_view = None
    if by_view is not None or by_height is not None:
        return by_view or by_height
    raise BadInput("no pinhole camera with its principal point at the image centre sees the calibration's plane so "
                   + (f"from z = {camera_z_mm:g} mm" if focal_from != "view" else "with the focal length of the view"))


def _tilt_deg(base2cam: np.ndarray) -> float:
    """The optical axis' angle from straight down."""
    axis = base2cam[2]  # the camera's z axis in the base frame
    return float(np.degrees(np.arccos(np.clip(-axis[2], -1.0, 1.0))))


def scale_about_nadir(camera_mm: np.ndarray, plane_z_mm: float, z_mm: float) -> float:
    """s: a point at z is its ray's point at plane_z_mm scaled by s about the nadir."""
    return (camera_mm[2] - z_mm) / (camera_mm[2] - plane_z_mm)


def plane_to_z(xy0: np.ndarray, camera_mm: np.ndarray, plane_z_mm: float, z_mm: float) -> np.ndarray:
    """Points (n, 2) on the plane z0 -> the same rays' points on the plane z."""
    s = scale_about_nadir(camera_mm, plane_z_mm, z_mm)
    return camera_mm[:2] + (np.asarray(xy0, float) - camera_mm[:2]) * s


def z_to_plane(xy: np.ndarray, camera_mm: np.ndarray, plane_z_mm: float, z_mm: float) -> np.ndarray:
    """Points (n, 2) on the plane z -> the same rays' points on the plane z0."""
    s = scale_about_nadir(camera_mm, plane_z_mm, z_mm)
    return camera_mm[:2] + (np.asarray(xy, float) - camera_mm[:2]) / s


ASSUMED = "a pinhole camera with its principal point at the image centre, square pixels, no skew, no lens distortion"


class OffPlaneMapping:
    """A homography-only calibration of a horizontal plane, mapped on other horizontal planes through the camera
    it implies (`estimate_camera`): `px_to_mm` and `mm_to_px` as Calibration's, and how far the assumptions'
    tolerances move the result (`error_bound`)."""

    def __init__(self, cal, camera_z_mm: float, height_from: str = "the camera's height"):
        """`height_from` names where `camera_z_mm` came from, in messages."""
        if cal.homography is None or cal.has_pose or cal.plane is not None:
            raise ValueError("OffPlaneMapping is for a horizontal plane's homography-only calibration")
        self.cal, self.camera_z_mm = cal, float(camera_z_mm)
        try:
            self.camera = estimate_camera(cal.homography, cal.size, cal.plane_z_mm, self.camera_z_mm)
        except BadInput as e:
            raise BadInput(f"{cal.label} with {height_from}: {e}") from None

    def px_to_mm(self, uv, z_mm: float, camera: CameraEstimate | None = None) -> np.ndarray:
        cam = camera or self.camera
        self._check_below_camera(z_mm, cam)
        return plane_to_z(self.cal.px_to_mm(uv), cam.camera_mm, self.cal.plane_z_mm, z_mm)

    def mm_to_px(self, xy, z_mm: float, camera: CameraEstimate | None = None) -> np.ndarray:
        cam = camera or self.camera
        self._check_below_camera(z_mm, cam)
        return self.cal.mm_to_px(z_to_plane(np.asarray(xy, float), cam.camera_mm, self.cal.plane_z_mm, z_mm))

    def _check_below_camera(self, z_mm: float, cam: CameraEstimate) -> None:
        if cam.camera_mm[2] - z_mm < MIN_CAMERA_ABOVE_MM:
            raise BadInput(f"{self.cal.label}: the plane z = {z_mm:g} mm is not below the camera the homography "
                           f"implies (its optical centre at z = {cam.camera_mm[2]:.1f} mm; a plane to map on lies "
                           f"at least {MIN_CAMERA_ABOVE_MM:g} mm lower)")

    def error_bound(self, pts, z_mm: float, way: str) -> float | None:
        """How far the points mapped `way` ("mm": pixels to mm, "px": mm to pixels) move, at most, with the
        camera's height off by HEIGHT_TOLERANCE_MM (when f came from it) plus the principal point off by
        PRINCIPAL_TOLERANCE of the image along u or v; None when such a camera is not found."""
        mapping = self.px_to_mm if way == "mm" else self.mm_to_px
        nominal = mapping(pts, z_mm)
        w, h = self.cal.size
        du, dv = PRINCIPAL_TOLERANCE * w, PRINCIPAL_TOLERANCE * h
        cam, z0 = self.camera, self.cal.plane_z_mm
        try:
            heights = [] if cam.focal_from == "view" else [
                estimate_camera(self.cal.homography, (w, h), z0, self.camera_z_mm + d, focal_from="height")
                for d in (-HEIGHT_TOLERANCE_MM, HEIGHT_TOLERANCE_MM)]
            principal = [estimate_camera(self.cal.homography, (w, h), z0, self.camera_z_mm, offset, cam.focal_from)
                         for offset in ((du, 0.0), (-du, 0.0), (0.0, dv), (0.0, -dv))]
            return sum(max((float(np.linalg.norm(mapping(pts, z_mm, c) - nominal, axis=1).max()) for c in cams),
                           default=0.0) for cams in (heights, principal))
        except BadInput:
            return None

    def describe(self) -> dict:
        cam = self.camera
        return {"estimate": True, "camera_mm": [round(float(v), 2) for v in cam.camera_mm],
                "focal_px": round(cam.focal_px, 1), "tilt_deg": round(cam.tilt_deg, 2), "focal_from": cam.focal_from,
                "camera_height_mm": self.camera_z_mm, "assumed": ASSUMED}
