"""The simulated camera: a realistic frame of parts on the tray, with known ground truth.

Every part is a vertical prism (its outline from z_bottom to z_top, holes go through).
Its top face, its walls and its bottom edge are projected through the calibration (pose,
perspective and lens distortion), so tall parts off the image centre show their walls,
exactly as the real camera sees them. Edges are anti-aliased by supersampling each
part's bounding box. On top of the geometry: a slightly textured tray, soft shadows cast
by a broad light, a lighting gradient with vignetting, specular highlights on metal,
lens blur, and sensor noise (read + shot noise). A seed makes a frame reproducible.

Materials come from `part.meta["material"]` (see MATERIALS) or, without one, from a
palette by part id.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import cv2
import numpy as np
from shapely.geometry import Polygon
from shapely.ops import unary_union

from calibration.camera import Calibration
from cell.scene import Part

# name -> (top colour BGR at full light, specular)
MATERIALS: dict[str, tuple[tuple[float, float, float], bool]] = {
    "steel": ((168.0, 166.0, 160.0), True),
    "aluminium": ((205.0, 205.0, 200.0), True),
    "dark_plastic": ((42.0, 40.0, 44.0), False),
    "blue_plastic": ((165.0, 95.0, 40.0), False),
    "red_plastic": ((40.0, 50.0, 170.0), False),
    "pcb_green": ((55.0, 115.0, 35.0), False),
    "white_plastic": ((225.0, 228.0, 226.0), False),
    "brass": ((70.0, 150.0, 185.0), True),
    "grey_plastic": ((122.0, 106.0, 90.0), False),  # low contrast against the tray
}
PALETTE = ("dark_plastic", "blue_plastic", "steel", "pcb_green", "white_plastic", "red_plastic", "brass")
PLASTICS = ("dark_plastic", "blue_plastic", "red_plastic", "white_plastic", "grey_plastic")
TRAY_BGR = (140.0, 115.0, 90.0)  # a blue anodised tray: metal parts stand out on it
WALL_SHADE = 0.62  # walls get less light than the top face


@dataclass(frozen=True)
class SimCameraOptions:
    """What the simulated camera adds to the geometry; every effect can be turned off."""

    seed: int = 0
    distortion: bool = True  # False: render as if the lens had none (the calibration still has it)
    shadows: bool = True
    shadow_strength: float = 0.3  # darkening at the shadow's core
    light_azimuth_deg: float = 35.0  # direction the shadows fall, in the base frame
    light_elevation_deg: float = 62.0
    lighting_gradient: float = 0.18  # relative brightness change across the frame
    vignetting: float = 0.12
    tray_texture: float = 0.02
    highlights: bool = True
    blur_sigma_px: float = 0.7
    read_noise_dn: float = 1.5
    shot_noise: float = 0.12  # sigma = shot_noise * sqrt(signal)
    supersample: int = 4
    tray_bgr: tuple[float, float, float] = TRAY_BGR
    wall_shade: float = WALL_SHADE  # a wall's brightness relative to the top face


class SimCamera:
    """Renders frames of parts on the tray under `cal` (default: the default cell's)."""

    def __init__(self, cal: Calibration | None = None, options: SimCameraOptions | None = None):
        if cal is None:
            from calibration import load_calibration

            cal = load_calibration()
        if not cal.has_pose:
            from cell.errors import BadInput

            raise BadInput(f"the simulated camera needs a calibration with intrinsics and a camera pose: "
                           f"{cal.label} has none")
        self.cal = cal
        self.options = options or SimCameraOptions()
        self._frame_index = 0

    # ---- public ---------------------------------------------------------------------------
    def render(self, parts: list[Part] | tuple[Part, ...] = ()) -> np.ndarray:
        """A BGR uint8 frame (height_px, width_px, 3); the same seed gives the same frame."""
        o = self.options
        rng = np.random.default_rng(o.seed)
        h, w = self.cal.height_px, self.cal.width_px
        img = self._tray(rng)
        if o.shadows and parts:
            img *= (1.0 - self._shadow_map(parts))[:, :, None]
        for part in sorted(parts, key=lambda p: p.z_top_mm):
            self._paint_part(img, part, rng)
        img *= self._lighting()[:, :, None]
        if o.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), o.blur_sigma_px)
        noise = rng.standard_normal((h, w, 3)).astype(np.float32)
        img += noise * np.sqrt(o.read_noise_dn ** 2 + (o.shot_noise ** 2) * np.clip(img, 0, None))
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def read(self, parts=()) -> np.ndarray:
        """Camera-like: each call renders with the next seed (frame i uses seed + i)."""
        cam = SimCamera(self.cal, _with_seed(self.options, self.options.seed + self._frame_index))
        self._frame_index += 1
        return cam.render(parts)

    def project_ring(self, ring_mm: np.ndarray, z_mm: float, step_mm: float = 1.0) -> np.ndarray:
        """A closed ring at height z, densified every `step_mm`, projected to pixels (m, 2)."""
        return self.project_points(densify(ring_mm, step_mm), z_mm)

    def project_points(self, xy_mm: np.ndarray, z_mm: float) -> np.ndarray:
        """Base-frame points (n, 2) at height z -> pixels (n, 2), as this camera renders them."""
        xyz = np.column_stack([xy_mm, np.full(len(xy_mm), z_mm)])
        if self.options.distortion:
            return self.cal.project(xyz)
        nodist = Calibration(self.cal.width_px, self.cal.height_px, self.cal.camera_matrix, np.zeros(5),
                             self.cal.cam2base)
        return nodist.project(xyz)

    # ---- pieces ---------------------------------------------------------------------------
    def _tray(self, rng) -> np.ndarray:
        h, w = self.cal.height_px, self.cal.width_px
        o = self.options
        img = np.empty((h, w, 3), np.float32)
        img[:] = np.array(o.tray_bgr, np.float32)
        if o.tray_texture > 0:  # low-frequency mottling of the anodised surface
            small = rng.standard_normal((h // 32 + 2, w // 32 + 2)).astype(np.float32)
            tex = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
            img *= (1.0 + o.tray_texture * tex)[:, :, None]
        return img

    def _lighting(self) -> np.ndarray:
        h, w = self.cal.height_px, self.cal.width_px
        o = self.options
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        un, vn = (u - w / 2) / (w / 2), (v - h / 2) / (h / 2)
        a = math.radians(o.light_azimuth_deg)
        ramp = 1.0 + 0.5 * o.lighting_gradient * (math.cos(a) * vn + math.sin(a) * un)
        vig = 1.0 - o.vignetting * (un ** 2 + vn ** 2) / 2.0
        return ramp * vig

    def _shadow_map(self, parts) -> np.ndarray:
        """Soft shadows on the tray from a broad light: each part's outline swept from its base
        to its top's shadow, blurred more for taller parts (a wider penumbra)."""
        o = self.options
        h, w = self.cal.height_px, self.cal.width_px
        scale = 2  # shadows are soft: a half-resolution map is plenty
        shadow = np.zeros((h // scale, w // scale), np.float32)
        a = math.radians(o.light_azimuth_deg)
        mm_per_px = self.cal.mm_per_px()
        for p in parts:
            height = p.height_mm
            off = height / math.tan(math.radians(o.light_elevation_deg)) * np.array([math.cos(a), math.sin(a)])
            dense = densify(p.outline_mm, 2.0)
            base = self.project_points(dense, p.z_bottom_mm) / scale - 0.5
            tip = self.project_points(dense + off, p.z_bottom_mm) / scale - 0.5
            layer = np.zeros_like(shadow)
            polys = [base, tip] + [np.array([base[i], base[(i + 1) % len(base)], tip[(i + 1) % len(tip)], tip[i]])
                                   for i in range(len(base))]
            for poly in polys:
                cv2.fillPoly(layer, [np.round(poly * 16).astype(np.int32)], 1.0, cv2.LINE_AA, 4)
            for hole in p.holes_mm:  # light passes through holes
                hb = self.project_ring(hole + off, p.z_bottom_mm, 2.0) / scale - 0.5
                cv2.fillPoly(layer, [np.round(hb * 16).astype(np.int32)], 0.0, cv2.LINE_AA, 4)
            sigma = max(0.5, 0.15 * height / mm_per_px / scale)
            layer = cv2.GaussianBlur(layer, (0, 0), sigma)
            shadow = np.maximum(shadow, layer)
        return cv2.resize(shadow * o.shadow_strength, (w, h), interpolation=cv2.INTER_LINEAR)

    def _paint_part(self, img: np.ndarray, part: Part, rng) -> None:
        o = self.options
        ss = o.supersample
        top = self.project_ring(part.outline_mm, part.z_top_mm)
        bottom = self.project_ring(part.outline_mm, part.z_bottom_mm)
        holes_top = [self.project_ring(hr, part.z_top_mm) for hr in part.holes_mm]
        holes_bottom = [self.project_ring(hr, part.z_bottom_mm) for hr in part.holes_mm]
        allpts = np.vstack([top, bottom])
        h, w = img.shape[:2]
        u0, v0 = np.floor(allpts.min(axis=0)).astype(int) - 2
        u1, v1 = np.ceil(allpts.max(axis=0)).astype(int) + 2
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w), min(v1, h)
        if u1 <= u0 or v1 <= v0:
            return  # entirely outside the frame
        bw, bh = (u1 - u0) * ss, (v1 - v0) * ss
        origin = np.array([u0, v0], float)

        def fill(mask, geom):
            # OpenCV fills every sub-pixel whose centre is within half a sub-pixel of the shape:
            # shrink by that half, so coverage is the true area. OpenCV draws with pixel centres
            # at integers, the CONTRACT frame at +0.5: shift by half a sub-pixel, so that
            # INTER_AREA's blocks are exactly the frame's pixels.
            geom = geom.buffer(-0.5 / ss, join_style="mitre")
            for poly in getattr(geom, "geoms", [geom]):
                if poly.is_empty or poly.geom_type != "Polygon":
                    continue
                rings = [np.asarray(poly.exterior.coords)] + [np.asarray(r.coords) for r in poly.interiors]
                cv2.fillPoly(mask, [np.round(((r - origin) * ss - 0.5) * 16).astype(np.int32) for r in rings],
                             1, cv2.LINE_8, 4)

        quads = [Polygon([top[i], top[(i + 1) % len(top)], bottom[(i + 1) % len(top)], bottom[i]]).buffer(0)
                 for i in range(len(top))]  # walls between the top and the bottom edge
        silhouette = unary_union([Polygon(top), Polygon(bottom)] + quads)
        open_holes = [Polygon(ht).intersection(Polygon(hb)) for ht, hb in zip(holes_top, holes_bottom, strict=True)]
        if open_holes:  # the tray is seen through where both ends of a hole are open
            silhouette = silhouette.difference(unary_union(open_holes))
        sil = np.zeros((bh, bw), np.uint8)
        fill(sil, silhouette)
        topm = np.zeros((bh, bw), np.uint8)
        fill(topm, Polygon(top, holes_top))
        cov_sil = cv2.resize(sil.astype(np.float32), (u1 - u0, v1 - v0), interpolation=cv2.INTER_AREA)
        cov_top = cv2.resize(topm.astype(np.float32), (u1 - u0, v1 - v0), interpolation=cv2.INTER_AREA)
        colour, specular = self._material(part)
        base = np.array(colour, np.float32)
        top_col = np.empty((v1 - v0, u1 - u0, 3), np.float32)
        top_col[:] = base
        if specular:  # brushed metal: fine streaks, then highlights that saturate the sensor
            streak = rng.standard_normal((v1 - v0, 1)).astype(np.float32)
            top_col *= (1.0 + 0.04 * np.repeat(streak, u1 - u0, axis=1))[:, :, None]
            if o.highlights:
                top_col += self._highlights(v1 - v0, u1 - u0, rng)[:, :, None]
        wall_col = base * o.wall_shade
        roi = img[v0:v1, u0:u1]
        cw = (cov_sil - cov_top).clip(0, 1)[:, :, None]
        ct = cov_top[:, :, None]
        roi[:] = roi * (1.0 - cw - ct) + wall_col * cw + top_col * ct

    def _highlights(self, h: int, w: int, rng) -> np.ndarray:
        out = np.zeros((h, w), np.float32)
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        for _ in range(int(rng.integers(1, 4))):
            cu, cv = rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h
            su, sv = rng.uniform(0.04, 0.15) * w, rng.uniform(0.02, 0.06) * h
            ang = rng.uniform(0, math.pi)
            du, dv = u - cu, v - cv
            a = (du * math.cos(ang) + dv * math.sin(ang)) / su
            b = (-du * math.sin(ang) + dv * math.cos(ang)) / sv
            out += rng.uniform(90, 200) * np.exp(-0.5 * (a * a + b * b))
        return out

    def _material(self, part: Part) -> tuple[tuple[float, float, float], bool]:
        name = part.meta.get("material")
        if isinstance(name, str) and name in MATERIALS:
            return MATERIALS[name]
        if name == "fr4":  # the parts library's materials
            return MATERIALS["pcb_green"]
        if name == "plastic":
            return MATERIALS[PLASTICS[zlib.crc32(part.id.encode()) % len(PLASTICS)]]
        colour = part.meta.get("color_bgr")
        if isinstance(colour, list) and len(colour) == 3:
            return tuple(float(c) for c in colour), False
        return MATERIALS[PALETTE[zlib.crc32(part.id.encode()) % len(PALETTE)]]


def densify(ring: np.ndarray, step_mm: float) -> np.ndarray:
    """Insert points along each edge of a closed ring so no edge is longer than `step_mm`."""
    ring = np.asarray(ring, float)
    nxt = np.roll(ring, -1, axis=0)
    out = []
    for a, b in zip(ring, nxt, strict=True):
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / step_mm)))
        t = np.arange(n)[:, None] / n
        out.append(a + t * (b - a))
    return np.vstack(out)


def _with_seed(o: SimCameraOptions, seed: int) -> SimCameraOptions:
    from dataclasses import replace

    return replace(o, seed=seed)
