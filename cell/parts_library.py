"""The parts library: realistic disassembly parts in families, as in the paper's database.

Every part is built by a deterministic generator function from a few dimensions (mm),
as seen from above (its outline and holes) with its height, centred on its centre of
gravity at the origin. `meta` carries `family`, `size`, `name`, `material` and `mass_g`
(the physical check needs the mass; housings and PCBs are hollow or sparse, so their
`fill` is below 1).

    parts()                 -> list[Part]   all parts, in a fixed order (ids are the names)
    part(name)              -> Part
    families()              -> list[str]
    place(part, x, y, theta_deg, part_id=None) -> Part   the part at a pose in the base frame

Sizes stay within what an 80 mm stroke gripper can hold in some direction (some parts are
too wide in another direction, as real ones are); heights 2..60 mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from functools import cache

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon, box
from shapely.ops import unary_union

from cell.errors import BadInput
from cell.materials import DENSITY_G_CM3
from cell.scene import Part

# --- small shape helpers (shapely geometries, mm) -------------------------------------------

def _rrect(w: float, h: float, r: float = 0.0, cx: float = 0.0, cy: float = 0.0):
    """A w x h rectangle centred on (cx, cy) with corner fillets of radius r."""
    if r <= 0:
        return box(cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)
    return box(cx - w / 2 + r, cy - h / 2 + r, cx + w / 2 - r, cy + h / 2 - r).buffer(r, quad_segs=4)


def _chamfer_rect(w: float, h: float, c: float, cx: float = 0.0, cy: float = 0.0):
    """A rectangle with its four corners cut at 45 degrees by c."""
    x0, x1, y0, y1 = cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2
    return Polygon([(x0 + c, y0), (x1 - c, y0), (x1, y0 + c), (x1, y1 - c), (x1 - c, y1),
                    (x0 + c, y1), (x0, y1 - c), (x0, y0 + c)])


def _circle(r: float, cx: float = 0.0, cy: float = 0.0, segs: int = 8):
    return Point(cx, cy).buffer(r, quad_segs=segs)


def _ngon(n: int, across_flats: float, rot_deg: float = 0.0):
    r = across_flats / 2 / math.cos(math.pi / n)
    a0 = math.radians(rot_deg) + math.pi / n
    return Polygon([(r * math.cos(a0 + 2 * math.pi * k / n), r * math.sin(a0 + 2 * math.pi * k / n))
                    for k in range(n)])


def _gear(teeth: int, tip_r: float, root_r: float, tip_frac: float = 0.35, root_frac: float = 0.45):
    """A spur gear outline: trapezoidal teeth between root and tip radius."""
    pts = []
    pitch = 2 * math.pi / teeth
    for k in range(teeth):
        a = k * pitch
        flank = (1 - tip_frac - root_frac) / 2
        for frac, r in ((0.0, root_r), (root_frac, root_r), (root_frac + flank, tip_r),
                        (root_frac + flank + tip_frac, tip_r), (1 - 1e-6, root_r)):
            t = a + frac * pitch
            pts.append((r * math.cos(t), r * math.sin(t)))
    return Polygon(pts).buffer(0)


def _slot(length: float, width: float, cx: float = 0.0, cy: float = 0.0, angle_deg: float = 0.0):
    """A long hole with round ends (centre distance `length`)."""
    s = LineString([(-length / 2, 0), (length / 2, 0)]).buffer(width / 2, quad_segs=4)
    return affinity.translate(affinity.rotate(s, angle_deg, origin=(0, 0)), cx, cy)


def _ring_sector(r_out: float, r_in: float, gap_deg: float, rot_deg: float = 0.0):
    """An annulus with a gap (a C shape) centred on the +x axis gap."""
    ring = _circle(r_out, segs=12).difference(_circle(r_in, segs=12))
    half = math.radians(gap_deg / 2)
    wedge = Polygon([(0, 0), (3 * r_out * math.cos(half), 3 * r_out * math.sin(half)),
                     (3 * r_out * math.cos(-half), 3 * r_out * math.sin(-half))])
    return affinity.rotate(ring.difference(wedge), rot_deg, origin=(0, 0))


def _finish(geom, name: str, family: str, size: str, height_mm: float, material: str,
            fill: float = 1.0) -> Part:
    """Turn a shapely geometry into a Part centred on its centroid, outline CCW, holes CW."""
    geom = geom.buffer(0)
    if geom.geom_type == "MultiPolygon":  # generators make one piece; keep the largest if not
        geom = max(geom.geoms, key=lambda g: g.area)
    geom = shapely.geometry.polygon.orient(geom.simplify(0.02, preserve_topology=True), 1.0)
    c = geom.centroid
    geom = affinity.translate(geom, -c.x, -c.y)
    outline = np.asarray(geom.exterior.coords, float)[:-1]
    holes = tuple(np.asarray(r.coords, float)[:-1] for r in geom.interiors)
    mass_g = geom.area * height_mm * fill * DENSITY_G_CM3[material] / 1000.0
    meta = {"family": family, "size": size, "name": name, "material": material,
            "mass_g": round(mass_g, 2)}
    return Part(name, outline, holes, 0.0, float(height_mm), meta=meta)


# --- the families ------------------------------------------------------------------------------

def cover_rect(size: str, w: float, h: float, t: float) -> Part:
    """A stamped cover: rounded rectangle with four screw holes."""
    g = _rrect(w, h, 6)
    for sx in (-1, 1):
        for sy in (-1, 1):
            g = g.difference(_circle(2.2, sx * (w / 2 - 7), sy * (h / 2 - 7), 4))
    return _finish(g, f"cover_rect_{size}", "cover", size, t, "aluminium")


def cover_ears(size: str, w: float, h: float, t: float) -> Part:
    """A cover with two mounting ears (each with a hole) on its short sides."""
    g = _rrect(w, h, 4)
    for sx in (-1, 1):
        ear = _rrect(14, 18, 5, sx * (w / 2 + 5), 0)
        g = g.union(ear).difference(_circle(3, sx * (w / 2 + 7), 0, 4))
    return _finish(g, f"cover_ears_{size}", "cover", size, t, "aluminium")


def cover_round(size: str, d: float, t: float) -> Part:
    """A round lid with three tabs."""
    g = _circle(d / 2, segs=12)
    for k in range(3):
        a = math.radians(90 + 120 * k)
        tab = affinity.rotate(_rrect(10, 8, 2, d / 2 + 2, 0), math.degrees(a), origin=(0, 0))
        g = g.union(tab)
    return _finish(g, f"cover_round_{size}", "cover", size, t, "plastic")


def cover_notched(size: str, w: float, h: float, t: float) -> Part:
    """A cover with a cable notch in one long side and chamfered corners."""
    g = _chamfer_rect(w, h, 5).difference(_rrect(16, 12, 3, 0, h / 2))
    return _finish(g, f"cover_notched_{size}", "cover", size, t, "plastic")


def l_bracket(size: str, a: float, b: float, leg: float, height: float) -> Part:
    """An L bracket standing on its edge: L profile from above, fillet in the inner corner."""
    g = unary_union([box(0, 0, a, leg), box(0, 0, leg, b)])
    g = g.union(box(leg, leg, leg + 4, leg + 4).difference(_circle(4, leg + 4, leg + 4, 4)))
    return _finish(g, f"l_bracket_{size}", "bracket", size, height, "steel")


def u_bracket(size: str, w: float, d: float, wall: float, height: float) -> Part:
    """A U channel seen from its end."""
    g = box(-w / 2, 0, w / 2, d).difference(box(-w / 2 + wall, wall, w / 2 - wall, d + 1))
    return _finish(g, f"u_bracket_{size}", "bracket", size, height, "steel")


def flat_bracket_slotted(size: str, l: float, w: float, t: float) -> Part:
    """A flat strap bracket with two slots and rounded ends."""
    g = _slot(l - w, w)
    for sx in (-1, 1):
        g = g.difference(_slot(10, 5, sx * (l / 2 - w / 2 - 5), 0))
    return _finish(g, f"flat_bracket_{size}", "bracket", size, t, "steel")


def t_bracket(size: str, l: float, w: float, stem: float, t: float) -> Part:
    """A T-shaped mounting plate with a hole in each arm."""
    g = unary_union([box(-l / 2, 0, l / 2, w), box(-w / 2, -stem, w / 2, 0.5)])
    for cx, cy in ((-l / 2 + 6, w / 2), (l / 2 - 6, w / 2), (0, -stem + 6)):
        g = g.difference(_circle(2.5, cx, cy, 4))
    return _finish(g, f"t_bracket_{size}", "bracket", size, t, "steel")


def z_bracket(size: str, l: float, w: float, height: float) -> Part:
    """A Z profile standing on its edge."""
    g = unary_union([box(0, 0, w, 3), box(w - 3, 0, w, l), box(w - 3, l - 3, 2 * w - 3, l)])
    return _finish(g, f"z_bracket_{size}", "bracket", size, height, "steel")


def plate_holes(size: str, w: float, h: float, t: float, hole_d: float) -> Part:
    """A base plate with chamfered corners and four mounting holes."""
    g = _chamfer_rect(w, h, 4)
    for sx in (-1, 1):
        for sy in (-1, 1):
            g = g.difference(_circle(hole_d / 2, sx * (w / 2 - 8), sy * (h / 2 - 8), 4))
    return _finish(g, f"plate_holes_{size}", "plate", size, t, "aluminium")


def plate_slotted(size: str, w: float, h: float, t: float) -> Part:
    """An adjusting plate with a long central slot."""
    g = _rrect(w, h, 3).difference(_slot(w * 0.5, 8))
    return _finish(g, f"plate_slotted_{size}", "plate", size, t, "steel")


def gusset(size: str, a: float, t: float) -> Part:
    """A triangular gusset plate with a lightening hole and clipped corners."""
    g = Polygon([(0, 0), (a, 0), (0, a)]).buffer(-2).buffer(2, quad_segs=3)
    g = g.difference(_circle(a * 0.12, a * 0.3, a * 0.3, 6))
    return _finish(g, f"gusset_{size}", "plate", size, t, "steel")


def flange_plate(size: str, d: float, t: float) -> Part:
    """A round flange: centre bore and a bolt circle of six holes."""
    g = _circle(d / 2, segs=12).difference(_circle(d * 0.2, segs=8))
    for k in range(6):
        a = 2 * math.pi * k / 6
        g = g.difference(_circle(2.5, d * 0.35 * math.cos(a), d * 0.35 * math.sin(a), 4))
    return _finish(g, f"flange_plate_{size}", "plate", size, t, "steel")


def plate_notched(size: str, w: float, h: float, t: float) -> Part:
    """A plate with a rectangular notch in one corner and a hole."""
    g = box(-w / 2, -h / 2, w / 2, h / 2).difference(box(w / 2 - w * 0.3, h / 2 - h * 0.35, w, h))
    g = g.difference(_circle(4, -w / 4, 0, 6))
    return _finish(g, f"plate_notched_{size}", "plate", size, t, "aluminium")


def spur_gear(size: str, teeth: int, tip_d: float, t: float) -> Part:
    """A spur gear with a keyed bore."""
    module = tip_d / (teeth + 2)
    g = _gear(teeth, tip_d / 2, tip_d / 2 - 2.25 * module)
    bore = _circle(tip_d * 0.12, segs=6).union(box(-1.5, 0, 1.5, tip_d * 0.12 + 2))
    return _finish(g.difference(bore), f"spur_gear_{size}", "gear", size, t, "steel", fill=0.8)


def rack(size: str, l: float, w: float, t: float) -> Part:
    """A gear rack: a bar with teeth along one long side."""
    pitch = 6.0
    g = box(-l / 2, -w / 2, l / 2, w / 2 - 3)
    x = -l / 2 + 1.5
    while x + pitch / 2 < l / 2:
        g = g.union(Polygon([(x, w / 2 - 3.01), (x + 1.2, w / 2), (x + 3.8, w / 2), (x + 5, w / 2 - 3.01)]))
        x += pitch
    return _finish(g, f"rack_{size}", "gear", size, t, "steel")


def hex_nut(size: str, af: float, t: float) -> Part:
    """A hex nut (across flats `af`) with its thread bore."""
    g = _ngon(6, af).difference(_circle(af * 0.32, segs=6))  # bore ~ thread size (M16: 24 AF, 16 bore)
    return _finish(g, f"hex_nut_{size}", "nut", size, t, "steel")


def square_nut(size: str, a: float, t: float) -> Part:
    g = _chamfer_rect(a, a, 1).difference(_circle(a * 0.3, segs=6))
    return _finish(g, f"square_nut_{size}", "nut", size, t, "steel")


def wing_nut(size: str, span: float, t: float) -> Part:
    """A wing nut from above: round body with two wings."""
    body = _circle(span * 0.2, segs=8)
    wings = _rrect(span, span * 0.22, span * 0.1)
    g = body.union(wings).difference(_circle(span * 0.1, segs=6))
    return _finish(g, f"wing_nut_{size}", "nut", size, t, "steel")


def flange_nut(size: str, af: float, t: float) -> Part:
    """A hex flange nut: the flange's round outline is what shows from above."""
    g = _circle(af * 0.72, segs=10).difference(_circle(af * 0.32, segs=6))
    return _finish(g, f"flange_nut_{size}", "nut", size, t, "steel")


