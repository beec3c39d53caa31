"""Scenes and assemblies (CONTRACT.md): parts as 2D outlines with heights, base frame, mm.

`load_scene` / `load_assembly` read and validate the JSON files; every problem is a
`BadInput` that names the file, the part and what is wrong. Outlines are normalised
to counter-clockwise outer contours and clockwise holes (shapely's orient), so the
outward normal of every edge is its direction turned right by 90 degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.validation import explain_validity

from cell.errors import BadInput
from cell.fileio import is_finite_number, read_json, short_repr
from cell.materials import check_mass_keys

UP = (0.0, 0.0, 1.0)
# Outline coordinates beyond 1 km from the base are not millimetres of a part on the tray (and a
# target that large would be resampled into millions of candidate points): bad input.
MAX_COORD_MM = 1e6
# A part rests on another when its bottom is within this of the other's top (heights are rounded)
REST_MM = 0.5
TABLE_TOL_MM = 1e-6  # a z_bottom this little under the table (float noise: -1e-9 was refused) is on it
# Parts of an assembly touch: a shared edge overlaps by float noise and the 4 decimals files are written with
PART_OVERLAP_MM2 = 1.0


@dataclass(frozen=True, eq=False)
class Part:
    """One part seen from above: outline and holes in mm (base frame), heights in mm."""

    id: str
    outline_mm: np.ndarray  # (n, 2), counter-clockwise
    holes_mm: tuple[np.ndarray, ...] = ()  # each (m, 2), clockwise
    z_bottom_mm: float = 0.0
    z_top_mm: float = 10.0
    direction: tuple[float, float, float] = UP
    meta: dict = field(default_factory=dict)  # free keys kept from the file (family, size ...)

    def __post_init__(self):
        # The planner's outward normals and attributes take the outline counter-clockwise and the holes
        # clockwise; scene files and the library are normalised, a Part built in Python may not be (a
        # clockwise square was planned with its normals pointing inwards).
        if _turn(self.outline_mm) < 0:
            object.__setattr__(self, "outline_mm", np.asarray(self.outline_mm, float)[::-1].copy())
        turned = [_turn(h) > 0 for h in self.holes_mm]
        if any(turned):
            object.__setattr__(self, "holes_mm", tuple(np.asarray(h, float)[::-1].copy() if t else h
                                                       for h, t in zip(self.holes_mm, turned, strict=True)))

    @cached_property
    def polygon(self) -> Polygon:
        return Polygon(self.outline_mm, [h for h in self.holes_mm])

    @property
    def height_mm(self) -> float:
        return self.z_top_mm - self.z_bottom_mm

    def lies_on(self, other: Part) -> bool:
        """Does this part rest on `other`: its bottom on the other's top (within 0.5 mm) and its
        outline (nine tenths of it) over the other's in plan? A part on a base plate moves with
        the plate, and does not stand out against the tray on its own."""
        return (self.id != other.id and abs(self.z_bottom_mm - other.z_top_mm) <= REST_MM
                and self.polygon.intersection(other.polygon).area > 0.9 * self.polygon.area)

    def moved(self, dx_mm: float, dy_mm: float, dtheta_deg: float = 0.0, about=None) -> Part:
        """The same part rotated by dtheta about `about` (default: its centroid), then shifted."""
        c = np.asarray(about if about is not None else self.polygon.centroid.coords[0], float)
        t = math.radians(dtheta_deg)
        rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])

        def tf(p):
            return (p - c) @ rot.T + c + (dx_mm, dy_mm)

        return Part(self.id, tf(self.outline_mm), tuple(tf(h) for h in self.holes_mm),
                    self.z_bottom_mm, self.z_top_mm, self.direction, dict(self.meta))

    def to_json(self) -> dict:
        d = {"id": self.id, "outline": np.round(self.outline_mm, 4).tolist(),
             "z_bottom": self.z_bottom_mm, "z_top": self.z_top_mm}
        if self.holes_mm:
            d["holes"] = [np.round(h, 4).tolist() for h in self.holes_mm]
        if tuple(self.direction) != UP:
            d["direction"] = list(self.direction)
        d.update({k: v for k, v in self.meta.items() if k not in d})
        return d


@dataclass(frozen=True, eq=False)
class Scene:
    parts: tuple[Part, ...]
    target: str | None = None
    cell_path: str | None = None
    source: str = "<scene>"

    def part(self, part_id: str) -> Part:
        for p in self.parts:
            if p.id == part_id:
                return p
        raise BadInput(f"{self.source}: no part {part_id!r} in the scene (parts: {', '.join(self.ids)})")

    @property
    def ids(self) -> list[str]:
        return [p.id for p in self.parts]

    @property
    def target_part(self) -> Part:
        if self.target is None:
            raise BadInput(f"{self.source}: the scene names no 'target'")
        return self.part(self.target)

    @property
    def obstacles(self) -> tuple[Part, ...]:
        return tuple(p for p in self.parts if p.id != self.target)

    def without(self, part_id: str) -> Scene:
        return Scene(tuple(p for p in self.parts if p.id != part_id), None, self.cell_path, self.source)

    def with_target(self, part_id: str) -> Scene:
        self.part(part_id)
        return Scene(self.parts, part_id, self.cell_path, self.source)

    def to_json(self) -> dict:
        d = {"units": "mm", "parts": [p.to_json() for p in self.parts]}
        if self.target is not None:
            d["target"] = self.target
        if self.cell_path:
            d["cell"] = self.cell_path
        return d


@dataclass(frozen=True, eq=False)
class Assembly:
    parts: tuple[Part, ...]
    sequence: tuple[str, ...]
    name: str = "assembly"
    cell_path: str | None = None
    source: str = "<assembly>"

    def scene_at(self, step: int) -> Scene:
        """The scene of step `step`: the parts not yet removed, the step's part as target."""
        removed = set(self.sequence[:step])
        parts = tuple(p for p in self.parts if p.id not in removed)
        return Scene(parts, self.sequence[step], self.cell_path, f"{self.source} step {step}")

    def to_json(self) -> dict:
        d = {"units": "mm", "name": self.name, "parts": [p.to_json() for p in self.parts],
             "sequence": list(self.sequence)}
        if self.cell_path:
            d["cell"] = self.cell_path
        return d


