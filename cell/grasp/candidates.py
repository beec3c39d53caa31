"""Step 1: candidate contact points = the free outline, resampled at a fixed arc-length step.

Free area: the target's outline (outside and holes) minus where it touches or nearly touches
(closer than `free_gap_mm`) another part whose height range overlaps the target's sides. A
part lying wholly below the target (a base plate under it) touches its bottom, not its sides.
"""

from __future__ import annotations

import numpy as np
import shapely

from cell.grasp.attributes import OutlinePoints, describe_points
from cell.grasp.outline import Ring, part_rings, resample
from cell.grasp.params import SynthesisParams
from cell.scene import Part

Z_EPS_MM = 1e-6


def side_neighbours(target: Part, others) -> list[Part]:
    """Parts whose height range overlaps the target's sides."""
    return [o for o in others if o.z_top_mm > target.z_bottom_mm + Z_EPS_MM
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


def candidate_points(target: Part, others, params: SynthesisParams,
                     rings: list[Ring] | None = None) -> tuple[OutlinePoints, np.ndarray]:
    """All resampled outline points of the target and the mask (z_all,) of the free ones."""
    rings = rings or part_rings(target)
    ring_idx, arc = resample(rings, params.step_mm)
    op = describe_points(rings, ring_idx, arc, params.scales_mm)
    return op, free_mask(op.points, side_neighbours(target, others), params.free_gap_mm)
