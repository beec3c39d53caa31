"""Ring geometry for the outlines segmentation finds: signed area and centroid, and refined rings made
simple again (kept within the frame, loops the sub-pixel step made cut off)."""

from __future__ import annotations

import numpy as np


def tidy_rings(rings: list[np.ndarray], shape) -> list[np.ndarray]:
    """Refined rings kept within the frame ([0, w] x [0, h]: a point the refinement moved past the
    border is off the picture) and simple: where moving the points along their normals made a ring
    cross itself (tiny loops where the edge profile is noisy, or a point pushed across a narrow
    neck), the ring becomes the outline of the largest piece of area it encloses (Festo frame 2
    with noise added: 6 of 23 outlines and 3 of 67 holes crossed themselves; shapely and the scene
    files' reader need simple rings). Rings that are simple and inside are returned as they are."""
    import shapely

    h, w = shape[:2]
    out = list(rings)
    big = [i for i, r in enumerate(out) if len(r) >= 4]
    if not big:
        return out
    pts = np.concatenate([out[i] for i in big])
    if pts.min() < 0.0 or pts[:, 0].max() > w or pts[:, 1].max() > h:  # (one test for all rings)
        out = [np.column_stack([np.clip(r[:, 0], 0.0, w), np.clip(r[:, 1], 0.0, h)])
               if r.size and (r.min() < 0.0 or r[:, 0].max() > w or r[:, 1].max() > h) else r for r in out]
        pts = np.concatenate([out[i] for i in big])
    lr = shapely.linearrings(pts, indices=np.repeat(np.arange(len(big)), [len(out[i]) for i in big]))
    for i in np.asarray(big)[~shapely.is_simple(lr)]:
        out[i] = _untangled(out[i])
    return out


def _untangled(ring: np.ndarray) -> np.ndarray:
    """The exterior of the largest piece of area a self-crossing ring encloses, in the ring's own
    orientation (the ring unchanged when it encloses none). Each loop is cut off at its crossing
    first (`_loops_cut`; shapely's make_valid takes 10 - 30 ms on a region of 5000 points); whatever
    still crosses goes through make_valid."""
    import shapely

    cut = _loops_cut(ring)
    if len(cut) >= 4 and shapely.LinearRing(cut).is_simple:
        return cut
    if len(np.unique(cut, axis=0)) < len(cut):
        # a vertex visited twice: the contour of two blobs that touch at a pixel (OpenCV's contours
        # of 8-connected masks); the pinch is kept as the contour has it, both blobs in the region
        return cut
    cut = _loops_cut(cut, everywhere=True)
    if len(cut) >= 4 and shapely.LinearRing(cut).is_simple:
        return cut
    fixed = shapely.make_valid(shapely.Polygon(ring))
    pieces = [g for g in shapely.get_parts(shapely.get_parts(fixed)) if g.geom_type == "Polygon" and g.area > 0]
    if not pieces:
        return ring
    ext = np.asarray(max(pieces, key=lambda g: g.area).exterior.coords, float)[:-1]
    return ext if (signed_area(ext) > 0) == (signed_area(ring) > 0) else ext[::-1].copy()


LOOP_SPAN = 24  # loops up to this many points long are looked for segment by segment (numpy), longer ones
# through shapely's STRtree


