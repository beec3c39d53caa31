"""SCARA kinematics in closed form (pure functions, base frame, mm and degrees).

Joints: J1 shoulder and J2 elbow (revolute, about z), J3 finger-tip z (prismatic, mm),
J4 wrist (revolute). The tool x axis (the jaws' closing axis) points along
J1 + J2 + J4. The jaws are symmetric, so a closing axis is a direction mod 180 degrees:
each elbow gives every J4 = axis - J1 - J2 + k * 180 inside the J4 limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.cellconfig import Scara


@dataclass(frozen=True)
class Joints:
    j1_deg: float
    j2_deg: float
    j3_mm: float
    j4_deg: float

    def as_dict(self) -> dict:
        return {"j1_deg": self.j1_deg, "j2_deg": self.j2_deg, "j3_mm": self.j3_mm, "j4_deg": self.j4_deg}

    def as_array(self) -> np.ndarray:
        return np.array([self.j1_deg, self.j2_deg, self.j3_mm, self.j4_deg])

    @classmethod
    def from_dict(cls, d: dict) -> Joints:
        return cls(float(d["j1_deg"]), float(d["j2_deg"]), float(d["j3_mm"]), float(d["j4_deg"]))

    @property
    def elbow(self) -> str:
        """'right' when J2 > 0 (elbow turned counter-clockwise), 'left' otherwise."""
        return "right" if self.j2_deg > 0 else "left"

    def rounded(self, ndigits: int = 4) -> Joints:
        return Joints(*(round(v, ndigits) for v in (self.j1_deg, self.j2_deg, self.j3_mm, self.j4_deg)))


@dataclass(frozen=True)
class ToolPose:
    x_mm: float
    y_mm: float
    z_mm: float  # finger-tip z
    axis_deg: float  # closing-axis direction, in (-90, 90]


def normalize_axis_deg(angle_deg: float) -> float:
    """A closing-axis direction folded into (-90, 90]."""
    a = math.fmod(angle_deg, 180.0)
    if a <= -90.0:
        a += 180.0
    elif a > 90.0:
        a -= 180.0
    return a


def forward(j: Joints, scara: Scara) -> ToolPose:
    t1 = math.radians(j.j1_deg)
    t12 = math.radians(j.j1_deg + j.j2_deg)
    x = scara.l1_mm * math.cos(t1) + scara.l2_mm * math.cos(t12)
    y = scara.l1_mm * math.sin(t1) + scara.l2_mm * math.sin(t12)
    return ToolPose(x, y, j.j3_mm, normalize_axis_deg(j.j1_deg + j.j2_deg + j.j4_deg))


def tool_xy(joints: np.ndarray, scara: Scara) -> tuple[np.ndarray, np.ndarray]:
    """`forward`'s x_mm, y_mm for the rows of an (n, >= 2) array of j1_deg, j2_deg, ...: many at once."""
    t1, t12 = np.radians(joints[:, 0]), np.radians(joints[:, 0] + joints[:, 1])
    return scara.l1_mm * np.cos(t1) + scara.l2_mm * np.cos(t12), scara.l1_mm * np.sin(t1) + scara.l2_mm * np.sin(t12)


def elbow_points(j: Joints, scara: Scara) -> np.ndarray:
    """Base, elbow and wrist positions in the plane, shape (3, 2): the links for drawing and
    for the link collision check."""
    t1 = math.radians(j.j1_deg)
    t12 = math.radians(j.j1_deg + j.j2_deg)
    e = (scara.l1_mm * math.cos(t1), scara.l1_mm * math.sin(t1))
    w = (e[0] + scara.l2_mm * math.cos(t12), e[1] + scara.l2_mm * math.sin(t12))
    return np.array([(0.0, 0.0), e, w])


def limit_violations(j: Joints, scara: Scara, tol: float = 1e-9) -> list[str]:
    """Human-readable list of the joint limits `j` violates (empty when it is inside)."""
    out = []
    for name, value, (lo, hi), unit in (
        ("J1", j.j1_deg, scara.j1_deg, "deg"), ("J2", j.j2_deg, scara.j2_deg, "deg"),
        ("J3", j.j3_mm, scara.j3_mm, "mm"), ("J4", j.j4_deg, scara.j4_deg, "deg"),
    ):
        if not math.isfinite(value) or value < lo - tol or value > hi + tol:
            out.append(f"{name} = {value:.3f} {unit} outside [{lo:g}, {hi:g}]")
    return out


