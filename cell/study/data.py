"""Labelled data for the learning study: the operator's judgement on the planner's candidates.

Points (paper step 2): library parts at random poses, their outer outline resampled by the
planner's own candidate step; each point is described by the planner's local attributes
(distance to the centre of gravity in mm and relative, multiresolution convexity) and
labelled by the simulated operator's point judgement (`Operator.judge_point`).

Sets (paper step 4): pairs of those candidate points that a cascade would pass on (within
the stroke, both normals within 45 degrees of the line joining them, like the reachable
sets s'), described by the planner's global attributes (reference-point offset, multiresolution
normal angles) and labelled by the operator's grasp judgement (`Operator.judge_grasp`).

Parts are drawn until each class has n/2 examples; the data set is then drawn
class-balanced (half accepted, half rejected) so that chance is 50 %; the natural shares
of accepted points and sets are reported alongside.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cell import parts_library as L
from cell.cellconfig import Cell, default_cell
from cell.grasp.attributes import describe_points, global_attributes, global_names, local_attributes, local_names
from cell.grasp.outline import part_rings, resample
from cell.grasp.params import SynthesisParams
from cell.operator import Operator, random_pose

FACING_DEG = 45.0


@dataclass(frozen=True)
class Dataset:
    name: str  # "points" or "sets"
    X: np.ndarray  # (n, F)
    y: np.ndarray  # (n,) bool: the operator accepts
    feature_names: list[str]
    natural_valid_share: float  # share of accepted among all labelled before balancing
    n_parts: int


MAX_PARTS = 2000


def _pose_parts(rng: np.random.Generator, cell: Cell):
    """Library parts drawn at random, each at a random pose in the tray (endless)."""
    lib = L.parts()
    for _ in range(MAX_PARTS):
        p = lib[int(rng.integers(0, len(lib)))]
        x, y, th = random_pose(p, cell, rng)
        yield L.place(p, x, y, th)


def _enough(labels: list[bool], n: int) -> bool:
    k = sum(labels)
    return k >= n // 2 and len(labels) - k >= n - n // 2


def _balanced(X, y, n, rng):
    pos, neg = np.flatnonzero(y), np.flatnonzero(~y)
    idx = np.concatenate([rng.choice(pos, n // 2, replace=False), rng.choice(neg, n - n // 2, replace=False)])
    rng.shuffle(idx)
    return X[idx], y[idx]


def point_dataset(n: int = 400, seed: int = 0, cell: Cell | None = None,
                  params: SynthesisParams | None = None, points_per_part: int = 12) -> Dataset:
    cell = cell or default_cell()
    params = params or SynthesisParams()
    rng = np.random.default_rng(seed)
    op = Operator(cell, rng)
    rows, labels, n_parts = [], [], 0
    for part in _pose_parts(rng, cell):
        if _enough(labels, n) and n_parts >= 8:
            break
        n_parts += 1
        rings = part_rings(part, params.vertex_order_free)
        ring_idx, arc = resample(rings[:1], params.step_mm)  # the outer outline: what a pad can touch
        pick = rng.choice(len(arc), min(points_per_part, len(arc)), replace=False)
        desc = describe_points(rings[:1], ring_idx[pick], arc[pick], params.scales_mm)
        rows.append(local_attributes(desc, part, params.cog_radius_outer_disc, params.closed_slit_mm))
        labels += [op.judge_point(part, p).valid for p in desc.points]
    X, y = np.vstack(rows), np.array(labels, bool)
    Xb, yb = _balanced(X, y, n, rng)
    return Dataset("points", Xb, yb, local_names(params.scales_mm), float(y.mean()), n_parts)


def set_dataset(n: int = 400, seed: int = 0, cell: Cell | None = None,
                params: SynthesisParams | None = None, sets_per_part: int = 16) -> Dataset:
    cell = cell or default_cell()
    params = params or SynthesisParams()
    rng = np.random.default_rng(seed + 1)
    op = Operator(cell, rng)
    stroke = cell.gripper.opening_mm[1] - 2 * cell.gripper.approach_clearance_mm
    rows, labels, n_parts = [], [], 0
    for part in _pose_parts(rng, cell):
        if _enough(labels, n) and n_parts >= 8:
            break
        n_parts += 1
        rings = part_rings(part, params.vertex_order_free)
        ring_idx, arc = resample(rings[:1], params.step_mm)
        desc = describe_points(rings[:1], ring_idx, arc, params.scales_mm)
        P, N = desc.points, desc.normals
        d = P[None, :, :] - P[:, None, :]
        dist = np.linalg.norm(d, axis=2)
        u = d / np.maximum(dist[..., None], 1e-9)
        # i pushes along u (towards j): its inward normal -N_i should point along u; j the other way
        cos_i = np.einsum("ijk,ik->ij", u, -N)
        cos_j = np.einsum("ijk,jk->ij", -u, -N)
        ok = (dist > 1.0) & (dist <= stroke) & (cos_i >= np.cos(np.radians(FACING_DEG))) & (
            cos_j >= np.cos(np.radians(FACING_DEG)))
        ii, jj = np.nonzero(np.triu(ok, 1))
        if not len(ii):
            continue
        pick = rng.choice(len(ii), min(sets_per_part, len(ii)), replace=False)
        ii, jj = ii[pick], jj[pick]
        contacts = np.stack([P[ii], P[jj]], axis=1)
        cn = np.stack([desc.chord_normals[ii], desc.chord_normals[jj]], axis=1)
        rows.append(global_attributes(contacts, cn, part, params.cog_radius_outer_disc, params.closed_slit_mm,
                                      params.vertex_order_free))
        labels += [op.judge_grasp(part, c).valid for c in contacts]
    X, y = np.vstack(rows), np.array(labels, bool)
    Xb, yb = _balanced(X, y, n, rng)
    return Dataset("sets", Xb, yb, global_names(params.scales_mm), float(y.mean()), n_parts)


def with_label_noise(ds: Dataset, share: float, seed: int = 0) -> Dataset:
    """The data set with `share` of its labels flipped at random (a less consistent labeller)."""
    if share <= 0:
        return ds
    rng = np.random.default_rng(seed + 7)
    flip = rng.random(len(ds.y)) < share
    return replace(ds, y=ds.y ^ flip, name=ds.name)
