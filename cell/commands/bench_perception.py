"""`cell bench perception`: the loop's perception of one frame (segmentation, then matching the parts to the regions)
on trays of 6, 28 and 60 parts, matching timed both ways side by side: every region mapped at every part's heights
(as before 2026-12-05), and `RegionOutline` (each pair of heights mapped once, far regions ruled out by a box)."""

from __future__ import annotations

import json
import random
import time

import numpy as np

LAYOUTS = {  # parts on the tray -> (grid pitch mm, largest part across mm); 6: the default assembly
    28: (70.0, 60.0),  # the soak hunter's big28
    60: (50.0, 35.0),  # ... and big60
}


def add_arguments(p) -> None:
    p.add_argument("--repeats", type=int, default=3, help="timed frames per tray and way (default 3)")
    p.add_argument("--parts", type=int, nargs="+", default=[6, 28, 60], choices=[6, *LAYOUTS],
                   help="trays to time (default 6 28 60)")
    p.add_argument("--json", action="store_true", help="print one JSON object per tray")


def grid_layout(pitch_mm: float, max_extent_mm: float):
    """Parts of the library (up to max_extent_mm across, under 500 g) on a grid over the tray (x 200-500 mm,
    y -250-250 mm, 5 mm from its edge), turned at random (seed 1): the soak hunter's trays."""
    from cell import parts_library as lib

    rng = random.Random(1)
    pool = [p for p in lib.parts() if max(np.ptp(p.outline_mm, axis=0)) <= max_extent_mm
            and p.meta.get("mass_g", 0) < 500]
    xs = np.arange(200 + pitch_mm / 2, 495 - max_extent_mm / 2 + 1e-9, pitch_mm)
    ys = np.arange(-250 + pitch_mm / 2, 245 - max_extent_mm / 2 + 1e-9, pitch_mm)
    return [lib.place(pool[i % len(pool)], x, y, rng.uniform(0, 180), part_id=f"p{i:02d}")
            for i, (x, y) in enumerate((x, y) for x in xs for y in ys)]


def loop_mapping(seg, cal, frame):
    """The region's outline in mm at (z_top, z_bottom) as the loop maps it (segment_to_mm, the valid-area fix)."""
    from shapely.geometry import Polygon

    from cell.runtime.loop import valid_area
    from cell.vision import segment_to_mm

    def polygon_at(z_top, z_bottom):
        poly = Polygon(*segment_to_mm(seg, cal, z_top, z_bottom, frame))
        return poly if poly.is_valid else valid_area(poly)
    return polygon_at


def _tray(n_parts: int):
    from importlib import resources
    from pathlib import Path

    from cell.scene import load_assembly

    if n_parts == 6:
        return list(load_assembly(Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))).parts)
    return grid_layout(*LAYOUTS[n_parts])


def time_tray(n_parts: int, repeats: int, cal) -> dict:
    """Per-frame perception times (s) of one rendered tray, matching both ways in turn, and whether they agree."""
    from cell.runtime.matching import Region, RegionOutline, locate, unexplained
    from cell.vision import SegmentParams, SimCamera, SimCameraOptions, segment_frame

    parts = _tray(n_parts)
    frame = SimCamera(cal, SimCameraOptions(seed=3)).render(parts)
    params = SegmentParams.for_calibration(cal)
    times = {"segment": [], "every_region": [], "region_outline": []}
    results = {}
    for _ in range(repeats):
        t0 = time.perf_counter()
        segments = segment_frame(frame, params)
        times["segment"].append(time.perf_counter() - t0)
        for way in ("every_region", "region_outline"):
            t0 = time.perf_counter()
            regions = [Region(i, loop_mapping(s, cal, frame) if way == "every_region" else
                              RegionOutline(loop_mapping(s, cal, frame), [s.outline_px, *s.holes_px], cal),
                              s.merged, s.cut_off) for i, s in enumerate(segments)]
            found, strangers = locate(parts, regions)
            seen = {pid: loc.apply(next(p for p in parts if p.id == pid)) for pid, loc in found.items()}
            left = unexplained(regions, seen, found, max(p.z_top_mm for p in parts))
            times[way].append(time.perf_counter() - t0)
            results[way] = (found, strangers, [p.polygon.wkb for p in left])
    med = {k: float(np.median(v)) for k, v in times.items()}
    return {"parts": n_parts, "regions": len(segments), "found": len(results["region_outline"][0]),
            "same_decisions": results["every_region"] == results["region_outline"], "repeats": repeats,
            "segment_s": round(med["segment"], 3),
            "frame_s_every_region": round(med["segment"] + med["every_region"], 3),
            "frame_s_region_outline": round(med["segment"] + med["region_outline"], 3),
            "matching_s_every_region": round(med["every_region"], 3),
            "matching_s_region_outline": round(med["region_outline"], 3),
            "matching_speedup": round(med["every_region"] / med["region_outline"], 1)}


def run(args) -> int:
    from calibration import load_calibration
    from cell.errors import BadInput

    if not 1 <= args.repeats <= 100:
        raise BadInput("--repeats must be 1 to 100")
    cal = load_calibration()
    rows = [time_tray(n, args.repeats, cal) for n in args.parts]
    if args.json:
        for r in rows:
            print(json.dumps(r))
    else:
        print(f"perception of one frame (median of {args.repeats}; wall s): segmentation + matching, "
              "every region at every part's heights -> RegionOutline")
        for r in rows:
            print(f"{r['parts']:3d} parts, {r['regions']:3d} regions: frame {r['frame_s_every_region']:.2f} -> "
                  f"{r['frame_s_region_outline']:.2f} s (segmentation {r['segment_s']:.2f}; matching "
                  f"{r['matching_s_every_region']:.2f} -> {r['matching_s_region_outline']:.2f} s, "
                  f"x{r['matching_speedup']}), {r['found']} found, same decisions: {r['same_decisions']}")
    return 0 if all(r["same_decisions"] for r in rows) else 1
