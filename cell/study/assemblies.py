"""The shipped assemblies: how they are built from the parts library, and how each step is verified.

`python -m cell.study.assemblies` rewrites `cell/data/assemblies/*.json` from the recipes
below and prints, for every step, the planner's grasp and the independent physical check.
A recipe places library parts side by side (`beside`: along a direction from an anchor part,
with a given gap between outlines) or on top of another part (`on`: at an offset from its
centre, standing on its top face).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from cell import parts_library as L
from cell.cellconfig import Cell, default_cell
from cell.errors import NoFeasibleGrasp
from cell.fileio import write_json_atomic
from cell.physics import check_grasp, lift_clear
from cell.scene import Assembly, Part


def assemblies_dir() -> Path:
    return Path(str(resources.files("cell") / "data" / "assemblies"))


def shipped_assembly_paths() -> list[Path]:
    return sorted(assemblies_dir().glob("*.json"))


@dataclass(frozen=True)
class Step:
    id: str
    library: str
    theta_deg: float = 0.0
    at: tuple[float, float] | None = None  # absolute centre (x, y), mm
    beside: str | None = None  # anchor id: placed along `direction_deg` from it, `gap_mm` apart
    direction_deg: float = 0.0
    gap_mm: float = 4.0
    on: str | None = None  # stands on this part's top, centre at `offset` from its centre
    offset: tuple[float, float] = (0.0, 0.0)


def build(steps: list[Step]) -> list[Part]:
    from cell.operator import place_neighbour

    parts: dict[str, Part] = {}
    for s in steps:
        lib = L.part(s.library)
        if s.on is not None:
            base = parts[s.on]
            c = np.asarray(base.polygon.centroid.coords[0]) + np.asarray(s.offset)
            p = L.place(lib, float(c[0]), float(c[1]), s.theta_deg, s.id, z_bottom_mm=base.z_top_mm)
        elif s.beside is not None:
            p = place_neighbour(parts[s.beside], lib, s.gap_mm, s.direction_deg, s.theta_deg, s.id)
        else:
            p = L.place(lib, s.at[0], s.at[1], s.theta_deg, s.id)
        parts[s.id] = p
    return list(parts.values())


def _round_part(p: Part) -> Part:
    """Coordinates rounded as they are written, so the checks see exactly the file's geometry."""
    from dataclasses import replace

    return replace(p, outline_mm=np.round(p.outline_mm, 3), holes_mm=tuple(np.round(h, 3) for h in p.holes_mm))


RECIPES: dict[str, dict] = {
    # What `cell run` disassembles: six parts lying side by side on the tray (no stacking, so
    # the camera sees every outline), gaps of 6 mm (tight for the 10 mm fingers, wide enough
    # for the camera's ~0.9 mm pixels), tall (dark grey) and flat (light grey) neighbours mixed.
    "default": dict(
        name="default: six parts side by side on the tray",
        steps=[
            Step("housing", "box_housing_m", 0.0, at=(360.0, 60.0)),
            Step("cover", "cover_rect_s", 90.0, beside="housing", direction_deg=180.0, gap_mm=6.0),
            Step("pcb", "pcb_s", 0.0, beside="housing", direction_deg=-90.0, gap_mm=6.0),
            Step("washer", "washer_m24", 0.0, beside="pcb", direction_deg=-160.0, gap_mm=6.0),
            Step("nut", "hex_nut_m16", 15.0, beside="pcb", direction_deg=-40.0, gap_mm=6.0),
            Step("pulley", "pulley_s", 0.0, beside="housing", direction_deg=0.0, gap_mm=6.0),
        ],
        sequence=["nut", "pulley", "housing", "pcb", "washer", "cover"],
    ),
    # In the spirit of the paper's Fig. 18: a small product, a base plate carrying a cover, a
    # PCB and a nut on its top, with a motor housing and a shaft beside it.
    "fig18_product": dict(
        name="fig18-like product: base plate with parts on and beside it",
        steps=[
            Step("base", "plate_holes_l", 0.0, at=(340.0, -40.0)),
            Step("pcb", "pcb_s", 0.0, on="base", offset=(-22.0, 0.0)),
            Step("nut", "hex_nut_m12", 0.0, on="base", offset=(30.0, 14.0)),
            Step("washer", "washer_m16", 0.0, on="base", offset=(30.0, -16.0)),
            Step("motor", "motor_housing_s", 90.0, beside="base", direction_deg=90.0, gap_mm=4.0),
            Step("shaft", "keyed_shaft_m", 0.0, beside="base", direction_deg=0.0, gap_mm=5.0),
        ],
        sequence=["nut", "washer", "pcb", "shaft", "motor", "base"],
    ),
    # A gear train taken apart: a gearbox housing with a pulley, washers and a clip beside it.
    "drive_unit": dict(
        name="drive unit: housing, pulley, flange, washers, clip",
        steps=[
            Step("gearbox", "gearbox_housing_m", 0.0, at=(330.0, 120.0)),
            Step("pulley", "pulley_m", 0.0, beside="gearbox", direction_deg=-90.0, gap_mm=4.0),
            Step("flange", "flange_plate_m", 0.0, beside="pulley", direction_deg=-90.0, gap_mm=3.0),
            Step("washer", "washer_m16", 0.0, beside="pulley", direction_deg=0.0, gap_mm=2.0),
            Step("clip", "spring_clip_m", 0.0, beside="washer", direction_deg=-60.0, gap_mm=6.0),
            Step("cover", "cover_ears_m", 90.0, beside="flange", direction_deg=180.0, gap_mm=4.0),
        ],
        sequence=["washer", "clip", "gearbox", "pulley", "flange", "cover"],
    ),
}


