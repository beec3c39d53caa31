"""Parameters of the grasp synthesis (paper steps 1-4), with the reasons for their defaults."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from cell.errors import BadInput

MIN_STEP_MM = 0.5
MAX_STEP_MM = 20.0  # coarser, a 20 mm washer has three candidate points: no grasp (exit 3) for an absurd step
MAX_FINER_STEPS = 4  # halvings of the step tried where none gave a grasp (finer_steps); MIN_STEP_MM bounds them too
PART_SHAPE_WEIGHT = 1.0  # SynthesisParams.part_shape_weight (docs/grasp.md: step 4)


@dataclass(frozen=True)
class SynthesisParams:
    # Step 1: candidate points.
    step_mm: float = 2.0  # arc-length step of the resampled outline: a sixth of the 12 mm pad
    free_gap_mm: float = 1.5  # outline closer than this to another part is contact, not free area
    # The plan does not depend on which vertex a file lists first, or on the ring's direction: each ring is
    # sampled from its own first vertex (cell.grasp.outline.own_first_vertex), the global attributes' angles
    # are worked out stably (arccos near 0 turned 1e-13 of noise into 1e-6 deg), and example distances tie
    # within 1e-9 (a symmetric part's alike sets: the first in outline order). The same hexagon listed
    # reversed had a grasp one way and none the other. Off in recordings made before it (cell.runtime.replay).
    vertex_order_free: bool = True
    # Step 2: local attributes. Convexity scales in mm (absolute: the pad has a fixed size, so
    # "flat at the pad's scale" is a physical property, not a relative one).
    scales_mm: tuple[float, ...] = (3.0, 6.0, 12.0, 24.0)
    # Step 3: cascade.
    max_normal_angle_deg: float = 20.0  # each contact normal vs the closing axis (friction cone)
    contact_tol_mm: float = 1.0  # the pad's first touch may be this far from the candidate point
    # A face slanted to the pad by a few degrees (a tapered web, a segmented outline's wobble) is
    # first touched at the band's side; with this on, the contacts stage also accepts a candidate
    # that the pad presses on there (within the pad's compliance of the first touch) and reports
    # the candidate as the contact. Recordings made before this option existed replay with it
    # off (cell.runtime.replay); docs/data.md gives the figures both ways.
    slanted_faces: bool = True
    # The reported contact is the nearest point of the material the pad touches to where the pad
    # stops (on a face slanted to the pad, or across a notch, the pad's line runs up to its 0.5 mm
    # compliance in front of the outline); off, the point on the pad's line, as recordings made
    # before this option existed have it (cell.runtime.replay).
    contacts_on_material: bool = True
    # The line through the reported contacts within this of the closing axis. Contacts offset across
    # the axis (a pad touching a slanted face at its edge) make a couple the grip must resist, and
    # the physical check holds grasps to 3 degrees (cell.physics.AXIS_TOL_DEG). 90 turns it off, as
    # recordings made before it existed have it (cell.runtime.replay).
    max_contact_skew_deg: float = 3.0
    # The approach opening is checked against the stroke at the lines where the pads stop, not at the
    # reported contacts (up to the pads' 0.5 mm compliance behind them): a 70.46 mm disc no longer
    # fits an 80 mm stroke with 5 mm clearances on a 69.9 mm chord. Off, as recordings made before
    # it existed have it (cell.runtime.replay).
    stroke_at_pad_lines: bool = True
    # The grasp z moves into J3's range where the usual one is outside it (cell.grasp.height). Off,
    # as recordings made before it existed have it (cell.runtime.replay).
    grasp_z_within_j3: bool = True
    # With contacts_on_material, the pads are looked at again where the gripper puts them, centred on
    # the line through the moved contacts' midpoint: they must stop at the contacts, within their
    # compliance and the slant of the face over the move (a star's contacts moved 6.4 mm across the
    # axis, and the pads there met a slanted arm 4.9 mm in front of them). Off, as recordings made
    # before it existed have it (cell.runtime.replay).
    pads_at_grasp_centre: bool = True
    # ... and stop within their compliance of each contact, as the contacts are reported (README). Off, the
    # pads there may stop up to |off| tan(max_normal_angle) further out on a face slanted to them (a star's
    # contact then lay 0.76 mm behind where the pads stop and 2 mm across from what they touch), as
    # recordings made before it existed have it (cell.runtime.replay).
    touch_within_compliance: bool = True
    # The weight check's lower bound of rolling about the jaw line (cell.grasp.load.roll_demand) takes each pad's
    # patch as high as the part at the grasp z and the load shared equally; off, the whole pad's height and no
    # friction spent on the load (a 176 g bar 8 mm tall was held 41 mm off its centre of gravity, which the
    # physical check says rolls out), as recordings made before it existed have it (cell.runtime.replay).
    roll_bound_pad_overlap: bool = True
    # The weight check keeps only the sets the judge finds holding: its demands for slipping and rolling at their
    # worst over where the pads stop and the patches they touch there, worked out from the outline
    # (cell.grasp.load.judged_demands). Off, the lower bounds above, under which the judge still refused the
    # grasps chosen on conrod_m, l_bracket_m and lever_m at their own mass (roll 1.04-1.21: patches narrower than
    # the pad, pads carrying the load unequally), as recordings made before it have it (cell.runtime.replay).
    load_at_pad_patches: bool = True
    # Contacts on a face square to the closing axis all along the pad are reported on the closing line through
    # the grasp centre (cell.grasp.closing_line): sampled a step apart, a pair on parallel faces lay up to half
    # a step either side of it, and the contacts' line up to 3 degrees off the reported axis. Off, as recordings
    # made before it existed have it (cell.runtime.replay).
    contacts_on_closing_line: bool = True
    # The relative distance to the centre of gravity (and the relative centre offset) in radii of the disc
    # the outer outline encloses, holes included: a ring's rim lies at 1, as a disc's. Off, the disc of
    # the part's material (holes taken out: a 60 / 40 mm ring's rim at 1.34, where tree 1 rejects
    # protrusions), as recordings made before 2026-12-04 have it (cell.runtime.replay).
    cog_radius_outer_disc: bool = True
    # With it, a cavity that only a slit narrower than this joins to the outside counts as enclosed: a split
    # washer's, a circlip's or a slit ring's bore is a hole, as a closed ring's (outline.reference_radius_mm).
    # Without, a 60 mm split ring's rim lay at 1.7 radii, where tree 1 rejects protrusions, and it had no
    # grasp. 0: not, as recordings made before it existed have it (cell.runtime.replay).
    closed_slit_mm: float = 6.0
    # The contacts stage refuses a pair whose pads both touch material narrower than this across the pad
    # (within the pad's compliance): two corners, two tips, a corner and a tip. The part would pivot
    # about the line through them (the physical check's 'both pads sit on sharp corners', its sharp
    # patch being 2 mm). One narrow pad is allowed, as the check allows it. 0: off, as recordings made
    # before it existed have it (cell.runtime.replay).
    min_touch_width_mm: float = 2.0
    # Where no grasp is found at step_mm, the outline is sampled again at half the step, then a quarter
    # (not below MIN_STEP_MM), with the same trees: facing points of a strip 1-1.2 mm wide lie up to a
    # step apart along it (45 degrees off the closing line at 2 mm), and the library's six poses
    # without a grasp at 2 mm (a gusset, the small gear) have stable ones at 1 mm. 0: the configured
    # step only, as recordings made before this existed have it (cell.runtime.replay).
    finer_steps: int = 2
    # Where no grasp is found at the usual grasp z (cell.grasp.height), the grasp z 1 mm above each lower
    # neighbour's top within the fingers' reach, lowest first, while it stays within CONTRACT.md's
    # [z_bottom, z_top - 2] and J3's range: the fingers pass over that neighbour (a nut 13 mm tall in a
    # 4 mm gasket's hole is held at 5 mm). Off, as recordings made before this existed have it
    # (cell.runtime.replay).
    grasp_z_over_neighbours: bool = True
    # ... and where a neighbour's top lies less than those 1 mm under the highest z the part allows (z_top - 2),
    # that z, last (CONTRACT.md: only obstacles taller than the grasp z are collision regions). Off, as
    # recordings made before it have it (cell.runtime.replay).
    grasp_z_top_fallback: bool = True
    # Obstacles widened by this much for the fingers and the palm: 0 for outlines given exactly (a
    # scene file); the cell loop plans on measured poses and keeps a margin (cell.runtime.loop).
    obstacle_margin_mm: float = 0.0
    n_contacts: int = 2  # a parameter of the learning and the attributes; the gripper model is 2-jaw
    # Learning.
    tree_max_depth: int = 4
    # 4, not 2: a leaf of 2 rows (one heatsink grasp's contacts) let square corners through (docs/grasp.md)
    tree_min_samples_leaf: int = 4
    # The trees grow with balanced class weights (a rejected contact or set weighs n_accepted / n_rejected
    # accepted ones: the operator's rejections are rare and each is meant), but in a leaf's vote the rarer class
    # weighs at most this many of the other: a leaf says invalid only where rejections are more than a fifth of
    # its rows. Unbounded (0, as recordings made before it have it: cell.runtime.replay), 500 examples of the
    # shipped operator gave rejected points an 18-fold weight, and a leaf of 329 accepted and 58 rejected points
    # (dist_cog_mm 16.4-36.6, convexity_6mm > 0.277: gear tips) voted invalid: the spur gears had no grasp.
    tree_minority_weight_max: float = 4.0
    augment_shift_steps: int = 1  # each example set is augmented by its neighbours +- this many steps
    # The choice (nearest accepted example) also compares the parts' shape (ln elongation, solidity; attributes.
    # part_attributes), normalised like the global attributes and weighted by this: a set is compared with the
    # examples on parts of its kind first. 0: the global attributes alone, as recordings made before it
    # existed have it (cell.runtime.replay): a centred set of a lever matched a centred box example exactly,
    # and 8 examples holding levers at an end among 40 centred ones left levers held in the middle.
    part_shape_weight: float = PART_SHAPE_WEIGHT
    # A contact labels only the outline its pad touches (not the roots between teeth under it);
    # off, every point within half a pad width along the outline, as older recordings have it
    label_touched_only: bool = True
    # ... the outline its pad touches seated at the contact projected onto the outline (as tree 2's attributes
    # take it): off, at the contact as given, as recordings made before it have it (cell.runtime.replay); the
    # reader takes contacts up to 5 mm off the outline, and the shipped examples' points moved 1 mm outward
    # labelled 339 points instead of 725, 1.5 mm 80, 4 mm none, silently.
    label_from_outline: bool = True

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "scales_mm":
                if len(v) < 3 or any(not (s > 0 and math.isfinite(s)) for s in v):
                    raise BadInput("synthesis parameter scales_mm needs at least three positive scales (mm)")
            elif isinstance(v, (int, float)) and not math.isfinite(v):
                raise BadInput(f"synthesis parameter {f.name} must be a finite number, got {v}")
            elif isinstance(v, (int, float)) and v < 0:
                raise BadInput(f"synthesis parameter {f.name} must not be negative, got {v}")
        if self.step_mm < MIN_STEP_MM:
            raise BadInput(f"synthesis parameter step_mm must be at least {MIN_STEP_MM:g} mm (all pairs of "
                           f"points are formed: a finer step costs memory with the square), got {self.step_mm:g}")
        if self.step_mm > MAX_STEP_MM:
            raise BadInput(f"synthesis parameter step_mm must be at most {MAX_STEP_MM:g} mm (a coarser step leaves "
                           f"small parts a handful of candidate points), got {self.step_mm:g}")
        if not 0 < self.max_contact_skew_deg <= 90:
            raise BadInput(f"synthesis parameter max_contact_skew_deg must be in (0, 90] degrees, got "
                           f"{self.max_contact_skew_deg:g}")
        if isinstance(self.finer_steps, bool) or not isinstance(self.finer_steps, int) or \
                self.finer_steps > MAX_FINER_STEPS:
            raise BadInput(f"synthesis parameter finer_steps must be a whole number from 0 to {MAX_FINER_STEPS}, "
                           f"got {self.finer_steps!r}")
        for flag in ("grasp_z_over_neighbours", "grasp_z_top_fallback", "label_from_outline", "load_at_pad_patches"):
            if not isinstance(getattr(self, flag), bool):
                raise BadInput(f"synthesis parameter {flag} must be true or false, got {getattr(self, flag)!r}")
        for key in ("part_shape_weight", "tree_minority_weight_max"):  # (a recording's manifest gives them too)
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise BadInput(f"synthesis parameter {key} must be a number, got {v!r}")
        if 0 < self.tree_minority_weight_max < 1:
            raise BadInput("synthesis parameter tree_minority_weight_max must be 0 (unbounded) or at least 1, got "
                           f"{self.tree_minority_weight_max:g}")
        if self.n_contacts != 2:
            raise BadInput(f"this cell's gripper has two jaws: n_contacts must be 2, got {self.n_contacts}")

    def finer(self) -> list[SynthesisParams]:
        """These parameters at the finer steps tried where the configured one gives no grasp: half the step,
        then a quarter ..., finer_steps of them at most, none below MIN_STEP_MM."""
        steps = [self.step_mm / 2 ** k for k in range(1, self.finer_steps + 1)]
        return [replace(self, step_mm=s) for s in steps if s >= MIN_STEP_MM - 1e-9]

    def with_(self, **kw) -> SynthesisParams:
        return replace(self, **{k: v for k, v in kw.items() if v is not None})
