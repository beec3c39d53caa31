"""Step 1: candidate contact points = the free outline, resampled at a fixed arc-length step.

Free area: the target's outline (outside and holes) minus where it touches or nearly touches
(closer than `free_gap_mm`) another part whose height range overlaps the target's sides. A
part lying wholly below the target (a base plate under it) touches its bottom, not its sides;
one whose top is at or below the grasp z touches them only below the pads, which pass over it
as the fingers do (CONTRACT: only parts above the grasp z are collision regions for fingers).
"""

from __future__ import annotations

import numpy as np
import shapely

from cell.grasp.attributes import OutlinePoints, describe_points
from cell.grasp.outline import Ring, part_rings, resample
from cell.grasp.params import SynthesisParams
from cell.scene import Part

Z_EPS_MM = 1e-6


def side_neighbours(target: Part, others, grasp_z_mm: float | None = None) -> list[Part]:
    """Parts whose height range overlaps the target's sides (above `grasp_z_mm`, where the pads are)."""
    floor_mm = target.z_bottom_mm if grasp_z_mm is None else max(target.z_bottom_mm, grasp_z_mm)
    return [o for o in others if o.z_top_mm > floor_mm + Z_EPS_MM
            and o.z_bottom_mm < target.z_top_mm - Z_EPS_MM]


def free_mask(points: np.ndarray, neighbours: list[Part], gap_mm: float) -> np.ndarray:
    """(z,) bool: True where a point is at least `gap_mm` from every neighbour."""
    free = np.ones(len(points), bool)
    if not neighbours or not len(points):
        return free
    tree = shapely.STRtree([o.polygon for o in neighbours])
    pts = shapely.points(points)
    hit_pt, _ = tree.query(pts, predicate="dwithin", distance=gap_mm)
    free[np.unique(hit_pt)] = False
    return free


def candidate_points(target: Part, others, params: SynthesisParams, rings: list[Ring] | None = None,
                     grasp_z_mm: float | None = None) -> tuple[OutlinePoints, np.ndarray]:
    """All resampled outline points of the target and the mask (z_all,) of the free ones at the grasp z."""
    rings = rings or part_rings(target, params.vertex_order_free)
    ring_idx, arc = resample(rings, params.step_mm)
    op = describe_points(rings, ring_idx, arc, params.scales_mm)
    return op, free_mask(op.points, side_neighbours(target, others, grasp_z_mm), params.free_gap_mm)