def make_assembly(key: str) -> Assembly:
    r = RECIPES[key]
    parts = tuple(_round_part(p) for p in build(r["steps"]))
    return Assembly(parts, tuple(r["sequence"]), r["name"], None, f"{key}.json")


def write_all(out_dir: Path | None = None) -> list[Path]:
    out_dir = out_dir or assemblies_dir()
    paths = []
    for key in RECIPES:
        a = make_assembly(key)
        path = Path(out_dir) / f"{key}.json"
        write_json_atomic(path, a.to_json())
        path.chmod(0o644)
        paths.append(path)
    return paths


@dataclass(frozen=True)
class StepReport:
    step: int
    target: str
    ok: bool
    reasons: tuple[str, ...]
    contacts_mm: np.ndarray | None = None
    axis_deg: float | None = None
    dark: tuple[str, ...] = ()  # neighbours taller than the grasp z (the paper's dark grey)
    light: tuple[str, ...] = ()  # neighbours lower than the grasp z (light grey)


def verify(assembly: Assembly, planner, cell: Cell | None = None) -> list[StepReport]:
    """Plan every step with `planner` and check it independently: physics and lift."""
    cell = cell or default_cell()
    out = []
    for k in range(len(assembly.sequence)):
        scene = assembly.scene_at(k)
        target = scene.target_part
        try:
            g = planner.plan(scene).grasp
        except NoFeasibleGrasp as e:
            out.append(StepReport(k, target.id, False, (f"planner: {e.reason}",)))
            continue
        chk = check_grasp(target, g.contacts_mm, g.axis_deg, g.grasp_z_mm, scene.obstacles, cell)
        lift = lift_clear(target, scene.obstacles, g.contacts_mm, g.grasp_z_mm, cell)
        near = [o for o in scene.obstacles if o.polygon.distance(target.polygon) < 20]
        dark = tuple(o.id for o in near if o.z_top_mm > g.grasp_z_mm)
        light = tuple(o.id for o in near if o.z_top_mm <= g.grasp_z_mm)
        out.append(StepReport(k, target.id, chk.ok and lift.ok, chk.reasons + lift.reasons, g.contacts_mm,
                              g.axis_deg, dark, light))
    return out


def gaps_mm(assembly: Assembly) -> list[tuple[str, str, float]]:
    """Plan-view gaps between neighbouring parts lying side by side (not stacked), < 20 mm."""
    out = []
    ps = assembly.parts
    for i, a in enumerate(ps):
        for b in ps[i + 1:]:
            stacked = a.z_bottom_mm >= b.z_top_mm - 1e-9 or b.z_bottom_mm >= a.z_top_mm - 1e-9
            d = a.polygon.distance(b.polygon)
            if not stacked and d < 20:
                out.append((a.id, b.id, d))
    return out


def main() -> None:
    from cell.examples import load_examples
    from cell.grasp.synthesis import GraspPlanner

    paths = write_all()
    planner = GraspPlanner(default_cell(), load_examples())
    from cell.scene import load_assembly

    for path in paths:
        a = load_assembly(path)
        print(f"{path.name}: {a.name}")
        for g in gaps_mm(a):
            print(f"  gap {g[0]}-{g[1]}: {g[2]:.1f} mm")
        for r in verify(a, planner):
            ang = "" if r.axis_deg is None else f"axis {r.axis_deg:6.1f}"
            print(f"  step {r.step} {r.target:8s} {'ok ' if r.ok else 'BAD'} {ang} dark={list(r.dark)} "
                  f"light={list(r.light)} {'; '.join(r.reasons)}")


if __name__ == "__main__":
    main()
