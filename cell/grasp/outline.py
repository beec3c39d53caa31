"""A part's outline as arc-length parametrised rings (pure geometry, base frame, mm).

Scene parts are normalised so that the outer ring is counter-clockwise and holes clockwise:
walking along any ring the material is on the left, so the outward normal (away from the
material) is the walking direction turned right by 90 degrees, for holes as for the outside.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from shapely.geometry import Polygon

from cell.scene import Part


@dataclass(frozen=True, eq=False)
class Ring:
    """One closed ring: vertices (m, 2) with the material on the left, cumulative arc length (m + 1,)."""

    vertices: np.ndarray
    cum_mm: np.ndarray

    @classmethod
    def of(cls, vertices) -> Ring:
        v = np.asarray(vertices, float)
        seg = np.linalg.norm(np.diff(np.vstack([v, v[:1]]), axis=0), axis=1)
        return cls(v, np.concatenate([[0.0], np.cumsum(seg)]))

    @property
    def length_mm(self) -> float:
        return float(self.cum_mm[-1])

    def at(self, arc_mm) -> np.ndarray:
        """Points at arc positions (any shape (...,)), periodic; returns (..., 2)."""
        s = np.mod(np.asarray(arc_mm, float), self.length_mm)
        closed = np.vstack([self.vertices, self.vertices[:1]])
        return np.stack([np.interp(s, self.cum_mm, closed[:, 0]), np.interp(s, self.cum_mm, closed[:, 1])], -1)

    def edge_normals(self, arc_mm) -> np.ndarray:
        """Outward unit normal of the edge holding each arc position, (..., 2)."""
        s = np.mod(np.asarray(arc_mm, float), self.length_mm)
        k = np.clip(np.searchsorted(self.cum_mm, s, side="right") - 1, 0, len(self.vertices) - 1)
        d = np.roll(self.vertices, -1, axis=0)[k] - self.vertices[k]
        n = np.stack([d[..., 1], -d[..., 0]], -1)
        return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)

    def project(self, p) -> tuple[float, float]:
        """(arc position, distance) of the ring point nearest to p."""
        p = np.asarray(p, float)
        a, b = self.vertices, np.roll(self.vertices, -1, axis=0)
        d = b - a
        L2 = np.maximum((d * d).sum(1), 1e-24)
        t = np.clip(((p - a) * d).sum(1) / L2, 0.0, 1.0)
        q = a + t[:, None] * d
        dist = np.linalg.norm(q - p, axis=1)
        k = int(np.argmin(dist))
        return float(self.cum_mm[k] + t[k] * np.sqrt(L2[k])), float(dist[k])


def part_rings(part: Part, own_start: bool = False) -> list[Ring]:
    """The outer ring first, then the holes: all of them are outline. own_start: each ring listed from its own
    first vertex (`own_first_vertex`), not the one the file gave first: the samples start half a step past a
    ring's first vertex, and the same outline listed from another vertex, or reversed, was planned otherwise
    (a hexagon listed reversed had a grasp one way and none the other; SynthesisParams.vertex_order_free)."""
    rings = [part.outline_mm, *part.holes_mm]
    if own_start:
        rings = [np.roll(r, -own_first_vertex(r), axis=0) for r in rings]
    return [Ring.of(r) for r in rings]


def own_first_vertex(vertices) -> int:
    """The index of the ring's vertex farthest from its area centroid: the same vertex whichever vertex a list
    starts at, or its direction, and it moves with the part. Of vertices within 1e-9 of the farthest (a
    symmetric outline's, alike up to its symmetry), the first listed: a part moved or turned (its list in the
    same order) keeps it, where any choice by direction in the base frame would move it to another of them."""
    v = np.asarray(vertices, float)
    ring = Polygon(v)
    if ring.area < 1e-12:  # (a degenerate ring: the scene reader refuses those)
        return 0
    d = np.linalg.norm(v - np.asarray(ring.centroid.coords[0]), axis=1)
    return int(np.flatnonzero(d >= d.max() - 1e-9 * max(1.0, float(d.max())))[0])


def centre_of_gravity(part: Part) -> np.ndarray:
    """Area centroid with the holes taken out, (2,)."""
    return np.asarray(part.polygon.centroid.coords[0], float)


SLIT_LOOK_FILL = 0.95  # an outline filling this much of its convex hull has no room for a cavity worth counting


def reference_radius_mm(part: Part, outer_disc: bool = True, slit_mm: float = 0.0) -> float:
    """Equivalent-disc radius sqrt(area / pi) of the area the outer outline encloses, holes included:
    the size unit of the relative attributes (outer_disc=False: of the part's material, holes taken out,
    as recordings made before 2026-12-04 have it: SynthesisParams.cog_radius_outer_disc). With slit_mm,
    a cavity that only a slit narrower than that joins to the outside counts as enclosed too: a split
    washer's or a circlip's bore, as a ring's hole (SynthesisParams.closed_slit_mm)."""
    if not outer_disc:
        return float(np.sqrt(part.polygon.area / np.pi))
    outer = Polygon(part.outline_mm)
    area = outer.area
    if slit_mm > 0 and area < SLIT_LOOK_FILL * outer.convex_hull.area:
        area += _behind_slits_mm2(np.ascontiguousarray(part.outline_mm, float).tobytes(), float(slit_mm))
    return float(np.sqrt(area / np.pi))


@lru_cache(maxsize=512)
def _behind_slits_mm2(outline_bytes: bytes, slit_mm: float) -> float:
    """The area of the cavities the outline (x, y float64 pairs) encloses once closed across gaps narrower
    than slit_mm (a morphological closing: the holes it leaves are cavities behind such gaps; gear teeth's
    gaps and other open recesses are filled from the outside and leave none)."""
    r = slit_mm / 2
    closed = Polygon(np.frombuffer(outline_bytes).reshape(-1, 2)).buffer(r, quad_segs=4).buffer(-r, quad_segs=4)
    return float(sum(Polygon(h).area for g in getattr(closed, "geoms", [closed]) for h in g.interiors))


def resample(rings: list[Ring], step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Evenly spaced arc positions on every ring, about `step_mm` apart (mid-step, so a polygon's
    vertices fall between samples). Returns ring index (z,) and arc position (z,)."""
    idx, arcs = [], []
    for r, ring in enumerate(rings):
        n = max(3, int(round(ring.length_mm / step_mm)))
        h = ring.length_mm / n
        arcs.append((np.arange(n) + 0.5) * h)
        idx.append(np.full(n, r))
    return np.concatenate(idx), np.concatenate(arcs)


def project_to_outline(rings: list[Ring], p) -> tuple[int, float, float]:
    """(ring index, arc position, distance) of the outline point nearest to p."""
    best = (0, 0.0, np.inf)
    for r, ring in enumerate(rings):
        s, d = ring.project(p)
        if d < best[2]:
            best = (r, s, d)
    return best