def washer(size: str, od: float, id_: float, t: float) -> Part:
    g = _circle(od / 2, segs=10).difference(_circle(id_ / 2, segs=8))
    return _finish(g, f"washer_{size}", "washer", size, t, "steel")


def tab_washer(size: str, od: float, id_: float, t: float) -> Part:
    """A tab washer: a washer with a locking tab sticking out."""
    g = _circle(od / 2, segs=10).union(_rrect(8, od * 0.6, 1, 0, -od / 2))
    g = g.difference(_circle(id_ / 2, segs=8))
    return _finish(g, f"tab_washer_{size}", "washer", size, t, "steel")


def lock_washer(size: str, od: float, id_: float, t: float) -> Part:
    """A split lock washer (a ring with a cut)."""
    g = _ring_sector(od / 2, id_ / 2, 12)
    return _finish(g, f"lock_washer_{size}", "washer", size, t, "steel")


def motor_housing(size: str, d: float, height: float) -> Part:
    """A motor can with a flange: round body, two ears with holes, a terminal box."""
    g = _circle(d / 2, segs=12).union(_rrect(d + 20, 14, 5))
    g = g.union(_rrect(14, 10, 2, 0, d / 2 + 3))
    for sx in (-1, 1):
        g = g.difference(_circle(2.5, sx * (d / 2 + 5), 0, 4))
    return _finish(g, f"motor_housing_{size}", "housing", size, height, "aluminium", fill=0.3)


