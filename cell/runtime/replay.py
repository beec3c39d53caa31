"""Replay of a recorded session: the same loop on the recorded frames, compared decision by
decision with the recording.

The loop runs as it ran: frames come from the recording (a file camera), the drives are the
simulated CANopen nodes on a fresh virtual bus, the operator's approvals are the recorded
ones, and the gripper closes to the recorded width (the recording is the world). A drive or
bus fault the session stopped on mid-pick comes again (`RecordedFault`), in the step it cut
short or when the CAN log shows it, and one on the way up after a miss (the retreat) at the replay's
next move; one that cannot be re-created is taken from the recording, and the replay says so (`notes`),
as it says of one on the way home before the first frame (nothing is re-run there). Each decision the
loop makes is compared with the recorded one as it is made; the first divergence stops the replay and is
named. With other examples (`--examples`), the replay does not stop at differences but lists them: the
gripper then holds whatever the new plan grips, so the sequence goes on.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

from cell.errors import BadInput, CellError
from cell.fileio import as_written, short_repr
from cell.grasp.params import MAX_FINER_STEPS, SynthesisParams
from cell.runtime.control import Decision, RunControl
from drivers.sim_fault_injection import TIMED_EVENTS

REPLAY_SDO_TIMEOUT_S = 2.0
# A step's set-points and SDO requests go out at its first instant: a recorded fault is injected again this far
# into the step it cut short, a lost answer (SDO, set-point acknowledge) this far before it
INJECT_AT_STEP_S = 1e-3
# what an interrupted pick had done: where a fault or a stop hits within it differs from run to run (the replay
# injects a recorded drive fault at the start of the step it cut short), and recordings before 2026-12-05 do not
# have it (an EMCY then comes at the pick's next move, another fault at the pick's start)
NOT_COMPARED = {"interrupted"}
VOLATILE = {"planning_s", "cycle_s", "motion_s", "t_start_s", "t_end_s", "time_ms"}
TOLERANCE = 1e-3


class Divergence(Exception):  # noqa: N818 - not a CellError: the loop must not treat it as a cell fault
    """Replay made another decision than the recording (exit 1)."""


class RecordingIncomplete(BadInput):
    """The recording's end was never recorded (killed, failed: a full disk), and its first `matched` recorded
    decisions match the replay (exit 2: replay cannot say how the session went on)."""

    def __init__(self, message: str, matched: int):
        super().__init__(message)
        self.matched = matched


class RecordingEnds(Exception):  # noqa: N818 - not a CellError, like Divergence
    """The replay went on past the last decision of a recording that was never closed."""


# The planner settings a recording keeps (meta.planner), with the values that held before each was
# recorded: a recording made before `slanted_faces` planned without it, with leaves of 2 rows, no
# margin around the other parts, contacts reported on the pad's line (not moved onto the material),
# every outline point under a pad labelled by its contact (not only those the pad touches), any
# angle between the contacts' line and the closing axis, the pads not looked at again where the
# moved contacts put the grasp centre (and, once they were, allowed to stop further out on a slanted
# face), contacts on parallel faces where the samples lay, the configured step only and the usual
# grasp z only.
RECORDED_PLANNER = {"slanted_faces": False, "tree_min_samples_leaf": 2, "obstacle_margin_mm": 0.0,
                    "contacts_on_material": False, "label_touched_only": False, "max_contact_skew_deg": 90.0,
                    "stroke_at_pad_lines": False, "grasp_z_within_j3": False, "pads_at_grasp_centre": False,
                    "part_shape_weight": 0.0,
                    "finer_steps": 0, "grasp_z_over_neighbours": False, "cog_radius_outer_disc": False,
                    "min_touch_width_mm": 0.0, "closed_slit_mm": 0.0, "touch_within_compliance": False,
                    "label_from_outline": False,
                    "contacts_on_closing_line": False, "roll_bound_pad_overlap": False,
                    "tree_minority_weight_max": 0.0,
                    "grasp_z_top_fallback": False, "vertex_order_free": False, "load_at_pad_patches": False}


def planner_meta(params: SynthesisParams) -> dict:
    return {k: getattr(params, k) for k in RECORDED_PLANNER}


def planner_from_meta(planner, where: str) -> SynthesisParams:
    """The planner as the session ran it, from its manifest's meta.planner."""
    if not isinstance(planner, dict):
        raise BadInput(f"{where}: manifest meta.planner must be an object")
    values = {k: planner.get(k, old) for k, old in RECORDED_PLANNER.items()}
    for flag in ("slanted_faces", "contacts_on_material", "label_touched_only", "stroke_at_pad_lines",
                 "grasp_z_within_j3", "pads_at_grasp_centre", "grasp_z_over_neighbours", "cog_radius_outer_disc",
                 "touch_within_compliance", "contacts_on_closing_line", "roll_bound_pad_overlap",
                 "grasp_z_top_fallback", "vertex_order_free", "label_from_outline", "load_at_pad_patches"):
        if not isinstance(values[flag], bool):
            raise BadInput(f"{where}: manifest meta.planner.{flag} must be true or false")
    leaf = values["tree_min_samples_leaf"]
    if isinstance(leaf, bool) or not isinstance(leaf, int) or leaf < 1:
        raise BadInput(f"{where}: manifest meta.planner.tree_min_samples_leaf must be a whole number >= 1")
    for key in ("obstacle_margin_mm", "min_touch_width_mm", "closed_slit_mm"):
        mm = values[key]
        if isinstance(mm, bool) or not isinstance(mm, (int, float)) or not 0 <= mm < math.inf:
            raise BadInput(f"{where}: manifest meta.planner.{key} must be a number of mm >= 0")
    finer = values["finer_steps"]
    if isinstance(finer, bool) or not isinstance(finer, int) or not 0 <= finer <= MAX_FINER_STEPS:
        raise BadInput(f"{where}: manifest meta.planner.finer_steps must be a whole number from 0 to "
                       f"{MAX_FINER_STEPS}")
    for key in ("part_shape_weight", "tree_minority_weight_max"):  # 0: off (as before they were recorded)
        w = values[key]
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0 <= w < math.inf:
            raise BadInput(f"{where}: manifest meta.planner.{key} must be a number >= 0")
    skew = values["max_contact_skew_deg"]
    if isinstance(skew, bool) or not isinstance(skew, (int, float)) or not 0 < skew <= 90:
        raise BadInput(f"{where}: manifest meta.planner.max_contact_skew_deg must be a number of degrees in (0, 90]")
    return SynthesisParams(**values)

