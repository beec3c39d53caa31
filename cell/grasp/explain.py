"""Why the planner decided: the rules behind the chosen grasp and a sample of rejections."""

from __future__ import annotations

import numpy as np

from cell.grasp.attributes import part_attributes
from cell.grasp.cascade import STAGES
from cell.grasp.learning import part_distances

STAGE_WHY = {
    "stroke": "contact distance outside the jaw stroke",
    "reach": "pair centre outside the arm's reach or the workspace",
    "antipodal": "normals not facing each other along the closing line",
    "precheck": "a finger path or the palm centre inside material (cheap pre-check)",
    "contacts": "a jaw pad would first touch other material (hidden contact), the opening is out of stroke, or "
                "both pads would rest on material under 2 mm wide (a corner or tip each: the part pivots)",
    "ik": "no inverse-kinematics solution within the joint limits",
    "fingers_obstacles": "a finger's swept footprint overlaps an obstacle taller than the grasp z",
    "palm": "the palm overlaps an obstacle taller than its bottom",
}


def explain(result, planner, n_samples: int = 3, seed: int = 0) -> list[str]:
    """The chosen grasp's rules, then a sample of what each step rejected."""
    pt, st = planner.model.point_tree, planner.model.set_tree
    g = result.grasp
    vidx = np.flatnonzero(result.point_valid)
    lines = []
    for c, i in zip(g.contacts_mm, g.pair, strict=True):
        ci = vidx[i]
        lines.append(f"chosen contact {np.round(c, 2).tolist()}: tree 1 {pt.rule_for(result.candidate_attributes[ci])}")
    lines.append(f"chosen set: tree 2 {st.rule_for(g.global_attributes)}")
    lines.append(f"chosen set: nearest accepted example {g.nearest_example} at distance "
                 f"{g.distance_to_example:.3f} (normalised global attributes){_part_share(result, planner)}")
    made = {k: getattr(result, k) for k in ("outline", "free", "candidates", "candidate_attributes", "point_valid",
                                            "pairs", "cascade", "reachable_pairs", "reachable_attributes",
                                            "set_valid")}
    return lines + rejections(made, planner, n_samples, seed)


def _part_share(result, planner) -> str:
    """How much of the distance is the parts' shape (SynthesisParams.part_shape_weight), when the choice looks at it."""
    dp = part_distances(planner.model, part_attributes(result.context.target))
    if dp is None:
        return ""
    ex = planner.model.example_ids.index(result.grasp.nearest_example)
    return (f" and part shape (weight {planner.model.part_weight:g}; the parts' shapes differ by {dp[ex]:.3f}, "
            f"the nearest example part's by {dp.min():.3f})")


def explain_failure(partial: dict, planner, n_samples: int = 3, seed: int = 0) -> list[str]:
    """No grasp: a sample of what each step that ran rejected (`NoFeasibleGrasp.partial`)."""
    return rejections(partial, planner, n_samples, seed)


def rejections(made: dict, planner, n_samples: int = 3, seed: int = 0) -> list[str]:
    """A sample of the outline that is not free, the points tree 1 rejects, one pair per cascade
    stage that stopped some, and the sets tree 2 rejects, as far as the steps in `made` ran."""
    rng = np.random.default_rng(seed)
    pt, st = planner.model.point_tree, planner.model.set_tree
    lines = []
    outline, free = made.get("outline"), made.get("free")
    if outline is not None and free is not None and not free.all():
        blocked = np.flatnonzero(~free)
        i = int(rng.choice(blocked))
        lines.append(f"not a candidate: {len(blocked)} outline points within "
                     f"{planner.params.free_gap_mm:g} mm of another part above the grasp z, e.g. "
                     f"{np.round(outline.points[i], 2).tolist()} (contact is not free area)")
    if made.get("point_valid") is not None:
        bad = np.flatnonzero(~made["point_valid"])
        for i in rng.choice(bad, size=min(n_samples, len(bad)), replace=False) if len(bad) else []:
            lines.append(f"rejected point {np.round(made['candidates'].points[i], 2).tolist()}: tree 1 "
                         f"{pt.rule_for(made['candidate_attributes'][i])}")
    if made.get("cascade") is not None:
        P, rb = made["pairs"], made["cascade"].rejected_by
        for s, name in enumerate(STAGES):
            idx = np.flatnonzero(rb == s)
            for k in rng.choice(idx, size=min(1, len(idx)), replace=False) if len(idx) else []:
                lines.append(f"rejected pair {np.round(P.pi[k], 1).tolist()} - {np.round(P.pj[k], 1).tolist()}: "
                             f"{name} stage ({STAGE_WHY[name]}); {len(idx)} pairs stopped here")
    if made.get("set_valid") is not None:
        badsets = np.flatnonzero(~made["set_valid"])
        shown = np.round(made["reachable_pairs"], 1)
        for q in _distinct_sample(badsets, shown, n_samples, rng):
            rule = st.rule_for(made["reachable_attributes"][q])
            lines.append(f"rejected set {shown[q].tolist()}: tree 2 {rule}")
    return lines


def _distinct_sample(rows: np.ndarray, shown: np.ndarray, n: int, rng) -> np.ndarray:
    """Up to n of `rows`, drawn at random among those whose `shown` values differ: pairs of other
    candidates can have the same contacts (a pad seats on the same stretch), and one line each is enough."""
    if not len(rows):
        return rows
    _, first = np.unique(shown[rows].reshape(len(rows), -1), axis=0, return_index=True)
    distinct = rows[np.sort(first)]
    return rng.choice(distinct, size=min(n, len(distinct)), replace=False)