def box_housing(size: str, w: float, h: float, height: float) -> Part:
    """An enclosure with four corner bosses."""
    g = _rrect(w, h, 3)
    for sx in (-1, 1):
        for sy in (-1, 1):
            g = g.union(_circle(5, sx * (w / 2 - 2), sy * (h / 2 - 2), 4))
    return _finish(g, f"box_housing_{size}", "housing", size, height, "aluminium", fill=0.3)


def pump_housing(size: str, d: float, height: float) -> Part:
    """A volute pump casing: round body with a tangential outlet spout."""
    g = _circle(d / 2, segs=12).union(box(0, d / 2 - 14, d / 2 + 14, d / 2))
    g = g.union(_rrect(6, 18, 1, d / 2 + 14, d / 2 - 7))
    return _finish(g, f"pump_housing_{size}", "housing", size, height, "aluminium", fill=0.35)


def gearbox_housing(size: str, w: float, h: float, height: float) -> Part:
    """A gearbox: a long body with two round bearing bosses on one side."""
    g = _rrect(w, h, 6)
    for sx in (-1, 1):
        g = g.union(_circle(h * 0.28, sx * w * 0.25, h / 2, 8))
    return _finish(g, f"gearbox_housing_{size}", "housing", size, height, "aluminium", fill=0.3)


