"""The cell loop: frame -> segmentation -> which part is where -> the next part of the
sequence -> grasp and configuration -> pick commands -> the arm, until the sequence is done.

The loop only sees its sources (a camera with `read()`, an `Arm` on a CAN bus) and its
sinks (a decision sink such as a `RecordingWriter`, an optional rerun `Viz`, the
`RunControl` the operator acts through). Simulated or real, recorded or live, is decided by
whoever builds those; `cell replay` runs this same code on recorded frames.

Failures, as an operator wants them handled (each is logged with its reason):
- no feasible grasp: stop and ask, or skip the part (`on_no_grasp="skip"`);
- a missed grip (jaws closed past the expected width), or a part that slipped out of the jaws as
  they lifted it (the check grip after the lift closed past it): open, lift, look again (a new frame),
  retry once with the best grasp there other than the one that missed, then stop and ask;
- a part that did not leave the tray (seen again where it was picked): stop and ask;
- a part that fell out of the jaws on the way to the drop-off (the check above it closed past it): not removed;
  the arm goes up and opens there, and the next frame says where it is (back on the tray: picked again after the
  operator's reset; not on the tray: the operator is asked to find it); either way, stop and ask;
- a drive fault: the arm has stopped every axis; stop until the operator resets;
- a missing or unreadable frame: retry, then stop and ask.
"Stop and ask" waits for the operator at the station; without an operator (plain `cell run`)
the run ends there with the reason.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from shapely.geometry import Polygon, box

from cell.cellconfig import Cell
from cell.disassembly import lift_blocked_reason, parts_on_top
from cell.errors import BadInput, CellError, NoFeasibleGrasp
from cell.examples import GraspExample, append_examples, load_examples, parse_example
from cell.fileio import write_atomic
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import Grasp, GraspPlanner
from cell.kinematics import Joints
from cell.recording import RecordingFailed
from cell.runtime.control import Faulted, RunControl, Stopped
from cell.runtime.matching import Region, axis_deg_eigh, locate, locate_anywhere, unexplained
from cell.runtime.motion import (
    TRANSIT_CHECK,
    above,
    carry_off_commands,
    pick_commands,
    retreat_opening_mm,
)
from cell.runtime.pickway import TRAVEL_MARGIN_MM, LinksWouldHit, check_links, clear_way, travel_z_mm
from cell.runtime.ways import go_to
from cell.scene import REST_MM, Assembly, Part, Scene
from cell.vision.sources import blank_frame_reason, saturated_share

# Fingers and palm keep this clear of the other parts: their poses are measured (~0.3 mm off in
# the vision bench), and a finger planned flush with a neighbour came down on it
SEEN_OBSTACLE_MARGIN_MM = 1.0


# A knocked camera (or a moved tray) moves every part alike between two frames, where only the part the jaws last
# touched, and perhaps a neighbour it pushed, should move. Unmoved parts measured between frames (7 runs of the three
# assemblies at 2 and 8 mm and the shipped recording, 100 poses): their centroids 0.035 mm (median), 0.17 mm at most.
KNOCK_MM = 3.0  # a common motion moving the parts this far on average (2 mm kept the fingers clear, 5 mm did not)
KNOCK_DEG = 1.5  # ... or turning them this far (1 degree kept the fingers clear, 2 degrees did not)
ALIKE_MM = 1.0  # moved alike: each part within this of the common motion, plus ALIKE_SHARE of its own shift (a
ALIKE_SHARE = 0.1  # shifted image moves a 40 mm tall part's top 5 % less in mm than a flat part)
# A region no part explains reaches in across the tray's edge when, mapped at the table, it lies on the tray and
# beyond this band round it (a 40 mm tall thing on the tray's edge, 250 mm off the camera's axis, maps 12.5 mm out)
REACH_IN_BAND_MM = 15.0
STATIC_SHARE = 0.5  # a region lying this much of its area (at the table) on a fixture of the first frame is it
SWEEP_STEP_MM = 5.0  # a region of unknown height is mapped on planes this far apart (`swept_outline`)


@dataclass(frozen=True)
class CommonMotion:
    """A rigid motion of the parts `parts` between two frames: their mean shift and the turn."""

    parts: tuple[str, ...]
    dx_mm: float
    dy_mm: float
    turn_deg: float
    left_out: str | None = None  # the one part seen in both frames that moved otherwise (a pushed neighbour)

    def text(self) -> str:
        but = "" if self.left_out is None else f" but {self.left_out}"
        return (f"every part seen in both frames{but} ({', '.join(self.parts)}) moved alike, by ({self.dx_mm:.1f}, "
                f"{self.dy_mm:.1f}) mm / {self.turn_deg:.1f} deg since the last frame")


def common_motion(before_mm: dict[str, tuple[float, float]], after_mm: dict[str, tuple[float, float]]
                  ) -> CommonMotion | None:
    """The rigid motion taking every part's centroid `before_mm` to `after_mm` (all parts, or all but one of four
    or more: a neighbour the pick pushed), when it moves them more than KNOCK_MM on average or turns them more
    than KNOCK_DEG; else None. Two parts fit a turn whenever their distance stayed: of two, only a shift counts.
    (All but one of three is two: a part resting on another, pushed together, is no knock.)"""
    ids = sorted(before_mm)
    subsets = [ids] + ([[i for i in ids if i != out] for out in ids] if len(ids) >= 4 else [])
    for subset in (s for s in subsets if len(s) >= 2):
        a = np.array([before_mm[i] for i in subset])
        b = np.array([after_mm[i] for i in subset])
        turn_deg = _fitted_turn_deg(a, b) if len(subset) >= 3 else 0.0
        c, sn = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
        fitted = (a - a.mean(axis=0)) @ np.array([[c, sn], [-sn, c]]) + b.mean(axis=0)
        shifts = np.linalg.norm(b - a, axis=1)
        if np.any(np.linalg.norm(fitted - b, axis=1) > ALIKE_MM + ALIKE_SHARE * shifts):
            continue
        if shifts.mean() > KNOCK_MM or abs(turn_deg) > KNOCK_DEG:
            dx, dy = (b - a).mean(axis=0)
            left_out = next((i for i in ids if i not in subset), None)
            return CommonMotion(tuple(subset), float(dx), float(dy), float(turn_deg), left_out)
    return None


def _fitted_turn_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The turn of the least-squares rigid fit of the points `a` onto `b` (2D Kabsch)."""
    h = (a - a.mean(axis=0)).T @ (b - b.mean(axis=0))
    return float(np.degrees(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])))


def swept_outline(polygon_at):
    """`Region.polygon_at` for a region nothing was located in (its height unknown): the outline mapped on planes
    every SWEEP_STEP_MM from the table up to the top, together (each of its pixels may lie at any of those heights):
    where the thing may stand, however tall up to the top. (Mapped as a prism that tall with its walls taken out,
    an 8 mm block assumed 40 mm tall crossed itself and kept a quarter of its area, or none.)"""
    import shapely

    def at(z_top_mm: float, z_bottom_mm: float) -> Polygon:
        planes = max(2, int(np.ceil(z_top_mm / SWEEP_STEP_MM)) + 1)
        return shapely.union_all([polygon_at(z, z) for z in np.linspace(0.0, z_top_mm, planes)])

    return at


