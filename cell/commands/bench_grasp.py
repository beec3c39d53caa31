"""`cell bench grasp [--repeat N] [--examples FILE] [--cell FILE] [--json]`: synthesis speed per stage, and the
cascade against the brute force (every pair through every exact check) on the same scenes in
the same run: time ratio, number of exact checks, and whether both keep the same pairs."""

from __future__ import annotations

import functools
import json
import statistics
import time

MAX_REPEAT = 1000  # plans per scene (default 15)


def add_arguments(p):
    p.add_argument("--repeat", type=int, default=15, help="plans per scene for the median time (default 15)")
    p.add_argument("--examples", metavar="FILE",
                   help="teaching-example file (default: the shipped one, else the hand-made examples)")
    p.add_argument("--cell", metavar="FILE", help="cell file (default: the shipped default cell); the scenes lie "
                   "in the default cell's tray")
    p.add_argument("--json", action="store_true", help="print one JSON object per scene, then a summary")
    p.add_argument("--scenes", metavar="TEXT", help="only the scenes whose name contains TEXT")
    p.add_argument("--library", action="store_true",
                   help="every part of the parts library alone in mid-tray instead of the benchmark scenes")


def bench_scenes():
    """(name, scene) pairs: hand-made parts, alone and among taller and lower neighbours."""
    from cell.grasp import shapes
    from cell.scene import Scene

    bar = shapes.rectangle("bar", 240, 60, (350, 0), 10)
    gear = shapes.gear("gear", 30, 12, 4, (330, 60))
    ring = shapes.disc("ring", 30, (300, -120), hole_r_mm=12)
    ell = shapes.l_shape("ell", 70, 50, 18, (420, 150), 25)
    box = shapes.rectangle("box", 50, 30, (300, 100), 30)
    tall = shapes.rectangle("tall", 40, 40, (300, 150), 0, z_top_mm=40)
    low = shapes.rectangle("low", 30, 60, (250, 100), 0, z_top_mm=0.5)
    wall = shapes.rectangle("wall", 20, 120, (340, 100), 0, z_top_mm=80)
    scenes = [("bar-300pts", Scene((bar,), "bar")),
            ("gear", Scene((gear,), "gear")),
            ("ring-with-hole", Scene((ring,), "ring")),
            ("ell", Scene((ell,), "ell")),
            ("box-among-neighbours", Scene((box, tall, low, wall), "box")),
            ("bar-among-neighbours", Scene((bar, shapes.rectangle("post", 30, 30, (350, 50), 0, z_top_mm=60),
                                            shapes.rectangle("plate", 80, 40, (430, -45), 0, z_top_mm=3)), "bar"))]
    return scenes + library_scenes()


def library_sweep_scenes():
    """(name, scene): every part of the parts library alone, at one pose in mid-tray (a sample the
    benchmark scenes were not picked from)."""
    from cell import parts_library as lib
    from cell.scene import Scene

    return [(f"library:{p.id}", Scene((lib.place(p, 350, 0, 20),), p.id)) for p in lib.parts()]


def library_scenes():
    """Parts of the parts library and the first step of each shipped assembly, when present."""
    import importlib.util
    from importlib import resources
    from pathlib import Path

    from cell.scene import Scene, load_assembly

    out = []
    if importlib.util.find_spec("cell.parts_library") is not None:
        from cell import parts_library as lib

        names = {p.id for p in lib.parts()}
        for name, (x, y, th) in (("plate_holes_l", (330, 40, 25)), ("heatsink_m", (400, -80, -40)),
                                 ("spur_gear_xl", (300, 120, 10))):
            if name in names:
                out.append((f"library:{name}", Scene((lib.place(lib.part(name), x, y, th),), name)))
    folder = Path(str(resources.files("cell") / "data" / "assemblies"))
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        out.append((f"assembly:{path.stem}:step0", load_assembly(path).scene_at(0)))
    return out


ROUNDS = 7  # brute-force runs per scene
CASCADE_RUNS_MAX = 60  # cascade runs per round at most