def enclosure_gland(size: str, w: float, h: float, height: float) -> Part:
    """An electronics enclosure with a cable gland stub and a hinge."""
    g = _rrect(w, h, 4).union(_rrect(12, 10, 1, w / 2 + 4, 0)).union(box(-w / 2 - 3, -10, -w / 2 + 1, 10))
    return _finish(g, f"enclosure_{size}", "housing", size, height, "plastic", fill=0.3)


def pcb(size: str, w: float, h: float, height: float, connectors: tuple) -> Part:
    """A populated PCB: board with mounting holes and connectors sticking out of its edges.

    `connectors`: (side, offset_mm, width_mm, protrusion_mm) with side in 'N','S','E','W'.
    """
    g = _rrect(w, h, 2)
    for sx in (-1, 1):
        for sy in (-1, 1):
            g = g.difference(_circle(1.6, sx * (w / 2 - 4), sy * (h / 2 - 4), 4))
    for side, off, cw, pro in connectors:
        if side in "NS":
            s = 1 if side == "N" else -1
            g = g.union(box(off - cw / 2, s * h / 2 - (0 if s > 0 else pro), off + cw / 2,
                            s * h / 2 + (pro if s > 0 else 0)))
        else:
            s = 1 if side == "E" else -1
            g = g.union(box(s * w / 2 - (0 if s > 0 else pro), off - cw / 2,
                            s * w / 2 + (pro if s > 0 else 0), off + cw / 2))
    return _finish(g, f"pcb_{size}", "pcb", size, height, "fr4", fill=0.35)