def differences(recorded, replayed, path: str = "") -> list[str]:
    """Where two decision records differ (volatile timing keys ignored), as 'path: a != b'."""
    if isinstance(recorded, dict) and isinstance(replayed, dict):
        out = []
        for k in sorted(set(recorded) | set(replayed)):
            if k in VOLATILE:
                continue
            if k not in recorded or k not in replayed:
                out.append(f"{path}{k}: {'missing in replay' if k in recorded else 'not in the recording'}")
            else:
                out += differences(recorded[k], replayed[k], f"{path}{k}.")
        return out
    if isinstance(recorded, list) and isinstance(replayed, list):
        if len(recorded) != len(replayed):
            return [f"{path.rstrip('.')}: {len(recorded)} items recorded, {len(replayed)} replayed"]
        out = []
        for i, (a, b) in enumerate(zip(recorded, replayed, strict=True)):
            out += differences(a, b, f"{path}{i}.")
        return out
    if isinstance(recorded, bool) or isinstance(replayed, bool):  # true is no 1 ("holding": 1 matched true)
        if type(recorded) is type(replayed) and recorded == replayed:
            return []
    elif isinstance(recorded, (int, float)) and isinstance(replayed, (int, float)):
        if math.isclose(recorded, replayed, abs_tol=TOLERANCE, rel_tol=1e-9):
            return []
    elif recorded == replayed:
        return []
    return [f"{path.rstrip('.')}: recorded {as_written(recorded)}, replayed {as_written(replayed)}"]


class RecordedCamera:
    """The recorded frames in order. Frames the camera could not deliver (unreadable, or blank: dark, overexposed)
    were not recorded, only the stop they led to: where the recording's next decision is such a stop, a read past
    the recorded frames fails as the session's reads did, so the loop stops with the same reason."""

    def __init__(self, frames, sink: Comparison):
        from cell.vision import FileCamera

        self._files, self._sink = FileCamera(frames), sink

    def read(self):
        try:
            return self._files.read()
        except BadInput:
            expected = self._sink.next_recorded() or {}
            if expected.get("type") == "stop" and expected.get("source") == "camera":
                raise BadInput(str(expected.get("reason", "")).partition(" tries: ")[2] or "no frame") from None
            raise


