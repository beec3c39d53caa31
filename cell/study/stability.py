"""How physically sound are the planner's grasps? (`cell bench stability`, the generalisation test)

Every library part is presented standalone at `poses` random poses in the tray; the planner
(trained on some examples) picks a grasp; `cell.physics.check_grasp` judges it. Two figures:

* planned share: poses where the planner found a grasp at all;
* stable share: of those, the grasps that pass the physical check (jaws close on the part
  where reported, no collision, centre of gravity near the jaw line, friction cone, not both
  pads on sharp corners, opening within the stroke).

Leave-families-out: for each family, the planner learns from the examples of the *other*
families only and plans for the parts of the left-out family (parts it has never seen).
Clutter: every part with one or two random neighbours 3..15 mm away (collisions count).
Simple shapes: squares, rectangles, regular polygons, discs and L-shapes that are not in the
library (`simple_shapes`), in every size between a small nut and a large cover, so that an
attribute or a learned rule that only holds for the library's shapes shows.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cell import parts_library as L
from cell.cellconfig import Cell, default_cell
from cell.errors import NoFeasibleGrasp
from cell.examples import GraspExample
from cell.operator import random_pose
from cell.physics import check_grasp
from cell.scene import Part, Scene


@dataclass
class StabilityTally:
    presented: int = 0
    planned: int = 0
    stable: int = 0
    failures: list = field(default_factory=list)  # (part id, reasons) of planned but unstable grasps
    no_grasp: list = field(default_factory=list)  # (part id, planner's reason)
    plan_ms: list = field(default_factory=list)

    def add(self, other: StabilityTally) -> None:
        self.presented += other.presented
        self.planned += other.planned
        self.stable += other.stable
        self.failures += other.failures
        self.no_grasp += other.no_grasp
        self.plan_ms += other.plan_ms

    @property
    def planned_share(self) -> float:
        return self.planned / self.presented if self.presented else float("nan")

    @property
    def stable_share(self) -> float:
        return self.stable / self.planned if self.planned else float("nan")


def simple_shapes(height_mm: float = 10.0) -> list[Part]:
    """Plain prisms centred at the origin (ids say what they are): squares of every side 6-40 mm,
    rectangles of 4 widths x 4 aspect ratios, regular 3-, 5-, 6- and 8-gons and discs of 5-30 mm
    circumradius, three L-shapes."""
    def centred(xy) -> np.ndarray:
        xy = np.asarray(xy, float)
        return xy - xy.mean(axis=0)

    shapes: dict[str, np.ndarray] = {}
    for side in range(6, 41):
        h = side / 2
        shapes[f"square_{side}"] = centred([[-h, -h], [h, -h], [h, h], [-h, h]])
    for w in (6, 9, 13, 17, 21, 26):
        for aspect in (1.2, 1.6, 2.5, 4.0):
            a, b = w / 2, w * aspect / 2
            shapes[f"rect_{w}x{w * aspect:g}"] = centred([[-a, -b], [a, -b], [a, b], [-a, b]])
    for n in (3, 5, 6, 8, 64):
        for r in (5, 7, 9, 11, 13, 16, 20, 25, 30):
            ang = np.arange(n) * 2 * np.pi / n
            shapes[f"{'disc' if n == 64 else f'{n}-gon'}_r{r}"] = r * np.column_stack([np.cos(ang), np.sin(ang)])
    for a, b, t in ((30, 20, 8), (50, 40, 10), (20, 20, 6)):
        shapes[f"ell_{a}x{b}x{t}"] = centred([[0, 0], [a, 0], [a, t], [t, t], [t, b], [0, b]])
    return [Part(name, xy, z_bottom_mm=0.0, z_top_mm=height_mm) for name, xy in shapes.items()]


def holed_shapes(height_mm: float = 8.0) -> list[Part]:
    """Rings (washers, bearing rings) 16-70 mm across with a hole of 0.3-0.8 of that, and square plates
    20-60 mm with a round hole of 0.3 or 0.6 of their side, centred at the origin."""
    def circle(r: float, clockwise: bool = False) -> np.ndarray:
        a = np.arange(64) * (-1 if clockwise else 1) * 2 * np.pi / 64
        return r * np.column_stack([np.cos(a), np.sin(a)])

    out = []
    for outer in (8, 12, 16, 20, 25, 30, 35):
        for k in (0.3, 0.5, 0.65, 0.8):
            out.append(Part(f"ring_{2 * outer}x{2 * outer * k:g}", circle(outer), (circle(outer * k, True),),
                            z_bottom_mm=0.0, z_top_mm=height_mm))
    for side in (20, 30, 40, 50, 60):
        h = side / 2
        for k in (0.3, 0.6):
            out.append(Part(f"plate_{side}_hole{side * k:g}", np.array([[-h, -h], [h, -h], [h, h], [-h, h]], float),
                            (circle(h * k, True),), z_bottom_mm=0.0, z_top_mm=5.0))
    return out


def gear_shapes() -> list[Part]:
    """Steel spur gears not in the library: modules 0.8-3 mm with 14-50 teeth, the ones within the
    stroke (tip diameter at most 70 mm), each with a keyed bore as the library's; ids name module and
    teeth."""
    out = []
    for module in (0.8, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0):
        for teeth in (14, 20, 30, 40, 50):
            tip_d = module * (teeth + 2)
            if tip_d <= 70.0:
                out.append(L.spur_gear(f"m{module:g}z{teeth}", teeth, tip_d, max(6.0, round(4 * module))))
    return out


def star_shapes(height_mm: float = 8.0) -> list[Part]:
    """Stars (knobs, lobed heads, cams) centred at the origin: 4, 5, 6 and 8 points, tips 12, 20 and 30 mm from
    the centre, notches at 0.4, 0.6 and 0.8 of that."""
    out = []
    for n in (4, 5, 6, 8):
        for r_out in (12.0, 20.0, 30.0):
            for k in (0.4, 0.6, 0.8):
                a = np.arange(2 * n) * np.pi / n
                r = np.where(np.arange(2 * n) % 2 == 0, r_out, k * r_out)
                out.append(Part(f"star{n}_r{r_out:g}_k{k:g}", np.column_stack([r * np.cos(a), r * np.sin(a)]),
                                z_bottom_mm=0.0, z_top_mm=height_mm))
    return out


def presentations(parts: list[Part], poses: int, seed: int, cell: Cell) -> list[Part]:
    """Each part at `poses` random poses inside the tray (deterministic for a seed)."""
    rng = np.random.default_rng(seed)
    out = []
    for p in parts:
        for _ in range(poses):
            x, y, th = random_pose(p, cell, rng)
            out.append(L.place(p, x, y, th))
    return out


def cluttered(parts: list[Part], seed: int, cell: Cell) -> list[tuple[Part, tuple[Part, ...]]]:
    """Each (placed) part with one or two random library neighbours 3..15 mm away, inside the tray."""
    from cell.operator import random_neighbours

    rng = np.random.default_rng(seed + 100)
    lib = L.parts()
    return [(p, tuple(random_neighbours(p, lib, rng, cell))) for p in parts]


def evaluate(planner, parts, cell: Cell | None = None) -> StabilityTally:
    """Plan each placed part (standalone, or a (part, obstacles) pair) and check the grasp physically."""
    cell = cell or default_cell()
    t = StabilityTally()
    for item in parts:
        part, obstacles = item if isinstance(item, tuple) else (item, ())
        t.presented += 1
        try:
            res = planner.plan(Scene((part, *obstacles), part.id))
        except NoFeasibleGrasp as e:
            t.no_grasp.append((part.id, e.reason))
            continue
        t.planned += 1
        t.plan_ms.append(res.time_ms)
        g = res.grasp
        v = check_grasp(part, g.contacts_mm, g.axis_deg, g.grasp_z_mm, obstacles, cell)
        if v.ok:
            t.stable += 1
        else:
            t.failures.append((part.id, v.reasons))
    return t


def make_planner(examples: list[GraspExample], cell: Cell, params=None):
    from cell.grasp.synthesis import GraspPlanner

    return GraspPlanner(cell, examples, params)


def leave_families_out(examples: list[GraspExample], poses: int = 2, seed: int = 0, cell: Cell | None = None,
                       families: list[str] | None = None,
                       progress: Callable[[str], None] | None = None, params=None) -> dict[str, StabilityTally]:
    """Per family: plan its parts with a planner trained without that family's examples."""
    cell = cell or default_cell()
    out: dict[str, StabilityTally] = {}
    for fam in families or L.list_families():
        train = [e for e in examples if e.part.meta.get("family") != fam]
        planner = make_planner(train, cell, params)
        out[fam] = evaluate(planner, presentations(L.parts([fam]), poses, seed, cell), cell)
        if progress:
            t = out[fam]
            progress(f"{fam}: {t.stable}/{t.planned} stable, {t.planned}/{t.presented} planned "
                     f"({len(examples) - len(train)} examples held out)")
    return out


def random_baseline(parts: list[Part], seed: int = 0, cell: Cell | None = None) -> StabilityTally:
    """What the check says about grasps chosen without judgement: two random outline points
    within the stroke (the yardstick that shows the check discriminates)."""
    cell = cell or default_cell()
    rng = np.random.default_rng(seed)
    stroke = cell.gripper.opening_mm[1] - 2 * cell.gripper.approach_clearance_mm
    t = StabilityTally()
    for part in parts:
        ring = part.polygon.exterior
        for _ in range(200):
            c = np.array([ring.interpolate(s).coords[0] for s in rng.uniform(0, ring.length, 2)])
            if 1.0 < np.linalg.norm(c[1] - c[0]) <= stroke:
                break
        else:
            continue
        t.presented += 1
        t.planned += 1
        v = check_grasp(part, c, None, None, (), cell)
        t.stable += v.ok
        if not v.ok:
            t.failures.append((part.id, v.reasons))
    return t