def pcb_round(size: str, d: float, height: float) -> Part:
    """A round LED board with a connector tab."""
    g = _circle(d / 2, segs=12).union(box(-5, d / 2 - 1, 5, d / 2 + 5)).difference(_circle(2, segs=4))
    return _finish(g, f"pcb_round_{size}", "pcb", size, height, "fr4", fill=0.4)


def stepped_shaft(size: str, l: float, d: float) -> Part:
    """A stepped shaft lying on the tray: seen from above, three diameters with chamfered ends."""
    g = unary_union([_chamfer_rect(l * 0.3, d * 0.7, 1, -l * 0.35, 0), _chamfer_rect(l * 0.4, d, 1, 0, 0),
                     _chamfer_rect(l * 0.3, d * 0.8, 1, l * 0.35, 0)])
    return _finish(g, f"stepped_shaft_{size}", "shaft", size, d, "steel", fill=0.785)


def keyed_shaft(size: str, l: float, d: float) -> Part:
    """A plain shaft with chamfered ends and a key sticking up out of its keyway."""
    g = _chamfer_rect(l, d, 1.5).union(box(-l * 0.2, d / 2 - 1, l * 0.1, d / 2 + 1.5))
    return _finish(g, f"keyed_shaft_{size}", "shaft", size, d, "steel", fill=0.785)


def pin(size: str, l: float, d: float) -> Part:
    """A clevis pin: head collar and a cross hole end."""
    g = _chamfer_rect(l, d, 1).union(_rrect(4, d * 1.6, 1, -l / 2 + 2, 0))
    return _finish(g, f"clevis_pin_{size}", "shaft", size, d * 1.6, "steel", fill=0.785)


def spring_clip(size: str, d: float, t: float) -> Part:
    """A C spring clip (circlip-like) with two lug ears with holes."""
    r_out, r_in = d / 2, d / 2 - 3
    g = _ring_sector(r_out, r_in, 40, rot_deg=90)
    for sx in (-1, 1):
        a = math.radians(90 + sx * 28)
        cx, cy = (r_in + 2.5) * math.cos(a), (r_in + 2.5) * math.sin(a)
        g = g.union(_circle(3.2, cx, cy, 4)).difference(_circle(1.1, cx, cy, 3))
    return _finish(g, f"spring_clip_{size}", "clip", size, t, "steel")


