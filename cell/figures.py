"""Per-step pictures like the paper's Figs. 20-23 (matplotlib, written to PNG).

Three panels: (a) the valid contact points, (b) the valid contact sets, (c) the selected
set with the fingers' and the palm's footprints. The parts still present are shaded by
height: dark grey where taller than the grasp z (the fingers would collide), light grey
where lower (passed over).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import PathPatch  # noqa: E402
from matplotlib.path import Path as MplPath  # noqa: E402

from cell.cellconfig import Cell  # noqa: E402
from cell.grasp.footprints import finger_footprints, palm_footprint, swept_finger_footprints  # noqa: E402

DARK, LIGHT, TARGET = "#5a5a5a", "#cfcfcf", "#f2d29b"


def _patch(poly, **kw):
    rings = [poly.exterior, *poly.interiors]
    verts, codes = [], []
    for r in rings:
        xy = list(r.coords)
        verts += xy
        codes += [MplPath.MOVETO] + [MplPath.LINETO] * (len(xy) - 2) + [MplPath.CLOSEPOLY]
    return PathPatch(MplPath(verts, codes), **kw)


def _scene(ax, step_plan, grasp_z_mm):
    scene = step_plan.scene
    for p in scene.obstacles:
        dark = p.z_top_mm > grasp_z_mm
        ax.add_patch(_patch(p.polygon, facecolor=DARK if dark else LIGHT, edgecolor="black", lw=0.4))
    ax.add_patch(_patch(scene.target_part.polygon, facecolor=TARGET, edgecolor="black", lw=0.8))


def _frame(ax, step_plan, margin_mm=45.0):
    minx, miny, maxx, maxy = step_plan.scene.target_part.polygon.bounds
    ax.set_xlim(minx - margin_mm, maxx + margin_mm)
    ax.set_ylim(miny - margin_mm, maxy + margin_mm)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)


def step_figure(step_plan, cell: Cell, path: str | Path) -> Path:
    """Write the step's three-panel figure to `path` (PNG) and return the path."""
    path = Path(path)
    r = step_plan.result
    scene = step_plan.scene
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6), dpi=110)
    if r is None:
        gz = scene.target_part.z_top_mm
        for ax in axes:
            _scene(ax, step_plan, gz)
            _frame(ax, step_plan)
        fig.suptitle(f"step {step_plan.step}: {scene.target} - no grasp: {step_plan.reason}", fontsize=9,
                     parse_math=False)  # a part id is free text: "$x^$" is no TeX to parse
    else:
        g = r.grasp
        for ax in axes:
            _scene(ax, step_plan, g.grasp_z_mm)
            _frame(ax, step_plan)
        vp = r.valid_points.points
        cand = r.candidates.points
        axes[0].plot(cand[:, 0], cand[:, 1], ".", ms=2, color="#b03030", label="rejected by tree 1")
        axes[0].plot(vp[:, 0], vp[:, 1], ".", ms=3.5, color="#1060c0", label="valid points")
        axes[0].set_title(f"(a) valid contact points: {len(vp)} of {len(cand)}", fontsize=9)
        axes[0].legend(fontsize=6, loc="upper right")
        sets = r.valid_sets
        for s in sets[:400]:
            axes[1].plot(s[:, 0], s[:, 1], "-", lw=0.4, color="#1060c0", alpha=0.5)
        axes[1].set_title(f"(b) valid sets: {len(sets)} of {r.counts['reachable']} reachable", fontsize=9)
        for f in swept_finger_footprints(g, cell):
            axes[2].add_patch(_patch(f, facecolor="none", edgecolor="#2a8a2a", lw=0.6, ls="--"))
        for f in finger_footprints(g, cell):
            axes[2].add_patch(_patch(f, facecolor="#2a8a2a", alpha=0.7, edgecolor="black", lw=0.6))
        axes[2].add_patch(_patch(palm_footprint(g, cell), facecolor="none", edgecolor="#8a2a8a", lw=0.8))
        c = g.contacts_mm
        axes[2].plot(c[:, 0], c[:, 1], "o-", color="#d01010", ms=4, lw=1)
        q = g.joints
        axes[2].set_title(f"(c) grasp: opening {g.opening_mm:.1f} mm, axis {g.axis_deg:.1f} deg, z {g.grasp_z_mm:.1f}"
                          + (f", elbow {q.elbow}" if q else ""), fontsize=9)
        fig.suptitle(f"step {step_plan.step}: {scene.target}  (dark grey: taller than the grasp z; "
                     "light grey: lower, passed over)", fontsize=9, parse_math=False)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
