"""A handful of realistic part outlines for the simulated camera, its tests and the benchmark.

Gears, plates with holes, brackets, discs and a lever, in mm, centred on the origin;
`random_layout` places them at random non-overlapping poses on the tray.
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import Polygon

from cell.scene import Part


def circle(r: float, n: int = 96, c=(0.0, 0.0)) -> np.ndarray:
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return np.column_stack([c[0] + r * np.cos(t), c[1] + r * np.sin(t)])


def gear(teeth: int = 18, r_root: float = 24.0, r_tip: float = 28.0, bore: float = 6.0) -> tuple:
    pts = []
    for k in range(teeth):
        a0 = 2 * math.pi * k / teeth
        step = 2 * math.pi / teeth
        for frac, r in ((0.0, r_root), (0.22, r_root), (0.32, r_tip), (0.68, r_tip), (0.78, r_root)):
            a = a0 + frac * step
            pts.append((r * math.cos(a), r * math.sin(a)))
    return np.array(pts), [circle(bore, 48)[::-1]]


def plate_with_holes(w: float = 70.0, h: float = 45.0, r_hole: float = 4.0) -> tuple:
    outer = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    holes = [circle(r_hole, 40, (sx * (w / 2 - 10), 0.0))[::-1] for sx in (-1, 1)]
    return outer, holes


def bracket(a: float = 60.0, b: float = 40.0, t: float = 14.0) -> tuple:
    outer = np.array([[0, 0], [a, 0], [a, t], [t, t], [t, b], [0, b]], float)
    return outer - outer.mean(axis=0), []


def lever(length: float = 90.0, r_big: float = 14.0, r_small: float = 9.0, width: float = 10.0) -> tuple:
    """Two round bosses joined by a bar, one bore in the big boss."""
    big = Polygon(circle(r_big, 64, (-length / 2, 0.0)))
    small = Polygon(circle(r_small, 48, (length / 2, 0.0)))
    bar = Polygon([(-length / 2, -width / 2), (length / 2, -width / 2), (length / 2, width / 2),
                   (-length / 2, width / 2)])
    shape = big.union(small).union(bar).simplify(0.05)
    return np.asarray(shape.exterior.coords)[:-1], [circle(5.0, 40, (-length / 2, 0.0))[::-1]]


def disc(r: float = 20.0) -> tuple:
    return circle(r, 120), []


SHAPES = {
    "gear": (gear, 12.0, "steel"),
    "plate": (plate_with_holes, 4.0, "aluminium"),
    "bracket": (bracket, 20.0, "dark_plastic"),
    "lever": (lever, 8.0, "blue_plastic"),
    "disc": (disc, 6.0, "brass"),
    "cover": (lambda: plate_with_holes(80.0, 55.0, 5.0), 8.0, "pcb_green"),
    "grey_plate": (lambda: plate_with_holes(60.0, 40.0, 5.0), 5.0, "grey_plastic"),
    "white_block": (lambda: bracket(50.0, 50.0, 18.0), 15.0, "white_plastic"),
}


def make_part(kind: str, pid: str | None = None, x_mm: float = 350.0, y_mm: float = 0.0,
              angle_deg: float = 0.0, material: str | None = None, z_bottom_mm: float = 0.0) -> Part:
    """One sample part of `kind` (see SHAPES) at (x, y) turned by `angle_deg`."""
    build, height, default_material = SHAPES[kind]
    outer, holes = build()
    t = math.radians(angle_deg)
    rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    poly = Polygon(outer, holes)
    c = np.array(poly.centroid.coords[0])

    def tf(p):
        return (np.asarray(p) - c) @ rot.T + (x_mm, y_mm)

    outer_t = tf(outer)
    if Polygon(outer_t).exterior.is_ccw is False:
        outer_t = outer_t[::-1]
    return Part(pid or kind, outer_t, tuple(tf(h) for h in holes), z_bottom_mm, z_bottom_mm + height,
                meta={"material": material or default_material, "kind": kind})


def random_layout(rng: np.random.Generator, n: int, kinds=None, tray=((215.0, 485.0), (-235.0, 235.0)),
                  gap_mm: float = 8.0, max_tries: int = 400) -> list[Part]:
    """Up to `n` parts at random poses inside `tray`, at least `gap_mm` apart (isolated parts)."""
    kinds = list(kinds or SHAPES)
    placed: list[Part] = []
    for i in range(max_tries):
        if len(placed) == n:
            break
        kind = kinds[int(rng.integers(len(kinds)))]
        p = make_part(kind, f"{kind}_{i}", rng.uniform(*tray[0]), rng.uniform(*tray[1]), rng.uniform(-180, 180))
        if _fits(p, placed, tray, gap_mm):
            placed.append(p)
    return placed


def random_layout_of(rng: np.random.Generator, n: int, pool: list[Part],
                     tray=((215.0, 485.0), (-235.0, 235.0)), gap_mm: float = 8.0, max_tries: int = 400) -> list[Part]:
    """Like `random_layout`, drawing from `pool` (parts centred on the origin, e.g. the parts library)."""
    placed: list[Part] = []
    for i in range(max_tries):
        if len(placed) == n:
            break
        tpl = pool[int(rng.integers(len(pool)))]
        c = np.asarray(tpl.polygon.centroid.coords[0])
        p = tpl.moved(rng.uniform(*tray[0]) - c[0], rng.uniform(*tray[1]) - c[1], rng.uniform(-180, 180))
        p = Part(f"{tpl.id}_{i}", p.outline_mm, p.holes_mm, p.z_bottom_mm, p.z_top_mm, p.direction, dict(p.meta))
        if _fits(p, placed, tray, gap_mm):
            placed.append(p)
    return placed


def _fits(p: Part, placed: list[Part], tray, gap_mm: float) -> bool:
    """Inside the tray box and at least gap_mm from every part already placed."""
    minx, miny, maxx, maxy = p.polygon.bounds
    if minx < tray[0][0] or maxx > tray[0][1] or miny < tray[1][0] or maxy > tray[1][1]:
        return False
    return not any(p.polygon.distance(q.polygon) < gap_mm for q in placed)
