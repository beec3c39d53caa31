"""`cell bench vision`: segmentation accuracy (mm) and speed (ms) on rendered frames with ground truth."""

from __future__ import annotations

import json

MAX_COUNT = 1000  # frames per condition, timing repeats (defaults 12, 30)


def add_arguments(p) -> None:
    p.add_argument("--frames", type=int, default=12, help="rendered frames per condition (default 12)")
    p.add_argument("--parts", type=int, default=6, help="parts per frame (default 6)")
    p.add_argument("--seed", type=int, default=0, help="seed of the rendered frames and their parts (default 0)")
    p.add_argument("--conditions", nargs="+", default=None, metavar="NAME",
                   help="conditions to run (default all): " + ", ".join(repr(c) for c in _conditions()))
    p.add_argument("--repeats", type=int, default=30, help="timing repeats (default 30)")
    p.add_argument("--library", action="store_true",
                   help="draw the parts from the parts library (cell/parts_library.py) instead of the sample parts")
    p.add_argument("--photos", nargs="+", default=[], metavar="IMAGE",
                   help="also time these image files (real camera frames), without a calibration")
    p.add_argument("--json", action="store_true", help="print one JSON object per line")


def _conditions():
    from cell.vision.bench import CONDITIONS

    return list(CONDITIONS)


LARGE_FRAME_PX = (4000, 3200)  # (w, h): the default camera's 1280 x 1024 x 3.125, 12.8 MP


def run(args) -> int:
    import cv2
    import numpy as np

    from calibration import load_calibration
    from cell.errors import BadInput
    from cell.vision.bench import CONDITIONS, run_benchmark, time_segmentation
    from cell.vision.sample_parts import random_layout
    from cell.vision.segment import SegmentParams
    from cell.vision.simcamera import SimCamera, SimCameraOptions

    if args.frames < 1 or args.parts < 1 or args.repeats < 1:
        raise BadInput("--frames, --parts and --repeats must be at least 1")
    if max(args.frames, args.repeats) > MAX_COUNT:  # 1e14 frames or repeats would never end
        raise BadInput(f"--frames and --repeats must be at most {MAX_COUNT}")
    conditions = args.conditions or list(CONDITIONS)
    unknown = [c for c in conditions if c not in CONDITIONS]
    if unknown:
        raise BadInput(f"unknown condition(s) {unknown}; known: {list(CONDITIONS)}")
    from cell.vision.sources import read_image

    # all bad files refused before any work (a bad one was refused after the whole benchmark, 80 s)
    photos = [(path, read_image(path)) for path in args.photos]
    cal = load_calibration()
    params = SegmentParams.for_calibration(cal)
    pool = None
    if args.library:
        from cell.parts_library import parts as library_parts

        # parts that fit the tray with room to spare; the tall housings are included
        pool = [p for p in library_parts() if max(np.ptp(p.outline_mm, axis=0)) < 150]
    rows = []
    for c in conditions:
        rows.append(run_benchmark(args.frames, args.parts, args.seed, c, cal, params, pool))
    frame = SimCamera(cal, SimCameraOptions(seed=args.seed)).render(
        random_layout(np.random.default_rng(args.seed), 8))
    timing = {"timing": "segment_frame, 8 parts, all effects", **time_segmentation(frame, params, args.repeats)}
    # a 12 MP camera of the same tray, without a calibration: the thresholds follow the frame's size
    large = cv2.resize(frame, LARGE_FRAME_PX, interpolation=cv2.INTER_CUBIC)
    timing_large = {"timing": "segment_frame, the same frame upscaled, no calibration",
                    **time_segmentation(large, SegmentParams(), args.repeats)}
    # ... and with its calibration resized to it (a calibrated 12 MP camera): the same sizes from its mm per px
    large_cal = cal.resized(*LARGE_FRAME_PX)
    timing_large_cal = {"timing": "segment_frame, the same frame upscaled, its calibration resized",
                        **time_segmentation(large, SegmentParams.for_calibration(large_cal), args.repeats)}
    timing_photos = [{"timing": f"segment_frame, {path}, no calibration", **time_segmentation(img, SegmentParams(),
                                                                                               args.repeats)}
                     for path, img in photos]
    if args.json:
        for r in rows + [timing, timing_large, timing_large_cal] + timing_photos:
            print(json.dumps(r))
        return 0
    print(f"segmentation accuracy on rendered frames ({args.frames} frames x {args.parts} "
          f"{'library' if args.library else 'sample'} parts, mm on the part's "
          "top plane; outline error both ways, every vertex and every 0.5 mm of the true outline)")
    print(f"{'condition':22s} {'found':>7s} {'flag':>5s} {'extra':>5s} {'mean':>6s} {'rms':>6s} {'p95':>6s} "
          f"{'part rms med/max':>17s} {'centroid mean/p95':>18s}")
    for r in rows:
        print(f"{r['condition']:22s} {r['found']:3d}/{r['parts']:<3d} {r['flagged']:5d} {r['extra_segments']:5d} "
              f"{r['outline_mean_mm']:6.3f} {r['outline_rms_mm']:6.3f} {r['outline_p95_mm']:6.3f} "
              f"{r['part_rms_median_mm']:8.3f}/{r['part_rms_max_mm']:<8.3f} "
              f"{r['centroid_mean_mm']:8.3f}/{r['centroid_p95_mm']:<8.3f}")
    print(f"time to segment a {timing['frame']} frame: {_times(timing)}")
    print(f"the same frame upscaled to {timing_large['frame']}, no calibration: {_times(timing_large)}")
    print(f"the same frame upscaled to {timing_large_cal['frame']}, its calibration resized: "
          f"{_times(timing_large_cal)}")
    for (path, _), t in zip(photos, timing_photos):
        print(f"{path} ({t['frame']}): {_times(t)}")
    return 0


def _times(t: dict) -> str:
    return (f"median {t['median_ms']:.1f} ms wall (p10 {t['p10_ms']:.1f}, p90 {t['p90_ms']:.1f}), "
            f"{t['cpu_median_ms']:.1f} ms CPU, {t['repeats']} runs, {t['regions']} regions, "
            f"detected at 1 / {t['detection_scale']}")