def load_scene(path: str | Path) -> Scene:
    if str(path) == "":  # Path("") is the current folder: "scene file . is a directory" said nothing useful
        raise BadInput("scene file name is empty: give a path")
    raw = read_json(path, "scene file")
    return parse_scene(raw, str(path), base_dir=Path(path).parent)


def load_assembly(path: str | Path) -> Assembly:
    raw = read_json(path, "assembly file")
    return parse_assembly(raw, str(path), base_dir=Path(path).parent)


def parse_scene(raw, source: str = "<scene>", base_dir: Path | None = None) -> Scene:
    parts, cell_path = _parse_common(raw, source, base_dir)
    target = raw.get("target")
    if target is None:
        also = ("; this looks like an assembly file (it has a 'sequence'): `cell plan` takes assembly files"
                if "sequence" in raw else "")
        raise BadInput(f"{source}: the scene has no 'target' (the id of the part to grasp){also}")
    if not isinstance(target, str):
        raise BadInput(f"{source}: 'target' must be a part id string, got {short_repr(target)}")
    scene = Scene(parts, target, cell_path, source)
    _require_straight_up(scene.part(target), source)  # a target that is not in the scene is bad input too
    return scene


def _require_straight_up(p: Part, source: str) -> None:
    """The 2D normal grasp lifts a part straight up: any other disassembly direction is bad input."""
    d = np.asarray(p.direction, float)
    top = float(np.abs(d).max())
    d = d / top if top > 0 else d  # first to its largest component: 1e308 or 1e-300 squared is no float
    n = float(np.linalg.norm(d))
    if not (n > 0 and np.allclose(d / n, UP)):  # a direction, not a length: [0, 0, 2] is up too
        raise BadInput(
            f"{source}: part {p.id!r} has disassembly direction {list(p.direction)}; the 2D normal "
            "grasp supports only straight up [0, 0, 1]")


