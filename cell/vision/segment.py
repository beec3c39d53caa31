"""Frames -> part contours with holes, in pixels at sub-pixel accuracy.

Pipeline (one frame, see docs/vision.md for the parameters and why):
1. The tray's colour field B: a reference image of the empty tray when given, else a
   robust smooth fit to the frame itself (background.py), at the size of the frame's detection
   copies (detection.py). A frame whose tray looks taken for a part is read again with the other
   side as the tray (tray_checks.py).
2. At 1 / scale resolution (half on the default camera; larger frames: `SegmentParams.for_frame`),
   per pixel: brightness ratio r = sum(I) / sum(B) and chroma change c = |I / sum(I) - B / sum(B)|_1.
   A pixel is part if its chroma changed, or it is brighter than the tray, or darker than any
   shadow can make the tray (part_mask.py: colour_change.py, only in work_boxes.py's boxes).
3. Shadow-like pixels (darker, same chroma) are part only where the region they form is
   bounded by sharp edges (walls of parts, grey parts); soft-edged regions are shadows
   (shadowlike.py, sharp_edges.py).
4. Specks below a minimum area are dropped; parts touching each other are separated at
   narrow necks (watershed on the distance transform) or flagged `merged`; parts touching
   the image border are flagged `cut_off` (regions.py, touching.py).
5. Every boundary point is moved along its normal to where the full-resolution colour
   profile crosses half-way between the part and what lies outside it (sub-pixel, subpixel.py;
   outlines and holes: outlines.py).
6. Regions cut by the border that lie outside the tray are left out (outside.py).
Then `segment_to_mm` maps a segment to mm on the part's top plane, its walls taken into account (walls.py).

Pixel coordinates are CONTRACT-frame (origin at the top-left pixel's top-left corner).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from calibration.default import CAMERA_MM, FOCAL_PX, HEIGHT_PX, WIDTH_PX
from cell.vision.detection import Detection, as_bgr, detection_copies, field_tray, fitted_field, reference_tray
from cell.vision.outlines import regions_to_segments
from cell.vision.outside import split_outside
from cell.vision.part_mask import part_mask
from cell.vision.regions import split_regions
from cell.vision.tray_checks import (
    PARTS_AS_HOLES_SHARE,
    border_hole_share,
    holds_parts,
    panel_in_surround,
    panel_taken_for_a_part,
    region_seed,
    regions_besides,
    same_on,
    tray_taken_for_a_part,
    whole_parts,
)
from cell.vision.walls import segment_to_mm as segment_to_mm  # (the entry point's: cell.vision imports it from here)

DEFAULT_FRAME_PX = (WIDTH_PX, HEIGHT_PX)  # the default cell's camera: the pixel defaults below are for it
DEFAULT_MM_PER_PX = CAMERA_MM[2] / FOCAL_PX  # ... on the table (z = 0) it sees 0.5 mm per px (calibration/default.py)
SAME_CAMERA_SPREAD = 0.05  # a calibration within this of the default's px per mm reads as the default camera
# the pixel-sized defaults on the default camera; a field left None takes these, grown with the frame
DEFAULT_CAMERA_PX = {"scale": 2, "min_area_px": 300.0, "min_hole_area_px": 20.0, "sharp_edge": 0.06,
                     "min_lobe_radius_px": 6.0}


def frame_size_factor(shape) -> float:
    """How many times the default camera's frame a frame of `shape` (h, w, ...) is, by the long
    side, at least 1: a camera of the tray with a longer side (either way up, any aspect) has that
    many more pixels per mm. Smaller frames keep the default camera's pixel thresholds (a speck
    stays well above pixel noise)."""
    return max(1.0, max(shape[:2]) / max(DEFAULT_FRAME_PX))


def calibration_size_factor(cal) -> float:
    """How many times the default camera's pixels per mm a calibrated camera has on the
    calibration's plane (at the image centre): DEFAULT_MM_PER_PX / its mm per px, at least 1, and 1
    within SAME_CAMERA_SPREAD of it (the default camera's own mm per px varies by more across its
    view and with the parts' heights: 6 % at 45 mm; a recalibrated default cell stays the default).
    A camera coarser than the default keeps the default camera's pixel sizes, as smaller frames do."""
    f = DEFAULT_MM_PER_PX / cal.mm_per_px()
    return f if f >= 1.0 + SAME_CAMERA_SPREAD else 1.0


def _pixel_sizes(f: float, k: int) -> dict:
    """The default camera's pixel-sized values for a camera with f times its pixels per mm, detected
    at 1 / (2 k): areas x f^2, the sharp edge's ratio change per pixel / f, the lobe x f."""
    return {"scale": DEFAULT_CAMERA_PX["scale"] * k,
            "min_area_px": DEFAULT_CAMERA_PX["min_area_px"] * f * f,
            "min_hole_area_px": DEFAULT_CAMERA_PX["min_hole_area_px"] * f * f,
            "sharp_edge": DEFAULT_CAMERA_PX["sharp_edge"] / f,
            "min_lobe_radius_px": DEFAULT_CAMERA_PX["min_lobe_radius_px"] * f}


@dataclass(frozen=True)
class SegmentParams:
    """Segmentation parameters; the defaults suit the default cell (0.5 mm/px).

    The pixel-sized ones left None follow the frame (`for_frame`): the default camera's values
    (DEFAULT_CAMERA_PX) on frames up to its size, grown with the frame's linear size above it
    (areas by its square), so a 12 MP frame of the tray is read like a default one. A value
    given is used as it is."""

    tray: str = "auto"  # "bright": the tray is the bright side (back-lit panel in a dark surround)
    scale: int | None = None  # detection runs at 1 / scale resolution; outlines are refined at full resolution
    min_area_px: float | None = None  # full-resolution px; smaller regions are specks (75 mm^2 at 0.5 mm/px)
    min_hole_area_px: float | None = None
    chroma_min: float = 0.035  # L1 change of normalised colour that marks a part
    brighter_min: float = 0.12  # relative brightness above the tray that marks a part
    darker_min: float = 0.45  # relative darkening no shadow reaches: a part for sure
    noise_k: float = 5.0  # ... and the change must stand this many noise spreads above the tray's
    hysteresis: float = 0.6  # pixels this fraction of the way to a threshold join a part they touch
    shadow_aware: bool = True  # False: any darkening beyond `brighter_min` is a part
    sharp_edge: float | None = None  # ratio change per full-res px that counts as a sharp (material) edge
    crisp_edge: float | None = 0.06  # ... per detection px around a shadow-like region no part is near (a grey
    # part), at any detection scale; None: `sharp_edge` there too (as before 2026-12-05: at 1 / 2 grey parts
    # had to be darker than 0.65 of the tray)
    sharp_fraction: float = 0.6  # share of a shadow-like region's border that must be sharp
    vertical_px: tuple[float, float] | None = None  # image of the vertical (walls face it); None: centre
    walls_beyond: bool = True  # a wall is seen only where the image of the vertical lies beyond it (False: as
    # before 2026-12-05, anywhere within 72 degrees of its direction from the part's centre)
    refine: bool = True
    full_res_holes: bool = True  # look for holes again at 1 / (scale / 2) (full resolution on the default
    # camera; small holes blur away at detection resolution)
    refine_range_px: float = 4.0
    min_edge_contrast_dn: float = 10.0
    split_touching: bool = True
    neck_split: float = 0.75  # split where the neck is narrower than this x the smaller lobe's width
    neck_flag: float = 0.9  # ... and flag `merged` up to this ratio
    colour_split: float = 30.0  # CIE Lab distance (lightness counted half) between touching parts told apart
    seam_contrast_dn: float = 12.0  # brightness change along a cut that shows two parts meet there
    min_lobe_radius_px: float | None = None  # full-res px: teeth and tabs are not lobes of touching parts
    drop_outside_tray: bool = True  # leave out regions cut by the border that lie outside the tray (outside.py)

    @classmethod
    def for_calibration(cls, cal, min_area_mm2: float = 75.0, z_mm: float = 0.0, **kw) -> SegmentParams:
        """Parameters for the calibrated camera's frames. The speck and hole areas are given in mm^2 on
        the plane at z; the other pixel-sized ones follow the camera's pixels per mm as `for_frame`
        follows a frame's size, with f = `calibration_size_factor(cal)` (1 for the default cell's
        camera and any coarser one: the default camera's values): the smallest lobe x f, and the
        detection at 1 / (2 k) with the sharp edge's ratio change per pixel / g, where g is f but not
        above the frame's own size factor and k the whole number nearest g. These two are about the
        detection copy's pixels: a close-up camera whose frame is no larger than the default's keeps
        its detection copy and its edge threshold (per mm a lower one lets the noise of a finer
        copy through; small frames are detected at full size anyway). Keyword arguments win."""
        mm_per_px = cal.mm_per_px(z_mm)
        vp = tuple(float(v) for v in cal.vertical_vanishing_px())
        f = calibration_size_factor(cal)
        g = min(f, frame_size_factor((cal.height_px, cal.width_px)))
        fixed = {**_pixel_sizes(g, _nearest_whole(g)),
                 "min_lobe_radius_px": DEFAULT_CAMERA_PX["min_lobe_radius_px"] * f,  # a size in the scene
                 "min_area_px": min_area_mm2 / mm_per_px ** 2, "min_hole_area_px": max(6.0, 2.5 / mm_per_px ** 2),
                 "vertical_px": vp}
        return cls(**{**fixed, **kw})

    def for_frame(self, shape) -> SegmentParams:
        """These parameters with every pixel-sized one left None set for a frame of `shape` (h, w, ...):
        the default camera's value x the frame's size factor f (areas x f^2; the sharp edge's ratio
        change per pixel / f; the detection scale x the whole number nearest f, so that a detection
        pixel stays about the default's size in the scene)."""
        unset = [k for k in DEFAULT_CAMERA_PX if getattr(self, k) is None]
        if not unset:
            return self
        f = frame_size_factor(shape)
        grown = _pixel_sizes(f, _nearest_whole(f))
        return replace(self, **{k: grown[k] for k in unset})


def _nearest_whole(x: float) -> int:
    """The whole number nearest x >= 1, halves down (the finer detection)."""
    return max(1, math.ceil(x - 0.5))


@dataclass
class Segment:
    """One part region in the frame (CONTRACT-frame pixels).

    Attributes
    ----------
    outline_px : ndarray of shape (n, 2)
        Outer contour, sub-pixel, counter-clockwise in (u, v) axes.
    holes_px : list of ndarray of shape (m, 2)
    area_px, centroid_px : float, ndarray of shape (2,)
        Of the region (outline minus holes).
    merged : bool
        The region looks like touching parts that could not be separated.
    cut_off : bool
        The region touches the image border: the part is not all in view.
    mean_bgr : tuple of 3 floats
        Mean colour inside the region.
    """

    outline_px: np.ndarray
    holes_px: list[np.ndarray] = field(default_factory=list)
    area_px: float = 0.0
    centroid_px: np.ndarray = field(default_factory=lambda: np.zeros(2))
    merged: bool = False
    cut_off: bool = False
    mean_bgr: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_json(self, decimals: int = 2) -> dict:
        return {"outline_px": np.round(self.outline_px, decimals).tolist(),
                "holes_px": [np.round(h, decimals).tolist() for h in self.holes_px],
                "area_px": round(float(self.area_px), decimals),
                "centroid_px": np.round(self.centroid_px, decimals).tolist(),
                "merged": bool(self.merged), "cut_off": bool(self.cut_off)}


class SegmentList(list):
    """`segment_frame`'s result: the part regions on the tray, largest first (a list of `Segment`),
    and in `outside_tray` the regions left out because they lie outside the tray (the surround of a
    tray or back-lit panel that does not fill the view; cell/vision/outside.py), largest first."""

    def __init__(self, segs=(), outside_tray=()):
        super().__init__(segs)
        self.outside_tray: list[Segment] = list(outside_tray)


def segment_frame(frame_bgr: np.ndarray, params: SegmentParams | None = None, *,
                  reference_bgr: np.ndarray | None = None) -> SegmentList:
    """Segment one frame into part regions, largest first. Regions cut by the image border that lie
    outside the tray (its surround, where the tray does not fill the view) are left out of the list
    and given in its `outside_tray` (`SegmentParams.drop_outside_tray=False` keeps them in).

    Parameters
    ----------
    frame_bgr : ndarray of shape (h, w, 3) uint8 (a grey (h, w) image is accepted)
    params : SegmentParams, optional
    reference_bgr : ndarray of shape (h, w, 3), optional
        The empty tray under the same lighting; without it the tray is estimated.
    """
    frame = as_bgr(frame_bgr)
    gain = exposure_gain(frame)
    if gain == 1.0:
        return _segment_frame(frame, params, reference_bgr)
    # an underexposed frame (low light): its DN-sized steps (the tray colour's histogram bins and
    # ball, the edges' contrast) are brought to a normal exposure's; ratios and chroma are unchanged
    ref = None if reference_bgr is None else _gained(as_bgr(reference_bgr), gain)
    segs = _segment_frame(_gained(frame, gain), params, ref)
    for s in [*segs, *segs.outside_tray]:
        s.mean_bgr = tuple(float(v) / gain for v in s.mean_bgr)  # the frame's own colours
    return segs


DARK_FRAME_DN = 128.0  # a frame whose bright end (99.5th percentile of each pixel's brightest channel) is
EXPOSED_DN = 200.0  # ... below this is scaled so that its bright end lies here, ...
MAX_GAIN = 8.0  # ... by at most this (3 stops: a covered lens's noise is not blown up into parts)


def exposure_gain(frame: np.ndarray) -> float:
    """The gain that brings an underexposed frame's bright end to EXPOSED_DN (1 for a frame whose bright
    end reaches DARK_FRAME_DN, every frame of a lit cell): the tray fit's and the edges' steps are in
    DN and sized for a normal exposure (Festo frame 1 at 0.35 x its exposure: every colour within the
    tray colour's 40 DN ball, the tray fitted as the mean of everything, no part found)."""
    sample = frame[::8, ::8]  # (a strided view: a 12 MP frame is looked at in 190 000 pixels)
    top = float(np.percentile(sample.max(axis=2), 99.5)) if sample.size else 0.0
    if top >= DARK_FRAME_DN:
        return 1.0
    return min(EXPOSED_DN / max(top, 1.0), MAX_GAIN)


def _gained(img: np.ndarray, gain: float) -> np.ndarray:
    return cv2.convertScaleAbs(img, alpha=gain)  # (rounded, saturated to 0 - 255)


def _segment_frame(frame: np.ndarray, params: SegmentParams | None, reference_bgr: np.ndarray | None
                   ) -> SegmentList:
    p = (params or SegmentParams()).for_frame(frame.shape)
    d = detection_copies(frame, p)
    segs = _segments_of(frame, p, d, reference_bgr)
    if not p.drop_outside_tray:
        return SegmentList(segs)
    # the surround of a tray that does not fill the view (outside.py); the outlines' refinement range
    # is how far a region's edge may lie from where the tray's pixels end
    on_tray, outside = split_outside(segs, d.det.shape[:2], d.scale, p.min_area_px,
                                     max(p.refine_range_px, 2.0 * p.scale))
    return SegmentList(on_tray, outside)


def _segments_of(frame: np.ndarray, p: SegmentParams, d: Detection, reference_bgr: np.ndarray | None
                 ) -> list[Segment]:
    """Every region of the frame, the surround of the tray included: the tray's colour from the
    reference image or fitted, and for a frame whose tray looks taken for a part the other readings."""
    if reference_bgr is not None:
        return _segment(frame, p, d, *reference_tray(reference_bgr, frame, d))
    tray_field = fitted_field(d, p.tray)
    segs = _segment(frame, p, d, *field_tray(tray_field, d))
    if p.tray == "auto" and panel_taken_for_a_part(segs, frame.shape, tray_field, p):
        # the lit panel cut by the border so that it holds no part as a hole (each part it holds is
        # cut by the border too, a notch in its outline): no hole areas to compare (pca_test1.jpg with
        # its left 280 px cut away: the panel as a 115,356 px part). The bright side as the tray is
        # taken when no region holds others as holes, step 6 leaves out the dark side (the first
        # reading's tray, a quarter of the view at least) as the surround and keeps no region over
        # TRAY_TAKEN_SHARE: it explains the frame as parts on a panel in a dark surround
        seg_other = _segment(frame, p, d, *field_tray(fitted_field(d, "bright"), d))
        if not holds_parts(seg_other, frame.shape) and panel_in_surround(seg_other, frame.shape, p, d):
            return seg_other
        return segs
    if p.tray == "auto" and tray_taken_for_a_part(segs, frame.shape):
        # a back-lit panel in a dark surround: the dark side outnumbered the panel, so the panel came
        # out as one part cut by the border with the parts as its holes; the panel as the tray
        # shows more whole parts (and costs a second pass only on such frames). Counted, not
        # summed: a tray beside a lighter table would be one whole part as large as the tray
        # The same with the panel dark and the surround light (light parts on a dark panel, or the
        # photograph's contrast inverted): the bright side is the surround, the tray taken already;
        # the panel's own colour, looked for in the region taken for a part, is the other reading
        seed = region_seed(segs, frame.shape, d)
        fields = [fitted_field(d, "bright")]
        first_hole_share = border_hole_share(segs, frame.shape)
        if first_hole_share >= PARTS_AS_HOLES_SHARE:
            fields.append(fitted_field(d, "auto", seed))
        best, tried = segs, [tray_field]
        for other in fields:
            # the tray model only chooses the field: where a field is one fitted already (the Festo
            # frames: their tray is the bright side), so are the segments; a field that agrees with
            # one tried on the region in question (the lit panel of pca_test1.jpg, fitted from the
            # bright side and from the region) reads the frame alike: not run again
            if any(np.array_equal(other, f) or same_on(other, f, seed) for f in tried):
                continue
            tried.append(other)
            seg_other = _segment(frame, p, d, *field_tray(other, d))
            # and it must leave less in the holes of a large region cut by the border (the parts seen
            # as holes of the tray taken for a part): the Festo frames' table as the tray makes the
            # paper with the parts on it such a region, 8 - 11 % holes against 1 - 5 % the first time.
            # More whole parts; or no region holding others as holes over TRAY_TAKEN_SHARE of the
            # frame at all (a reading that has none explains the frame as parts on a tray) and more
            # regions besides such regions. Whole parts alone were fooled where the view cuts most
            # parts (pca_test1.jpg cut at u = 520: ragged pieces of the panel's glow counted as 2
            # whole parts, the panel's 1 whole bar and 5 cut off as 1; 4 regions besides the panel
            # against 7). A dark tray beside a lighter table, the table taken for the tray, still has
            # such a region (the tray, its parts as holes) and stays refused; a reading that finds
            # little (no holes, but fewer regions: the Festo frames inverted) too
            if (border_hole_share(seg_other, frame.shape) < first_hole_share
                    and (whole_parts(seg_other) > whole_parts(best)
                         or (not holds_parts(seg_other, frame.shape)
                             and regions_besides(seg_other, frame.shape) > regions_besides(best, frame.shape)))):
                best = seg_other
        return best
    return segs


def _segment(frame: np.ndarray, p: SegmentParams, d: Detection, bg: np.ndarray, bg_coarse: np.ndarray | None
             ) -> list[Segment]:
    """`segment_frame` with the tray's colour `bg` at detection size (and `bg_coarse` at 1 / COARSE
    of it, or None)."""
    mask, boxes = part_mask(d.det, bg, p, d.scale, d.smoothed.result(), bg_coarse)
    if not mask.any():
        return []  # the empty tray
    pieces = split_regions(mask, boxes, p, d.scale, d.det_u8)
    segs = regions_to_segments(pieces, frame, d.det, bg, p, d.scale)
    segs.sort(key=lambda g: -g.area_px)
    return segs