def hose_clamp(size: str, d: float, t: float) -> Part:
    """A worm-drive hose clamp: band ring plus the screw housing."""
    g = _circle(d / 2, segs=12).difference(_circle(d / 2 - 1.5, segs=12))
    g = g.union(_rrect(16, 10, 1, 0, d / 2 + 3))
    return _finish(g, f"hose_clamp_{size}", "clip", size, t, "steel")


def hairpin_clip(size: str, l: float, w: float) -> Part:
    """An R-clip / hairpin spring made of 2 mm wire: a U with one wavy leg."""
    leg1 = LineString([(0, 0), (l, 0)])
    leg2 = LineString([(0, w)] + [(l * k / 8, w - (2.5 if k % 2 else 0)) for k in range(1, 9)])
    bend = LineString([(0, 0), (-w * 0.4, w * 0.5), (0, w)])
    g = unary_union([leg1, leg2, bend]).buffer(1.0, quad_segs=3)
    return _finish(g, f"hairpin_clip_{size}", "clip", size, 2.0, "steel")


def spring_clamp_clip(size: str, w: float, t: float) -> Part:
    """A binder-style clip seen from above: body with two handle loops (the springs)."""
    body = _rrect(w, w * 0.45, 2)
    loops = unary_union([LineString([(-w * 0.35, w * 0.2), (-w * 0.4, w * 0.75), (w * 0.4, w * 0.75),
                                     (w * 0.35, w * 0.2)]).buffer(1.0, quad_segs=3)])
    return _finish(body.union(loops), f"spring_clamp_{size}", "clip", size, t, "steel")


def conrod(size: str, c: float, big_d: float, small_d: float, t: float) -> Part:
    """A connecting rod: big end and small end joined by a tapered web, both eyes bored."""
    web = Polygon([(0, -big_d * 0.3), (c, -small_d * 0.3), (c, small_d * 0.3), (0, big_d * 0.3)])
    g = unary_union([_circle(big_d / 2, 0, 0, 8), _circle(small_d / 2, c, 0, 6), web])
    g = g.difference(_circle(big_d * 0.3, 0, 0, 8)).difference(_circle(small_d * 0.28, c, 0, 6))
    return _finish(g, f"conrod_{size}", "link", size, t, "steel")


def lever(size: str, l: float, w: float, t: float) -> Part:
    """A lever arm: a tapered bar with a boss at the pivot and a handle hole."""
    g = unary_union([Polygon([(0, -w / 2), (l, -w * 0.3), (l, w * 0.3), (0, w / 2)]),
                     _circle(w * 0.7, 0, 0, 6), _circle(w * 0.3, l, 0, 4)])
    g = g.difference(_circle(w * 0.3, 0, 0, 6))
    return _finish(g, f"lever_{size}", "link", size, t, "steel")


def heatsink(size: str, w: float, fins: int, fin_l: float, height: float) -> Part:
    """An extruded heat sink standing on end: a base with a comb of fins."""
    base = box(-w / 2, 0, w / 2, 6)
    pitch = w / fins
    g = base.union(unary_union([box(-w / 2 + k * pitch + pitch * 0.3, 5.9, -w / 2 + k * pitch + pitch * 0.7,
                                    6 + fin_l) for k in range(fins)]))
    return _finish(g, f"heatsink_{size}", "heatsink", size, height, "aluminium")


def dsub(size: str, w: float, height: float) -> Part:
    """A D-sub connector shell with its two screw ears."""
    trap = Polygon([(-w * 0.35, -5), (w * 0.35, -5), (w * 0.3, 5), (-w * 0.3, 5)]).buffer(1, quad_segs=3)
    g = _rrect(w, 10, 1).union(trap.buffer(1.5)).difference(_circle(1.6, -w / 2 + 4, 0, 4))
    g = g.difference(_circle(1.6, w / 2 - 4, 0, 4))
    return _finish(g, f"dsub_{size}", "connector", size, height, "steel", fill=0.4)