def parse_assembly(raw, source: str = "<assembly>", base_dir: Path | None = None) -> Assembly:
    parts, cell_path = _parse_common(raw, source, base_dir)
    seq = raw.get("sequence")
    if seq is None and "target" in raw:  # `cell plan scene.json`
        raise BadInput(f"{source}: no 'sequence' (the order the parts are removed in): this looks like a scene "
                       "file (it names a 'target'); `cell grasp` takes scene files")
    if not isinstance(seq, list) or not all(isinstance(s, str) for s in seq):
        raise BadInput(f"{source}: 'sequence' must be a list of part ids")
    ids = [p.id for p in parts]
    unknown = [s for s in seq if s not in ids]
    if unknown:
        raise BadInput(f"{source}: sequence names parts that are not in the assembly: {', '.join(unknown)}")
    if sorted(seq) != sorted(ids):
        missing = sorted(set(ids) - set(seq))
        dup = sorted({s for s in seq if seq.count(s) > 1})
        why = (f"missing {', '.join(missing)}" if missing else "") + ("; " if missing and dup else "") + (
            f"repeated {', '.join(dup)}" if dup else "")
        raise BadInput(f"{source}: the sequence must name every part exactly once ({why})")
    for p in parts:
        _require_straight_up(p, source)
    _no_two_parts_in_one_place(parts, source)
    return Assembly(parts, tuple(seq), str(raw.get("name", Path(source).stem)), cell_path, source)


def _no_two_parts_in_one_place(parts: tuple[Part, ...], source: str) -> None:
    """Refuse two parts of an assembly that overlap in plan and in height (one lying on another, on a base
    plate, or in another's hole is fine): such an assembly was run, and stopped half way (exit 1) when the
    camera saw one part where the model has two."""
    polygons = [p.polygon for p in parts]
    near = shapely.STRtree(polygons).query(polygons, predicate="intersects")
    for i, j in sorted(zip(*near.tolist(), strict=True)):
        a, b = parts[i], parts[j]
        height = min(a.z_top_mm, b.z_top_mm) - max(a.z_bottom_mm, b.z_bottom_mm)
        if i < j and height > REST_MM:
            area = polygons[i].intersection(polygons[j]).area
            if area > PART_OVERLAP_MM2:
                raise BadInput(f"{source}: parts {a.id!r} and {b.id!r} are in one place: their outlines overlap by "
                               f"{area:.1f} mm2 and their heights by {height:g} mm")


def _parse_common(raw, source, base_dir):
    if not isinstance(raw, dict):
        raise BadInput(f"{source}: top level must be a JSON object")
    units = raw.get("units", "mm")
    if units != "mm":
        raise BadInput(f"{source}: 'units' must be 'mm', got {short_repr(units)}")
    raw_parts = raw.get("parts")
    if not isinstance(raw_parts, list) or not raw_parts:
        raise BadInput(f"{source}: 'parts' must be a non-empty list")
    parts = tuple(parse_part(p, f"{source}: part #{i}") for i, p in enumerate(raw_parts))
    ids = [p.id for p in parts]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise BadInput(f"{source}: duplicate part ids: {', '.join(dup)}")
    return parts, own_cell_path(raw, source, base_dir)


def own_cell_path(raw: dict, source: str, base_dir: Path | None) -> str | None:
    """A scene's or assembly's own "cell" file, relative to the file's folder `base_dir`; None: none."""
    cell_path = raw.get("cell")
    if cell_path is not None:
        if not isinstance(cell_path, str) or not cell_path.strip():  # "" named the scene's own folder
            raise BadInput(f"{source}: 'cell' must be a path string, got {short_repr(cell_path)}")
        # relative to the file's folder only: a fallback to the working directory (tried) took an unrelated cell
        # file, limits and tray, without a word where the one beside the scene was misspelt
        if base_dir is not None and not Path(cell_path).is_absolute():
            cell_path = str(base_dir / cell_path)
    return cell_path


def _turn(ring) -> int:
    """1 where the ring (n, 2) runs counter-clockwise, -1 clockwise, 0 for fewer than 3 points."""
    ring = np.asarray(ring, float)
    return 0 if len(ring) < 3 else 1 if shapely.is_ccw(shapely.linearrings(ring)) else -1


