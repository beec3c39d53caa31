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


def hand_made_examples() -> list:
    """A few teaching examples given by hand on simple parts (tests and the benchmark use them
    until the shipped default example file exists): grasps across the middle of flat faces are
    accepted, grasps at corners and across the long side's ends rejected."""
    from cell.examples import GraspExample

    src = {"kind": "manual", "by": "cell.grasp.shapes", "note": "hand-made example"}
    r = rectangle("rect-60x30", 60, 30)
    big = rectangle("rect-90x40", 90, 40)
    d = disc("disc-r20", 20)
    ell = l_shape("ell-60x40")
    lc = ell.outline_mm
    return [
        GraspExample("hm-rect-mid", r, np.array([[350, 15], [350, -15]]), True, src),
        GraspExample("hm-rect-off", r, np.array([[362, 15], [362, -15]]), True, src),
        GraspExample("hm-big-mid", big, np.array([[345, 20], [345, -20]]), True, src),
        GraspExample("hm-disc", d, np.array([[370, 0], [330, 0]]), True, src),
        GraspExample("hm-ring-wall", disc("ring-r30", 30, hole_r_mm=12), np.array([[380, 0], [362, 0]]), True, src),
        GraspExample("hm-rect-corners", r, np.array([[379, 15], [321, -15]]), False, src, (False, False)),
        GraspExample("hm-rect-ends", r, np.array([[380, 0], [320, 0]]), False, src, (False, False)),
        GraspExample("hm-rect-skew", r, np.array([[340, 15], [360, -15]]), False, src),
        GraspExample("hm-big-end", big, np.array([[392, 17], [392, -17]]), False, src, (False, False)),
        GraspExample("hm-ell-arm", ell, np.array([(lc[1] + lc[2]) / 2 + [0, 0], (lc[0] + lc[5]) / 2]), False, src),
    ]
