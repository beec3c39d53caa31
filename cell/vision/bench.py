"""Segmentation accuracy and speed on rendered frames with known ground truth.

Each frame holds sample parts at random poses (isolated, at least 8 mm apart). Every part is
matched to the segment that lies mostly (MATCH_SHARE of its area) on its true silhouette; the segment is mapped
to mm on the plane of the part's top (walls handled, `segment_to_mm` with the frame), and
compared with the true outline both ways: each measured vertex to the true boundary and
each true boundary point (every 0.5 mm) to the measured one. Errors pool over all parts.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import shapely
from shapely.geometry import Polygon

from calibration import Calibration, load_calibration
from cell.vision.detection import detection_scale
from cell.vision.sample_parts import random_layout, random_layout_of
from cell.vision.segment import SegmentParams, segment_frame, segment_to_mm
from cell.vision.simcamera import SimCamera, SimCameraOptions, densify

MATCH_SHARE = 0.6  # of a segment's area on a part's silhouette (2 px margin) for the two to match

CONDITIONS = {
    "all effects": {},
    "strong shadows": {"shadow_strength": 0.45},
    "uneven light": {"lighting_gradient": 0.5, "vignetting": 0.3},
    "no shadows": {"shadows": False},
    "no highlights": {"highlights": False},
    "no noise": {"read_noise_dn": 0.0, "shot_noise": 0.0},
    "plain (no effects)": {"shadows": False, "highlights": False, "read_noise_dn": 0.0, "shot_noise": 0.0,
                           "lighting_gradient": 0.0, "vignetting": 0.0, "tray_texture": 0.0},
}


def _ring_errors(measured: list[np.ndarray], truth: Polygon) -> tuple[np.ndarray, np.ndarray]:
    """Distances (mm): measured vertices -> true boundary, true boundary samples -> measured."""
    pts = np.vstack(measured)
    d1 = shapely.distance(shapely.points(pts), truth.boundary)
    meas_poly = Polygon(measured[0], measured[1:])
    rings = [np.asarray(truth.exterior.coords)[:-1]] + [np.asarray(r.coords)[:-1] for r in truth.interiors]
    tpts = np.vstack([densify(r, 0.5) for r in rings])
    d2 = shapely.distance(shapely.points(tpts), meas_poly.boundary)
    return d1, d2


def evaluate_frame(cal: Calibration, parts, frame: np.ndarray, params: SegmentParams) -> dict:
    t0 = time.perf_counter()
    segs = segment_frame(frame, params)
    seg_ms = 1000 * (time.perf_counter() - t0)
    cam = SimCamera(cal, SimCameraOptions())
    seg_polys = [shapely.make_valid(Polygon(s.outline_px, s.holes_px)) for s in segs]
    used: set[int] = set()
    out_err, cen_err, found, flagged = [], [], 0, 0
    for part in parts:
        sil = Polygon(cam.project_ring(part.outline_mm, part.z_top_mm)).union(
            Polygon(cam.project_ring(part.outline_mm, part.z_bottom_mm)))
        # the segment lying mostly on the part's silhouette (its centroid need not: a split ring's
        # or a U-bracket's centroid lies outside the part)
        near = sil.buffer(2.0)
        overlap = {i: seg_polys[i].intersection(near).area for i in range(len(segs)) if i not in used}
        hits = [i for i, a in overlap.items() if a >= MATCH_SHARE * seg_polys[i].area > 0]
        if not hits:
            continue
        i = max(hits, key=lambda k: overlap[k])
        used.add(i)
        found += 1
        flagged += int(segs[i].merged or segs[i].cut_off)
        outline, holes = segment_to_mm(segs[i], cal, part.z_top_mm, part.z_bottom_mm, frame)
        d1, d2 = _ring_errors([outline] + holes, part.polygon)
        out_err.append(np.concatenate([d1, d2]))
        meas = Polygon(outline, holes)
        cen_err.append(float(np.linalg.norm(np.asarray(meas.centroid.coords[0]) -
                                            np.asarray(part.polygon.centroid.coords[0]))))
    return {"segment_ms": seg_ms, "parts": len(parts), "found": found, "flagged": flagged,
            "extra": len(segs) - len(used), "outline_err": out_err, "centroid_err": cen_err}


def run_benchmark(frames: int = 12, parts_per_frame: int = 6, seed: int = 0, condition: str = "all effects",
                  cal: Calibration | None = None, params: SegmentParams | None = None,
                  pool: list | None = None) -> dict:
    """Accuracy (mm) and timing (ms) over `frames` rendered frames under one condition.

    `pool`: parts centred on the origin to draw from (e.g. the parts library); default the
    sample parts of `sample_parts.SHAPES`.
    """
    cal = cal or load_calibration()
    params = params or SegmentParams.for_calibration(cal)
    rng = np.random.default_rng(seed)
    opts = replace(SimCameraOptions(), **CONDITIONS[condition])
    rows = []
    for k in range(frames):
        parts = random_layout(rng, parts_per_frame) if pool is None else random_layout_of(rng, parts_per_frame, pool)
        frame = SimCamera(cal, replace(opts, seed=seed * 1000 + k)).render(parts)
        rows.append(evaluate_frame(cal, parts, frame, params))
    err = np.concatenate([e for r in rows for e in r["outline_err"]]) if rows else np.zeros(0)
    cen = np.array([c for r in rows for c in r["centroid_err"]])
    per_part_rms = [float(np.sqrt(np.mean(e ** 2))) for r in rows for e in r["outline_err"]]
    return {
        "condition": condition, "frames": frames,
        "parts": sum(r["parts"] for r in rows), "found": sum(r["found"] for r in rows),
        "flagged": sum(r["flagged"] for r in rows), "extra_segments": sum(r["extra"] for r in rows),
        "outline_mean_mm": float(err.mean()) if err.size else None,
        "outline_rms_mm": float(np.sqrt(np.mean(err ** 2))) if err.size else None,
        "outline_p95_mm": float(np.percentile(err, 95)) if err.size else None,
        "part_rms_median_mm": float(np.median(per_part_rms)) if per_part_rms else None,
        "part_rms_max_mm": float(np.max(per_part_rms)) if per_part_rms else None,
        "centroid_mean_mm": float(cen.mean()) if cen.size else None,
        "centroid_p95_mm": float(np.percentile(cen, 95)) if cen.size else None,
        "segment_ms_median": float(np.median([r["segment_ms"] for r in rows])),
    }


def time_segmentation(frame: np.ndarray, params: SegmentParams | None = None, repeats: int = 30) -> dict:
    """Median and spread of the wall time to segment `frame` (after one warm-up run), the
    number of regions found and the detection scale used."""
    regions = len(segment_frame(frame, params))
    ts, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        segment_frame(frame, params)
        ts.append(1000 * (time.perf_counter() - t0))
        cpu.append(1000 * (time.process_time() - c0))
    # CPU time is reported too: on a shared machine wall time also counts other processes
    return {"median_ms": float(np.median(ts)), "p10_ms": float(np.percentile(ts, 10)),
            "p90_ms": float(np.percentile(ts, 90)), "cpu_median_ms": float(np.median(cpu)), "repeats": repeats,
            "frame": f"{frame.shape[1]}x{frame.shape[0]}", "regions": regions, "detection_scale": _detection_scale(
                frame, params)}


def _detection_scale(frame: np.ndarray, params: SegmentParams | None) -> int:
    """1 / the resolution `segment_frame` detects `frame` at with `params`."""
    return detection_scale(frame.shape, (params or SegmentParams()).for_frame(frame.shape))
