"""Grasps for a whole disassembly sequence (paper section 8.2).

Each step plans a grasp for the step's part against the parts still present, exactly as
`cell grasp` does for one scene, and then checks the lift: the part, moving straight up
(the only disassembly direction of the 2D normal grasp), must not meet a part still lying
on it. The gripper's own column above the grasp is already kept clear by the cascade
(fingers against parts taller than the grasp z, palm against parts taller than its bottom).
"""

from __future__ import annotations

from dataclasses import dataclass

from cell.errors import NoFeasibleGrasp
from cell.grasp.synthesis import GraspPlanner, SynthesisResult
from cell.scene import PART_OVERLAP_MM2, REST_MM, Assembly, Part, Scene

AREA_EPS_MM2 = 1e-3


@dataclass(eq=False)
class StepPlan:
    step: int
    scene: Scene
    result: SynthesisResult | None
    error: str | None = None
    reason: str | None = None
    counts: dict | None = None
    time_ms: float | None = None
    blocked_by: tuple[str, ...] = ()  # parts still lying on the target (no grasp can lift it)

    @property
    def ok(self) -> bool:
        return self.result is not None

    def to_json(self) -> dict:
        d = {"step": self.step}
        if self.result is not None:
            d.update(self.result.to_json())
            d["lift"] = {"clear": True}
        else:
            d.update({"target": self.scene.target, "error": self.error, "reason": self.reason})
            if self.blocked_by:
                d["lift"] = {"clear": False, "blocked_by": list(self.blocked_by)}
            if self.counts:
                d["counts"] = {k: v for k, v in self.counts.items() if k != "time_ms"}
            if self.time_ms is not None:
                d["time_ms"] = self.time_ms
        return d


def parts_on_top(target: Part, present: tuple[Part, ...], rest_mm: float = REST_MM) -> list[str]:
    """Ids of the parts that lie on the target: over it in plan, not wholly below it, their bottom at most
    `rest_mm` under its top (the height overlap the assembly files allow a part resting on another: a cover
    at 9.7 mm on a base 10 mm tall was lifted with it, "lift clear"; 1e-9 for the loop's older recordings).
    One whose bottom is under the target's top overlaps it in plan by more than the files' touch
    (PART_OVERLAP_MM2): a clip beside the base, touching its edge by 0.4 mm2, blocked it."""
    def on_it(o: Part) -> bool:
        area = o.polygon.intersection(target.polygon).area
        return area > (AREA_EPS_MM2 if o.z_bottom_mm >= target.z_top_mm - 1e-9 else PART_OVERLAP_MM2)

    return [o.id for o in present if o.id != target.id and o.z_top_mm > target.z_bottom_mm + 1e-9
            and o.z_bottom_mm >= target.z_top_mm - rest_mm and on_it(o)]


def lift_blocked_reason(scene: Scene, blockers: list[str]) -> str:
    """Why the scene's target has no grasp while `blockers` (`parts_on_top`) still lie on it."""
    return (f"{scene.target!r} cannot be lifted straight up: {', '.join(map(repr, blockers))} "
            "still lies on it (is the sequence right?)")


def plan_step(planner: GraspPlanner, scene: Scene, step: int) -> StepPlan:
    blockers = parts_on_top(scene.target_part, scene.obstacles)
    if blockers:  # CONTRACT's one error value for a step without a grasp; `lift` says why
        return StepPlan(step, scene, None, "no_feasible_grasp", lift_blocked_reason(scene, blockers),
                        blocked_by=tuple(blockers))
    try:
        return StepPlan(step, scene, planner.plan(scene))
    except NoFeasibleGrasp as e:
        return StepPlan(step, scene, None, "no_feasible_grasp", e.reason, e.counts, e.counts.get("time_ms"))


def plan_assembly(planner: GraspPlanner, assembly: Assembly) -> list[StepPlan]:
    """One StepPlan per step of the sequence, each against the parts present at that step."""
    return [plan_step(planner, assembly.scene_at(i), i) for i in range(len(assembly.sequence))]