def _crossing_params(p: np.ndarray, e: np.ndarray, q: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where segments p + t e and q + u f (rows) meet: (t, u); both in (0, 1) where they cross, NaN or
    infinite where they are parallel."""
    den = e[:, 0] * f[:, 1] - e[:, 1] * f[:, 0]
    pq = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        return (pq[:, 0] * f[:, 1] - pq[:, 1] * f[:, 0]) / den, (pq[:, 0] * e[:, 1] - pq[:, 1] * e[:, 0]) / den


def _crossings_near(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, i + d), 2 <= d <= LOOP_SPAN, of a ring's segments a -> b that cross."""
    n = len(a)
    e = b - a
    ii, jj = [], []
    for d in range(2, min(LOOP_SPAN, n // 2 - 1) + 1):
        t, u = _crossing_params(a, e, np.roll(a, -d, axis=0), np.roll(e, -d, axis=0))
        hit = np.flatnonzero((t > 0) & (t < 1) & (u > 0) & (u < 1))
        ii.append(hit)
        jj.append((hit + d) % n)
    return (np.concatenate(ii), np.concatenate(jj)) if ii else (np.zeros(0, int), np.zeros(0, int))


def _crossings_all(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All pairs (i, j) of a ring's segments a -> b that cross (candidates by their boxes, shapely's STRtree)."""
    import shapely

    boxes = shapely.box(np.minimum(a[:, 0], b[:, 0]), np.minimum(a[:, 1], b[:, 1]),
                        np.maximum(a[:, 0], b[:, 0]), np.maximum(a[:, 1], b[:, 1]))
    i, j = shapely.STRtree(boxes).query(boxes)  # boxes that meet (no predicate: GEOS's takes 5 x as long)
    keep = np.abs(i - j) > 1
    i, j = i[keep], j[keep]
    t, u = _crossing_params(a[i], b[i] - a[i], a[j], b[j] - a[j])
    hit = (t > 0) & (t < 1) & (u > 0) & (u < 1)
    return i[hit], j[hit]


def _loops_cut(ring: np.ndarray, everywhere: bool = False) -> np.ndarray:
    """The ring with its loops cut off: where segment i crosses segment j, the points on the side with
    fewer of them (a loop the refinement made) are replaced by the crossing point; the longest such
    loop first (it holds shorter ones), a loop overlapping one cut already is left. Loops up to
    LOOP_SPAN points, or (`everywhere`) of any length."""
    n = len(ring)
    if n < 8:
        return ring
    a, b = ring, np.roll(ring, -1, axis=0)
    i, j = (_crossings_all if everywhere else _crossings_near)(a, b)
    i, j = np.minimum(i, j), np.maximum(i, j)
    keep = j > i
    i, j = i[keep], j[keep]
    if not len(i):
        return ring
    e = b[i] - a[i]
    t, _ = _crossing_params(a[i], e, a[j], b[j] - a[j])
    cross = a[i] + t[:, None] * e
    inner = j - i  # points i + 1 .. j lie on one side, j + 1 .. i (round the end) on the other
    start = np.where(inner <= n - inner, i + 1, j + 1)
    span = np.minimum(inner, n - inner)
    drop = np.zeros(n, bool)
    insert = {}
    for k in np.argsort(-span, kind="stable"):
        idx = (start[k] + np.arange(span[k])) % n
        if not np.isfinite(cross[k]).all() or span[k] >= n - 3 or drop[idx].any():
            continue
        drop[idx] = True
        insert[int(idx[0])] = cross[k]
    if not insert:
        return ring
    pos = np.array(sorted(insert))
    out = np.insert(ring, pos, np.array([insert[q] for q in pos]), axis=0)
    return out[~np.insert(drop, pos, False)]


def signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, ahead(y, 1)) - np.dot(ahead(x, 1), y))


def ahead(a: np.ndarray, k: int) -> np.ndarray:
    """The ring's points k steps ahead (np.roll(a, -k, axis=0), a few times faster for short rings)."""
    k %= len(a)
    return np.concatenate((a[k:], a[:k]))


def ring_area_centroid(ring: np.ndarray) -> tuple[float, np.ndarray]:
    """Signed area (positive counter-clockwise in (u, v) axes) and centroid (2,) of a ring (n, 2)."""
    x, y = ring[:, 0], ring[:, 1]
    x1, y1 = ahead(x, 1), ahead(y, 1)
    cr = x * y1 - x1 * y
    a = 0.5 * float(cr.sum())
    if abs(a) < 1e-12:
        return 0.0, ring.mean(axis=0)
    return a, np.array([((x + x1) * cr).sum(), ((y + y1) * cr).sum()]) / (6 * a)