@dataclass
class Comparison:
    """The decision sink of a replay."""

    recorded: list[dict]
    drives: object
    strict: bool = True
    position: int = 0
    found: list[str] = field(default_factory=list)
    cut_short: bool = False  # the recording was never closed (crash) or lost its last line
    faulted_again: bool = False  # a pick the recording shows ending on a drive or bus fault: injected again or
    # taken from the recording (the moment within the move may differ: the host's frames are not compared)
    recorded_summary: dict | None = None  # the session's last line, when it ran to its end
    interrupted: dict[int, dict] = field(default_factory=dict)  # `_interrupted_before`
    can_log: object = None  # () -> the recorded CAN frames, where they are on the decisions' clock (simulated)
    notes: list[str] = field(default_factory=list)  # what the output says beside the match (a fault re-created)
    fault_stop_at: int | None = None  # the recorded stop a drive or bus fault ended the pick being replayed on
    fault: RecordedFault | None = None  # that fault, as injected again (None: not re-creatable)

    def write_frame(self, index, frame_bgr):
        return None

    def write_decision(self, record: dict) -> None:
        record = json.loads(json.dumps(record))  # the recording holds JSON: compare like with like
        if record.get("type") == "summary":
            self._compare_summary(record)
            return
        if record.get("type") in NOT_COMPARED:
            return
        expected = self.recorded[self.position] if self.position < len(self.recorded) else None
        if _recorded_since(record) and (expected or {}).get("type") != record["type"]:
            return  # a recording made before such records were written: it goes on without it
        diff = None if expected is None else differences(expected, record)
        if record.get("type") == "commands":
            self._set_gripper(record, same_pick=expected is not None and expected.get("type") == "commands"
                              and not diff)
            if self.strict:
                self._replay_drive_fault()
        if expected is None:
            if self.cut_short:  # not a divergence: the rest of the session was never recorded
                raise RecordingEnds()
            self._diverged(f"decision #{self.position} ({record.get('type')}): the recording has no more decisions")
            return
        if self.position == self.fault_stop_at:
            # where the arm stood when the fault came differs: the replay injects it at the step's start
            same = differences(_without_arm_stood(expected), _without_arm_stood(record))
            self._hardware_stop(record, same)  # StopRun where the replay did not stop so
            diff = None
        self.position += 1
        if expected.get("type") == "stop" and expected.get("source") == "operator":
            from cell.runtime.loop import StopRun

            raise StopRun("the operator stopped the recorded session here")  # nobody presses Stop in a replay
        if diff:
            self._diverged(f"decision #{self.position - 1} ({expected.get('type')}"
                           f"{', ' + str(expected.get('part')) if expected.get('part') else ''}): {diff[0]}"
                           + (f" (+{len(diff) - 1} more)" if len(diff) > 1 else ""))
            if not self.strict and expected.get("type") != record.get("type"):
                self._resync(record)
        elif self.strict and record.get("type") == "executed":
            self._fault_after_the_pick(record)

    def examples_taught_here(self) -> list:
        """The examples the recorded session learned before the plan the replay is at (its
        'example' decisions from here on): the replay learns them at the same point."""
        from cell.examples import parse_example

        out, i = [], self.position
        while i < len(self.recorded) and self.recorded[i].get("type") == "example":
            out.append(parse_example(self.recorded[i].get("example"), f"recorded decision #{i} (example)"))
            i += 1
        return out

    def next_recorded(self) -> dict | None:
        """The recorded decision the replay is to write next (None past the recording's end)."""
        return self.recorded[self.position] if self.position < len(self.recorded) else None

    def compared_up_to_here(self, why: str) -> None:
        """The replay cannot follow the recording beyond this point: a divergence saying so, once (not again
        as "the replay ended after")."""
        at, self.position = self.position, len(self.recorded)
        self._diverged(f"decision #{at}: {why}, so it is compared up to the fault only ({at} of "
                       f"{len(self.recorded)} decisions)")

    def _compare_summary(self, record: dict) -> None:
        """The run's outcome as recorded: the parts removed and skipped, and each part's outcome. Not its times
        (another run's are others), nor what older summaries counted otherwise (grasps, attempts) or lacked."""
        if self.recorded_summary is None:
            return
        diff = differences(_summary_outcome(self.recorded_summary), _summary_outcome(record))
        if diff:
            self._diverged(f"the summary: {'; '.join(diff[:3])}")

    def _diverged(self, what: str) -> None:
        if self.strict:
            raise Divergence(what)
        self.found.append(what)

    def _resync(self, record: dict) -> None:
        """After a different kind of decision, skip the recording ahead to the same kind."""
        for i in range(self.position - 1, len(self.recorded)):
            if self.recorded[i].get("type") == record.get("type"):
                self.position = i + 1
                return

    def _replay_drive_fault(self) -> None:
        """A pick the recording shows ending on a drive or bus fault: the same fault again at the same point of
        the same step (the step the recorded `interrupted` decision was in; its first instant where the
        recording has none), or at the moment the CAN log shows (a boot-up, an error frame), so the replay
        takes the same path. A fault that cannot be re-created is taken from the recording (`_hardware_stop`)."""
        at = self._fault_stop_of_this_pick()
        if at is None:
            return
        self.fault_stop_at = at
        cut = self.interrupted.get(at)
        steps = (cut or {}).get("records") or []
        now = self.drives.clock.now()
        pick_start_s = steps[0]["t_start_s"] if steps else now  # on the recording's clock
        frames = [] if self.can_log is None else [m for m in self.can_log() if m.timestamp >= pick_start_s - 1e-9]
        fault = recorded_fault(self.recorded[at], {n: d.node_id for n, d in self.drives.drives.items()}, frames)
        if fault is not None and cut is None and fault.kind == "emcy":  # recorded before `interrupted`: next move
            self.drives.inject_fault("emcy", fault.node, code=fault.code, after_s=0.0)
        elif fault is not None:
            if not fault.times_s:
                fault = self._in_the_step_cut_short(fault, steps, pick_start_s, cut is not None)
            for t_s in fault.times_s:
                at_clock(self.drives.clock, now + t_s - pick_start_s, lambda: inject_again(self.drives, fault))
        self.fault, self.faulted_again = fault, fault is not None

    def _fault_after_the_pick(self, executed: dict) -> None:
        """The recording shows a drive or bus fault right after this pick ran to its end: on the way up after a
        miss (the retreat). The same fault again at the replay's next move: an EMCY at its node's next set-point,
        STO or a quick stop just into its next move, one the CAN log times at that time after the pick's end,
        another at once (the retreat follows at once). One
        that cannot be re-created is taken from the recording and said so (`_hardware_stop`)."""
        stop = self.next_recorded()
        if stop is None or stop.get("type") != "stop" or not self._by_hardware(stop):
            return
        if stop.get("source") in self.drives.drives and not str(stop.get("reason", "")).startswith(
                f"{stop['source']} (node "):  # the loop's own ("gripper": "nut: missed 2 times"), no drive's error
            return
        steps = executed.get("records") or []
        end_s = steps[-1]["t_end_s"] if steps else self.drives.clock.now()  # on the recording's clock
        frames = [] if self.can_log is None else [m for m in self.can_log() if m.timestamp >= end_s - 1e-9]
        fault = recorded_fault(stop, {n: d.node_id for n, d in self.drives.drives.items()}, frames)
        if fault is not None:
            fault = replace(fault, what=f"{fault.what}, after the pick ended (the way up after a miss)")
            if fault.kind == "emcy":
                self.drives.inject_fault("emcy", fault.node, code=fault.code, after_s=0.0)
            elif fault.kind in TIMED_EVENTS:  # (STO, a quick stop: "during a move", as recorded, not "while idle")
                self.drives.inject_fault(fault.kind, fault.node, after_s=INJECT_AT_STEP_S)
            elif fault.times_s:
                now = self.drives.clock.now()
                for t_s in fault.times_s:
                    at_clock(self.drives.clock, now + t_s - end_s, lambda: inject_again(self.drives, fault))
            else:
                inject_again(self.drives, fault)
        self.fault_stop_at, self.fault, self.faulted_again = self.position, fault, True

    def _by_hardware(self, stop: dict) -> bool:
        """A recorded stop a drive (its source) or the bus made."""
        return stop.get("source") in self.drives.drives or str(stop.get("reason", "")).startswith("bus: ")

    def _in_the_step_cut_short(self, fault: RecordedFault, steps: list[dict], pick_start_s: float,
                               known: bool) -> RecordedFault:
        """`fault` just before or just into the step the recorded pick was cut short in (after its `steps` done),
        on the recording's clock; at the pick's start where the recording does not say (not `known`)."""
        step_start_s = steps[-1]["t_end_s"] if steps else pick_start_s
        commands = self.recorded[self.position].get("commands") or []
        step = commands[len(steps)].get("label") if known and len(steps) < len(commands) else None
        where = f"step '{step}'" if step else "the pick"
        nudge_s = -INJECT_AT_STEP_S if fault.before_step else INJECT_AT_STEP_S
        return replace(fault, times_s=(step_start_s + nudge_s,),
                       what=f"{fault.what}, {'just before' if fault.before_step else 'at the start of'} {where}")

    def _fault_stop_of_this_pick(self) -> int | None:
        """The recorded stop a drive (its source) or the bus made in the pick whose commands the replay just sent,
        before any `executed`: where the recording shows it cut short."""
        for i in range(self.position + 1, len(self.recorded)):
            rec = self.recorded[i]
            if rec.get("type") == "executed":
                return None
            if rec.get("type") == "stop":
                return i if self._by_hardware(rec) else None
        return None

    def _hardware_stop(self, record: dict, diff: list[str] | None) -> None:
        """The replay is at a stop a drive or bus fault made: re-created (the replay stopped the same way), or
        taken from the recording: said, and the replay ends there (the arm of the replay stands elsewhere). A fault
        re-created that did not stop the replay at all is a divergence: the loop no longer stops on it."""
        from cell.runtime.loop import StopRun

        at, stop = self.position, self.recorded[self.position]
        self.fault_stop_at = None
        said = f"decision #{at} (stop, {stop.get('source')}: {stop.get('reason')})"
        if not diff:  # (a stop the replay comes to on its own, a move refused, is no fault injected)
            if self.fault is not None:
                self.notes.append(f"{said}: a hardware fault, re-created: {self.fault.what}")
            return
        self.faulted_again = True  # the replay's pick went on otherwise: its frames on the bus are others
        if self.fault is not None and record.get("type") != "stop":
            # the fault was sent again and the loop went on: the loop no longer stops on it (a regression)
            self._diverged(f"decision #{at} (stop): the replay did not stop on the re-created fault "
                           f"({self.fault.what}; its next decision: {record.get('type')})")
        if self.fault is None:
            why = "the replay cannot re-create it from what the recording holds"
        elif record.get("type") == "stop":
            why = f"{self.fault.what}, the replay stopped on {record.get('source')}: {record.get('reason')}"
        else:
            why = f"{self.fault.what}, the replay did not stop there (its next decision: {record.get('type')})"
        self.notes.append(f"{said}: a hardware fault, taken from the recording, not re-run ({why})")
        self.position += 1
        if self.position < len(self.recorded):
            self.compared_up_to_here("the session went on after a hardware fault the replay took from the recording")
        raise StopRun(f"{stop.get('source')}: {stop.get('reason')} (taken from the recording)")

    def _recorded_pick(self) -> dict | None:
        """What the recording shows the pick whose commands the replay is sending did: its `executed` or
        `interrupted` decision (None past the recording's end)."""
        for i in range(self.position, len(self.recorded)):
            if i > self.position and i in self.interrupted:
                return self.interrupted[i]
            if self.recorded[i].get("type") == "executed":
                return self.recorded[i]
        return None

    def _set_gripper(self, record: dict, same_pick: bool) -> None:
        """The recording is the world: the jaws stop where they stopped in the session, on the part or blocked
        wider (a neighbour, a chip on a pad), in a pick that ran to its end or one a fault cut short. With
        other examples a pick the recording holds too (`same_pick`: the same commands) closes on the recorded
        width as well; another pick closes on its planned opening. A pick with a grip and a check after the
        lift: the grip's width at the grasp, the check's above it (nothing where the part slipped out), and the
        check above the drop-off's there (nothing where the part was lost on the way)."""
        from cell.runtime.motion import TRANSIT_CHECK

        width, fn = None, None
        if self.strict or same_pick:
            steps = (self._recorded_pick() or {}).get("records", [])
            grip = next((r for r in steps if r.get("action") == "grip"), None)
            check = next((r for r in steps if r.get("action") == "check" and r.get("label") != TRANSIT_CHECK), None)
            transit = next((r for r in steps if r.get("label") == TRANSIT_CHECK), None)
            # jaws that stopped on something (a check's "holding" is just that); a carry-off after a fault: its check
            stopped = [r for r in (grip, check) if r is not None and (r.get("holding") or r.get("blocked"))]
            width = stopped[0]["width_mm"] if stopped else None
            if grip is not None and grip.get("holding") and check is not None:
                fn = self._on_lift(record, grip["width_mm"], check["width_mm"] if check.get("holding") else None,
                                   transit)
        else:
            grips = [c for c in record["commands"] if c["action"] == "grip"]
            width = grips[0]["width_mm"] if grips else None
        self.drives.gripper_object_width_mm = width
        self.drives.drives["gripper"].object_width_fn = fn

    def _on_lift(self, record: dict, grip_mm: float, check_mm: float | None, transit: dict | None = None):
        """What lies between the jaws as the recorded pick found it (as the simulated world decides it,
        `SimWorld`, by the height): closing at the grasp, the part at its grip width; closing above it, at its
        check width (pressed further, turned between the jaws), or nothing (it slipped out on the lift); above
        the drop-off (J1 and J2 at the lowering's), as the recorded check there (`transit`) found it."""
        from cell.runtime.simworld import LIFTED_MM

        grasp_z = next(c["joints"]["j3_mm"] for c in record["commands"] if c["label"] == "descend")
        drop = next((c["joints"] for c in record["commands"] if c["label"] == "lower"), None)

        def at_drop() -> bool:
            at = self.drives.positions()
            return abs(at["j1"] - drop["j1_deg"]) < 0.5 and abs(at["j2"] - drop["j2_deg"]) < 0.5

        def between_jaws() -> float | None:
            if self.drives.positions()["j3"] <= grasp_z + LIFTED_MM:
                return grip_mm
            if transit is not None and drop is not None and at_drop():
                return transit["width_mm"] if transit.get("holding") else None
            return check_mm

        return between_jaws


