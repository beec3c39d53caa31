"""`cell bench can`: command round trip over the virtual bus and the bus load of one pick."""

from __future__ import annotations

import json

MAX_N = 100000  # round trips per figure: about 10-20 s each at the most


def add_arguments(p) -> None:
    p.add_argument("--n", type=int, default=200, help="round trips per figure (default 200)")
    p.add_argument("--cell", default=None, help="cell file (default: the shipped cell)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args) -> int:
    from cell.cellconfig import load_cell
    from cell.commands._vision_args import count
    from drivers import bench

    count(args.n, "--n", MAX_N)  # 1e14 ran without end (and would have stored every time)
    cell = load_cell(args.cell)
    rt = bench.round_trips(cell, args.n)
    pick = bench.pick_cycle(cell)
    if args.json:
        print(json.dumps({"round_trip": rt, "pick": pick}))
        return 0
    print(f"command round trip over python-can's virtual bus (wall time, drives in this process, n = {args.n}):")
    for name, s in rt.items():
        print(f"  {name:16s} median {s['median_ms']:.3f} ms  p95 {s['p95_ms']:.3f} ms  max {s['max_ms']:.3f} ms")
    print(f"one pick cycle (simulated time, {'held' if pick['held'] else 'MISSED'}):")
    print(
        f"  cycle {pick['cycle_s']:.3f} s, {pick['frames']} frames ({pick['command_frames']} host commands), "
        f"{pick['bits']} bits with worst-case stuffing"
    )
    print("  by kind: " + ", ".join(f"{k} {v}" for k, v in sorted(pick["frames_by_kind"].items())))
    print(f"  bus load at {pick['bitrate'] / 1e6:g} Mbit/s: {pick['bus_load_percent']:.2f} %")
    return 0