def valid_area(poly: Polygon):
    """All the area of a self-crossing polygon as a valid (multi)polygon. (Not the largest piece of
    `buffer(0)`: a motor in a region merged with its base plate, mapped at its top height, crossed
    itself, and keeping the largest piece dropped the motor: "motor is not found".)"""
    import shapely

    fixed = shapely.make_valid(poly)
    pieces = [g for g in getattr(fixed, "geoms", [fixed]) if g.geom_type in ("Polygon", "MultiPolygon")]
    return shapely.union_all(pieces) if pieces else Polygon()


def loop_planner_params() -> SynthesisParams:
    """The planner's parameters as the loop runs it on measured poses."""
    return SynthesisParams(obstacle_margin_mm=SEEN_OBSTACLE_MARGIN_MM)


class StopRun(CellError):
    """The loop stopped and nobody is there to answer (no station): the reason is the message."""


class HandWork(CellError):
    """The operator must do something by hand before the loop can go on (take a part out of the jaws):
    nothing failed, the loop asks."""


def across_edge(at_table: Polygon, cut_off: bool, tray: Polygon) -> str:
    """What a region no part explains reaches in across ("the frame's edge", "the tray's edge"), "" when nothing:
    `at_table` its outline mapped at the table, `cut_off` whether the frame's edge cuts it, `tray` the tray's box.
    Cut by the frame's edge, it reaches in only when it reaches onto the tray's box (a bin or the tray's wall beside
    it does not); else across the tray's edge when it lies on the box and beyond it by more than
    `REACH_IN_BAND_MM` (the box is a configured work area, not the tray's physical edge)."""
    if not at_table.intersects(tray):
        return ""
    if cut_off:
        return "the frame's edge"
    return "" if at_table.within(tray.buffer(REACH_IN_BAND_MM)) else "the tray's edge"


@dataclass
class LoopOptions:
    on_no_grasp: str = "stop"  # "stop" (ask the operator) or "skip" the part
    frame_retries: int = 2
    grip_retries: int = 1  # retries after a missed grip, each planned on a new frame
    interactive: bool = False  # an operator answers (the station); else a stop ends the run
    min_area_mm2: float = 75.0  # smaller regions are dust
    lift_check: bool = True  # grip again after the lift (motion.pick_commands); off in recordings made before it
    # A part picked again (it stayed on the tray, the run stopped on it) goes on in its report: its attempts
    # and times add up. Off in recordings made before: their reports started anew.
    whole_part_report: bool = True
    # A part the camera finds with its centre off the tray is not picked (the arm picks on the tray, as `cell hw
    # pick` does): the loop stops and asks. Off in recordings made before: it was picked.
    tray_check: bool = True
    # A frame that cannot show the tray (dark, overexposed, one flat colour) is unreadable, retried, then a stop;
    # and the part picked last, not found where it was, is looked for anywhere on the tray (it fell back 80 mm
    # away). Before (off in older recordings), both read as "gone": the part counted as removed.
    removal_checks: bool = True
    # The registration's start along a region's axis in closed form (the same on every machine); off in recordings
    # made before: LAPACK's eigenvector, whose sign started the search half a turn round on 3 of 4 outlines.
    axis_closed_form: bool = True
    # A part resting on the target with its bottom up to 0.5 mm under the target's top (the height overlap the
    # assembly files allow) blocks its lift; off in recordings made before: only a part wholly above it did.
    lift_rest_overlap: bool = True
    # A shadow-like strip beside a part is its wall only where the image of the vertical lies beyond it
    # (`SegmentParams.walls_beyond`); off in recordings made before: a part holding the image of the vertical
    # kept its own shadow as a wall on the side the vertical leans to.
    walls_beyond: bool = True
    # A shadow-like region no part is near is material when its edge is crisp at the detection's own resolution
    # (`SegmentParams.crisp_edge`); off in recordings made before: frames detected at 1 / 2 (960 px wide and more)
    # asked it for the sharp edge per full-resolution px, and grey parts lighter than 0.65 of the tray were lost.
    crisp_edges: bool = True
    # The grip checked again above the drop-off, before the lowering (`motion.TRANSIT_CHECK`): a part that fell out
    # on the way is "lost", not removed, and the run stops and says whether the next frame shows it back on the
    # tray. Off in recordings made before: a nut dropped off the tray on the carry counted as removed.
    transit_check: bool = True
    # Every part seen in this frame and the last (not the one the jaws last touched) moved alike, by more than a few mm
    # (`common_motion`): the camera or the tray was moved; stop and ask, not plan on it. Off in recordings made
    # before: a knocked camera's frames were planned on, and fingers came down on a pulley's rim.
    common_motion_check: bool = True
    # A region no part explains that reaches in across the frame's edge or the tray's (a person's arm, a cable) stops
    # the loop and asks; one wholly on the tray stays an obstacle, as tall as the assembly's tallest part (not the
    # tallest left). Off in recordings made before: an arm reaching in was an obstacle whose height fell from 40 to
    # 3 mm as parts left, and the arm kept moving.
    stranger_checks: bool = True
    # A pick's move that none of the few simple ways round takes (a longer arm's elbow flip, whose stretched arm leaves
    # the workspace at every J1 tried) goes the grid's way (`ways._grid_way`), each step with the links checked too.
    # Off in recordings made before: only a home searched the grid, and such a pick had no way (the grasp refused).
    grid_ways: bool = True


@dataclass
class PartReport:
    part: str
    outcome: str  # removed | skipped | lost (fell out of the jaws on the way to the drop-off); in the summary also
    # stopped (the part the run stopped on) and carried (let go at the drop-off, the run stopped before a frame
    # showed it gone)
    attempts: int = 0
    motion_s: float = 0.0  # on the arm's clock (simulated seconds in simulation)
    planning_s: float = 0.0  # wall time of perception and planning
    reason: str = ""

    @property
    def cycle_s(self) -> float:
        return self.motion_s + self.planning_s

    def to_json(self) -> dict:
        return {"part": self.part, "outcome": self.outcome, "attempts": self.attempts,
                "motion_s": round(self.motion_s, 3), "planning_s": round(self.planning_s, 4),
                "cycle_s": round(self.cycle_s, 3), "reason": self.reason}


def _as_saved(example: GraspExample) -> GraspExample:
    """The example as the example file (and a recording) hold it, rounded: a live run learns exactly
    what a replay of it reads back."""
    return parse_example(example.to_json(), f"example {example.id}")


class DecisionSink:
    """Where decisions go (a RecordingWriter, a replay comparison); the default drops them."""

    def write_frame(self, index: int, frame_bgr) -> str | None:
        return None

    def write_decision(self, record: dict) -> None:
        pass


@dataclass
class LoopState:
    """What the station shows: the last frame, what was seen there, the pending proposal."""

    frame: np.ndarray | None = None
    frame_index: int | None = None
    seen: dict = field(default_factory=dict)  # part id -> Part at its measured pose
    proposal: dict | None = None