ARM_STOOD = re.compile(r"; the arm stood at .*?, as last heard\)")  # drivers.arm's note on a lost node


def _without_arm_stood(record: dict) -> dict:
    """A stop without where the arm stood when a node was lost (`Arm._held_part_note`): a replay injects the
    fault at the start of the step it cut short, not the moment in it, so the arm stands elsewhere."""
    if "reason" not in record:
        return record
    return {**record, "reason": ARM_STOOD.sub("", str(record["reason"]))}


def _recorded_since(record: dict) -> bool:
    """A record the loop writes since 2026-12-04 (a part let go at the drop-off but seen again on the tray:
    "not removed"), after the outcome "removed" that older recordings leave standing."""
    return record.get("type") == "outcome" and record.get("outcome") == "not removed"


def _interrupted_before(decisions: list[dict]) -> dict[int, dict]:
    """The recorded `interrupted` decisions (a pick a fault or a stop cut short: its steps done), each by the
    index, among the compared decisions, of the one that followed it (the stop)."""
    out, compared, cut = {}, 0, None
    for d in decisions:
        if d.get("type") == "interrupted":
            cut = d
        elif d.get("type") not in NOT_COMPARED and d.get("type") != "summary":
            if cut is not None:
                out[compared], cut = cut, None
            compared += 1
    return out