def terminal_block(size: str, poles: int, height: float) -> Part:
    """A screw terminal block: a row of cells with notches between the poles."""
    pitch = 7.5
    w = poles * pitch
    g = box(-w / 2, -6, w / 2, 6)
    for k in range(1, poles):
        x = -w / 2 + k * pitch
        g = g.difference(Polygon([(x - 1, 6.01), (x, 4.5), (x + 1, 6.01)]))
    return _finish(g, f"terminal_block_{size}", "connector", size, height, "plastic", fill=0.6)


def pulley(size: str, d: float, t: float) -> Part:
    """A V-belt pulley from above: round, with a keyed bore."""
    g = _circle(d / 2, segs=12).difference(_circle(d * 0.15, segs=6).union(box(-1.5, 0, 1.5, d * 0.15 + 2)))
    return _finish(g, f"pulley_{size}", "pulley", size, t, "aluminium", fill=0.7)


def knob(size: str, d: float, flutes: int, t: float) -> Part:
    """A fluted knob: a disc with round grip flutes cut into its rim."""
    g = _circle(d / 2, segs=12)
    for k in range(flutes):
        a = 2 * math.pi * k / flutes
        g = g.difference(_circle(d * 0.07, d / 2 * math.cos(a), d / 2 * math.sin(a), 4))
    return _finish(g, f"knob_{size}", "pulley", size, t, "plastic")


