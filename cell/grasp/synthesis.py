"""The grasp planner: paper steps 1-4 for one scene, learned from examples.

    scene -> candidate points (free outline)      candidates.py   z
          -> valid points (tree 1)                learning.py     z'
          -> pairs -> reachable pairs (cascade)   cascade.py      s -> s'
          -> valid sets (tree 2)                  learning.py     s''
          -> grasp nearest to an accepted example, joints chosen by `choose_joints`

The planner only ever sees examples: trees and the nearest-example space are fitted from
them in `GraspPlanner.__init__`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from cell.cellconfig import Cell
from cell.errors import BadInput, NoFeasibleGrasp
from cell.examples import GraspExample
from cell.grasp.attributes import OutlinePoints, global_attributes, global_names, local_attributes, part_attributes
from cell.grasp.bands import PAD_COMPLIANCE_MM
from cell.grasp.candidates import candidate_points
from cell.grasp.cascade import STAGES, CascadeResult, Context, Pairs, joints_of, run_cascade
from cell.grasp.closing_line import onto_closing_line
from cell.grasp.height import TIP_BELOW_TOP_MM, grasp_z_mm, raised_grasp_z_mm
from cell.grasp.learning import LearnedModel, fit_model, nearest_example
from cell.grasp.load import holding, too_heavy
from cell.grasp.outline import part_rings
from cell.grasp.params import SynthesisParams
from cell.kinematics import Joints, normalize_axis_deg
from cell.scene import Scene

# valid contact points at most: all pairs are formed (~200 bytes each), 3.1 M pairs is ~0.6 GB; a part
# that fits the workspace has under 1600 at the 2 mm step
MAX_VALID_POINTS = 2500
# Outline samples (candidates) at most: 100 m of outline at the 2 mm step. A 1 km square took 9 s
# and 1.2 GB to be refused for its valid points; it is refused before it is sampled.
MAX_OUTLINE_SAMPLES = 50_000
# A finer step is tried (SynthesisParams.finer_steps) only while the outline samples and valid points it would give,
# estimated from the configured step's, stay under these (about 180 000 pairs, tens of ms): a part 300 mm
# round that has no grasp at 2 mm (wider than the stroke, say) is not sampled at 0.5 mm for nothing
FINER_MAX_OUTLINE_POINTS = 4000
FINER_MAX_VALID_POINTS = 600
# Raised grasp z tried at most (SynthesisParams.grasp_z_over_neighbours), the lowest ones: each is the whole
# pipeline again, with its finer steps
MAX_RAISED_GRASP_Z = 4


@dataclass(eq=False)
class Grasp:
    target: str
    contacts_mm: np.ndarray  # (n, 2) where the pads touch
    normals: np.ndarray  # (n, 2) outward unit normals at the contacts
    center_mm: np.ndarray  # (2,) midpoint of the contacts, the tool point
    axis_deg: float  # closing-axis direction in (-90, 90]
    opening_mm: float  # distance between the contacts
    grasp_z_mm: float
    joint_options: list[Joints]  # every IK solution within limits that passed the exact checks
    joints: Joints | None = None
    distance_to_example: float = float("nan")
    global_attributes: np.ndarray = field(default_factory=lambda: np.zeros(0))
    nearest_example: str | None = None
    pair: tuple[int, int] = (-1, -1)  # indices into the result's valid points

    def to_json(self) -> dict:
        d = {"target": self.target, "contacts": np.round(self.contacts_mm, 4).tolist(),
             "center": np.round(self.center_mm, 4).tolist(), "angle_deg": _printed_axis_deg(self.axis_deg),
             "opening_mm": round(float(self.opening_mm), 4), "grasp_z_mm": round(float(self.grasp_z_mm), 4),
             "joints": self.joints.rounded().as_dict() if self.joints else None,
             "normals": np.round(self.normals, 4).tolist(),
             "joint_options": [j.rounded().as_dict() for j in self.joint_options],
             "distance_to_example": round(float(self.distance_to_example), 4),
             "nearest_example": self.nearest_example}
        return d


class RankedGrasps(Sequence):
    """The valid sets as Grasps, nearest to an example first (rows `rows` of the reachable sets'
    arrays). Each Grasp is built when first read, then kept: a plan reads one or two of hundreds."""

    def __init__(self, target: str, grasp_z_mm: float, P: Pairs, pairs: np.ndarray, rows: np.ndarray,
                 contacts, normals, centers, openings, G, distances, example_ids: list, first: int = 0, built=None,
                 boundary=None):
        self._target, self._gz, self._P, self._pairs, self._rows = target, grasp_z_mm, P, pairs, rows
        self._arrays = (contacts, normals, centers, openings, G, distances, example_ids)
        self._first, self._built = first, {} if built is None else built
        self._boundary = boundary  # the target's outline: contacts onto the closing line (None: as found)

    def __len__(self) -> int:
        return len(self._rows) - self._first

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[r] for r in range(*i.indices(len(self)))]
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"grasp {i} of {n}")
        r = self._first + (i % n)
        if r not in self._built:
            q = int(self._rows[r])
            contacts, normals, centers, openings, G, distances, ids = self._arrays
            pk, (a, b) = int(self._pairs[q]), self._P.ij[self._pairs[q]].tolist()
            axis_deg, c, opening = self._P.axis_deg(pk), contacts[q], float(openings[q])
            if self._boundary is not None:
                c = onto_closing_line(self._boundary, c, centers[q], axis_deg)
                opening = float(np.linalg.norm(c[0] - c[1]))
            self._built[r] = Grasp(self._target, c, normals[q], centers[q], axis_deg, opening, self._gz,
                                   joints_of(self._P, pk), None, float(distances[r]), G[q], ids[r], (a, b))
        return self._built[r]

    def after_first(self) -> RankedGrasps:
        """The same ranking without its first grasp (step 5 refused it)."""
        return RankedGrasps(self._target, self._gz, self._P, self._pairs, self._rows, *self._arrays,
                            first=min(self._first + 1, len(self._rows)), built=self._built, boundary=self._boundary)


def _mm(values: list[float]) -> str:
    return f"{' and '.join(f'{v:g}' for v in values)} mm"


def _steps_note(steps: list[float]) -> str:
    """' (and at the finer steps 1 and 0.5 mm)': the steps a part with no grasp was tried at besides; '' for none."""
    return f" (and at the finer step{'s' if len(steps) > 1 else ''} {_mm(steps)})" if steps else ""


def _tried_note(reason: str, heights: list[float], tried: dict[float, list[float]], raised_reasons: list[str]) -> str:
    """What a part with no grasp was tried at besides the usual z (heights[0]) at the configured step: the finer
    steps `tried` at each z, the raised z (heights[1:]) and, where it differs from `reason`, why the lowest raised
    z gave none (the fingers clear the neighbours there and the palm meets a wall: what the operator must change)."""
    note = _steps_note(tried.get(heights[0], []))
    raised = heights[1:]
    if raised:
        finer = sorted({s for z in raised for s in tried.get(z, [])}, reverse=True)
        there = f", there also at the finer step{'s' if len(finer) > 1 else ''} {_mm(finer)}" if finer else ""
        why = raised_reasons[0] if raised_reasons and raised_reasons[0] != reason else ""
        note += f" (and at the grasp z {_mm(raised)} over lower neighbours{there}{': ' + why if why else ''})"
    return note


def _least_width_mm(part) -> float:
    """The part's width in its narrowest direction: the least, over its convex hull's edges, of the
    hull's extent across the edge."""
    hull = np.asarray(part.polygon.convex_hull.exterior.coords, float)
    d = np.diff(hull, axis=0)
    n = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    depth = np.einsum("kj,kij->ki", n, hull[None, :-1, :] - hull[:-1, None, :])  # edge k's normal, to vertex i
    return float((depth.max(1) - depth.min(1)).min())