@dataclass(frozen=True)
class RecordedFault:
    """A drive or bus fault a recorded pick stopped on, as the replay brings it again: `kind` one of
    `SimHandle.inject_fault`'s ("reboot": the node resets and boots, as on a power glitch). When:
    `times_s` on the recording's clock (what the CAN log shows), else the step it cut short, just before it
    (`before_step`: a lost answer, for the step's first request) or just into it."""

    kind: str
    node: str | None
    what: str  # for people: what is injected, and when
    code: int = 0  # an EMCY's
    error_class: str = ""  # an error frame's (drivers.sim.ERROR_FRAMES)
    count: int = 1  # error frames sent each time
    times_s: tuple[float, ...] = ()
    before_step: bool = False


def recorded_fault(stop: dict, node_ids: dict[str, int], frames: list) -> RecordedFault | None:
    """The fault behind a recorded stop, by what its reason says (not its exact text: the node and the kind), and
    the recorded CAN `frames` from the pick's start on (empty where the log is not on the decisions' clock);
    None when it cannot be re-created (a move timeout without a reboot to explain it, another kind)."""
    from drivers import codec

    reason, node = str(stop.get("reason", "")), stop.get("source")
    if reason.startswith("bus: "):
        return _bus_fault(reason, frames)
    if node not in node_ids:
        return None
    boot_ups = [m.timestamp for m in frames if m.arbitration_id == codec.HEARTBEAT_BASE + node_ids[node]
                and bytes(m.data) == b"\x00"]  # the boot-up message (CiA 301)
    if boot_ups and re.search(r"reboot|target not reached in time|no answer \(", reason):
        return RecordedFault("reboot", node, f"{node} rebooted at {boot_ups[0]:.3f} s (its boot-up frame)",
                             times_s=(boot_ups[0],))
    emcy = re.search(r"EMCY 0x([0-9A-Fa-f]{4})", reason)
    if emcy:
        return RecordedFault("emcy", node, f"{node} sent EMCY 0x{emcy.group(1)} again", code=int(emcy.group(1), 16))
    for pattern, kind, what, before in FAULT_KINDS_BY_REASON:
        if re.search(pattern, reason):
            return RecordedFault(kind, node, f"{node} {what} again", before_step=before)
    return None


# what a stop's reason says -> the fault injected again, said so, and whether just before the step it cut short
FAULT_KINDS_BY_REASON = (
    (r"no heartbeat for", "silent", "fell silent (no heartbeat)", False),
    (r"no SDO answer", "drop_sdo", "lost its SDO answers", True),
    (r"left OPERATION ENABLED .*now in QUICK_STOP_ACTIVE", "quick_stop", "quick-stopped on its own input", False),
    (r"left OPERATION ENABLED .*without a fault", "disable", "switched its drive function off (STO)", False),
    (r"no answer \(set-point acknowledge\)", "ignore_set_point", "ignored its set-points", True),
    (r"reboot", "reboot", "rebooted", False),
)


def _bus_fault(reason: str, frames: list) -> RecordedFault | None:
    """Error frames of the class the reason names, at the times the CAN log shows them (their class is not in
    the log python-can reads back), or as many as it counted at the start of the step."""
    from drivers.errorframes import classify
    from drivers.sim import ERROR_FRAMES, error_frame

    texts = {name: classify(error_frame(name)).text for name in ERROR_FRAMES}
    named = [name for name, text in texts.items() if f"error frame {text}" in reason or f"the last: {text}" in reason]
    if not named:
        return None  # (the host's heartbeat could not be sent: nothing on the bus to re-create)
    error_class = max(named, key=lambda name: len(texts[name]))  # the fullest text that matches
    times = tuple(m.timestamp for m in frames if m.is_error_frame)
    counted = re.match(r"bus: (\d+) error frames", reason)
    count = 1 if times or not counted else int(counted.group(1))
    when = f"at {', '.join(f'{t:.3f}' for t in times)} s" if times else "in the step it cut short"
    return RecordedFault("error_frames", None, f"{len(times) or count} {error_class} error frame(s) sent again {when}",
                         error_class=error_class, times_s=times, count=count)


def inject_again(drives, fault: RecordedFault) -> None:
    """Bring `fault` on the replay's simulated drives."""
    if fault.kind == "error_frames":
        drives.inject_fault("error_frames", error_class=fault.error_class, count=fault.count)
    elif fault.kind == "emcy":
        drives.inject_fault("emcy", fault.node, code=fault.code)
    else:
        drives.inject_fault(fault.kind, fault.node)


def at_clock(clock, t_s: float, fn) -> None:
    """fn() once on the drives' clock at t_s (at once when that has passed), as the hardware brings a fault."""
    if t_s <= clock.now():
        fn()
        return

    def once():
        job.cancel()
        fn()

    job = clock.every(t_s - clock.now(), once, name="replay-fault")


class RecordedApprovals(RunControl):
    """The operator's recorded answers, in order (a reject becomes an invalid example again)."""

    def __init__(self, decisions: list[dict], where: str = "recording"):
        super().__init__(require_approval=False)
        self._answers = [d for d in decisions if d.get("type") == "decision"]
        for d in self._answers:
            if not isinstance(d.get("approved"), bool):
                raise BadInput(f"{where}: a recorded operator decision has no true/false 'approved'")

        self.sink: Comparison | None = None  # where the replay is in the recording

    def request_approval(self, proposal: dict, *, timeout_s=None) -> Decision:
        if not self._answers:
            return super().request_approval(proposal, timeout_s=timeout_s)
        d = self._answers.pop(0)
        return Decision(bool(d["approved"]), d.get("reason", ""), d.get("by", "operator"))

    def report_fault(self, source: str, why: str, *, asking: bool = False) -> None:
        """The loop stopped to ask: answer as the operator did at the station. The session went on (the next
        recorded decision is the loop's): reset and run. The operator stopped it: stop, with their reason.
        Nothing more is recorded: the session ended here. A drive fault the operator reset is as far as a
        replay can follow: where the arm stood when it faulted again is not where it stood in the session."""
        from cell.runtime.loop import StopRun

        super().report_fault(source, why, asking=asking)
        following = None if self.sink is None else self.sink.next_recorded()
        if following is None:
            raise StopRun(f"{source}: {why}")
        if following.get("type") == "stop" and following.get("source") == "operator":
            self.stop(str(following.get("reason") or ""), by="replay")
        elif not asking:
            self.sink.compared_up_to_here(f"the session went on after a fault the operator reset ({source}: "
                                          f"{why}); a replay cannot repeat where the arm stood when it faulted")
            raise StopRun(f"{source}: {why}")
        else:
            self.reset(by="replay")
            self.run(by="replay")