# (generator, size label, kwargs): the library in a fixed order. Several parts come in sizes.
_CATALOGUE: list[tuple[Callable[..., Part], str, dict]] = [
    (cover_rect, "s", dict(w=60, h=40, t=3)),
    (cover_rect, "m", dict(w=90, h=55, t=3)),
    (cover_rect, "l", dict(w=110, h=64, t=4)),
    (cover_ears, "m", dict(w=70, h=45, t=3)),
    (cover_round, "m", dict(d=56, t=6)),
    (cover_notched, "m", dict(w=80, h=50, t=4)),
    (l_bracket, "s", dict(a=40, b=30, leg=6, height=25)),
    (l_bracket, "m", dict(a=60, b=45, leg=8, height=35)),
    (u_bracket, "m", dict(w=50, d=40, wall=5, height=20)),
    (flat_bracket_slotted, "m", dict(l=100, w=20, t=4)),
    (t_bracket, "m", dict(l=70, w=16, stem=40, t=4)),
    (z_bracket, "m", dict(l=40, w=25, height=30)),
    (plate_holes, "s", dict(w=60, h=40, t=5, hole_d=5)),
    (plate_holes, "m", dict(w=90, h=60, t=6, hole_d=6)),
    (plate_holes, "l", dict(w=120, h=68, t=8, hole_d=8)),
    (plate_slotted, "m", dict(w=70, h=36, t=6)),
    (gusset, "m", dict(a=60, t=5)),
    (flange_plate, "m", dict(d=64, t=8)),
    (plate_notched, "m", dict(w=80, h=56, t=6)),
    (spur_gear, "s", dict(teeth=12, tip_d=30, t=10)),
    (spur_gear, "m", dict(teeth=18, tip_d=44, t=12)),
    (spur_gear, "l", dict(teeth=24, tip_d=58, t=15)),
    (spur_gear, "xl", dict(teeth=30, tip_d=66, t=15)),
    (rack, "m", dict(l=100, w=16, t=12)),
    (hex_nut, "m8", dict(af=13, t=6.5)),
    (hex_nut, "m12", dict(af=19, t=10)),
    (hex_nut, "m16", dict(af=24, t=13)),
    (hex_nut, "m20", dict(af=30, t=16)),
    (square_nut, "m10", dict(a=17, t=8)),
    (wing_nut, "m8", dict(span=40, t=14)),
    (flange_nut, "m12", dict(af=19, t=12)),
    (washer, "m10", dict(od=20, id_=10.5, t=2)),
    (washer, "m16", dict(od=30, id_=17, t=3)),
    (washer, "m24", dict(od=44, id_=25, t=4)),
    (tab_washer, "m16", dict(od=30, id_=17, t=2)),
    (lock_washer, "m20", dict(od=34, id_=21, t=5)),
    (motor_housing, "s", dict(d=40, height=45)),
    (motor_housing, "m", dict(d=56, height=60)),
    (box_housing, "m", dict(w=70, h=50, height=40)),
    (pump_housing, "m", dict(d=54, height=35)),
    (gearbox_housing, "m", dict(w=100, h=56, height=45)),
    (enclosure_gland, "m", dict(w=80, h=60, height=30)),
    (pcb, "s", dict(w=50, h=35, height=12, connectors=(("E", 0, 10, 5),))),
    (pcb, "m", dict(w=80, h=50, height=18, connectors=(("N", -20, 16, 6), ("W", 8, 10, 4)))),
    (pcb, "l", dict(w=100, h=64, height=15,
                    connectors=(("S", 25, 20, 7), ("E", -10, 8, 4), ("N", 0, 12, 5)))),
    (pcb_round, "m", dict(d=50, height=8)),
    (stepped_shaft, "s", dict(l=80, d=14)),
    (stepped_shaft, "m", dict(l=120, d=22)),
    (keyed_shaft, "m", dict(l=90, d=18)),
    (pin, "m", dict(l=50, d=10)),
    (spring_clip, "m", dict(d=40, t=2)),
    (hose_clamp, "m", dict(d=44, t=10)),
    (hairpin_clip, "m", dict(l=50, w=14)),
    (spring_clamp_clip, "m", dict(w=40, t=12)),
    (conrod, "m", dict(c=70, big_d=40, small_d=22, t=12)),
    (lever, "m", dict(l=90, w=18, t=8)),
    (heatsink, "s", dict(w=40, fins=5, fin_l=20, height=30)),
    (heatsink, "m", dict(w=60, fins=7, fin_l=26, height=40)),
    (dsub, "de9", dict(w=31, height=12)),
    (terminal_block, "4p", dict(poles=4, height=14)),
    (pulley, "s", dict(d=40, t=16)),
    (pulley, "m", dict(d=64, t=20)),
    (knob, "m", dict(d=36, flutes=10, t=18)),
]


@cache
def _build() -> tuple[Part, ...]:
    return tuple(gen(size, **kw) for gen, size, kw in _CATALOGUE)


def parts(families: list[str] | tuple[str, ...] | None = None) -> list[Part]:
    """All library parts (centred at the origin), optionally only those of some families."""
    out = list(_build())
    if families is not None:
        unknown = sorted(set(families) - set(list_families()))
        if unknown:
            raise BadInput(f"unknown part families: {', '.join(unknown)} "
                           f"(known: {', '.join(list_families())})")
        out = [p for p in out if p.meta["family"] in families]
    return out


def list_families() -> list[str]:
    seen: list[str] = []
    for p in _build():
        if p.meta["family"] not in seen:
            seen.append(p.meta["family"])
    return seen


families = list_families


def part(name: str) -> Part:
    for p in _build():
        if p.id == name:
            return p
    raise BadInput(f"no part {name!r} in the parts library")


def place(p: Part, x_mm: float, y_mm: float, theta_deg: float = 0.0, part_id: str | None = None,
          z_bottom_mm: float = 0.0) -> Part:
    """The part (centred at the origin) rotated by theta about the origin, then moved to (x, y);
    optionally renamed and lifted to stand at z_bottom."""
    moved = p.moved(x_mm, y_mm, theta_deg, about=(0.0, 0.0))
    dz = z_bottom_mm - p.z_bottom_mm
    return replace(moved, id=part_id or p.id, z_bottom_mm=p.z_bottom_mm + dz, z_top_mm=p.z_top_mm + dz)