class CellLoop:
    def __init__(self, *, cell: Cell, calibration, assembly: Assembly, camera, arm, control: RunControl,
                 examples_path: str | Path, sink: DecisionSink | None = None, viz=None,
                 options: LoopOptions | None = None, planner_params=None, examples_out: str | Path | None = None,
                 taught=None):
        from cell.vision import SegmentParams

        self.cell, self.cal, self.assembly = cell, calibration, assembly
        self.camera, self.arm, self.control = camera, arm, control
        self.examples_path = Path(examples_path)
        # New examples (rejects, teaching) go here; the first one starts it as a copy of the
        # examples in use (the shipped default file is never written).
        self.examples_out = Path(examples_out) if examples_out is not None else self.examples_path
        self.sink = sink or DecisionSink()
        self.viz = viz
        self.options = options or LoopOptions()
        self.planner_params = planner_params if planner_params is not None else loop_planner_params()
        self.segment_params = SegmentParams.for_calibration(
            calibration, self.options.min_area_mm2, walls_beyond=self.options.walls_beyond,
            **({} if self.options.crisp_edges else {"crisp_edge": None}))
        self.poses: dict[str, Part] = {p.id: p for p in assembly.parts}
        self.unexplained: list[Part] = []  # seen material no located part explains: obstacles too
        self.remaining: list[str] = list(assembly.sequence)
        self.reports: list[PartReport] = []
        self._unfinished: PartReport | None = None  # the part being worked on, until removed or skipped
        self._stop_reason = ""  # why the loop last stopped and asked (for the summary)
        self.state = LoopState()
        self._frame_counter = 0
        self._first_saturated: float | None = None  # the share of the first frame at 250 or more (back-lit: white)
        self._last_picked: tuple[str, Part] | None = None
        # the pick being sent: part, grasp, report, attempt, and its stage (sent, gripped, released)
        self._pick: dict | None = None
        self._taken_by_hand: dict | None = None  # a pick whose part the operator was asked to take out of the jaws
        # a part whose jaws the carry-off after a fault found empty: let go at the drop-off, or fallen back onto the
        # tray; the next frame says which (seen again: planned again, no stop)
        self._found_empty: str | None = None
        self._lost: str | None = None  # fell out of the jaws on the way to the drop-off (`_lost_in_transit`)
        self._located_last: set[str] = set()  # parts the last frame located by registration (`_camera_moved`)
        self._knocks = 0  # frames in a row that read every part moved alike (`_camera_moved`): stops said so
        self._static: list[Polygon] | None = None  # fixtures at the table (`_reaching_in`); None: no frame yet
        self._touched: str | None = None  # the part the last pick was sent for (it may have moved: not compared)
        self._examples_lock = threading.Lock()
        self._taught: list[GraspExample] = []  # taught on the station, not yet learned by the loop
        # where the loop finds taught examples at each plan: the station's (default), or a replay's
        self._taught_source = taught or self._drain_taught
        self.home_first: Joints | None = None  # set: move there once the operator lets the loop run
        self.examples = load_examples(self.examples_path)
        self.rebuild_planner()

    # ------------------------------------------------------------------ learning
    def rebuild_planner(self) -> None:
        """Fit both trees again on the examples learned so far (after a reject or a teach)."""
        self.planner = GraspPlanner(self.cell, self.examples, self.planner_params)

    def add_example(self, example: GraspExample) -> None:
        """Append an example (a reject, from the loop thread) and rebuild the model."""
        with self._examples_lock:
            self._save(example)
            self.examples = [*self.examples, _as_saved(example)]
            self.rebuild_planner()
        self.control.log("example", f"{'valid' if example.valid else 'invalid'} example {example.id} added; "
                         "model rebuilt", id=example.id)

    def teach(self, example: GraspExample) -> int:
        """A grasp taught on the station (its thread): saved to the example file at once, learned by
        the loop at its next plan, where it is recorded ('example' decision) so that a replay learns
        it at the same point. Returns the number of examples the next plan learns from."""
        with self._examples_lock:
            self._save(example)
            self._taught.append(example)
            n = len(self.examples) + len(self._taught)
        self.control.log("example", f"valid example {example.id} taught; the next plan learns it", id=example.id)
        return n

    def _save(self, example: GraspExample) -> None:
        """Append to the examples file (the first new example starts `examples_out` as a copy)."""
        if self.examples_out != self.examples_path:
            if not self.examples_out.exists():
                write_atomic(self.examples_out, self.examples_path.read_bytes())
            self.examples_path = self.examples_out
        append_examples(self.examples_path, [example])

    def _drain_taught(self) -> list[GraspExample]:
        with self._examples_lock:
            taught, self._taught = self._taught, []
        return taught

    def _learn_taught(self) -> None:
        """Before a plan: learn what was taught since the last one, and record it."""
        taught = self._taught_source()
        if not taught:
            return
        for ex in taught:
            self.sink.write_decision({"type": "example", "source": "station-teach", "example": ex.to_json()})
        with self._examples_lock:
            self.examples = [*self.examples, *map(_as_saved, taught)]
            self.rebuild_planner()

    # ------------------------------------------------------------------ the loop
    def run(self) -> dict:
        self.control.log("start", f"disassembly of {self.assembly.name}: {len(self.remaining)} parts")
        while self.remaining or self._last_picked is not None:
            try:
                if self.remaining:
                    self._one_part(self.remaining[0])
                else:
                    self._final_check()
            except Stopped as e:
                self.sink.write_decision({"type": "stop", "source": "operator", "reason": str(e)})
                self.stopped_on(f"operator: {e}")
                raise
            except StopRun:
                raise
            except Faulted:
                continue  # a fault was reported meanwhile: the next checkpoint holds until reset
            except CellError as e:  # drive faults and anything else the cell reports
                if self.control.stop_requested:  # the operator's stop quick-stopped the arm: no fault,
                    continue  # the next checkpoint raises Stopped
                self._stop_and_ask(getattr(e, "node", None) or "cell", str(e), fault=not isinstance(e, HandWork))
        summary = self.summary()
        self.control.done(summary)  # first: a Stop from now on is one after the end (nothing is sent)
        self.sink.write_decision({"type": "summary", **summary})
        return summary

    def _one_part(self, part_id: str) -> None:
        self.control.checkpoint("frame", step=len(self.assembly.sequence) - len(self.remaining), part=part_id)
        if self.home_first is not None:  # the first motion waits for the operator's Run
            home, self.home_first = self.home_first, None
            go_to(self.arm, home)  # a real cell's arm may stand anywhere: up first, then across
        faulted = bool(self.arm.faults)
        if faulted:
            self.arm.reset_faults()
            if self.control.stop_requested:  # pressed as the reset began: cleared with the faults, so stop again
                self.arm.stop()
                return  # the next checkpoint raises Stopped, before anything moves
        if self._taken_by_hand is not None:  # the operator was asked to take the part out of the jaws, and reset
            pick = self._taken_by_hand
            self._require_taken_out(pick)
            self._taken_by_hand = None
            self._retreat(pick["grasp"])
            self._picked(pick, "taken out of the jaws by hand after a drive fault")
            return
        if self._pick is not None:  # a pick was cut short (a drive fault, a refused move)
            grasp = self._pick["grasp"]
            if self._recover_pick():
                return  # the part left the tray in the jaws: the next frame checks that
            self._retreat(grasp)
        elif faulted:
            self._retreat()
        frame, index = self._read_frame()
        t0 = time.perf_counter()
        report = self._unfinished = self._report_for(part_id)
        scene = self._scene_in(frame, index, part_id)
        if scene is None:
            return
        grasps = self._plan(scene, part_id)
        report.planning_s += time.perf_counter() - t0
        if grasps is None:
            return
        attempt = misses = 0
        left_out: list[np.ndarray] = []  # the contacts rejected or missed this cycle: not proposed again
        refused = ""
        while True:
            t1 = time.perf_counter()
            grasp = grasps[attempt] if attempt < len(grasps) else None
            if grasp is None:
                why = f"{part_id}: no further grasp to try" + (f" ({refused})" if refused else "")
                self._stop_and_ask("planner", why)
                return
            if grasp.joints is None and self.planner.choose_for(grasp, scene) is None:
                attempt += 1  # step 5 finds no configuration whose links clear the parts
                continue
            report.planning_s += time.perf_counter() - t1  # the operator's time to answer is not planning
            decision = self._approve(grasp, scene, attempt)
            if not decision.approved:
                self._rejected(grasp, scene, decision.reason)
                left_out.append(grasp.contacts_mm)
                t2 = time.perf_counter()
                grasps = self._plan(scene, part_id)
                report.planning_s += time.perf_counter() - t2
                if grasps is None:
                    return
                # The example teaches the trees; this cycle, the operator also simply expects
                # not to be asked the same again (sets of a symmetric part look alike to them).
                grasps = self._other_than(grasps, left_out)
                if not grasps:
                    self._stop_and_ask("planner", f"{part_id}: every feasible grasp was rejected; teach one")
                    return
                attempt = 0
                continue
            try:
                commands = self._clear_pick(part_id, grasp)
            except LinksWouldHit as e:  # every way of this grasp sweeps a link over a tall part: the next one
                refused = str(e)
                self.control.log("links", refused, part=part_id)
                attempt += 1
                continue
            report.attempts += 1
            self._pick = {"part": part_id, "grasp": grasp, "report": report, "attempt": attempt, "stage": "sent"}
            records = self._execute(grasp, part_id, attempt, commands)
            self._pick = None
            report.motion_s += records[-1]["t_end_s"] - records[0]["t_start_s"]
            if records[-1].get("holding") is not False:
                break
            if records[-1]["label"] == TRANSIT_CHECK:
                self._lost_in_transit({"part": part_id, "report": report}, grasp, records)
                return
            self.control.log("miss", _missed(part_id, grasp, records), part=part_id)
            t3 = self.arm.clock.now()
            self._retreat(grasp)
            report.motion_s += self.arm.clock.now() - t3
            misses += 1
            if misses > self.options.grip_retries:
                slipped = "; the last time it slipped out of the jaws as they lifted it"
                self._stop_and_ask("gripper", f"{part_id}: missed {misses} times"
                                   + (slipped if records[-1]["action"] == "check" else ""))
                return
            # The jaws closed through where the part was thought to lie: it was not there, or they pushed it;
            # or it slipped out on the lift and fell back.
            # The next grasp is planned on a new frame, not on the one that misled this one.
            left_out.append(grasp.contacts_mm)
            frame, index = self._read_frame()
            t4 = time.perf_counter()
            scene = self._scene_in(frame, index, part_id)
            grasps = None if scene is None else self._plan(scene, part_id)
            report.planning_s += time.perf_counter() - t4
            if grasps is None:
                return
            grasps = self._other_than(grasps, left_out)
            attempt = 0
        self._picked({"part": part_id, "report": report})

    def _scene_in(self, frame, index: int, part_id: str) -> Scene | None:
        """The scene of `part_id` as `frame` shows it; None when the loop stopped to ask (the part picked
        last is still there, or `part_id` is not found)."""
        located = self._perceive(frame, index)
        if not self._last_pick_left(located):
            return None
        if part_id not in located:
            self._stop_and_ask("vision", f"{part_id} is not found in frame {index}")
            return None
        outside = self.cell.tray.outside_text(*located[part_id].polygon.centroid.coords[0])
        if outside and self.options.tray_check:
            self._stop_and_ask("vision", f"{part_id} {outside} in frame {index}: the arm picks on the tray only; "
                                         "put it back on the tray")
            return None
        # everything not removed, skipped parts included: they still lie there
        return Scene(tuple(self._on_tray()), part_id, source=f"frame {index}")

    def _final_check(self) -> None:
        """One more frame after the last pick: the last part must be gone too."""
        self.control.checkpoint("final frame")
        frame, index = self._read_frame()
        self._last_pick_left(self._perceive(frame, index))

    def _last_pick_left(self, located: dict[str, Part]) -> bool:
        """Is the part picked last gone from where it was? If not, it goes back to the front
        of the sequence and the operator is asked."""
        if self._last_picked is None:
            return True
        pid = self._last_picked[0]
        self._last_picked = None
        fell, self._found_empty = self._found_empty == pid, None
        lost, self._lost = self._lost == pid, None
        report = next(r for r in self.reports if r.part == pid)
        if pid in located:  # still on the tray, near where it was picked (perhaps it slipped)
            self.remaining.insert(0, pid)
            self.poses[pid] = located[pid]
            self.reports.remove(report)
            self._unfinished = report
            self._record_not_removed(report)
            if fell:  # the jaws were found empty after a fault: it fell back, and is picked again from here
                report.reason = ""
                self.control.log("again", f"{pid} fell out of the jaws while the arm stood and lies on the tray: "
                                 "it is picked again", part=pid)
            else:
                self._stop_and_ask("cell", f"{pid} did not leave the tray" + (
                    ": it fell out of the jaws on the way to the drop-off; after the reset it is picked again from "
                    "where the next frame shows it" if lost else ""))
            return False
        if lost:  # neither at the drop-off nor on the tray: the floor, the arm's way, where a person must look
            self._unfinished = None  # (the stop is about this part, not the next one's)
            self._stop_and_ask("gripper", f"{pid} fell out of the jaws on the way to the drop-off and is not on the "
                               "tray: find it (the floor, the arm's way to the drop-off), then reset; it stays "
                               "counted as lost, not removed")
            return False
        self.control.log("removed", f"{pid} removed in {report.cycle_s:.2f} s (gone from the next frame)", part=pid)
        return True

    def _record_not_removed(self, report: PartReport) -> None:
        """The check's verdict after the part's "removed" outcome (written at the drop-off), so that the
        decisions do not say it was removed. (Replay lets recordings made before it was written do without.)"""
        self.sink.write_decision({"type": "outcome", **report.to_json(), "outcome": "not removed",
                                  "reason": "did not leave the tray"})

    # ------------------------------------------------------------------ steps
    def _read_frame(self):
        last = None
        for _ in range(self.options.frame_retries + 1):
            try:
                frame = self.camera.read()
                if frame is None:
                    raise BadInput("the camera returned no frame")
                self.cal.check_frame(frame)  # another camera mode or the wrong camera: not this calibration
                if self._first_saturated is None:  # a back-lit tray's frames are white: the first one says so
                    first = saturated_share(frame)
                else:
                    first = self._first_saturated
                blank = blank_frame_reason(frame, first) if self.options.removal_checks else None
                if blank:
                    raise BadInput(blank)
                self._first_saturated = first
                break
            except (BadInput, OSError) as e:
                last = e
                self.control.log("frame", f"frame missing or unreadable: {e}")
        else:
            self._stop_and_ask("camera", f"no readable frame after {self.options.frame_retries + 1} tries: {last}",
                               fault=True)
            raise Faulted(str(last))
        index = self._frame_counter
        self._frame_counter += 1
        self.sink.write_frame(index, frame)
        if self.viz is not None:
            self.viz.frame(index, frame)
        return frame, index

    def _perceive(self, frame, index: int) -> dict[str, Part]:
        from cell.vision import segment_frame, segment_to_mm

        segments = segment_frame(frame, self.segment_params)

        def mapper(seg):
            def polygon_at(z_top, z_bottom):
                outline, holes = segment_to_mm(seg, self.cal, z_top, z_bottom, frame)
                poly = Polygon(outline, holes)
                if not poly.is_valid:  # a wall-corrected outline may cross itself at a corner
                    poly = valid_area(poly)
                return poly
            from cell.runtime.matching import RegionOutline  # (mapped once per heights, far parts ruled out)

            return RegionOutline(polygon_at, [seg.outline_px, *seg.holes_px], self.cal)

        regions = [Region(i, mapper(s), s.merged, s.cut_off) for i, s in enumerate(segments)]
        expected = list(self.poses.values())
        if self._last_picked is not None:  # look for it too: it should be gone
            expected.append(self._last_picked[1])
        axis = None if self.options.axis_closed_form else axis_deg_eigh
        found, strangers = locate(expected, regions, axis)
        if self._last_picked is not None and self._last_picked[0] not in found and self.options.removal_checks:
            # not where it was picked: perhaps it fell back further off than a part is looked for
            pid, part = self._last_picked
            fell = locate_anywhere(part, [r for r in regions if r.index in strangers], axis)
            if fell is not None:
                found[pid] = fell
                strangers = [i for i in strangers if i != fell.region]
        seen = {}
        for pid, loc in found.items():
            part = self.poses.get(pid) or self._last_picked[1]
            seen[pid] = loc.apply(part)
        carried = {}
        for part in expected:
            if part.id in found or (self._last_picked is not None and part.id == self._last_picked[0]):
                continue
            carrier = self._carrier(part, found)
            if carrier is not None:  # lying on a part that was seen: it moved with it
                loc, base = found[carrier], self.poses[carrier]
                seen[part.id] = part.moved(loc.dx_mm, loc.dy_mm, loc.dtheta_deg, about=base.polygon.centroid.coords[0])
                carried[part.id] = carrier
        moved = self._camera_moved(found)
        reaching, static = self._reaching_in(segments, regions, strangers)
        for pid, part in seen.items():
            if pid in self.poses and moved is None:  # (knocked: the poses stay as the last frame measured them)
                self.poses[pid] = part
        # the station's frame, its index and the parts seen on it change together, once the parts are known: a
        # teach names the frame its clicks were on and is checked against the parts of that frame (while this
        # frame was segmented the index named it and the parts were the last frame's)
        self.state.frame, self.state.frame_index, self.state.seen = frame, index, seen
        self.unexplained = self._unexplained(regions, seen, found, strangers)
        self.sink.write_decision({
            "type": "perception", "frame": index, "segments": len(segments),
            "merged": [i for i, s in enumerate(segments) if s.merged],
            "cut_off": [i for i, s in enumerate(segments) if s.cut_off],
            "located": {pid: {"region": l.region, "dx_mm": round(l.dx_mm, 3), "dy_mm": round(l.dy_mm, 3),
                              "dtheta_deg": round(l.dtheta_deg, 3), "overlap": round(l.overlap, 4)}
                        for pid, l in found.items()},
            "carried": carried, "unclaimed": strangers,
            **({"unexplained": [{"region": u.meta["region"], "area_mm2": round(u.polygon.area, 1),
                                 "z_top_mm": u.z_top_mm} for u in self.unexplained]} if self.unexplained else {}),
            **({"common_motion": {"parts": list(moved.parts), "dx_mm": round(moved.dx_mm, 3),
                                  "dy_mm": round(moved.dy_mm, 3), "turn_deg": round(moved.turn_deg, 3)}}
               if moved else {}),
            **({"static": static} if static else {}), **({"reaching_in": reaching} if reaching else {})})
        if strangers:
            self.control.log("vision", f"{len(strangers)} region(s) match no part of the assembly",
                             regions=strangers)
        if self.viz is not None:
            self.viz.contours([s.outline_px for s in segments])
            self.viz.parts([p.outline_mm for p in seen.values()], [p.z_top_mm for p in seen.values()],
                           list(seen))
        if moved is not None:
            why = (f"{moved.text()}: was the camera or the tray moved? check the calibration; after the reset the "
                   "next frame is compared with the parts as they were" if self._knocks == 1 else
                   f"still {moved.text()} (before the last stop): if the camera was knocked, put it back or "
                   "recalibrate it (cell calibrate plane); if the tray was moved on purpose, reset again and the "
                   "parts are taken where the next frame shows them")
            self._stop_and_ask("camera", why, fault=True)
            raise Faulted(why)
        if reaching:
            self._stop_and_ask("vision", reaching)
            raise Faulted(reaching)
        return seen

    def _reaching_in(self, segments, regions: list[Region], strangers: list[int]) -> tuple[str, list[int]]:
        """(what the operator reads of the regions no part explains (`strangers`) that reach in across the frame's
        edge onto the tray or across the tray's edge (`across_edge`): "" when none does; the regions of the first
        frame that do, taken as fixtures). Nothing may reach in while the arm moves; what the first frame shows
        reaching in is a fixture (a tray's wall, a clamp, a bin: nothing the operator could clear), remembered by
        its outline at the table, and a later region lying mostly on one is that fixture (`STATIC_SHARE`)."""
        if not self.options.stranger_checks:
            return "", []
        t = self.cell.tray
        tray = box(t.x_mm[0], t.y_mm[0], t.x_mm[1], t.y_mm[1])
        first, reaching, fixed = self._static is None, [], []
        if first:
            self._static = []
        for i in strangers:
            at_table = regions[i].polygon_at(0.0, 0.0)
            across = across_edge(at_table, segments[i].cut_off, tray)
            if not across:
                continue
            if first:
                self._static.append(at_table)
                fixed.append(i)
            elif not any(at_table.intersection(s).area >= STATIC_SHARE * at_table.area for s in self._static):
                reaching.append(f"region {i} ({at_table.area:.0f} mm2 at the table) across {across}")
        if fixed:
            self.control.log("vision", f"{len(fixed)} region(s) no part explains reach in across the frame's or "
                             "the tray's edge in the first frame: taken as fixtures (a tray's wall, a clamp, a bin), "
                             "they do not stop the run; anything else reaching in does", regions=fixed)
        if not reaching:
            return "", fixed
        return (f"something no part explains reaches into the cell: {'; '.join(reaching)}. A person's arm, a cable? "
                "Nothing may reach in while the arm moves: clear it, then reset"), fixed

    def _camera_moved(self, found: dict) -> CommonMotion | None:
        """The common motion (`common_motion`) of the parts located by registration in this frame and the last,
        the part the last pick was sent for and the part picked last left out; None when they did not all move
        alike, or too little. (The first frame has nothing to compare with: a knock before it goes unseen.)"""
        last, self._located_last = self._located_last, {pid for pid, loc in found.items() if not loc.merged}
        if not self.options.common_motion_check:
            return None
        compared = [pid for pid in self._located_last & last if pid in self.poses and pid != self._touched]
        before = {pid: self.poses[pid].polygon.centroid.coords[0] for pid in compared}
        after = {pid: tuple(np.add(before[pid], (found[pid].dx_mm, found[pid].dy_mm))) for pid in compared}
        moved = common_motion(before, after)
        # the poses stay as they were before the first stop, so after a reset the next frame is compared with them
        # again: the camera put back reads nothing moved; still moved stops a second time, saying so; a third frame
        # still moved (reset twice: the tray was moved on purpose) is taken as it shows the parts
        self._knocks = 0 if moved is None else self._knocks + 1
        if self._knocks > 2:
            self._knocks = 0
            self.control.log("camera", f"{moved.text()}, reset twice: taken as the tray moved on purpose")
            return None
        return moved

    def _unexplained(self, regions, seen: dict, found: dict, strangers: list) -> list[Part]:
        """Material no located part explains, as obstacles (matching.unexplained), looked for when a part
        still on the tray was not located, a region matches no part, or a part was placed in a region
        by coverage (merged)."""
        missing = [p for pid, p in self.poses.items() if pid not in seen]
        covered = any(loc.merged for loc in found.values())  # placed by coverage: the region may hold more
        if not (missing or strangers or covered) or not self.poses:
            return []
        tallest = max(p.z_top_mm for p in self.poses.values())
        if self.options.stranger_checks:  # an unknown thing does not get lower as parts leave; where it may stand
            tallest = max(p.z_top_mm for p in self.assembly.parts)
            regions = [replace(r, polygon_at=swept_outline(r.polygon_at)) if r.index in strangers else r
                       for r in regions]
        # leftovers beside located parts: most likely a part not found; a region nothing was located
        # in may be anything (a tool left on the tray): at least as tall as the tallest part
        return unexplained(regions, seen, found, max((p.z_top_mm for p in missing), default=tallest), tallest,
                           missing=bool(missing))

    def _on_tray(self, but: str | None = None) -> list[Part]:
        """Every part believed on the tray (`but` excepted: in the jaws) and the material no part explains."""
        return [p for pid, p in self.poses.items() if pid != but] + self.unexplained

    def _carrier(self, part: Part, found: dict) -> str | None:
        """The seen part this one lies on (its bottom on the other's top, inside its outline
        in plan): a part on a base plate does not stand out against the tray on its own."""
        return next((cid for cid in found if cid in self.poses and part.lies_on(self.poses[cid])), None)

    def _plan(self, scene: Scene, part_id: str) -> list[Grasp] | None:
        self._learn_taught()
        try:
            _require_lift_clear(scene, REST_MM if self.options.lift_rest_overlap else 1e-9)
            result = self.planner.plan(scene)
        except NoFeasibleGrasp as e:
            self.sink.write_decision({"type": "no_grasp", "part": part_id, "reason": e.reason})
            if self.options.on_no_grasp == "skip":
                self.remaining.remove(part_id)
                tried = self._unfinished if self._unfinished is not None and self._unfinished.part == part_id \
                    else PartReport(part_id, "skipped")  # (grips missed before this plan found nothing: kept)
                tried.outcome, tried.reason = "skipped", e.reason  # the same report: the caller adds this plan's time
                self.reports.append(tried)
                self._unfinished = None
                self.control.log("skip", f"{part_id} skipped: no feasible grasp ({e.reason})", part=part_id)
            else:
                self._stop_and_ask("planner", f"no feasible grasp for {part_id}: {e.reason}")
            return None
        g = result.grasp
        step = {} if result.step_mm is None else {"step_mm": result.step_mm}  # a finer step's counts (synthesis.py)
        self.sink.write_decision({"type": "grasp", "part": part_id, "counts": {
            k: v for k, v in result.counts.items() if k != "time_ms"}, "ranked": len(result.ranked),
            **step, **_grasp_json(g)})
        if self.viz is not None:
            self._show(result)
        return result.ranked

    def _approve(self, grasp: Grasp, scene: Scene, attempt: int):
        from cell.grasp.footprints import finger_footprints, palm_footprint

        proposal = {"target": grasp.target, "attempt": attempt, **_grasp_json(grasp)}
        to_px = self.cal.mm_to_px
        z = grasp.grasp_z_mm
        self.state.proposal = {
            "target": grasp.target,
            "contacts_px": to_px(grasp.contacts_mm, z).round(2).tolist(),
            "fingers_px": [to_px(np.asarray(f.exterior.coords)[:-1], z).round(2).tolist()
                           for f in finger_footprints(grasp, self.cell)],
            "palm_px": to_px(np.asarray(palm_footprint(grasp, self.cell).exterior.coords)[:-1], z).round(2).tolist(),
        }
        try:
            decision = self.control.request_approval(proposal)
        finally:
            self.state.proposal = None
        self.sink.write_decision({"type": "decision", "part": grasp.target, "approved": decision.approved,
                                  "reason": decision.reason, "by": decision.by})
        return decision

    def _other_than(self, grasps: list[Grasp], left_out: list[np.ndarray]) -> list[Grasp]:
        """The grasps whose contacts are none of `left_out` (`_same_contacts`)."""
        return [g for g in grasps if not any(self._same_contacts(g.contacts_mm, c) for c in left_out)]

    def _same_contacts(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Two contact sets the pads would cover alike (either order), within half a pad width."""
        tol = self.cell.gripper.pad_width_mm / 2
        return bool(np.all(np.linalg.norm(a - b, axis=1) <= tol) or np.all(np.linalg.norm(a - b[::-1], axis=1) <= tol))

    def _rejected(self, grasp: Grasp, scene: Scene, reason: str) -> None:
        """A rejected grasp becomes an invalid example (the operator said no to this set)."""
        ex = GraspExample(
            f"reject-{datetime.now(UTC).strftime('%Y%m%dT%H%M%S%f')}", scene.target_part, grasp.contacts_mm,
            False, {"kind": "station-reject", "by": "operator", "at": datetime.now(UTC).isoformat(),
                    "note": reason or "rejected at the station"},
            obstacles=tuple(scene.obstacles), grasp_z_mm=grasp.grasp_z_mm, joints=grasp.joints)
        self.add_example(ex)

    def _execute(self, grasp: Grasp, part_id: str, attempt: int, commands, **record) -> list[dict]:
        """Send a pick's commands (checked already); `self._pick`'s stage follows the jaws."""
        from drivers.execute import run_commands

        self.sink.write_decision({"type": "commands", "part": part_id, "attempt": attempt, **record,
                                  "commands": [c.to_json() for c in commands]})
        self._touched = part_id
        self.control.checkpoint("pick", part=part_id)
        done, t0 = [], self.arm.clock.now()

        def on_step(rec):
            done.append(rec)
            if self._pick is not None:
                if rec["action"] == "grip" and rec.get("holding"):
                    self._pick.update(stage="gripped", grip_width_mm=rec["width_mm"])
                elif rec["action"] == "open" and rec["label"] == "release":
                    self._pick["stage"] = "released"
            if self.viz is not None:
                self._show_arm()
                if "width_mm" in rec:
                    self.viz.gripper_width(rec["width_mm"])

        try:
            records = run_commands(self.arm, commands, stop_on_miss=True, on_step=on_step)
        except BaseException as e:  # a fault, a stop, Ctrl-C: what the arm did up to it is kept, and its time
            if self._pick is not None:
                self._pick["report"].motion_s += self.arm.clock.now() - t0
            try:
                self.sink.write_decision({"type": "interrupted", "part": part_id, "attempt": attempt, **record,
                                          "records": done, "by": str(e) or type(e).__name__})
            except RecordingFailed:  # (a full disk) `e` stays the cause; the writer keeps the failure, said beside it
                pass
            raise
        self.sink.write_decision({"type": "executed", "part": part_id, "attempt": attempt, **record,
                                  "records": records})
        return records

    def _safe_z_mm(self, part_id: str, grasp_z_mm: float) -> float:
        """Travel height of the finger tips for a pick of `part_id` (`pickway.travel_z_mm`)."""
        return travel_z_mm(self.cell, self.poses[part_id], self._on_tray(but=part_id), grasp_z_mm)

    def _clear_pick(self, part_id: str, grasp: Grasp) -> list:
        """The pick's commands, by way of the first drop-off configuration whose moves keep the
        links clear (`_clear_way`)."""
        safe_z = self._safe_z_mm(part_id, grasp.grasp_z_mm)
        return self._clear_way(part_id, grasp, f"{part_id}: ", lambda drop: pick_commands(
            grasp.joints, grasp.opening_mm, self.cell, safe_z_mm=safe_z, drop=drop,
            check_grip=self.options.lift_check, check_in_transit=self.options.transit_check))

    def _clear_carry_off(self, part_id: str, grasp: Grasp, held_mm: float | None = None) -> list:
        """Carry-off commands from where the arm is, by way of the first drop-off configuration
        whose moves keep the links clear (`_clear_way`); the grip checked after the lift against `held_mm`,
        where the jaws held the part (default: the grasp's opening)."""
        safe_z, here = self._safe_z_mm(part_id, grasp.grasp_z_mm), self.arm.joints()
        # (the grip again also pushes again: the quick stop ended the jaws' push)
        width = grasp.opening_mm if held_mm is None else held_mm
        check = width if self.options.lift_check else None
        transit = width if self.options.transit_check else None
        return self._clear_way(part_id, grasp, "", lambda drop: carry_off_commands(
            here, grasp.joints, self.cell, safe_z, drop, check_width_mm=check, transit_width_mm=transit))

    def _clear_way(self, part_id: str, grasp: Grasp, why: str, commands_to) -> list:
        """`commands_to(drop)` by the first drop-off whose way keeps the links clear of the parts on the tray
        (`pickway.clear_way`); LinksWouldHit when none does."""
        return clear_way(self.arm, self.cell, self._on_tray(but=part_id), grasp.joints, why, commands_to,
                         lambda commands: self._check_links(part_id, commands, why), grid=self.options.grid_ways)

    def _check_links(self, part_id: str, commands, why: str) -> None:
        """The links along every move of `commands`, from where the arm is, against the parts on the
        tray (the part `part_id` is in the jaws, not on the tray): `pickway.check_links`."""
        check_links(self.arm, self.cell, self._on_tray(but=part_id), commands, why)

    def _recover_pick(self) -> bool:
        """After a pick was cut short (a drive fault, a refused move) and the operator's reset.
        Jaws that held the part: they stay shut, the arm goes straight up, grips again (the check: the quick
        stop ended the jaws' push) and lets the part go at the drop-off, not
        where the arm stopped (over the tray, on other parts). A part already let go at the
        drop-off: the arm goes up. True in both cases, and when the check found the jaws empty (the part let
        go at the drop-off as the fault hit, or fallen: open, up); the part then counts as picked and the next
        frame checks that it left its place (seen again after empty jaws, it is picked again without a stop).
        False when nothing was held (open, up, as usual).
        If the way to the drop-off is refused, the operator is asked to take the part out of the
        jaws by hand and reset again."""
        pick = self._pick
        if pick is None or pick["stage"] == "sent":
            self._pick = None
            return False
        pid, grasp = pick["part"], pick["grasp"]
        if pick["stage"] == "released":
            self._pick = None
            self._retreat()
            self._picked(pick, "let go at the drop-off before the pick was cut short")
            return True
        try:
            commands = self._clear_carry_off(pid, grasp, pick.get("grip_width_mm"))
            from drivers.limits import command_violations

            problems = [p for c in commands if c.joints is not None
                        for p in command_violations(self.cell, c.joints, None)]
            if problems:
                raise CellError("; ".join(problems))
        except CellError as e:
            self._pick, self._taken_by_hand = None, pick
            raise HandWork(f"{pid} is still in the jaws and cannot be carried off ({e}): take it out by hand, "
                            "then reset") from None
        records = self._execute(grasp, pid, pick["attempt"], commands, after_fault=True)
        self._pick = None
        pick["report"].motion_s += records[-1]["t_end_s"] - records[0]["t_start_s"]
        if records[-1].get("holding") is False and records[-1]["label"] == TRANSIT_CHECK:
            self._lost_in_transit(pick, grasp, records)
            return True
        if records[-1].get("holding") is False:  # the check after the lift: the jaws are empty
            self.control.log("miss", _missed(pid, grasp, records), part=pid)
            self._retreat(grasp)
            self._found_empty = pid
            self._picked(pick, "the jaws were found empty after the pick was cut short (let go at the drop-off)")
            return True
        self._picked(pick, "carried off after the pick was cut short")
        return True

    def _require_taken_out(self, pick: dict) -> None:
        """Raise (the operator is asked again) unless the part of `pick` is gone from between the jaws: opened,
        they would drop it where the arm stopped, over the tray. The jaws close again under the force limit:
        they stop on it while it is there, where they gripped it or, slid or half pulled out, elsewhere. (Their
        width alone does not tell: a drive that kept pushing closes on once the part is pulled out, but the
        quick stop after a fault ended that push.)"""
        grip_width_mm = pick["grip_width_mm"]
        closed = self.arm.gripper.grip(grip_width_mm)
        if closed.stopped:  # on something: not only within the grip's tolerance (holding) or wider (blocked)
            raise HandWork(f"{pick['part']} is still between the jaws (they stand at {closed.width_mm:.1f} mm; "
                            f"{grip_width_mm:.1f} mm when they gripped it): take it out by hand, then reset")
        self.control.log("taken", f"{pick['part']} is out of the jaws (they closed to {closed.width_mm:.1f} mm, "
                         f"{grip_width_mm:.1f} mm when they gripped it)", part=pick["part"])

    def _picked(self, pick: dict, reason: str = "") -> None:
        """The part of `pick` has left the tray in the jaws: out of the sequence; the next frame
        checks that it is gone from where it was."""
        pid, report = pick["part"], pick["report"]
        report.reason = reason
        if pid in self.remaining:
            self.remaining.remove(pid)
        if pid in self.poses:
            self._last_picked = (pid, self.poses.pop(pid))
        self.reports.append(report)
        self._unfinished = None
        # (the record keeps its "removed": recordings are replayed record by record; `_last_pick_left` confirms it)
        self.sink.write_decision({"type": "outcome", **report.to_json()})
        if report.outcome == "lost":
            self.control.log("lost", f"{pid} lost on the way to the drop-off ({reason}); the next frame checks "
                             "whether it fell back onto the tray", part=pid)
            return
        self.control.log("carried", f"{pid} carried off in {report.cycle_s:.2f} s" + (f" ({reason})" if reason else "")
                         + "; the next frame checks that it left the tray", part=pid)

    def _lost_in_transit(self, pick: dict, grasp: Grasp, records: list[dict]) -> None:
        """The check above the drop-off found the jaws empty (`records`: the pick's, up to it): the part fell out on
        the way. The jaws open there, out of the tray's way; the part is not removed ("lost"), and the next frame
        says whether it fell back onto the tray (`_last_pick_left`)."""
        report = pick["report"]
        t0 = self.arm.clock.now()
        self._retreat(grasp)
        report.motion_s += self.arm.clock.now() - t0
        report.outcome, self._lost = "lost", pick["part"]
        self._picked(pick, _missed(pick["part"], grasp, records))

    def _retreat_z_mm(self) -> float:
        """How high the empty jaws go up after a miss or a fault: the safe height, or above the tallest part
        on the tray by the travel margin (the next move starts there and heads across the tray), at most
        as high as J3 goes."""
        tallest = max((p.z_top_mm for p in self._on_tray()), default=0.0)
        wanted, top = max(self.cell.motion.safe_z_mm, tallest + TRAVEL_MARGIN_MM), self.cell.scara.j3_mm[1]
        if wanted > top:  # said, not hidden: the next pick's travel height check refuses to go on from here
            where = (f"{top - tallest:.0f} mm over" if top >= tallest else f"{tallest - top:.0f} mm below the top of")
            self.control.log("retreat", f"the empty jaws go up to J3's top, {top:g} mm, {where} the tallest part on "
                             f"the tray (a {TRAVEL_MARGIN_MM:g} mm margin was wanted)")
        return min(wanted, top)

    def _retreat(self, grasp: Grasp | None = None) -> None:
        """Let go and go straight up where the arm is to the travel height of empty jaws (`_retreat_z_mm`),
        then open the jaws fully. Below it the jaws open only to `grasp`'s approach opening, the width the
        planner cleared the fingers for there (fully, they overlapped a neighbour of the drive unit's clip),
        and not at all without a grasp (nothing is known to be clear)."""
        safe_z = self._retreat_z_mm()
        at = self.arm.joints()
        if at.j3_mm < safe_z:
            if grasp is not None:
                self.arm.gripper.open(retreat_opening_mm(grasp.opening_mm, self.arm.gripper.width_mm, self.cell))
            self.arm.move_joints(above(at, safe_z))
        self.arm.gripper.open()

    def _report_for(self, part_id: str) -> PartReport:
        """The report of this cycle's part: the one of its earlier tries when it is picked again."""
        earlier = self._unfinished
        if self.options.whole_part_report and earlier is not None and earlier.part == part_id:
            return replace(earlier, outcome="removed", reason="")
        return PartReport(part_id, "removed")

    def _stop_and_ask(self, source: str, why: str, fault: bool = False) -> None:
        """Hold for the operator (or end the run, when nobody is there to answer). `fault`: something
        failed (a drive, the camera); otherwise the loop only cannot decide on its own (no grasp)."""
        self.sink.write_decision({"type": "stop", "source": source, "reason": why})
        self.stopped_on(f"{source}: {why}")
        self.control.report_fault(source, why, asking=not fault)
        if not self.options.interactive:
            raise StopRun(f"{source}: {why}")

    def stopped_on(self, reason: str) -> None:
        """Why the part being worked on stopped (the summary lists it if the run ends there)."""
        self._stop_reason = reason
        if self._unfinished is not None:
            self._unfinished.reason = reason

    # ------------------------------------------------------------------ reporting
    def part_reports(self) -> list[PartReport]:
        """Every part removed or skipped, then the one the run stopped on (if it stopped while on one). A part let
        go at the drop-off that no frame has shown gone yet (the run stopped before the next one) is "carried", not
        removed."""
        reports = list(self.reports)
        if self._last_picked is not None:
            pid = self._last_picked[0]
            why = f"carried off; the run stopped before a frame showed it gone ({self._stop_reason or 'stopped'})"
            reports = [replace(r, outcome="carried", reason=why) if r.part == pid and r.outcome == "removed" else r
                       for r in reports]
        if self._unfinished is None:
            return reports
        stopped = replace(self._unfinished, outcome="stopped", reason=self._unfinished.reason or "the run was stopped")
        return [*reports, stopped]

    def summary(self) -> dict:
        reports = self.part_reports()
        removed = [r for r in reports if r.outcome == "removed"]
        cycles = [r.cycle_s for r in removed]
        mean = float(np.mean(cycles)) if cycles else 0.0
        planning = float(np.mean([r.planning_s for r in removed])) if removed else 0.0
        s = self.cell.scara
        return {
            "assembly": self.assembly.name,
            "parts_total": len(self.assembly.sequence),
            "parts_removed": len(removed),
            "parts_skipped": [r.part for r in self.reports if r.outcome == "skipped"],
            "grasps": sum(r.attempts for r in reports),  # every grasp tried, on the part stopped on too
            "cycle_s_mean": round(mean, 3),
            "planning_s_mean": round(planning, 4),
            "planning_share": round(planning / mean, 4) if mean else 0.0,
            "picks_per_hour": round(3600.0 / mean, 1) if mean else 0.0,
            "motion_limits": {"max_velocity": s.max_velocity, "max_acceleration": s.max_acceleration,
                              "gripper_speed_mm_s": self.cell.gripper.speed_mm_s,
                              "safe_z_mm": self.cell.motion.safe_z_mm},
            "parts": [r.to_json() for r in reports],
        }

    # ------------------------------------------------------------------ visualisation
    def _show(self, result) -> None:
        from cell.grasp.footprints import finger_footprints, palm_footprint

        g = result.grasp
        z = g.grasp_z_mm
        ok = result.point_valid
        self.viz.candidates(result.candidates.points, ok, space="mm", z_mm=z)
        self.viz.pairs(result.valid_sets, z_mm=z)
        self.viz.grasp(g.contacts_mm, [np.asarray(f.exterior.coords) for f in finger_footprints(g, self.cell)],
                       np.asarray(palm_footprint(g, self.cell).exterior.coords), grasp_z_mm=z)

    def _show_arm(self) -> None:
        from cell.kinematics import elbow_points

        j = self.arm.joints()
        self.viz.arm(elbow_points(j, self.cell.scara), j)
        self.viz.joints(j)


def _missed(part_id: str, grasp: Grasp, records: list[dict]) -> str:
    """What the operator reads of a pick that ended on a grip not holding (`records`: the pick's, up to it)."""
    last = records[-1]
    if last["label"] == TRANSIT_CHECK:
        return (f"{part_id} fell out of the jaws on the way to the drop-off: they closed to {last['width_mm']:.1f} mm "
                "when checked above it")
    if last["action"] == "check":
        gripped = next((r["width_mm"] for r in records if r["action"] == "grip"), None)
        if gripped is None:  # the carry-off after a fault: the grip was in the pick before it
            return (f"{part_id} was not in the jaws when the carry-off checked the grip (they closed to "
                    f"{last['width_mm']:.1f} mm): let go at the drop-off, or fallen; the next frame shows where")
        return (f"{part_id} slipped out of the jaws as they lifted it: gripped at {gripped:.1f} mm, they closed "
                f"to {last['width_mm']:.1f} mm when checked above the tray")
    how = "stopped at" if last.get("blocked") else "closed to"
    return f"{part_id}: the jaws {how} {last['width_mm']:.1f} mm, expected {grasp.opening_mm:.1f} mm: missed"


def _require_lift_clear(scene: Scene, rest_mm: float) -> None:
    """A part still lying on the target (a sequence out of order, the part on it skipped) has no grasp, as
    in `cell plan`: the jaws came down around the part on top and closed on it, and lifting the target
    would carry it along."""
    blockers = parts_on_top(scene.target_part, scene.obstacles, rest_mm)
    if blockers:
        raise NoFeasibleGrasp(lift_blocked_reason(scene, blockers))


def _grasp_json(g: Grasp) -> dict:
    return {"contacts": np.round(g.contacts_mm, 3).tolist(), "center": np.round(g.center_mm, 3).tolist(),
            "angle_deg": round(float(g.axis_deg), 3), "opening_mm": round(float(g.opening_mm), 3),
            "grasp_z_mm": round(float(g.grasp_z_mm), 3),
            "joints": g.joints.rounded(3).as_dict() if g.joints else None}