def replay(directory: str | Path, examples: str | Path | None = None, progress=None) -> dict:
    """Re-run a recording. Returns {"decisions", "matched", "differences", "notes" (a hardware fault re-created
    or taken from the recording), "session"} (`recorded_end`);
    raises Divergence (strict mode) at the first difference, BadInput on a missing or corrupt recording."""
    import shutil
    import tempfile

    from calibration import load_calibration
    from cell.cellconfig import load_cell
    from cell.examples import load_examples
    from cell.recording import RecordingReader
    from cell.runtime.loop import CellLoop, LoopOptions, StopRun
    from cell.runtime.session import EXAMPLES_AT_START, home_joints
    from cell.runtime.ways import go_to
    from cell.scene import parse_assembly
    from drivers import simulated_cell

    say = progress or (lambda s: None)
    rec = RecordingReader(directory)
    _check_can_log(rec, directory)
    _check_rrd(rec, directory)
    meta = rec.manifest.get("meta") or {}
    if not isinstance(meta, dict):
        raise BadInput(f"recording {directory}: manifest 'meta' must be an object")
    if "assembly" not in meta:
        raise BadInput(f"recording {directory}: the manifest does not hold the assembly (not made by cell run)")
    assembly = parse_assembly(meta["assembly"], f"recording {directory} assembly")
    _check_held_copies(rec, directory)
    cell = load_cell(rec.cell_path)
    if rec.calibration_path is None:
        raise BadInput(f"recording {directory} holds no calibration")
    cal = load_calibration(rec.calibration_path)
    strict = examples is None
    examples_src = Path(examples) if examples else rec.dir / EXAMPLES_AT_START
    if strict:
        _check_examples_at_start(rec, examples_src, directory)
    load_examples(examples_src)  # a bad file names itself, not the working copy the replay makes of it
    if meta.get("on_no_grasp", "stop") not in ("stop", "skip"):
        raise BadInput(f"recording {directory}: manifest meta.on_no_grasp must be 'stop' or 'skip', "
                       f"not {short_repr(meta.get('on_no_grasp'))}")
    # Loop settings absent in recordings made before the loop had them: off, as it ran then.
    lift_check = _meta_flag(meta, "lift_check", directory)
    whole_part_report = _meta_flag(meta, "whole_part_report", directory)
    tray_check = _meta_flag(meta, "tray_check", directory)
    removal_checks = _meta_flag(meta, "removal_checks", directory)
    axis_closed_form = _meta_flag(meta, "axis_closed_form", directory)
    lift_rest_overlap = _meta_flag(meta, "lift_rest_overlap", directory)
    walls_beyond = _meta_flag(meta, "walls_beyond", directory)
    crisp_edges = _meta_flag(meta, "crisp_edges", directory)
    transit_check = _meta_flag(meta, "transit_check", directory)
    common_motion_check = _meta_flag(meta, "common_motion_check", directory)
    stranger_checks = _meta_flag(meta, "stranger_checks", directory)
    grid_ways = _meta_flag(meta, "grid_ways", directory)
    planner = meta.get("planner")  # absent (or null) in recordings made before it was kept; [] is no planner
    planner_params = planner_from_meta({} if planner is None else planner, f"recording {directory}")
    recorded = [d for d in rec.decisions if d.get("type") != "summary" and d.get("type") not in NOT_COMPARED]
    frames = [rec.frame_path(i) for i in rec.frame_indices]
    if not frames:
        if recorded and all(d.get("type") == "stop" for d in recorded) and not _cut_short(rec):
            # stopped before the camera gave a frame (the operator, no readable frame, a fault on the way home):
            # nothing to re-run
            say("the session stopped before its first frame")
            from drivers.eds import NODE_NAMES

            notes = [f"decision #{i} (stop, {d.get('source')}: {d.get('reason')}): a hardware fault before the first "
                     "frame (on the way home), taken from the recording, not re-run" for i, d in enumerate(recorded)
                     if d.get("source") in NODE_NAMES or str(d.get("reason", "")).startswith("bus: ")]
            return {"decisions": len(recorded), "matched": len(recorded), "differences": [], "notes": notes,
                    "session": recorded_end(rec)}
        summary = rec.manifest.get("summary") or {}
        if not recorded and rec.manifest.get("status") == "incomplete" and summary.get("status") == "not started":
            # its set-up was cut short (SIGTERM during the start, no bus or camera): closed saying so, it holds
            # no decision and no frame, and there is nothing to re-run ("holds no frames", exit 2, read as corrupt)
            why = summary.get("error")
            say(f"the session did not start{f' ({why})' if why else ''}: nothing to re-run")
            return {"decisions": 0, "matched": 0, "differences": [], "notes": [], "session": recorded_end(rec)}
        raise BadInput(f"recording {directory} holds no frames")
    for i in rec.frame_indices:  # a frame the loop would skip as unreadable would shift all that follow
        frame = rec.read_frame(i)
        if frame.shape[:2] != (cell.camera.height_px, cell.camera.width_px):  # another session's cell file
            raise BadInput(f"recording {directory}: frame {i} is {frame.shape[1]} x {frame.shape[0]} px, the camera "
                           f"of its cell file {rec.cell_path.name} {cell.camera.width_px} x {cell.camera.height_px} "
                           "px: not the cell file the session ran with")
        if frame.shape[:2] != (cal.height_px, cal.width_px):
            raise BadInput(f"recording {directory}: frame {i} is {frame.shape[1]} x {frame.shape[0]} px, the "
                           f"calibration {cal.width_px} x {cal.height_px} px")
    with tempfile.TemporaryDirectory() as tmp:
        work_examples = Path(tmp) / "examples.jsonl"
        shutil.copyfile(examples_src, work_examples)  # rejects are appended again, not to the original
        replay_can = Path(tmp) / "replay_can.log"
        # the drives answer in this process: an SDO answer later than the usual 0.3 s is the host's load, not the
        # drives' (a replay beside other jobs timed one out, retried, and diverged on the host's frames)
        with simulated_cell(cell, record=str(replay_can), sdo_timeout_s=REPLAY_SDO_TIMEOUT_S) as (arm, drives):
            sink = Comparison(recorded, drives, strict, cut_short=_cut_short(rec),
                              recorded_summary=next((d for d in rec.decisions if d.get("type") == "summary"), None),
                              interrupted=_interrupted_before(rec.decisions),
                              # a real cell's CAN log keeps wall time, not the clock of its decisions
                              can_log=rec.can_messages if meta.get("real_cell") is None else None)
            control = RecordedApprovals(rec.decisions, f"recording {directory}")
            control.sink = sink
            # interactive: a stop to ask waits for the (recorded) operator's answer, as at the station
            loop = CellLoop(cell=cell, calibration=cal, assembly=assembly, camera=RecordedCamera(frames, sink), arm=arm,
                            control=control, examples_path=work_examples, sink=sink,
                            options=LoopOptions(on_no_grasp=meta.get("on_no_grasp", "stop"), lift_check=lift_check,
                                                whole_part_report=whole_part_report, tray_check=tray_check,
                                                removal_checks=removal_checks, axis_closed_form=axis_closed_form,
                                                lift_rest_overlap=lift_rest_overlap, walls_beyond=walls_beyond,
                                                crisp_edges=crisp_edges,
                                                transit_check=transit_check,
                                                common_motion_check=common_motion_check,
                                                stranger_checks=stranger_checks, grid_ways=grid_ways,
                                                interactive=True),
                            planner_params=planner_params, taught=sink.examples_taught_here)
            go_to(arm, home_joints(cell))
            control.run(by="replay")
            say(f"replaying {len(frames)} frames, {len(recorded)} decisions")
            try:
                loop.run()
            except RecordingEnds:
                pass  # reported below
            except StopRun:
                pass  # the recorded session stopped here too, or the comparison says where not
            except CellError as e:
                sink._diverged(f"the replay failed at decision #{sink.position}: {e}")
        # the host's commands on the bus, now that the drives' session has closed its log; only for the
        # simulated cell (real drives answer in their own time: the host's polling need not repeat)
        simulated = meta.get("real_cell") is None
        can_difference = (first_host_frame_difference(rec.can_messages(), replay_can)
                          if simulated and _host_frames_repeat(rec, recorded, sink) and rec.can_log_path is not None
                          else None)
    if sink.cut_short and not sink.found:
        raise RecordingIncomplete(f"recording {directory} is incomplete ({'; '.join(rec.problems)}): its "
                                  f"{sink.position} recorded decisions match the replay, but how the session went "
                                  "on is not recorded", matched=sink.position)
    if sink.position < len(recorded):
        sink._diverged(f"the replay ended after {sink.position} of {len(recorded)} recorded decisions; next: "
                       f"{recorded[sink.position].get('type')}")
    if can_difference and not sink.found:  # the decisions match: do the commands on the bus?
        sink._diverged(can_difference)
    return {"decisions": len(recorded), "matched": sink.position - len(sink.found), "differences": sink.found,
            "notes": sink.notes, "session": recorded_end(rec)}


