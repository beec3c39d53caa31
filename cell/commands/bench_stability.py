"""`cell bench stability`: share of physically stable grasps over the parts library.

Prints two tables: the whole library planned with the given examples, and leave-families-out
(each family planned by a planner that never saw an example of it). `--json` prints one
summary object as the last line.
"""

from __future__ import annotations

import json
import sys

MAX_POSES = 100  # random poses per part (default 3; 3 take about a minute)


def add_arguments(parser) -> None:
    parser.add_argument("--examples", default=None, help="example file (default: the shipped examples)")
    parser.add_argument("--cell", default=None, help="cell file (default: the shipped default cell)")
    parser.add_argument("--poses", type=int, default=3, help="random poses per part (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the poses (default 0)")
    parser.add_argument("--families", default=None,
                        help="comma-separated families to leave out one at a time (default: all)")
    parser.add_argument("--no-slanted-faces", action="store_true",
                        help="plan with SynthesisParams.slanted_faces off (the planner before it existed)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary as the last line")


def run(args) -> int:
    import numpy as np

    from cell import parts_library as L
    from cell.cellconfig import load_cell
    from cell.commands._vision_args import count
    from cell.examples import load_examples
    from cell.study.stability import (
        StabilityTally,
        cluttered,
        evaluate,
        gear_shapes,
        holed_shapes,
        leave_families_out,
        make_planner,
        presentations,
        random_baseline,
        simple_shapes,
        star_shapes,
    )

    count(args.poses, "--poses", MAX_POSES)  # 1e14 poses per part would never end
    families = [f.strip() for f in args.families.split(",") if f.strip()] if args.families else None
    if families:
        L.parts(families)  # unknown names are bad input, refused before the benchmark runs
    cell = load_cell(args.cell)
    examples = load_examples(args.examples)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    log(f"whole library: {len(L.parts())} parts x {args.poses} poses, planner trained on {len(examples)} examples")
    shown = presentations(L.parts(), args.poses, args.seed, cell)
    from cell.grasp.params import SynthesisParams

    params = SynthesisParams(slanted_faces=not args.no_slanted_faces)
    planner = make_planner(examples, cell, params)
    whole = evaluate(planner, shown, cell)
    log("clutter: every presentation with one or two neighbours 3..15 mm away")
    clutter = evaluate(planner, cluttered(shown, args.seed, cell), cell)
    baseline = random_baseline(shown, args.seed, cell)
    log(f"simple shapes not in the library: {len(simple_shapes())} x {args.poses} poses")
    simple = evaluate(planner, presentations(simple_shapes(), args.poses, args.seed, cell), cell)
    log(f"rings and plates with a hole: {len(holed_shapes())} x {args.poses} poses")
    holed = evaluate(planner, presentations(holed_shapes(), args.poses, args.seed, cell), cell)
    log(f"spur gears not in the library (modules 0.8-3 mm): {len(gear_shapes())} x {args.poses} poses")
    gears = evaluate(planner, presentations(gear_shapes(), args.poses, args.seed, cell), cell)
    log(f"stars (4-8 points): {len(star_shapes())} x {args.poses} poses")
    stars = evaluate(planner, presentations(star_shapes(), args.poses, args.seed, cell), cell)
    per_family = leave_families_out(examples, args.poses, args.seed, cell, families, progress=log, params=params)
    unseen = StabilityTally()
    for t in per_family.values():
        unseen.add(t)

    def pct(x):
        return f"{100 * x:5.1f} %"

    rows = (("whole library, all examples", "whole", whole), ("unseen families (leave-one-family-out)",
            "unseen_families", unseen), ("with 1-2 neighbours 3..15 mm away, all examples", "clutter", clutter),
            ("simple shapes not in the library, all examples", "simple_shapes", simple),
            ("rings and plates with a hole, all examples", "holed_shapes", holed),
            ("spur gears not in the library, all examples", "gears", gears),
            ("stars (4-8 points) not in the library, all examples", "stars", stars))
    print("| set | presented | planned | stable | planned share | stable share |")
    print("|---|---:|---:|---:|---:|---:|")
    for label, _, t in rows:
        print(f"| {label} | {t.presented} | {t.planned} | {t.stable} | {pct(t.planned_share)} | "
              f"{pct(t.stable_share)} |")
    print(f"| yardstick: two random outline points within the stroke | {baseline.presented} | - | "
          f"{baseline.stable} | - | {pct(baseline.stable_share)} |")
    print()
    print("| left-out family | presented | planned | stable |")
    print("|---|---:|---:|---:|")
    for fam, t in per_family.items():
        print(f"| {fam} | {t.presented} | {t.planned} | {t.stable} |")
    for _, _, t in rows:
        for pid, reasons in t.failures:
            log(f"unstable: {pid}: {'; '.join(reasons)}")
    if args.json:
        summary = {key: {"presented": t.presented, "planned": t.planned, "stable": t.stable,
                         "stable_share": round(t.stable_share, 4), "planned_share": round(t.planned_share, 4)}
                   for _, key, t in rows}
        summary["whole"]["plan_ms_median"] = round(float(np.median(whole.plan_ms)), 3) if whole.plan_ms else None
        summary["random_points"] = {"presented": baseline.presented, "stable": baseline.stable,
                                    "stable_share": round(baseline.stable_share, 4)}
        summary["per_family"] = {f: {"presented": t.presented, "planned": t.planned, "stable": t.stable}
                                 for f, t in per_family.items()}
        print(json.dumps(summary))
    return 0