def parse_part(raw, where: str = "part") -> Part:
    if not isinstance(raw, dict):
        raise BadInput(f"{where}: must be a JSON object")
    pid = raw.get("id")
    if not isinstance(pid, str) or not pid:
        raise BadInput(f"{where}: 'id' must be a non-empty string")
    where = f"{where.rsplit(':', 1)[0]}: part {pid!r}"
    outline = _ring(raw.get("outline"), f"{where} outline")
    holes_raw = raw.get("holes")
    holes_raw = [] if holes_raw is None else holes_raw  # (null: none, as an absent key)
    if not isinstance(holes_raw, list) or any(_is_point(h) for h in holes_raw):
        raise BadInput(f"{where}: 'holes' must be a list of rings, each a list of [x, y] points: "
                       "[[[x, y], [x, y], [x, y], ...], ...] (one hole too is in a list of its own)")
    holes = [_ring(h, f"{where} hole #{i}") for i, h in enumerate(holes_raw)]
    if "z_top" not in raw:  # (z_bottom defaults to the table)
        raise BadInput(f"{where}: 'z_top' is missing (the height of the part's top, mm)")
    zb, zt = _num(raw.get("z_bottom", 0.0), f"{where} z_bottom"), _num(raw["z_top"], f"{where} z_top")
    if max(abs(zb), abs(zt)) > MAX_COORD_MM:  # as for the outline: not mm of a part on the tray
        raise BadInput(f"{where}: z_bottom and z_top must be within {MAX_COORD_MM:g} mm of the table "
                       f"(got {max(abs(zb), abs(zt)):g}; the units are mm)")
    if -TABLE_TOL_MM <= zb < 0:  # float noise of a measured or converted height: on the table (first: a top
        zb = 0.0  # just under the table must not pass the check below against a bottom still under it)
    if zt <= zb:
        raise BadInput(f"{where}: z_top ({zt}) must be above z_bottom ({zb})")
    if zb < 0:  # CONTRACT: the table surface is z = 0; nothing lies below it
        raise BadInput(f"{where}: z_bottom ({zb}) is below the table (z = 0 mm in the base frame)")
    direction = raw.get("direction", list(UP))
    if not (isinstance(direction, list) and len(direction) == 3):
        raise BadInput(f"{where}: 'direction' must be [dx, dy, dz]")
    direction = tuple(_num(d, f"{where} direction") for d in direction)
    check_mass_keys(raw, where)  # "mass_g" and "material", free keys the physical check weighs the part by
    if holes:  # a hole around, across or along the outline is no hole in it
        _holes_inside(outline, holes, where)
    poly = Polygon(outline, holes)
    if not poly.is_valid:
        _no_overlapping_holes(holes, where)
        poly = _repaired(poly, outline, holes, where)
    if poly.area <= 0:
        raise BadInput(f"{where}: the outline has no area")
    poly = shapely.geometry.polygon.orient(poly, 1.0)  # outer CCW, holes CW
    outer = np.asarray(poly.exterior.coords, float)[:-1]
    inner = tuple(np.asarray(r.coords, float)[:-1] for r in poly.interiors)
    meta = {k: v for k, v in raw.items() if k not in ("id", "outline", "holes", "z_bottom", "z_top", "direction")}
    _refuse_non_finite(meta, where)
    return Part(pid, outer, inner, zb, zt, direction, meta)


# A camera contour (a thousand vertices or more, a few hundredths of a mm of noise) often crosses
# itself in tiny loops. Such an outline is repaired, not refused, when the repair is negligible:
# every piece of area it drops (a loop cut off, a pinhole made by a loop turning inward) is
# smaller than REPAIR_PIECE_MM2 and all of them together less than REPAIR_SHARE of the area. A
# bow tie, a figure eight or a hole outside the outline changes more than that: still refused.
# The repaired part is also compared with the material the file describes (each ring's own area:
# the outline's less the holes'): every piece the repair drops or adds must be within the same
# bounds. make_valid reads a hole lying along the outline as a line, and gave the bare outline.
REPAIR_PIECE_MM2 = 1.0
REPAIR_SHARE = 0.01


HOLE_OVERLAP_MM2 = 1e-6  # holes sharing an edge overlap by float noise (1e-14 mm2) once turned
# A hole may reach this far out of the outline (a vertex on it, rounded to the 4 decimals files
# are written with, lies up to 5e-5 mm out); the polygon is then repaired like any other
HOLE_OUTSIDE_TOL_MM = 1e-3
# A hole whose edges run this long within HOLE_OUTSIDE_TOL_MM of the outline is a notch drawn as a
# hole: refused at every turn (the outline's edge over it would be a wall of no width, or gone).
# A hole touching the outline at a point has a few thousandths of a mm of its edges there.
HOLE_ALONG_OUTLINE_MM = 0.1
NOTCH = ("a hole must lie inside the outline: draw a notch or a slot open to the outside as part of the "
         "outline")