def _summary_outcome(summary: dict) -> dict:
    parts = summary.get("parts")
    return {**{k: summary.get(k) for k in ("parts_total", "parts_removed", "parts_skipped")},
            "parts": [{"part": p.get("part"), "outcome": p.get("outcome")} if isinstance(p, dict) else p
                      for p in parts] if isinstance(parts, list) else parts}


def _host_frames_repeat(rec, recorded: list[dict], sink: Comparison) -> bool:
    """Must the replay send the host's CAN frames of the recording, frame for frame? For a session closed
    complete, and for one closed whole at a stop the loop made itself (a "stop and ask" with nobody to
    answer: missed grips, a part that did not leave the tray): the replay reaches that stop by the same
    commands. Not where the operator stopped it (when, within a move, was theirs), nor at a drive fault
    faulted again (the moment within the move may differ), nor for a recording cut short or torn."""
    if rec.manifest.get("status") == "complete":
        return True
    stopped = (rec.manifest.get("summary") or {}).get("status") == "stopped"
    by_operator = any(d.get("type") == "stop" and d.get("source") == "operator" for d in recorded)
    from cell.recording import CAN_LOG

    torn = any(p.startswith(CAN_LOG) for p in rec.problems)
    return (rec.manifest.get("status") == "incomplete" and stopped and not by_operator and not sink.faulted_again
            and not sink.cut_short and not torn)


def recorded_end(rec) -> dict:
    """How the recorded session ended, from its manifest: `status` (the run's: complete, stopped), the parts
    removed of the total, and for a stopped one why (its last stop decision). A stopped session is recorded
    up to its stop, so its replay can match; this says that it did not run to the end."""
    summary = rec.manifest.get("summary") or {}
    end = {"status": summary.get("status", rec.manifest.get("status")), "recording": rec.manifest.get("status"),
           "parts_removed": summary.get("parts_removed"), "parts_total": summary.get("parts_total")}
    stops = [d for d in rec.decisions if d.get("type") == "stop"]
    if stops and end["status"] != "complete":
        end["stopped"] = f"{stops[-1].get('source')}: {stops[-1].get('reason')}"
    elif end["status"] == "stopped" and isinstance(summary.get("stopped"), str):
        end["stopped"] = summary["stopped"]  # stopped after its last decision (its .rrd cut short at the close)
    return end


