"""Small hand-made parts (outlines in mm) for tests and the benchmark until a parts library is
available, and to build hand-made teaching examples. Pure functions returning `Part`s."""

from __future__ import annotations

import math

import numpy as np

from cell.scene import Part


def rectangle(pid: str, w_mm: float, h_mm: float, center=(350.0, 0.0), angle_deg: float = 0.0,
              z_top_mm: float = 15.0, z_bottom_mm: float = 0.0) -> Part:
    pts = np.array([[-w_mm / 2, -h_mm / 2], [w_mm / 2, -h_mm / 2], [w_mm / 2, h_mm / 2], [-w_mm / 2, h_mm / 2]])
    return _place(pid, pts, (), center, angle_deg, z_bottom_mm, z_top_mm)


def disc(pid: str, r_mm: float, center=(350.0, 0.0), n: int = 96, hole_r_mm: float = 0.0,
         z_top_mm: float = 15.0) -> Part:
    a = np.linspace(0, 2 * math.pi, n, endpoint=False)
    pts = np.column_stack([np.cos(a), np.sin(a)]) * r_mm
    holes = (pts[::-1] * hole_r_mm / r_mm,) if hole_r_mm > 0 else ()
    return _place(pid, pts, holes, center, 0.0, 0.0, z_top_mm)


def l_shape(pid: str, a_mm: float = 60.0, b_mm: float = 40.0, t_mm: float = 15.0, center=(350.0, 0.0),
            angle_deg: float = 0.0, z_top_mm: float = 15.0) -> Part:
    pts = np.array([[0, 0], [a_mm, 0], [a_mm, t_mm], [t_mm, t_mm], [t_mm, b_mm], [0, b_mm]], float)
    pts -= pts.mean(axis=0)
    return _place(pid, pts, (), center, angle_deg, 0.0, z_top_mm)


def gear(pid: str, r_mm: float = 30.0, teeth: int = 12, depth_mm: float = 4.0, center=(350.0, 0.0),
         n: int = 240, z_top_mm: float = 12.0) -> Part:
    """A toothed disc: about 300 candidate points at the default 2 mm step when r is 45 mm."""
    a = np.linspace(0, 2 * math.pi, n, endpoint=False)
    r = r_mm + depth_mm * (np.sin(teeth * a) > 0)
    return _place(pid, np.column_stack([np.cos(a) * r, np.sin(a) * r]), (), center, 0.0, 0.0, z_top_mm)


def _place(pid, pts, holes, center, angle_deg, zb, zt) -> Part:
    t = math.radians(angle_deg)
    rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    c = np.asarray(center, float)
    from cell.scene import parse_part

    raw = {"id": pid, "outline": (pts @ rot.T + c).tolist(), "holes": [(h @ rot.T + c).tolist() for h in holes],
           "z_bottom": zb, "z_top": zt}
    return parse_part(raw, f"shape {pid}")