def _region(ring: np.ndarray):
    """The area a ring encloses by itself: its polygon or, for a ring crossing itself, the
    polygonal pieces shapely's make_valid makes of that ring alone."""
    p = Polygon(ring)
    return p if p.is_valid else shapely.union_all(_polygons(shapely.make_valid(p)))


def _polygons(geom) -> list[Polygon]:
    """The polygons in a geometry (lines and points have no area)."""
    polygonal = [g for g in shapely.get_parts(geom) if g.geom_type in ("Polygon", "MultiPolygon")]
    return [g for g in shapely.get_parts(polygonal) if g.area > 0]


def _holes_inside(outline: np.ndarray, holes: list[np.ndarray], where: str) -> None:
    """Refuse a hole around, across or along the outline: it is no hole in the part."""
    shell = _region(outline)
    wider = shell.buffer(HOLE_OUTSIDE_TOL_MM)
    edge = shell.boundary.buffer(HOLE_OUTSIDE_TOL_MM)
    for i, h in enumerate(holes):
        hole = _region(h)
        if hole.is_empty:  # a ring of no area (a spike): the polygon's repair drops it, as before
            continue
        if not wider.contains(hole):
            if hole.buffer(HOLE_OUTSIDE_TOL_MM).contains(shell):
                raise BadInput(f"{where} hole #{i}: lies outside the outline (all around it; holes must be inside it)")
            if shell.intersection(hole).area > HOLE_OVERLAP_MM2:
                raise BadInput(f"{where} hole #{i}: lies outside the outline in part: it crosses the outline; {NOTCH}")
            raise BadInput(f"{where} hole #{i}: lies outside the outline (holes must be inside it)")
        if hole.area >= shell.area - HOLE_OVERLAP_MM2:
            raise BadInput(f"{where} hole #{i}: covers the whole outline (the part would have no material)")
        along = hole.boundary.intersection(edge).length
        if along > HOLE_ALONG_OUTLINE_MM:
            raise BadInput(f"{where} hole #{i}: touches the outline along an edge ({along:.4g} mm of its edges lie "
                           f"on the outline); {NOTCH}")


def _no_overlapping_holes(holes: list[np.ndarray], where: str) -> None:
    """Refuse holes that overlap or lie in one another: the material between them is not defined
    (a repair read it as hole or as an island depending on how the part was turned)."""
    rings = [Polygon(h) for h in holes]
    rings = [r if r.is_valid else shapely.make_valid(r) for r in rings]
    if len(rings) < 2:
        return
    tree = shapely.STRtree(rings)
    for i, j in zip(*tree.query(rings, predicate="intersects"), strict=True):
        both = rings[i].intersection(rings[j]) if i < j else None
        # an overlap no wider than HOLE_OUTSIDE_TOL_MM (area over half its perimeter) is a shared edge
        # written with 4 decimals: 1e-4 mm2 along 10 mm once turned
        if both is not None and both.area > HOLE_OVERLAP_MM2 and 2 * both.area / both.length > HOLE_OUTSIDE_TOL_MM:
            raise BadInput(f"{where}: holes #{i} and #{j} overlap (holes must be apart; draw one hole for both)")


def _repaired(poly: Polygon, outline: np.ndarray, holes: list[np.ndarray], where: str) -> Polygon:
    why = explain_validity(poly)
    pieces = _polygons(shapely.make_valid(poly))
    if pieces:
        keep = max(pieces, key=lambda g: g.area)
        pinholes = [r for r in keep.interiors if Polygon(r).area < REPAIR_PIECE_MM2]
        dropped = [g.area for g in pieces if g is not keep] + [Polygon(r).area for r in pinholes]
        repaired = Polygon(keep.exterior, [r for r in keep.interiors if Polygon(r).area >= REPAIR_PIECE_MM2])
        if (repaired.is_valid and all(a < REPAIR_PIECE_MM2 for a in dropped)
                and sum(dropped) < REPAIR_SHARE * repaired.area):
            _same_material(repaired, outline, holes, why, where)
            return repaired
    raise BadInput(f"{where}: the outline is not a valid polygon ({why})")


