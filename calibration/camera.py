"""The camera model: pixels <-> base-frame millimetres on a horizontal plane at height z, or on the
calibration's own plane when that is tilted (`plane`, calibration/tilted.py).

Two kinds of mapping, both behind one class:

- pose: intrinsics (camera matrix + lens distortion) and the camera's pose in the base
  frame (`cam2base`, 4 x 4). A pixel is undistorted into a ray and the ray is cut with the
  plane z = z_mm, so any plane height works (part tops are not at z = 0).
- homography: a 3 x 3 image-to-plane homography (pixels to mm) fitted without intrinsics. It is exact
  only on its own plane (`plane_z_mm`); other heights are refused. On a tilted plane it maps the image to
  the plane's own 2D frame, and from there into the base frame.

Pixel coordinates follow CONTRACT.md: origin at the top-left pixel's top-left corner, so
the centre of pixel (row i, column j) is (j + 0.5, i + 0.5). The camera matrix is stored
as OpenCV computes and publishes it (pixel centres at integers, e.g. OpenCV's `cx`), and
the half-pixel shift is applied here, once, at the boundary.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calibration.tilted import TiltedPlane
from cell.errors import BadInput

HALF_PX = 0.5  # CONTRACT frame = OpenCV pixel-centre frame + 0.5
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
# A horizontal plane to map on lies at least this far below the camera's optical centre (inside that is the
# lens): at 799.9999 mm under the default camera (800 mm, as a calibration prints it rounded) every pixel
# mapped to the camera's own x, y, exit 0; above it the rays miss the plane (below, for a camera looking up)
MIN_PLANE_BELOW_CAMERA_MM = 10.0


def check_points(pts, name: str) -> np.ndarray:
    """Return `pts` as a float64 array of shape (n, 2); a single point (2,) becomes (1, 2)."""
    arr = np.asarray(pts, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == 2:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise BadInput(f"{name}: expected points of shape (n, 2), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise BadInput(f"{name}: points must be finite numbers")
    return arr.copy()


@dataclass(frozen=True, eq=False)
class Calibration:
    """A camera calibration for images of `width_px` x `height_px`.

    Attributes
    ----------
    camera_matrix : ndarray of shape (3, 3) or None
        OpenCV camera matrix (pixel centres at integers); None for a homography-only file.
    dist : ndarray of shape (k,)
        OpenCV distortion coefficients (k1, k2, p1, p2, k3[, ...]); zeros when unknown.
    cam2base : ndarray of shape (4, 4) or None
        Pose of the camera in the robot base frame (mm); None when there is no pose.
    homography : ndarray of shape (3, 3) or None
        CONTRACT-frame pixels -> base-frame (x, y) on the plane z = `plane_z_mm` (on a tilted `plane`:
        -> the plane's own 2D coordinates).
    plane_z_mm : float or None
        The height of the calibration's fiducials; the default height for mapping. None with a tilted
        `plane` (no one height): mapping with z_mm None is then on that plane.
    report : dict
        How the calibration was made (residuals, images used, warnings); kept in the file.
    plane : TiltedPlane or None
        The fiducials' plane when it is not horizontal.
    """

    width_px: int
    height_px: int
    camera_matrix: np.ndarray | None = None
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    cam2base: np.ndarray | None = None
    homography: np.ndarray | None = None
    plane_z_mm: float | None = 0.0
    name: str = "calibration"
    report: dict = field(default_factory=dict)
    plane: TiltedPlane | None = None
    source: str | None = None  # the file it was read from (not written): messages name it, not `name`

    @property
    def label(self) -> str:
        """How messages name it: the file the user gave, else its own name."""
        return f"calibration file {self.source}" if self.source else f"calibration {self.name!r}"

    # ---- what the calibration can do -------------------------------------------------
    @property
    def has_intrinsics(self) -> bool:
        return self.camera_matrix is not None

    @property
    def has_pose(self) -> bool:
        return self.camera_matrix is not None and self.cam2base is not None

    @property
    def can_map(self) -> bool:
        return self.has_pose or self.homography is not None

    @property
    def size(self) -> tuple[int, int]:
        return self.width_px, self.height_px

    def resized(self, width_px: int, height_px: int) -> Calibration:
        """The calibration of this camera's frames resized to `width_px` x `height_px` (a frame
        upscaled or reduced as a whole): the same pose and lens, the intrinsics scaled with the
        image; a homography's pixels scaled too. In the CONTRACT frame a pixel (u, v) becomes
        (u sx, v sy); OpenCV's matrix counts from pixel centres, so its cx becomes
        (cx + 0.5) sx - 0.5."""
        if int(width_px) < 1 or int(height_px) < 1:
            raise BadInput(f"a resized calibration needs a positive size, got {width_px} x {height_px}")
        sx, sy = int(width_px) / self.width_px, int(height_px) / self.height_px
        k = None
        if self.camera_matrix is not None:
            k = self.camera_matrix.astype(float).copy()
            k[0, :2] *= sx
            k[1, 1] *= sy
            k[0, 2] = (k[0, 2] + HALF_PX) * sx - HALF_PX
            k[1, 2] = (k[1, 2] + HALF_PX) * sy - HALF_PX
        h = None if self.homography is None else self.homography @ np.diag([1.0 / sx, 1.0 / sy, 1.0])
        return Calibration(int(width_px), int(height_px), k, self.dist.copy(),
                           None if self.cam2base is None else self.cam2base.copy(), h, self.plane_z_mm,
                           f"{self.name} resized to {int(width_px)} x {int(height_px)}", dict(self.report),
                           self.plane, self.source)

    def check_frame(self, frame: np.ndarray, what: str = "frame") -> None:
        """Refuse a frame whose size is not the calibration's."""
        h, w = frame.shape[:2]
        if (w, h) != (self.width_px, self.height_px):
            raise BadInput(f"{what} is {w} x {h} px but {self.label} is for "
                           f"{self.width_px} x {self.height_px} px images")

    # ---- pixel -> mm --------------------------------------------------------------------
    def px_to_mm(self, uv, z_mm: float | None = None) -> np.ndarray:
        """Map pixels (CONTRACT frame) to base-frame (x, y) on the plane at height `z_mm`.

        Parameters
        ----------
        uv : array-like of shape (n, 2)
        z_mm : float, optional
            Height of the plane; default `plane_z_mm` (with a tilted `plane`: onto that plane; their z is
            in `px_to_xyz`).

        Returns
        -------
        ndarray of shape (n, 2), mm.
        """
        uv = check_points(uv, "px_to_mm")
        if self.plane is not None and z_mm is None:
            return self.px_to_xyz(uv)[:, :2]
        z = self._plane(z_mm)
        if self.has_pose:
            self._check_below_camera(z)
            rays_cam = self._rays(uv)
            r, t = self.cam2base[:3, :3], self.cam2base[:3, 3]
            rays = rays_cam @ r.T
            dz = rays[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (z - t[2]) / dz
            if np.any(~np.isfinite(s)) or np.any(s <= 0):
                raise BadInput(f"{self.label}: the plane z = {z:g} mm is not in front of the camera "
                               "for some pixels (beyond its horizon, or a plane above the camera)")
            return _finite_result((t[None, :] + s[:, None] * rays)[:, :2], "px_to_mm")
        if self.homography is not None:
            self._check_plane(z)
            return _finite_result(self._h_to_plane(uv), "px_to_mm")
        raise BadInput(f"{self.label} has intrinsics only: no mapping to the base frame "
                       "(run `cell calibrate plane`)")

    def mm_to_px(self, xy, z_mm: float | None = None) -> np.ndarray:
        """Map base-frame (x, y) on the plane at height `z_mm` to pixels (CONTRACT frame).

        Parameters
        ----------
        xy : array-like of shape (n, 2)
        z_mm : float, optional
            Height of the plane; default `plane_z_mm` (with a tilted `plane`: the points of that plane above
            (x, y)).

        Returns
        -------
        ndarray of shape (n, 2), px, lens distortion applied.
        """
        xy = check_points(xy, "mm_to_px")
        if self.plane is not None and z_mm is None:
            return self.plane_points_to_px(self.plane.lift(xy))
        z = self._plane(z_mm)
        if self.has_pose:
            self._check_below_camera(z)
            xyz = np.column_stack([xy, np.full(len(xy), z)])
            return _finite_result(self.project(xyz), "mm_to_px")
        if self.homography is not None:
            self._check_plane(z)
            return _finite_result(self._h_from_plane(xy), "mm_to_px")
        raise BadInput(f"{self.label} has intrinsics only: no mapping to the base frame")

    def px_to_xyz(self, uv, z_mm: float | None = None) -> np.ndarray:
        """Map pixels to base-frame points (n, 3) on the calibration's plane (tilted or not) or, with `z_mm`,
        on the horizontal plane at that height."""
        uv = check_points(uv, "px_to_mm")
        if self.plane is None or z_mm is not None:
            z = self._plane(z_mm)
            xy = self.px_to_mm(uv, z)
            return np.column_stack([xy, np.full(len(xy), z)])
        if self.has_pose:
            t = self.cam2base[:3, 3]
            rays = self._rays(uv) @ self.cam2base[:3, :3].T
            s = self.plane.cut(t, rays)
            if np.any(~np.isfinite(s)) or np.any(s <= 0):
                raise BadInput(f"{self.label}: its tilted plane is not in front of the camera for some "
                               "pixels (beyond its horizon)")
            return _finite_result(t[None, :] + s[:, None] * rays, "px_to_mm")
        if self.homography is None:
            raise BadInput(f"{self.label} has intrinsics only: no mapping to the base frame")
        return _finite_result(self.plane.from_plane(self._h_to_plane(uv)), "px_to_mm")

    def plane_points_to_px(self, xyz: np.ndarray) -> np.ndarray:
        """Points (n, 3) of the tilted plane -> pixels: projected through the pose, or through the homography
        from the plane's own 2D coordinates."""
        if self.has_pose:
            return _finite_result(self.project(xyz), "mm_to_px")
        if self.homography is None:
            raise BadInput(f"{self.label} has intrinsics only: no mapping to the base frame")
        return _finite_result(self._h_from_plane(self.plane.to_plane(xyz)), "mm_to_px")

    def _h_to_plane(self, uv: np.ndarray) -> np.ndarray:
        """Pixels -> the homography's plane coordinates (base x, y; on a tilted plane its own 2D frame); pixels
        beyond the plane's horizon (on the other side from the image centre) refused."""
        centre = np.array([[self.width_px / 2.0, self.height_px / 2.0]])
        try:
            return _apply_h(self.homography, uv, centre)
        except BadInput as e:  # as the pose's refusal: which calibration
            raise BadInput(f"{self.label}: {e}") from None

    def _h_from_plane(self, ab: np.ndarray) -> np.ndarray:
        """The homography's plane coordinates -> pixels; points beyond the horizon refused (`_h_to_plane`)."""
        centre = _apply_h(self.homography, np.array([[self.width_px / 2.0, self.height_px / 2.0]]))
        return _apply_h(np.linalg.inv(self.homography), ab, centre)

    def project(self, xyz_mm) -> np.ndarray:
        """Project base-frame points of shape (n, 3) to pixels (n, 2), CONTRACT frame."""
        if not self.has_pose:
            raise BadInput(f"{self.label} has no camera pose: cannot project 3D points")
        xyz = np.asarray(xyz_mm, dtype=float).reshape(-1, 3)
        base2cam = np.linalg.inv(self.cam2base)
        pc = xyz @ base2cam[:3, :3].T + base2cam[:3, 3]
        if np.any(pc[:, 2] <= 0):
            raise BadInput(f"{self.label}: some points are behind the camera (above it)")
        img, _ = cv2.projectPoints(pc.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.camera_matrix, self.dist)
        return img.reshape(-1, 2) + HALF_PX

    def undistort_px(self, uv) -> np.ndarray:
        """Distorted pixels -> ideal (distortion-free) pixels, both CONTRACT frame, shape (n, 2)."""
        uv = check_points(uv, "undistort_px")
        if not self.has_intrinsics:
            return uv
        n = self._rays(uv)
        k = self.camera_matrix
        return np.column_stack([k[0, 0] * n[:, 0] + k[0, 1] * n[:, 1] + k[0, 2],
                                k[1, 1] * n[:, 1] + k[1, 2]]) + HALF_PX

    def _rays(self, uv: np.ndarray) -> np.ndarray:
        pts = (uv - HALF_PX).reshape(-1, 1, 2)
        norm = cv2.undistortPoints(pts, self.camera_matrix, self.dist, criteria=_UNDISTORT_CRITERIA)
        norm = norm.reshape(-1, 2)
        return np.column_stack([norm, np.ones(len(norm))])

    def _plane(self, z_mm: float | None) -> float:
        z = self.plane_z_mm if z_mm is None else float(z_mm)
        if not np.isfinite(z):
            raise BadInput(f"the plane height z must be a finite number of mm, got {z_mm!r}")
        return z

    def _check_below_camera(self, z: float) -> None:
        """Refuse a horizontal plane at z within MIN_PLANE_BELOW_CAMERA_MM of the camera's optical centre, or on
        the side it does not look to (above a camera looking down). A camera looking up (markers given in a
        mirrored frame) is named by the calibration file's own check, with what to do."""
        cam_z, look_z = float(self.cam2base[2, 3]), float(self.cam2base[2, 2])  # the optical axis' z: < 0 down
        down = look_z <= 0
        if abs(z - cam_z) < MIN_PLANE_BELOW_CAMERA_MM or (z - cam_z) * look_z < 0:
            raise BadInput(f"{self.label}: the plane z = {z:g} mm is not {'below' if down else 'above'} the camera: "
                           f"the camera's optical centre is at z = {cam_z:.6g} mm, looking {'down' if down else 'up'}, "
                           f"and a plane to map on lies at least {MIN_PLANE_BELOW_CAMERA_MM:g} mm "
                           f"{'lower' if down else 'higher'}")

    def _check_plane(self, z: float) -> None:
        if self.plane is not None:
            raise BadInput(f"{self.label} is a homography for its tilted plane "
                           f"({self.plane.describe()['equation']}) only: without a camera model it cannot map on "
                           f"another plane, such as z = {z:g} mm; calibrate with intrinsics (--camera-matrix or "
                           "--intrinsics) for that")
        if abs(z - self.plane_z_mm) > 1e-6:
            raise BadInput(f"{self.label} is a homography for the plane z = {self.plane_z_mm} mm "
                           f"only; mapping at z = {z} mm needs intrinsics and a camera pose")

    # ---- derived figures ----------------------------------------------------------------
    def vertical_vanishing_px(self) -> np.ndarray:
        """Image point (2,) where vertical lines meet: tops of walls lie farther from it than bottoms.

        For a homography-only calibration (no pose) the image centre is returned.
        """
        if not self.has_pose:
            return np.array([self.width_px / 2.0, self.height_px / 2.0])
        down_cam = np.linalg.inv(self.cam2base)[:3, :3] @ np.array([0.0, 0.0, -1.0])
        if down_cam[2] <= 1e-9:
            return np.array([self.width_px / 2.0, self.height_px / 2.0])
        p = self.camera_matrix @ (down_cam / down_cam[2])
        return p[:2] + HALF_PX

    def mm_per_px(self, z_mm: float | None = None) -> float:
        """Ground sampling distance at the image centre on the plane z (default the calibration's, tilted or
        not), mm per pixel: along u; on a tilted plane the side of the square of a pixel's area on it (a
        pixel spans 1 / cos(view angle) x more across the tilt: mm^2 thresholds in pixels need the area)."""
        c = np.array([[self.width_px / 2.0, self.height_px / 2.0]])
        if self.plane is not None and z_mm is None:
            p0, p1, p2, p3 = self.px_to_xyz(c + [[-5.0, -5.0], [5.0, -5.0], [5.0, 5.0], [-5.0, 5.0]])
            area_mm2 = np.linalg.norm(np.cross(p2 - p0, p3 - p1)) / 2.0  # a quadrilateral's: half its diagonals'
            return float(np.sqrt(area_mm2) / 10.0)
        a = self.px_to_xyz(c + [[-5.0, 0.0]], z_mm)
        b = self.px_to_xyz(c + [[5.0, 0.0]], z_mm)
        return float(np.linalg.norm(b - a) / 10.0)

    def camera_position_mm(self) -> np.ndarray | None:
        return None if self.cam2base is None else self.cam2base[:3, 3].copy()


def _finite_result(pts: np.ndarray, what: str) -> np.ndarray:
    """A mapping's result, refused when it overflowed (a degenerate calibration, or a point at
    the horizon): NaN or infinity would otherwise reach the JSON output."""
    if not np.all(np.isfinite(pts)):
        raise BadInput(f"{what}: some points map to infinity or NaN (a degenerate calibration, or points "
                       "on the plane's horizon)")
    return pts


def _apply_h(h: np.ndarray, pts: np.ndarray, same_side_as: np.ndarray | None = None) -> np.ndarray:
    """Apply the homography; with `same_side_as` (a point of the view), points on the other side of the
    plane's horizon are refused: they are not on the plane in front of the camera, and the division would
    give them a point on it all the same."""
    with np.errstate(over="ignore", invalid="ignore"):
        ph = np.column_stack([pts, np.ones(len(pts))]) @ h.T
    if np.any(np.abs(ph[:, 2]) < 1e-12):
        raise BadInput("point maps to infinity under the homography")
    if same_side_as is not None:
        with np.errstate(over="ignore", invalid="ignore"):
            w_ref = (np.append(np.asarray(same_side_as, float).ravel()[:2], 1.0) @ h.T)[2]
        if np.any(np.sign(ph[:, 2]) != np.sign(w_ref)):
            raise BadInput("some points lie beyond the plane's horizon (not on the plane in front of the camera)")
    with np.errstate(over="ignore", invalid="ignore"):
        return ph[:, :2] / ph[:, 2:3]


def pose_matrix(r: np.ndarray, t) -> np.ndarray:
    """4 x 4 homogeneous transform from a rotation (3, 3) and a translation (3,)."""
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = np.asarray(t, float).reshape(3)
    return m
