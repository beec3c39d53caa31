"""`cell rules [--examples FILE] [--json]`: the two learned decision trees as if-then rules."""

from __future__ import annotations

import json


def add_arguments(p):
    p.add_argument("--examples", metavar="FILE", help="teaching-example file (default: the shipped one)")
    p.add_argument("--cell", metavar="FILE", help="cell file (the pad width sets the labelling band)")
    p.add_argument("--json", action="store_true", help="print the rules as a JSON object")


def run(args) -> int:
    from cell.cellconfig import load_cell
    from cell.commands.grasp import load_planner_inputs
    from cell.grasp.synthesis import GraspPlanner

    planner = GraspPlanner(load_cell(args.cell), load_planner_inputs(args.examples))
    rules, counts = planner.rules(), planner.model.counts
    if args.json:
        print(json.dumps({**rules, "training": counts}))
        return 0
    print(f"Learned from {counts['examples']} examples ({counts['valid_examples']} accepted).")
    print(f"\nTree 1, contact points ({counts['point_rows']} labelled points, {counts['point_rows_valid']} valid):")
    for r in rules["points"]:
        print("  " + r)
    print(f"\nTree 2, contact sets ({counts['set_rows']} sets with neighbours, {counts['set_rows_valid']} valid):")
    for r in rules["sets"]:
        print("  " + r)
    return 0