def inverse(x_mm: float, y_mm: float, z_mm: float, axis_deg: float, scara: Scara,
            *, within_limits: bool = True) -> list[Joints]:
    """Every joint solution placing the finger tips' centre at (x, y, z) with the closing axis
    along `axis_deg` (mod 180): both elbows, every admissible J4 turn. Empty when unreachable."""
    r2 = x_mm * x_mm + y_mm * y_mm
    l1, l2 = scara.l1_mm, scara.l2_mm
    c2 = (r2 - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    if c2 > 1.0 + 1e-12 or c2 < -1.0 - 1e-12:
        return []
    c2 = min(1.0, max(-1.0, c2))
    out: list[Joints] = []
    for sign in (1.0, -1.0):
        t2 = sign * math.acos(c2)
        t1 = math.atan2(y_mm, x_mm) - math.atan2(l2 * math.sin(t2), l1 + l2 * math.cos(t2))
        j1 = _wrap180(math.degrees(t1))
        j2 = math.degrees(t2)
        base = axis_deg - j1 - j2
        lo4, hi4 = scara.j4_deg if within_limits else (-360.0, 360.0)
        k_lo, k_hi = math.ceil((lo4 - base) / 180.0 - 1e-9), math.floor((hi4 - base) / 180.0 + 1e-9)
        for k in range(k_lo, k_hi + 1):
            cand = Joints(j1, j2, z_mm, base + 180.0 * k)
            if not within_limits or not limit_violations(cand, scara):
                out.append(cand)
        if c2 >= 1.0 - 1e-15:
            break  # stretched arm: both elbows coincide
    return out


def _wrap180(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


# Up to this many points both elbows go through one pass (half the numpy calls, each of which costs
# microseconds on the cascade's few hundred pairs); more go elbow by elbow (cheaper for large batches).
ELBOWS_STACKED_MAX = 2048


def _elbow_within_limits(t2, to_wrist, a, scara: Scara) -> np.ndarray:
    """For elbow angles t2 (J2 in radians) reaching wrist directions to_wrist: are J1, J2 and some
    J4 turn of the axis a (degrees) within the limits?"""
    l1, l2 = scara.l1_mm, scara.l2_mm
    j1 = (np.degrees(to_wrist - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))) + 180.0) % 360.0 - 180.0
    j2 = np.degrees(t2)
    base = a - j1 - j2
    lo4, hi4 = scara.j4_deg
    # the turns k `inverse` tries, and whether one of them is within the limits as `limit_violations`
    # has them (1e-9 deg): the turns' own 1e-9 is of a half turn, 1.8e-7 deg, so the outermost may not be
    k_lo, k_hi = np.ceil((lo4 - base) / 180.0 - 1e-9), np.floor((hi4 - base) / 180.0 + 1e-9)
    if hi4 - lo4 >= 181.0:  # a turn just past one limit has a neighbour well inside: any turn will do
        some_j4 = k_hi >= k_lo
    else:
        j4_lo, j4_hi = base + 180.0 * k_lo, base + 180.0 * k_hi
        some_j4 = (k_hi >= k_lo) & ((k_hi - k_lo >= 2) | ((j4_lo >= lo4 - 1e-9) & (j4_lo <= hi4 + 1e-9))
                                     | ((j4_hi >= lo4 - 1e-9) & (j4_hi <= hi4 + 1e-9)))
    return ((j1 >= scara.j1_deg[0] - 1e-9) & (j1 <= scara.j1_deg[1] + 1e-9)
            & (j2 >= scara.j2_deg[0] - 1e-9) & (j2 <= scara.j2_deg[1] + 1e-9) & some_j4)


