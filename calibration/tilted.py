"""A calibration plane that is not horizontal: a fixture tilted across the tray, a board leaning on a
block, a tray on a slightly tilted table measured with the robot.

The plane is a point on it and an orthonormal frame: `x_axis` and `y_axis` in the plane (`x_axis` is
base x laid onto the plane, so a plane tilted a little has a frame close to the base's) and `normal`
= x_axis x y_axis, pointing up (its front: the side a camera over the tray sees). Its base (x, y)
place a point on it (z from the equation) as long as it is not steep: tilts over MAX_TILT_DEG are
refused when fitting and reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cell.errors import BadInput

OFF_PLANE_MM = 2.5  # a point this far off the fitted plane is on another one: the horizontal path's 5 mm
# of z spread is +-2.5 mm about its mean plane
MAX_TILT_DEG = 75.0  # steeper, base (x, y) hardly place a point on the plane (dz / dx 3.7 and more)


@dataclass(frozen=True, eq=False)
class TiltedPlane:
    """point_mm (3,), x_axis (3,), y_axis (3,): a point of the plane and its in-plane unit axes."""

    point_mm: np.ndarray
    x_axis: np.ndarray
    y_axis: np.ndarray

    @classmethod
    def from_normal(cls, point_mm, normal) -> TiltedPlane:
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        if n[2] < 0:
            n = -n
        x = np.array([1.0, 0.0, 0.0]) - n[0] * n  # base x onto the plane: never short below MAX_TILT_DEG
        x /= np.linalg.norm(x)
        return cls(np.asarray(point_mm, float).copy(), x, np.cross(n, x))

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.x_axis, self.y_axis)

    @property
    def tilt_deg(self) -> float:
        return float(np.degrees(np.arccos(np.clip(self.normal[2], -1.0, 1.0))))

    def z_at(self, xy) -> np.ndarray:
        """z (n,) of the plane's points above base (x, y) (n, 2)."""
        n = self.normal
        xy = np.asarray(xy, float).reshape(-1, 2)
        return self.point_mm[2] - ((xy - self.point_mm[:2]) @ n[:2]) / n[2]

    def lift(self, xy) -> np.ndarray:
        """Base (x, y) (n, 2) -> the plane's points (n, 3)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.column_stack([xy, self.z_at(xy)])

    def to_plane(self, xyz) -> np.ndarray:
        """Base points (n, 3) -> the plane's own 2D coordinates (n, 2), mm (of their feet on it)."""
        d = np.asarray(xyz, float).reshape(-1, 3) - self.point_mm
        return np.column_stack([d @ self.x_axis, d @ self.y_axis])

    def from_plane(self, ab) -> np.ndarray:
        """The plane's 2D coordinates (n, 2) -> base points (n, 3)."""
        ab = np.asarray(ab, float).reshape(-1, 2)
        return self.point_mm + ab[:, :1] * self.x_axis + ab[:, 1:] * self.y_axis

    def foot(self, xyz) -> np.ndarray:
        """Base points (n, 3) moved along the normal onto the plane."""
        return self.from_plane(self.to_plane(xyz))

    def off(self, xyz) -> np.ndarray:
        """Signed distance (n,) of base points from the plane, mm, positive in front (above)."""
        return (np.asarray(xyz, float).reshape(-1, 3) - self.point_mm) @ self.normal

    def cut(self, origin, rays) -> np.ndarray:
        """Where the rays (n, 3) from `origin` (3,) meet the plane: s (n,) with origin + s ray on it (inf,
        nan or <= 0: they do not meet it in front)."""
        n = self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            return ((self.point_mm - origin) @ n) / (rays @ n)

    def describe(self) -> dict:
        """The plane as a person reads it: normal, a point, z = a x + b y + c, tilt."""
        n = self.normal
        a, b = -n[0] / n[2], -n[1] / n[2]
        c = self.point_mm[2] - a * self.point_mm[0] - b * self.point_mm[1]
        a, b, c = (round(float(v), 9) + 0.0 for v in (a, b, c))  # no "1e-17 y" or "-0 x"
        sign = {False: "+", True: "-"}
        return {"normal": [round(float(v), 6) for v in n], "point_mm": [round(float(v), 3) for v in self.point_mm],
                "equation": f"z = {a:.6g} x {sign[bool(b < 0)]} {abs(b):.6g} y {sign[bool(c < 0)]} {abs(c):.6g} (mm)",
                "tilt_deg": round(self.tilt_deg, 3)}


def fit_plane(xyz, names: list[str] | None = None) -> tuple[TiltedPlane, np.ndarray]:
    """The least-squares plane through base points (n, 3) and their signed distances from it (n,).
    Refused (BadInput) when a point lies more than OFF_PLANE_MM off it, naming the worst (`names`:
    what to call each point; default "point #i"), or when it is steeper than MAX_TILT_DEG."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    centre = xyz.mean(axis=0)
    _, _, vt = np.linalg.svd(xyz - centre)  # the direction of least spread is the normal
    plane = TiltedPlane.from_normal(centre, vt[2])
    off = plane.off(xyz)
    worst = int(np.argmax(np.abs(off)))
    if abs(off[worst]) > OFF_PLANE_MM:
        name = names[worst] if names else f"point #{worst}"
        raise BadInput(f"the points are not on one plane: the plane that fits them best (tilted "
                       f"{plane.tilt_deg:.1f} deg, {plane.describe()['equation']}) leaves {name} "
                       f"{abs(off[worst]):.2f} mm off it (at most {OFF_PLANE_MM:g} mm); check its coordinates, or "
                       "calibrate each plane on its own")
    if plane.tilt_deg > MAX_TILT_DEG:
        raise BadInput(f"the points' plane is tilted {plane.tilt_deg:.1f} deg from horizontal (at most "
                       f"{MAX_TILT_DEG:g}): on a plane that steep base (x, y), which the mappings give, do not "
                       "place a point")
    return plane, off