def _printed_axis_deg(axis_deg: float) -> float:
    # folded again after rounding: -89.99996 rounds to -90.0, outside CONTRACT's (-90, 90]
    return normalize_axis_deg(round(float(axis_deg), 4))


def choose_joints(grasp: Grasp, examples: list[GraspExample], cell: Cell, scene: Scene) -> Joints | None:
    """Paper step 5: among `grasp.joint_options`, the configuration nearest to an example's that
    clears every part with the arm's links (`cell.configuration`), or None to refuse the grasp
    (the planner then takes the next best). Another rule can be passed as `choose=`."""
    from cell.configuration import choose_configuration

    return choose_configuration(grasp.joint_options, examples, cell, scene.parts)


@dataclass(eq=False)
class SynthesisResult:
    grasp: Grasp
    ranked: Sequence[Grasp]  # every valid reachable set, nearest to an example first (joints chosen for
    # the first only; `GraspPlanner.choose_for(grasp, scene)` runs step 5 for another)
    counts: dict
    time_ms: float
    candidates: OutlinePoints  # z free outline points with normals
    candidate_attributes: np.ndarray  # (z, F) local attributes
    point_valid: np.ndarray  # (z,) tree-1 verdict
    pairs: Pairs  # every pair of valid points (indices into the valid points)
    cascade: CascadeResult
    reachable_attributes: np.ndarray  # (s', G) global attributes of the reachable pairs
    set_valid: np.ndarray  # (s',) tree-2 verdict
    stage_time_ms: dict = field(default_factory=dict)
    context: Context | None = None  # the scene as the cascade saw it (obstacles by height, target edges)
    outline: OutlinePoints | None = None  # every outline sample, free or not
    free: np.ndarray | None = None  # (n,) which outline samples are free (the candidates)
    valid_sample_index: np.ndarray | None = None  # (z',) each valid point's index among the outline samples
    global_attribute_names: list = field(default_factory=list)
    step_mm: float | None = None  # the finer step that gave the grasp (None: the configured one)

    @property
    def valid_points(self) -> OutlinePoints:
        return self.candidates.subset(self.point_valid)

    @property
    def reachable_pairs(self) -> np.ndarray:
        """(s', 2, 2) contact points of the reachable pairs."""
        k = self.cascade.survivors
        return np.stack([self.pairs.ci[k], self.pairs.cj[k]], axis=1)

    @property
    def valid_sets(self) -> np.ndarray:
        """(s'', 2, 2) contact points of the valid sets."""
        return self.reachable_pairs[self.set_valid]

    def to_json(self) -> dict:
        d = self.grasp.to_json()
        d["counts"] = dict(self.counts)
        d["time_ms"] = round(self.time_ms, 3)
        d["ranked"] = len(self.ranked)
        if self.step_mm is not None:  # the counts are that step's
            d["step_mm"] = self.step_mm
        if self.global_attribute_names:
            d["global_attributes"] = {n: round(float(v), 4) for n, v in
                                      zip(self.global_attribute_names, self.grasp.global_attributes, strict=True)}
        return d