def box_surely_reachable(x0: float, y0: float, x1: float, y1: float, z_mm: float, scara: Scara,
                         margin_deg: float = 1e-6) -> bool:
    """Is `reachable_mask` True at every point of the box [x0, x1] x [y0, y1] (right of the base), for
    any closing axis? Sufficient: J4 spans more than a half turn (some turn of any axis fits), z is
    within J3, and one elbow reaches the whole box with J1 and J2 margin_deg inside their limits (far
    above the mask's rounding), from the box's range of distance r and direction phi from the base:
    the elbow angle t = arccos(c2(r)) falls with r, and J1 = phi -+ beta(t) with beta the angle link 1
    makes with the wrist's direction (largest at cos t = -l2 / l1)."""
    lo4, hi4 = scara.j4_deg
    if hi4 - lo4 < 181.0 or not scara.j3_mm[0] <= z_mm <= scara.j3_mm[1] or x0 <= 0.0:
        return False
    l1, l2 = scara.l1_mm, scara.l2_mm
    corners = [(x0, y0), (x0, y1), (x1, y0), (x1, y1)]
    r_lo, r_hi = math.hypot(x0, max(y0, -y1, 0.0)), max(math.hypot(x, y) for x, y in corners)
    c_lo, c_hi = ((r * r - l1 * l1 - l2 * l2) / (2 * l1 * l2) for r in (r_lo, r_hi))
    if c_lo < -1.0 + 1e-9 or c_hi > 1.0 - 1e-9:
        return False
    t_lo, t_hi = math.acos(c_hi), math.acos(c_lo)
    ts = [t_lo, t_hi] + ([math.acos(-l2 / l1)] if l2 <= l1 and t_lo < math.acos(-l2 / l1) < t_hi else [])
    betas = [math.degrees(math.atan2(l2 * math.sin(t), l1 + l2 * math.cos(t))) for t in ts]
    phis = [math.degrees(math.atan2(y, x)) for x, y in corners]  # x > 0: the extremes are at corners
    (p_lo, p_hi), (b_lo, b_hi), (j2_lo, j2_hi) = (min(phis), max(phis)), (min(betas), max(betas)), scara.j2_deg
    # J1 as the solver has it, in [-180, 180): limits past that add no room here, and J1 = phi -+ beta is
    # taken unwrapped, so a box needing a wrap is not certified (l2 > l1 lets beta pass 90 deg: with J1 in
    # [-300, 100] a box at (35, -205) was certified with no solution there)
    j1_lo, j1_hi = max(scara.j1_deg[0], -180.0) + margin_deg, min(scara.j1_deg[1], 180.0) - margin_deg
    t_deg = (math.degrees(t_lo), math.degrees(t_hi))
    elbow_up = (j2_lo + margin_deg <= t_deg[0] and t_deg[1] <= j2_hi - margin_deg
                and j1_lo <= p_lo - b_hi and p_hi - b_lo <= j1_hi)  # J2 = t, J1 = phi - beta
    elbow_down = (j2_lo + margin_deg <= -t_deg[1] and -t_deg[0] <= j2_hi - margin_deg
                  and j1_lo <= p_lo + b_lo and p_hi + b_hi <= j1_hi)  # J2 = -t, J1 = phi + beta
    return elbow_up or elbow_down


def reachable_mask(x_mm, y_mm, z_mm: float, axis_deg, scara: Scara) -> np.ndarray:
    """Vectorised `bool(inverse(x, y, z, axis, scara))`: does any solution within the joint
    limits exist? Shapes (n,) in, (n,) bool out. The cascade asks this for every pair; the
    solutions themselves are only worked out for the grasps that are looked at."""
    x, y, a = (np.asarray(v, float) for v in (x_mm, y_mm, axis_deg))
    if not scara.j3_mm[0] - 1e-9 <= z_mm <= scara.j3_mm[1] + 1e-9:
        return np.zeros(x.shape, bool)
    l1, l2 = scara.l1_mm, scara.l2_mm
    c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    inside = (c2 <= 1.0 + 1e-12) & (c2 >= -1.0 - 1e-12)
    t = np.arccos(np.minimum(np.maximum(c2, -1.0), 1.0))  # np.clip, at a fraction of its call's cost
    to_wrist = np.arctan2(y, x)
    if x.ndim == 1 and len(x) <= ELBOWS_STACKED_MAX:  # both elbows in one pass (-t exactly, as sign * t)
        ok = _elbow_within_limits(np.concatenate([t, -t]), np.concatenate([to_wrist, to_wrist]),
                                  np.concatenate([a, a]), scara)
        return (ok[:len(x)] | ok[len(x):]) & inside
    ok = np.zeros(x.shape, bool)
    for t2 in (t, -t):
        ok |= _elbow_within_limits(t2, to_wrist, a, scara)
    return ok & inside
