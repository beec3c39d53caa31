"""`cell grasp SCENE.json [SCENE2.json ...] [--json] [--examples FILE] [--cell FILE] [--explain]`.

Plans a grasp per scene (CONTRACT.md). One scene: exit 0 with a grasp, 3 when none is
feasible, 2 on bad input. Several scenes: one line per scene, in order, each with a `scene`
key; exit 2 if any scene file was bad input, else 0. The cell: `--cell` if given, else the
scene's own "cell" key, else the default cell.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_arguments(p):
    p.add_argument("scenes", nargs="+", metavar="SCENE", help="scene JSON file(s) (CONTRACT.md)")
    p.add_argument("--json", action="store_true", help="print one JSON object per scene")
    p.add_argument("--examples", metavar="FILE", help="teaching-example file (default: the shipped one)")
    p.add_argument("--cell", metavar="FILE", help="cell file (overrides the scene's own 'cell' key)")
    p.add_argument("--explain", action="store_true",
                   help="say which rule or cascade stage decided, for the grasp and a sample of rejections")
    p.add_argument("--step-mm", type=float, help="arc-length step of the candidate points (default 2)")
    p.add_argument("--gap-mm", type=float, help="outline closer than this to another part is not free (default 1.5)")


def load_planner_inputs(examples_path):
    """Examples from FILE, or the shipped default (a clear error when it is missing)."""
    from cell.errors import BadInput
    from cell.examples import default_examples_path, load_planner_examples

    if examples_path is None and not default_examples_path().exists():
        raise BadInput(f"the shipped default example file {default_examples_path()} is missing; "
                       "pass --examples FILE")
    return load_planner_examples(examples_path)


class PlannerCache:
    """One planner per cell file: the trees are fitted once per process."""

    def __init__(self, examples, params):
        self.examples, self.params, self._by_cell = examples, params, {}

    def get(self, cell_path):
        from cell.cellconfig import load_cell
        from cell.grasp.synthesis import GraspPlanner

        key = str(Path(cell_path).resolve()) if cell_path else None
        if key not in self._by_cell:
            from cell.heap import freeze_startup

            self._by_cell[key] = GraspPlanner(load_cell(cell_path), self.examples, self.params)
            freeze_startup()  # no full collection of the start-up objects inside a scene's time_ms
        return self._by_cell[key]


def run(args) -> int:
    from cell.errors import BadInput, NoFeasibleGrasp
    from cell.grasp.params import SynthesisParams
    from cell.scene import load_scene

    params = SynthesisParams().with_(step_mm=args.step_mm, free_gap_mm=args.gap_mm)
    examples = load_planner_inputs(args.examples)
    cache = PlannerCache(examples, params)
    many = len(args.scenes) > 1
    any_bad, code = False, 0
    for path in args.scenes:
        try:
            scene = load_scene(path)
            planner = cache.get(args.cell or scene.cell_path)
            try:
                result = planner.plan(scene)
            except NoFeasibleGrasp as e:
                out = {"target": scene.target, "error": "no_feasible_grasp", "reason": e.reason,
                       "counts": {k: v for k, v in e.counts.items() if k != "time_ms"},
                       "time_ms": e.counts.get("time_ms")}
                code = 3
                _emit(out, path, many, args, None, planner, e.partial)
                continue
            _emit(result.to_json(), path, many, args, result, planner)
        except BadInput as e:
            if not many:
                raise
            any_bad = True
            print(f"cell: error: {e}", file=sys.stderr)
            if args.json:
                print(json.dumps({"scene": Path(path).name, "error": "bad_input", "reason": str(e)}), flush=True)
    if many:
        return 2 if any_bad else 0
    return code


def _emit(obj, path, many, args, result, planner, partial=None):
    """Print one scene's outcome; with --explain, why (for a grasp, or for none: `partial`)."""
    if many:
        obj = {"scene": Path(path).name, **obj}
    lines = None
    if args.explain:
        from cell.grasp.explain import explain, explain_failure

        lines = explain(result, planner) if result is not None else explain_failure(partial or {}, planner)
    if args.json:
        if lines is not None:
            obj["explain"] = lines
        print(json.dumps(obj), flush=True)
        return
    print(summary(obj, path))
    for line in lines or ():
        print("  " + line)


def summary(obj, path) -> str:
    if "error" in obj:
        c = obj.get("counts", {})
        stages = "  ".join(f"{k[len('after_'):]} {v}" for k, v in c.items() if k.startswith("after_"))
        return (f"{Path(path).name}: no feasible grasp for {obj.get('target')!r}: {obj['reason']}\n"
                f"  z={c.get('candidates', 0)} candidates -> z'={c.get('valid_points', 0)} valid points -> "
                f"s={c.get('pairs', 0)} pairs" + (f"; cascade kept: {stages}" if stages else ""))
    c, j = obj["counts"], obj["joints"]
    step = f" (at the finer {obj['step_mm']:g} mm outline step)" if "step_mm" in obj else ""
    return (f"{Path(path).name}: grasp {obj['target']!r}{step} at ({obj['center'][0]:.1f}, {obj['center'][1]:.1f}) mm, "
            f"axis {obj['angle_deg']:.1f} deg, opening {obj['opening_mm']:.1f} mm, z {obj['grasp_z_mm']:.1f} mm\n"
            f"  contacts {obj['contacts'][0]} and {obj['contacts'][1]}\n"
            f"  joints J1 {j['j1_deg']:.2f} deg, J2 {j['j2_deg']:.2f} deg, J3 {j['j3_mm']:.2f} mm, "
            f"J4 {j['j4_deg']:.2f} deg ({len(obj['joint_options'])} options)\n"
            f"  z={c['candidates']} candidates -> z'={c['valid_points']} valid points -> s={c['pairs']} pairs -> "
            f"s'={c['reachable']} reachable -> s''={c['valid_sets']} valid sets; nearest example "
            f"{obj['nearest_example']} at {obj['distance_to_example']:.3f}; {obj['time_ms']:.1f} ms")