def side_by_side(ctx, fresh_pairs, rounds: int = ROUNDS):
    """The cascade and the brute force on the same pairs, interleaved: each round one brute-force
    run, then cascade runs until they have taken as long (at least one, at most CASCADE_RUNS_MAX), so
    both are sampled over the same stretches of a noisy host. Returns the times (ms) of every cascade
    and brute-force run, the last result of each with its pairs, and the stage times of the fastest
    brute force."""
    from cell.grasp.cascade import run_brute_force, run_cascade

    tc, tb, cr, br, bstages = [], [], None, None, {}
    for _ in range(rounds):
        Pb = fresh_pairs()
        t = time.perf_counter()
        br = run_brute_force(ctx, Pb)
        tb.append((time.perf_counter() - t) * 1e3)
        if tb[-1] == min(tb):
            bstages = br.time_ms
        spent_ms = 0.0
        for _ in range(CASCADE_RUNS_MAX):
            Pc = fresh_pairs()
            t = time.perf_counter()
            cr = run_cascade(ctx, Pc)
            tc.append((time.perf_counter() - t) * 1e3)
            spent_ms += tc[-1]
            if spent_ms >= tb[-1]:
                break
    return tc, tb, (cr, Pc), (br, Pb), bstages


def run(args) -> int:
    import numpy as np

    from cell.cellconfig import load_cell
    from cell.commands._vision_args import count
    from cell.errors import BadInput, NoFeasibleGrasp
    from cell.examples import default_examples_path, load_examples
    from cell.grasp.cascade import Pairs
    from cell.grasp.shapes import hand_made_examples
    from cell.grasp.synthesis import GraspPlanner

    count(args.repeat, "--repeat", MAX_REPEAT)  # 1e14 plans per scene would never end
    if args.examples:
        examples, source = load_examples(args.examples), args.examples
    elif default_examples_path().exists():
        examples, source = load_examples(None), str(default_examples_path())
    else:
        examples, source = hand_made_examples(), "hand-made examples (cell.grasp.shapes)"
    cell = load_cell(args.cell)  # None: the default cell
    t0 = time.perf_counter()
    planner = GraspPlanner(cell, examples)
    fit_ms = (time.perf_counter() - t0) * 1e3
    from cell.heap import freeze_startup

    freeze_startup()  # as `cell grasp` does: no full collection of start-up objects in a timed plan
    rows = []
    scenes = [(n, s) for n, s in (library_sweep_scenes() if args.library else bench_scenes())
              if not args.scenes or args.scenes in n]
    if not scenes:
        raise BadInput(f"no benchmark scene name contains {args.scenes!r}")
    for name, scene in scenes:
        times, result, err = [], None, None
        for _ in range(args.repeat):
            try:
                t = time.perf_counter()
                result = planner.plan(scene)
                times.append((time.perf_counter() - t) * 1e3)
            except NoFeasibleGrasp as e:
                times.append(e.counts.get("time_ms", float("nan")))
                err = e.reason
        # The cascade and the brute force side by side on the same pairs (valid points of this scene).
        op_pts = result.valid_points if result else None
        row = {"scene": name, "median_ms": round(statistics.median(times), 3),
               "error": err}
        if result is not None:
            ctx = result.context
            fresh = functools.partial(Pairs.of, op_pts.points, op_pts.normals, result.valid_sample_index)
            tc, tb, (cr, Pc), (br, Pb), bstages = side_by_side(ctx, fresh)
            kept = np.sort(cr.survivors)
            same = bool(np.array_equal(kept, np.sort(br.survivors))
                        and np.array_equal(Pc.ci[kept], Pb.ci[kept]) and np.array_equal(Pc.cj[kept], Pb.cj[kept]))
            row.update(counts=result.counts, stage_ms={k: round(v, 3) for k, v in result.stage_time_ms.items()},
                       cascade_ms=round(min(tc), 3), brute_ms=round(min(tb), 3),
                       cascade_median_ms=round(statistics.median(tc), 3),
                       brute_median_ms=round(statistics.median(tb), 3), cascade_runs=len(tc), brute_runs=len(tb),
                       speedup_median=round(statistics.median(tb) / max(statistics.median(tc), 1e-9), 1),
                       # where the brute force's time goes (its fastest run): the exact stages on every pair
                       brute_stage_ms={k: round(v, 3) for k, v in bstages.items()},
                       speedup=round(min(tb) / max(min(tc), 1e-9), 1),
                       # the exact stages must see at least the s' pairs they keep: a cascade whose exact
                       # checks cost the same per pair as the brute force's is at most about s/s' faster
                       bound=round(result.counts["pairs"] / max(result.counts["reachable"], 1), 1),
                       exact_checks_cascade=cr.exact_checks, exact_checks_brute=br.exact_checks,
                       same_pairs=same)  # the same pairs kept, with the same contacts bit for bit
        rows.append(row)
    ok = [r for r in rows if "speedup" in r]
    summary = {"cell": cell.source, "examples": source, "n_examples": len(examples), "fit_ms": round(fit_ms, 2),
               "median_synthesis_ms": round(statistics.median(r["median_ms"] for r in rows), 3),
               "median_speedup": round(statistics.median(r["speedup"] for r in ok), 1) if ok else None,
               "median_speedup_of_medians": (round(statistics.median(r["speedup_median"] for r in ok), 1)
                                             if ok else None),
               "median_bound": round(statistics.median(r["bound"] for r in ok), 1) if ok else None,
               "speedup_at_least_20x": sum(r["speedup"] >= 20 for r in ok), "planned": len(ok),
               # all the scenes' brute-force time over all their cascade time (fastest runs): the
               # workload's ratio, which the scenes with the most pairs weigh most
               "total_speedup": (round(sum(r["brute_ms"] for r in ok) / max(sum(r["cascade_ms"] for r in ok), 1e-9), 1)
                                 if ok else None),
               "all_same_pairs": all(r["same_pairs"] for r in ok)}
    if args.json:
        for r in rows:
            print(json.dumps(r))
        print(json.dumps(summary))
        return 0
    print(f"grasp synthesis benchmark: {len(examples)} examples from {source}; trees fitted in {fit_ms:.1f} ms"
          + ("" if args.cell is None else f"; cell {cell.source}"))
    for r in rows:
        if "counts" not in r:
            print(f"\n{r['scene']}: no grasp ({r['error']}), median {r['median_ms']:.2f} ms")
            continue
        c = r["counts"]
        print(f"\n{r['scene']}: median synthesis {r['median_ms']:.2f} ms over {args.repeat} plans")
        print(f"  z={c['candidates']} candidates  z'={c['valid_points']} valid points  s={c['pairs']} pairs  "
              f"s'={c['reachable']} reachable  s''={c['valid_sets']} valid sets")
        stages = [k[len("after_"):] for k in c if k.startswith("after_")]
        print("  cascade: " + "  ".join(f"{s} {c['after_' + s]} ({r['stage_ms'].get('cascade_' + s, 0):.2f} ms)"
                                       for s in stages))
        print(f"  cascade {r['cascade_ms']:.2f} ms with {r['exact_checks_cascade']} exact checks; brute force "
              f"{r['brute_ms']:.2f} ms with {r['exact_checks_brute']} exact checks: {r['speedup']:.1f}x faster "
              f"(bound s/s' {r['bound']:.0f}x), same pairs and contacts kept: {r['same_pairs']}")
        print(f"  (fastest of {r['cascade_runs']} cascade and {r['brute_runs']} brute-force runs, interleaved; "
              f"medians {r['cascade_median_ms']:.2f} and {r['brute_median_ms']:.2f} ms: {r['speedup_median']:.1f}x)")
        print("  brute force: " + "  ".join(f"{s} {v:.2f} ms" for s, v in r["brute_stage_ms"].items()))
    print(f"\nmedian synthesis {summary['median_synthesis_ms']:.2f} ms; median cascade speed-up "
          f"{summary['median_speedup']}x ({summary['median_speedup_of_medians']}x from the runs' medians; median bound "
          f"s/s' {summary['median_bound']}x; at least 20x on "
          f"{summary['speedup_at_least_20x']} of {summary['planned']} planned scenes; all scenes' times summed: "
          f"{summary['total_speedup']}x); cascade and brute force agree "
          f"everywhere (pairs kept, and their contacts bit for bit): {summary['all_same_pairs']}")
    return 0