class GraspPlanner:
    """Fits both trees from the examples; `plan(scene)` runs steps 1-4 and step 5's hook."""

    def __init__(self, cell: Cell, examples: list[GraspExample], params: SynthesisParams | None = None,
                 choose: Callable = choose_joints):
        self.cell = cell
        self.examples = examples
        self.params = params or SynthesisParams()
        self.choose = choose
        self.model: LearnedModel = fit_model(examples, self.params, cell.gripper.pad_width_mm / 2)

    def plan(self, scene: Scene) -> SynthesisResult:
        """Steps 1-4 (and step 5's hook) at the usual grasp z and the configured step; where they give no
        grasp, at the finer steps (SynthesisParams.finer_steps) with the same trees, then at the grasp z over
        each lower neighbour (SynthesisParams.grasp_z_over_neighbours), likewise. The reason and counts of a
        part with no grasp at any z and step are the usual z's at the configured step (what `--explain`
        shows), with the steps and z tried appended."""
        t_start = time.perf_counter()
        p0 = self.params
        target = scene.target_part
        usual = grasp_z_mm(target.z_bottom_mm, target.z_top_mm, self.cell.gripper,
                           self.cell.scara.j3_mm if p0.grasp_z_within_j3 else None)
        # Each attempt is the whole pipeline at one z and one step. The order: z by z, lowest first (the
        # usual z, then over each lower neighbour), and at each z the configured step, then the finer steps
        # that z's configured-step counts allow (FINER_*). The lowest z holds most of the part on the pads,
        # and every grasp found at the usual z is the one found before the raised z existed. At most
        # (1 + MAX_RAISED_GRASP_Z) x (1 + finer_steps) attempts.
        def heights():  # the raised ones looked for only once the usual z gave none
            yield usual
            if p0.grasp_z_over_neighbours:
                yield from self._raised_z(scene, usual)

        first = None  # the usual z's failure at the configured step: the reason and counts reported
        tried: dict[float, list[float]] = {}  # the finer steps tried at each z
        done = []  # the z tried
        raised_reasons = []  # each raised z's reason at the configured step
        for z in heights():
            done.append(z)
            at_z = None  # this z's failure at the configured step
            for p in [p0, *p0.finer()]:
                if at_z is not None and not self._finer_worth(at_z, p):
                    break
                try:
                    result = self._plan(scene, p, t_start, z)
                except NoFeasibleGrasp as e:
                    if e.at_any_step or (first is None and self._too_wide(target)):
                        # too heavy or too wide for any grasp: so at any z and step, and the reason to give
                        e.counts["time_ms"] = round((time.perf_counter() - t_start) * 1e3, 3)
                        raise
                    if at_z is None:
                        at_z = e
                        first = first or e
                        if e is not first:
                            raised_reasons.append(e.reason)
                    else:
                        tried.setdefault(z, []).append(p.step_mm)
                    continue
                if p is not p0:
                    result.step_mm = p.step_mm
                return result
        first.reason += _tried_note(first.reason, done, tried, raised_reasons)
        first.args = (first.reason,)
        first.counts["time_ms"] = round((time.perf_counter() - t_start) * 1e3, 3)
        raise first

    def _finer_worth(self, at_z: NoFeasibleGrasp, p: SynthesisParams) -> bool:
        """Whether step p is tried at a z whose configured step gave no grasp: not for a part refused before its
        outline was sampled or with no free outline (so at any step), nor where the outline samples (free or
        not: a 40 m outline walled in but for 100 mm) and valid points it would give, estimated from the
        configured step's, exceed FINER_*."""
        c = at_z.counts
        ratio = self.params.step_mm / p.step_mm
        return bool(c.get("candidates")) and c.get("outline_points", 0) * ratio <= FINER_MAX_OUTLINE_POINTS and \
            c.get("valid_points", 0) * ratio <= FINER_MAX_VALID_POINTS

    def _too_wide(self, target) -> bool:
        """Is the part wider than the jaws take (the opening less the approach clearances) in every direction?"""
        g = self.cell.gripper
        return _least_width_mm(target) > g.opening_mm[1] - 2 * g.approach_clearance_mm + 1e-6

    def _raised_z(self, scene: Scene, usual_z: float) -> list[float]:
        """The grasp z over the lower neighbours that can be in the gripper's way (cell.grasp.height.
        raised_grasp_z_mm), lowest first, MAX_RAISED_GRASP_Z at most. In the way: within the fingers' reach of
        the target's outline (approach clearance, pad thickness and half its width, the pads' compliance and
        the contact tolerance, the obstacle margin) or the free gap; the palm only rises with the grasp z."""
        g, p, target = self.cell.gripper, self.params, scene.target_part
        reach = max(g.approach_clearance_mm + g.pad_thickness_mm + g.pad_width_mm / 2 + PAD_COMPLIANCE_MM
                    + p.contact_tol_mm, p.free_gap_mm) + p.obstacle_margin_mm
        tops = [o.z_top_mm for o in scene.obstacles if o.polygon.distance(target.polygon) <= reach]
        zs = raised_grasp_z_mm(target.z_bottom_mm, target.z_top_mm, usual_z, tops, self.cell.scara.j3_mm,
                               p.grasp_z_top_fallback)
        return zs[:MAX_RAISED_GRASP_Z]

    def _plan(self, scene: Scene, p: SynthesisParams, t_start: float, gz: float) -> SynthesisResult:
        cell = self.cell
        target = scene.target_part
        obstacles = scene.obstacles
        counts = {k: 0 for k in ("candidates", "valid_points", "pairs", "reachable", "valid_sets")}
        times = {}
        partial: dict = {}  # what the steps made so far: `cell grasp --explain` says why none was left

        def fail(reason, at_any_step: bool = False):
            counts["time_ms"] = round((time.perf_counter() - t_start) * 1e3, 3)
            raise NoFeasibleGrasp(reason, counts, partial, at_any_step)

        if gz > target.z_top_mm - TIP_BELOW_TOP_MM + 1e-9:  # CONTRACT: z_bottom <= grasp z <= z_top - 2
            fail(f"the part is {target.height_mm:g} mm tall: the pads need a grasp z at least "
                 f"{TIP_BELOW_TOP_MM:g} mm below its top and not below its bottom")

        samples = target.polygon.length / p.step_mm
        if samples > MAX_OUTLINE_SAMPLES:  # before sampling it: the attributes cost memory with the samples
            raise BadInput(f"part {target.id!r}: its outline is {target.polygon.length / 1000:.1f} m long, "
                           f"{samples:.0f} points at the {p.step_mm:g} mm step: more than the planner takes "
                           f"({MAX_OUTLINE_SAMPLES} points, {MAX_OUTLINE_SAMPLES * p.step_mm / 1000:g} m); "
                           f"{self._workspace_note()}")
        t0 = time.perf_counter()
        rings = part_rings(target, p.vertex_order_free)
        op_all, free = candidate_points(target, obstacles, p, rings, gz)
        cand_index = np.flatnonzero(free)
        cand = op_all.subset(cand_index)
        counts["outline_points"] = len(op_all)
        counts["candidates"] = len(cand)
        times["candidates"] = (time.perf_counter() - t0) * 1e3
        partial.update(outline=op_all, free=free, candidates=cand)
        if len(cand) == 0:
            fail(f"no free outline: every outline point is within {p.free_gap_mm:g} mm of another part above the "
                 f"grasp z ({gz:g} mm)")

        t0 = time.perf_counter()
        L = local_attributes(cand, target, p.cog_radius_outer_disc, p.closed_slit_mm)
        point_valid = self.model.point_tree.predict(L)
        vp = cand.subset(point_valid)
        counts["valid_points"] = len(vp)
        times["valid_points"] = (time.perf_counter() - t0) * 1e3
        partial.update(candidate_attributes=L, point_valid=point_valid)
        if len(vp) < p.n_contacts:
            fail(f"tree 1 keeps {len(vp)} of {len(cand)} candidate points: fewer than {p.n_contacts} valid "
                 "contact points")

        if len(vp) > MAX_VALID_POINTS:  # every pair is formed: memory grows with the square
            raise BadInput(f"part {target.id!r}: {len(vp)} valid contact points, "
                           f"{len(vp) * (len(vp) - 1) // 2} pairs: more than the planner takes "
                           f"({MAX_VALID_POINTS} points, {MAX_VALID_POINTS * (MAX_VALID_POINTS - 1) // 2} pairs, "
                           f"about 0.6 GB). The outline is {target.polygon.length / 1000:.1f} m long; "
                           f"{self._workspace_note()}")
        # no grasp holds it (cell/grasp/load.py): said before the pairs, after what makes the scene bad input
        # (a 10 m square weighs tons, and its size is the thing to say)
        heavy = too_heavy(target, cell)
        if heavy:  # (s, the sets of n valid points, is what z' makes, formed or not: it read 0 beside z' = 76)
            counts["pairs"] = math.comb(len(vp), p.n_contacts)
            fail(heavy, at_any_step=True)
        t0 = time.perf_counter()
        P = Pairs.of(vp.points, vp.normals, cand_index[point_valid])
        counts["pairs"] = len(P)
        ctx = Context.build(target, obstacles, cell, p, gz, op_all.points, op_all.ring, op_all.normals)
        cr = run_cascade(ctx, P)
        for name in STAGES:
            counts[f"after_{name}"] = cr.kept[name]
        counts["reachable"] = len(cr.survivors)
        counts["exact_checks"] = cr.exact_checks
        times["cascade"] = (time.perf_counter() - t0) * 1e3
        partial.update(pairs=P, cascade=cr)
        if len(cr.survivors) == 0:
            fail(self._empty_stage_reason(cr, ctx, P))

        t0 = time.perf_counter()
        k = cr.survivors
        contacts = np.stack([P.ci[k], P.cj[k]], axis=1)
        ij = P.ij[k]
        G = global_attributes(contacts, vp.chord_normals[ij], target, p.cog_radius_outer_disc, p.closed_slit_mm,
                              p.vertex_order_free)
        set_valid = self.model.set_tree.predict(G)
        counts["valid_sets"] = int(set_valid.sum())
        times["valid_sets"] = (time.perf_counter() - t0) * 1e3
        partial.update(reachable_pairs=contacts, reachable_attributes=G, set_valid=set_valid)
        if not set_valid.any():
            fail(f"tree 2 rejects all {len(k)} reachable contact sets")

        t0 = time.perf_counter()
        sel = np.flatnonzero(set_valid)
        dist, ex_idx = nearest_example(self.model, G[sel], part_attributes(target))
        # sets alike up to a symmetric part's symmetry lie at one distance up to float noise: rounded, the tie goes
        # to the first in outline order (from each ring's own first vertex: the same whichever vertex a file
        # lists first)
        order = np.argsort(np.round(dist, 9) if p.vertex_order_free else dist, kind="stable")
        # Sets that slip or roll out of the jaws are dropped, not ranked lower (cell/grasp/load.py: the judge's
        # demands at their worst): ranking by the load would move the learned choice on light parts too
        holds, why = holding(target, contacts[sel[order]], P.u[k[sel[order]]], cell,
                             gz if p.roll_bound_pad_overlap else None, gz if p.load_at_pad_patches else None)
        if not holds.all():
            counts["load_refused"] = int((~holds).sum())
            if why:
                fail(why)
            order = order[holds]
        normals = np.stack([P.ni[k], P.nj[k]], axis=1)
        centers = 0.5 * (contacts[:, 0] + contacts[:, 1])
        openings = np.linalg.norm(contacts[:, 0] - contacts[:, 1], axis=1)
        ranked = RankedGrasps(target.id, gz, P, k, sel[order], contacts, normals, centers, openings,
                              G, dist[order], [self.model.example_ids[e] for e in ex_idx[order].tolist()],
                              boundary=target.polygon.boundary if p.contacts_on_closing_line else None)
        # Step 5's hook may refuse a grasp (None: no configuration clears the parts): take the
        # next best, as the paper's "retry with the next grasp".
        refused = 0
        while len(ranked):
            ranked[0].joints = self.choose(ranked[0], self.examples, cell, scene)
            if ranked[0].joints is not None:
                break
            ranked = ranked.after_first()
            refused += 1
        counts["configuration_refused"] = refused
        if not len(ranked):
            fail(f"no arm configuration for any of the {refused} valid contact sets (step 5 refused them all)")
        best = ranked[0]
        # the alternatives keep their joint options; step 5 runs for one when it is needed
        # (`choose_for`), not for every ranked set: it checks the links against every part
        times["select"] = (time.perf_counter() - t0) * 1e3
        time_ms = (time.perf_counter() - t_start) * 1e3
        return SynthesisResult(best, ranked, counts, time_ms, cand, L, point_valid, P, cr, G, set_valid,
                               {**times, **{f"cascade_{n}": v for n, v in cr.time_ms.items()}},
                               context=ctx, outline=op_all, free=free, valid_sample_index=cand_index[point_valid],
                               global_attribute_names=global_names(p.scales_mm))

    def choose_for(self, grasp: Grasp, scene: Scene) -> Joints | None:
        """Step 5 for one of `result.ranked` (the best one has its joints already): sets and returns
        `grasp.joints`, None when the hook refuses it."""
        grasp.joints = self.choose(grasp, self.examples, self.cell, scene)
        return grasp.joints

    def _empty_stage_reason(self, cr: CascadeResult, ctx: Context, P: Pairs) -> str:
        g, p = self.cell.gripper, self.params
        first = next(n for n in STAGES if cr.kept[n] == 0)
        smallest, widest = g.opening_mm[0], g.opening_mm[1] - 2 * g.approach_clearance_mm
        clearance = f"opening {g.opening_mm[1]:g} mm minus 2 x {g.approach_clearance_mm:g} mm approach clearance"

        def narrower(which: str, at_most_mm: float) -> str:
            return (f"the part is narrower than the gripper's smallest opening: {which}contact points are at most "
                    f"{at_most_mm:.1f} mm apart, the jaws close to {smallest:g} mm at the least")

        why = {
            "stroke": f"every pair of valid points is outside the jaw stroke (contact distance at most "
                      f"{widest:g} mm: {clearance})",
            "reach": "no pair centre is within the arm's reach and the workspace",
            "antipodal": f"no two valid points face each other (normals within {p.max_normal_angle_deg:g} deg "
                         "of the closing line)",
            "precheck": "every facing pair puts a finger on material (the target or an obstacle taller "
                        "than the grasp z)",
            "contacts": "for every facing pair a jaw pad would touch other material first (a protrusion "
                        "in its band) or land on the part",
            "ik": "no grasp pose is reachable within the joint limits" + self._j3_note(ctx),
            "fingers_obstacles": "every remaining pair collides: a finger's swept footprint overlaps an "
                                 f"obstacle taller than the grasp z ({', '.join(ctx.finger_obstacle_ids)})",
            "palm": "every remaining pair collides: the palm overlaps an obstacle taller than its bottom",
        }[first]
        if first == "stroke" and len(P) and smallest > 0:
            narrow = P.d < smallest
            if narrow.all():
                return narrower("", float(P.d.max()))
            if narrow.any():
                why = (f"every pair of valid points is either closer than the jaws' smallest opening "
                       f"({smallest:g} mm) or farther apart than {widest:g} mm ({clearance})")
        if first in ("precheck", "contacts") and not P.stroke_refused:
            across = _least_width_mm(ctx.target)
            if across > widest + 1e-6:  # facing points fit on chords, but the part's widest stretch is in the band
                return (f"the part is wider than the gripper's stroke: at least {across:.1f} mm across in every "
                        f"direction, the jaws take at most {widest:g} mm ({clearance}); the facing points that fit "
                        f"lie on chords where a finger meets the part further out ({first} stage)")
        if first == "contacts" and P.pivot_refused and not P.stroke_refused:
            return (f"no reachable pair (contacts stage): where the pads would stop on the contacts, both rest on "
                    f"material narrower than {p.min_touch_width_mm:g} mm ({P.pivot_refused} pairs: two corners or "
                    f"tips), about which the part would pivot; the other facing pairs' pads touch other material "
                    f"first{self._reach_note(cr, first)}")
        if first == "contacts" and P.stroke_refused:
            # Contacts that fit the stroke on pads stopped wider apart than the stroke allows (a disc
            # just wider than it, grasped on a chord): say so, not "a protrusion"
            return (f"the part is wider than the gripper's stroke where the pads stop: contact points fit "
                    f"(at most {widest:g} mm apart) only where the pads would stop on material up to "
                    f"{PAD_COMPLIANCE_MM:g} mm further out ({clearance})")
        if STAGES.index(first) > STAGES.index("stroke"):
            # Facing points exist, but none close enough: say so, it is the usual cause.
            from cell.grasp.cascade import stage_antipodal, stage_stroke

            every = np.arange(len(P))
            facing = stage_antipodal(ctx, P, every)
            if facing.any() and not (facing & stage_stroke(ctx, P, every)).any():
                closest, farthest = float(P.d[facing].min()), float(P.d[facing].max())
                if farthest < smallest:
                    return narrower("facing ", farthest)
                if closest < smallest:
                    return (f"no facing contact points fit the jaws: they are {closest:.1f}-{farthest:.1f} mm apart, "
                            f"the jaws take {smallest:g}-{widest:g} mm ({clearance})")
                return (f"the part is wider than the gripper's stroke: facing contact points are at least "
                        f"{closest:.1f} mm apart, the jaws take at most {widest:g} mm ({clearance})")
        return f"no reachable pair ({first} stage): {why}{self._reach_note(cr, first)}"

    def _reach_note(self, cr: CascadeResult, first: str) -> str:
        """Where the reach stage took most pairs before a later stage took the rest, that is the cause to name
        (a part mostly beyond the workspace's edge: its few reachable pairs then do not face each other)."""
        within, reached = cr.kept["stroke"], cr.kept["reach"]
        if STAGES.index(first) <= STAGES.index("reach") or not 2 * reached < within:
            return ""
        ws, (r0, r1) = self.cell.workspace, self.cell.scara.reach_mm
        return (f"; before it, the reach stage left only {reached} of the {within} pairs within the stroke: the part "
                f"lies mostly beyond the arm's reach ({r0:g}-{r1:g} mm from the base) or the workspace (x "
                f"{ws.x_mm[0]:g} to {ws.x_mm[1]:g}, y {ws.y_mm[0]:g} to {ws.y_mm[1]:g} mm)")

    def _workspace_note(self) -> str:
        ws = self.cell.workspace
        return (f"the cell's workspace is {ws.x_mm[1] - ws.x_mm[0]:g} x {ws.y_mm[1] - ws.y_mm[0]:g} mm (a larger "
                "--step-mm takes fewer points)")

    def _j3_note(self, ctx: Context) -> str:
        lo, hi = self.cell.scara.j3_mm
        if ctx.grasp_z_mm < lo - 1e-9:
            return (f" (J3 reaches down to {lo:g} mm, the grasp z is {ctx.grasp_z_mm:g} mm: the part's top, "
                    f"{ctx.target.z_top_mm:g} mm, is less than {TIP_BELOW_TOP_MM:g} mm above J3's lowest)")
        if ctx.grasp_z_mm > hi + 1e-9:
            palm = self.cell.gripper.palm_offset_mm
            why = (f": lower, the palm ({palm:g} mm above the tips) would be inside the part, whose top is at z "
                   f"{ctx.target.z_top_mm:g} mm" if hi + palm < ctx.target.z_top_mm else "")
            return f" (J3 reaches up to {hi:g} mm, the grasp z is {ctx.grasp_z_mm:g} mm{why})"
        return ""

    def rules(self) -> dict:
        return {"points": self.model.point_tree.rules(), "sets": self.model.set_tree.rules()}