def _same_material(repaired: Polygon, outline: np.ndarray, holes: list[np.ndarray], why: str, where: str) -> None:
    """Refuse a repair that drops or adds more material than REPAIR_PIECE_MM2 and REPAIR_SHARE allow,
    measured against the file's own rings: the outline's area less the holes' (their sum and the
    region they leave), not against what make_valid made of them together."""
    shell = _region(outline)
    cuts = [_region(h) for h in holes]
    area = shell.area - sum(c.area for c in cuts)
    material = shell.difference(shapely.union_all(cuts)) if cuts else shell
    changed = [g.area for g in _polygons(repaired.symmetric_difference(material))]
    total = max(sum(changed), abs(repaired.area - area))
    if all(a < REPAIR_PIECE_MM2 for a in changed) and total < REPAIR_SHARE * repaired.area:
        return
    change = (f"repairing it would change the part's material by {total:.4g} mm2 (it has {repaired.area:.6g} mm2, "
              f"the file describes {area:.6g} mm2; a repair may drop or add pieces under {REPAIR_PIECE_MM2:g} mm2 "
              f"each, under {REPAIR_SHARE:.0%} of the area together)")
    near = [i for i, c in enumerate(cuts) if c.distance(shell.boundary) <= HOLE_OUTSIDE_TOL_MM]
    if near:
        which = (f"hole #{near[0]} touches" if len(near) == 1
                 else f"holes {', '.join(f'#{i}' for i in near[:-1])} and #{near[-1]} touch")
        raise BadInput(f"{where}: {which} the outline ({why}): {change}; {NOTCH}")
    raise BadInput(f"{where}: the outline is not a valid polygon ({why}): {change}")


def _ring(raw, where) -> np.ndarray:
    if not isinstance(raw, list) or len(raw) < 3:
        raise BadInput(f"{where}: must be a list of at least 3 [x, y] points")
    # numbers only: numpy would read true as 1 and "330" as 330
    if any(not isinstance(p, list) or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in p)
           for p in raw):
        raise BadInput(f"{where}: every point must be [x, y] with numbers")
    try:
        arr = np.asarray(raw, dtype=float)
    except OverflowError:  # an integer literal too large for a float (JSON allows any length)
        raise BadInput(f"{where}: coordinates must be finite numbers (one is too large)") from None
    except (TypeError, ValueError):
        raise BadInput(f"{where}: every point must be [x, y] with numbers") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise BadInput(f"{where}: every point must be [x, y], got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise BadInput(f"{where}: coordinates must be finite numbers")
    if np.abs(arr).max() > MAX_COORD_MM:
        raise BadInput(f"{where}: coordinates must be within {MAX_COORD_MM:g} mm of the base "
                       f"(got {np.abs(arr).max():g}; the units are mm)")
    if np.allclose(arr[0], arr[-1]) and len(arr) > 3:
        arr = arr[:-1]  # tolerate a repeated first point
    if np.linalg.matrix_rank(arr - arr[0]) < 2:  # shapely calls it a "Self-intersection"
        raise BadInput(f"{where}: its points all lie on one line (or are one point): it has no area")
    return arr


def _is_point(raw) -> bool:
    """[x, y] where a ring was expected: a flat list of points given for 'holes'."""
    return isinstance(raw, list) and bool(raw) and all(isinstance(v, (int, float)) for v in raw)


def _refuse_non_finite(meta: dict, where: str) -> None:
    """The free keys are kept and written again (a recording's manifest holds the assembly): NaN or Infinity
    in one ended `cell run` in an internal error with a half-made recording folder."""
    def bad(v) -> bool:  # a walk with a stack: a key nested 330 deep overflowed a recursive one (RecursionError)
        todo = [v]
        while todo:
            x = todo.pop()
            if isinstance(x, float) and not math.isfinite(x):
                return True
            if isinstance(x, dict):
                todo.extend(x.values())
            elif isinstance(x, list):
                todo.extend(x)
        return False

    for k, v in meta.items():
        if bad(v):
            raise BadInput(f"{where}: {k!r} holds NaN or Infinity, which JSON cannot store")


def _num(v, where) -> float:
    if not is_finite_number(v):
        raise BadInput(f"{where}: must be a finite number, got {short_repr(v)}")
    return float(v)