def _host_frames(messages) -> dict[int, list[bytes]]:
    """The frames the host sends, by CAN id, in order: NMT (0x000), the drives' receive PDOs (0x200-0x57f)
    and SDO requests (0x600-0x67f). The drives' answers, heartbeats and their timing are left out: the
    host's commands are what must repeat (they do, frame for frame, in a simulated replay)."""
    out: dict[int, list[bytes]] = {}
    for m in messages:
        i = m.arbitration_id
        if i == 0 or 0x200 <= i < 0x580 or 0x600 <= i < 0x680:
            out.setdefault(i, []).append(bytes(m.data))
    return out


def first_host_frame_difference(recorded_messages, replayed_log) -> str | None:
    """Where the host's CAN frames of the replay differ from the recording's (None: nowhere)."""
    import can

    rec, rep = _host_frames(recorded_messages), _host_frames(can.LogReader(str(replayed_log)))
    for i in sorted(set(rec) | set(rep)):
        a, b = rec.get(i, []), rep.get(i, [])
        for k, (x, y) in enumerate(zip(a, b)):
            if x != y:
                return (f"CAN id 0x{i:03X}: the host's frame #{k} is {y.hex()} in the replay, {x.hex()} in the "
                        "recording")
        if len(a) != len(b):
            return f"CAN id 0x{i:03X}: the host sent {len(b)} frames in the replay, {len(a)} in the recording"
    return None


def _meta_flag(meta: dict, key: str, directory) -> bool:
    """A true/false loop setting of the manifest's meta; absent: false (recordings made before it)."""
    value = meta.get(key, False)
    if not isinstance(value, bool):
        raise BadInput(f"recording {directory}: manifest meta.{key} must be true or false, not {short_repr(value)}")
    return value


def _cut_short(rec) -> bool:
    """A recording whose end is missing: its writer was never closed (the session crashed or was
    killed), the session failed (an error ended it, e.g. a full disk: closed as incomplete with
    status "failed", no decision says where), its CAN log was cut short (`can_log_failed`: the frames after it
    are missing, not different), or its last decision line was torn off."""
    from cell.recording import DECISIONS

    summary = rec.manifest.get("summary") or {}
    failed = rec.manifest.get("status") == "incomplete" and (summary.get("status") == "failed"
                                                              or bool(summary.get("can_log_failed")))
    return rec.manifest.get("status") == "recording" or failed or any(
        p.startswith(f"{DECISIONS} line") and "is torn" in p for p in rec.problems)


def _check_examples_at_start(rec, path: Path, directory) -> None:
    """The examples the session started with are the ones its manifest names by sha256 (a recording made
    without examples names none): a file cut short or swapped for another replayed as if it were them."""
    ex = rec.manifest.get("examples")
    if ex is None:
        return
    if not isinstance(ex, dict) or not isinstance(ex.get("sha256"), str):
        raise BadInput(f"recording {directory}: manifest 'examples' must be an object with a 'sha256'")
    if not path.exists():
        raise BadInput(f"recording {directory}: the examples the session started with, {path.name}, are missing")
    _check_sha256(directory, path, ex["sha256"], "the example file the session started with")


def _check_held_copies(rec, directory) -> None:
    """The cell.json and calibration.json the recording holds are the ones its manifest names by sha256
    (recordings made before it was kept name none): another session's file, or an edited one, of the same
    camera size replayed as if the session had run with it."""
    for key, path, what in (("cell", rec.cell_path, "cell file"),
                            ("calibration", rec.calibration_path, "calibration")):
        expected = rec.held_sha256(key)
        if expected is not None and path is not None:
            _check_sha256(directory, path, expected, f"the {what} the session ran with")


def _check_sha256(directory, path: Path, expected: str, what: str) -> None:
    """`path` is `what` ("the cell file the session ran with"), which the manifest names by its sha256."""
    from cell.fileio import file_sha256

    try:
        found = file_sha256(path)
    except OSError as e:
        raise BadInput(f"recording {directory}: {path.name} cannot be read: {e.strerror or e}") from None
    if found != expected:
        raise BadInput(f"recording {directory}: {path.name} is not {what} "
                       f"(sha256 {found[:12]}..., the manifest says {expected[:12]}...)")


def _check_can_log(rec, directory) -> None:
    """The CAN log the manifest names is part of the recording: missing, unreadable, or (in a
    recording closed as complete) torn or empty is a corrupt recording."""
    from cell.recording import CAN_LOG

    if not (rec.manifest.get("files") or {}).get("can_log"):
        return  # a recording made without one
    if rec.can_log_path is None:
        raise BadInput(f"recording {directory}: the CAN log {CAN_LOG} is missing")
    n_before = len(rec.problems)
    messages = rec.can_messages()  # BadInput when python-can cannot read it
    if rec.manifest.get("status") == "complete":
        if len(rec.problems) > n_before:
            raise BadInput(f"recording {directory}: {CAN_LOG} is cut off (its last line is torn), but the "
                           "session was closed as complete")
        if not messages:
            raise BadInput(f"recording {directory}: {CAN_LOG} holds no CAN traffic, but the session was "
                           "closed as complete")
    at_close = rec.manifest.get("can_frames_at_close")
    if isinstance(at_close, int) and not isinstance(at_close, bool) and len(messages) < at_close:
        raise BadInput(f"recording {directory}: {CAN_LOG} holds {len(messages)} CAN frames, the manifest says it "
                       f"held {at_close} when the session was closed (cut off)")


def _check_rrd(rec, directory) -> None:
    """The rerun recording the manifest names is part of the recording (replay does not read it,
    but a recording that lost it is not the session as recorded)."""
    from cell.recording import RRD

    name = (rec.manifest.get("files") or {}).get("rrd")
    if not name or rec.manifest.get("status") == "recording":
        return  # none was written, or the writer never got to say
    if (rec.manifest.get("summary") or {}).get("rrd_failed"):
        return  # rerun stopped writing it (a full disk), as the manifest says: replay does not read it
    path = rec.dir / RRD
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except FileNotFoundError:
        raise BadInput(f"recording {directory}: the rerun recording {RRD} is missing") from None
    except OSError as e:
        raise BadInput(f"recording {directory}: {RRD} cannot be read: {e.strerror or e}") from None
    if not head.startswith(b"RRF"):  # rerun's file header (RRF2 in rerun 0.41)
        raise BadInput(f"recording {directory}: {RRD} is not a rerun recording")
