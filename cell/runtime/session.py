"""Putting the cell together for one run: the sources (simulated world and camera, or
recorded frames), the CAN bus with the drives, the sinks (recording, rerun), the operator
station, and the loop.

`run_session(cfg)` is what `cell run` does; `cell replay` builds the same loop on a
recording (cell.runtime.replay).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from cell.cellconfig import load_cell
from cell.cellgeometry import require_cell_can_move
from cell.examples import default_examples_path
from cell.fileio import check_writable, json_text, make_folder
from cell.recording import RecordingFailed
from cell.runtime.control import RunControl, Stopped
from cell.runtime.loop import CellLoop, LoopOptions, StopRun
from cell.runtime.recording_end import RecordingEnd
from cell.runtime.simworld import SimWorld, WorldFaults
from cell.scene import Assembly, Part, load_assembly, parse_assembly

EXAMPLES_AT_START = "examples_at_start.jsonl"
STATION_LINGER_S = 2.0  # the station answers this long after the run ends: the page shows how it ended
STATION_LINGER_INTERRUPTED_S = 1.0  # ... after Ctrl-C at the terminal: three of the page's polls
OVERLAP_SLACK_MM2 = 0.5  # displaced parts may overlap this much more than designed (rasterising, rounding)


def default_assembly_path() -> Path:
    from importlib import resources

    return Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))


@dataclass(frozen=True)
class RealCell:
    """The real cell: the drives on a CAN bus (python-can interface and channel) and a camera
    (`cell.vision.sources.open_camera` spec: device index, URL, or a folder of frames)."""

    interface: str
    channel: str
    camera: str


@dataclass
class RunConfig:
    assembly: str | Path | None = None  # None: the shipped default assembly
    cell: str | Path | None = None
    calibration: str | Path | None = None
    examples: str | Path | None = None
    record: str | Path | None = None
    rerun: bool = False
    save_rrd: str | Path | None = None
    seed: int = 0
    shift_mm: float = 2.0  # parts lie up to this far (and 2 deg per mm) from their nominal pose
    on_no_grasp: str = "stop"
    require_approval: bool = False
    station: bool = False
    station_port: int = 8765
    station_token: str | None = None
    faults: WorldFaults = field(default_factory=WorldFaults)
    real_cell: RealCell | None = None  # None: the simulated cell
    # a region no part explains reaching in stops the run (LoopOptions.stranger_checks; `cell run --no-stranger-check`)
    stranger_checks: bool = True
    drive_fault: tuple | None = None  # (node, kind, {kw}) injected into the simulated drives at the start
    progress: object = None  # callable(str) for progress lines


class SimCameraSource:
    """The simulated camera looking at the simulated world (a camera like any other: read())."""

    def __init__(self, world: SimWorld, cal, seed: int):
        from cell.vision import SimCamera, SimCameraOptions

        self.world = world
        self.camera = SimCamera(cal, SimCameraOptions(seed=seed))

    def read(self):
        if self.world.faults.bad_frames > 0:
            self.world.faults.bad_frames -= 1
            from cell.errors import BadInput

            raise BadInput("the camera delivered a corrupt frame (simulated)")
        return self.camera.read(self.world.visible_parts())


def displaced(assembly: Assembly, shift_mm: float, seed: int, tries: int = 40, layouts: int = 10):
    """The assembly's parts as they really lie: each moved a little from its nominal pose; a
    part lying on another moves with it (a base plate carries what sits on it). Parts do not
    move into each other: a move that makes a part overlap one already placed (more than they
    overlap as designed) is drawn again, up to `tries` times (else the least overlapping pose,
    the designed one included); a layout that still has an overlap is drawn again, up to
    `layouts` times (else the least overlapping one)."""
    rng = np.random.default_rng(seed)
    best = None
    for _ in range(layouts):
        parts, excess = _layout(assembly, shift_mm, rng, tries)
        if best is None or excess < best[1]:
            best = (parts, excess)
        if excess <= OVERLAP_SLACK_MM2:
            break
    return best[0]


def _layout(assembly: Assembly, shift_mm: float, rng: np.random.Generator, tries: int) -> tuple[list[Part], float]:
    """One draw of `displaced`: the parts and how much they overlap beyond their designs (mm^2)."""
    nominal = {p.id: p for p in assembly.parts}
    moves: dict[str, tuple] = {}
    placed: list[Part] = []
    total = 0.0
    for p in sorted(assembly.parts, key=lambda q: q.z_bottom_mm):
        carrier = next((c for c in placed if nominal[p.id].lies_on(nominal[c.id])), None)
        if carrier is not None:
            moves[p.id] = moves[carrier.id]
        else:
            about = p.polygon.centroid.coords[0]
            best = (_overlap_excess(p, placed, nominal), (0.0, 0.0, 0.0, about))
            for _ in range(tries):
                move = (*_within(shift_mm, rng), rng.uniform(-2 * shift_mm, 2 * shift_mm), about)
                excess = _overlap_excess(p.moved(*move[:3], about=about), placed, nominal)
                if excess <= OVERLAP_SLACK_MM2:
                    best = (excess, move)
                    break
                best = min(best, (excess, move), key=lambda b: b[0])
            moves[p.id] = best[1]
            total += best[0]
        placed.append(p.moved(*moves[p.id][:3], about=moves[p.id][3]))
    return [p.moved(*moves[p.id][:3], about=moves[p.id][3]) for p in assembly.parts], total


def _within(radius_mm: float, rng: np.random.Generator) -> tuple[float, float]:
    """A shift (dx, dy) drawn evenly over the disc of `radius_mm`: "up to this far" is a distance
    (a square of that half-side reaches 1.4 times as far along its diagonals)."""
    r, turn = np.sqrt(rng.uniform()) * radius_mm, rng.uniform(0.0, 2.0 * np.pi)
    return float(r * np.cos(turn)), float(r * np.sin(turn))


def _overlap_excess(part: Part, placed: list[Part], nominal: dict[str, Part]) -> float:
    """How much more (mm^2) `part` overlaps the parts already placed than their designs overlap
    (parts lying on one another, e.g. on a base plate, overlap in plan view by design)."""
    excess = 0.0
    for q in placed:
        designed = nominal[part.id].polygon.intersection(nominal[q.id].polygon).area
        excess += max(0.0, part.polygon.intersection(q.polygon).area - designed)
    return excess


def _calibration(cfg: RunConfig, cell):
    """(file, calibration): --calibration, else the shipped one of the default camera over the default
    tray; the simulated cell of a cell file with another camera or tray gets a nominal camera of its own
    (file None), so the frames have the cell's size and show its tray. The real cell of such a cell file is
    refused without --calibration (the shipped one took a camera at 1200 mm for one at 800 mm: every part
    placed wrongly)."""
    from calibration import default_calibration_path, load_calibration
    from cell.cellconfig import default_cell
    from cell.errors import BadInput

    default = default_cell()
    if cfg.real_cell is not None and not cfg.calibration:
        if (cell.camera, cell.tray) != (default.camera, default.tray):
            raise BadInput(f"cell file {cell.source}: its camera or tray is not the default cell's, and the shipped "
                           "calibration is of the default camera over the default tray: calibrate this cell's camera "
                           "(`cell calibrate plane IMAGE --markers FILE --out FILE`) and pass --calibration FILE; "
                           "nothing moved")
        return default_calibration_path(), load_calibration(default_calibration_path())
    return camera_calibration(cell, cfg.calibration)


TRAY_EDGE_POINTS = 25  # looked at along each side of the tray (lens distortion bends its image)


def _require_tray_in_view(cal, cell) -> None:
    """The tray's outline, on the calibration's plane, lies in the image: a part on a piece the camera
    does not see is never found (the run ends with it left, or stops on it as "not found"), and one
    half seen is cut off. Refused (exit 2), not warned: the cell file's tray is where the arm picks. For
    any run, after the calibration's own checks (its size; the parts at their heights)."""
    from cell.errors import BadInput

    (x0, x1), (y0, y1) = cell.tray.x_mm, cell.tray.y_mm
    t = np.linspace(0.0, 1.0, TRAY_EDGE_POINTS)
    xy = np.vstack([np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y)]) for y in (y0, y1)]
                   + [np.column_stack([np.full_like(t, x), y0 + (y1 - y0) * t]) for x in (x0, x1)])
    try:
        px = cal.mm_to_px(xy)
    except BadInput as e:
        raise BadInput(f"{cal.label} cannot show the cell's tray: {e}") from None
    out = ~((px >= 0).all(axis=1) & (px[:, 0] <= cal.width_px) & (px[:, 1] <= cal.height_px))
    if out.any():
        (x, y), (u, v) = xy[out][0], px[out][0]
        raise BadInput(f"{cal.label} does not show all of the cell's tray (x {x0:g} to {x1:g}, y {y0:g} to "
                       f"{y1:g} mm): ({x:.0f}, {y:.0f}) mm is at pixel ({u:.0f}, {v:.0f}), outside its "
                       f"{cal.width_px} x {cal.height_px} px image; pass the calibration of this cell's camera, or "
                       "give the cell file the tray the camera sees")


def camera_calibration(cell, path=None):
    """(file, calibration) of the simulated camera of `cell`: `path` when given; else the shipped
    calibration when the cell's camera and tray are the default's, else a nominal camera of the
    cell's size and height over its tray (file None)."""
    from calibration import default_calibration_path, load_calibration
    from calibration.default import nominal_calibration
    from cell.cellconfig import default_cell

    default = default_cell()
    if path or (cell.camera, cell.tray) == (default.camera, default.tray):
        path = Path(path) if path else default_calibration_path()
        return path, load_calibration(path)
    cam = cell.camera
    return None, nominal_calibration(cam.width_px, cam.height_px, cam.height_mm, cell.tray.x_mm, cell.tray.y_mm)


def run_session(cfg: RunConfig) -> dict:
    """Run the disassembly in the simulated cell, or on the real one (`cfg.real_cell`); returns
    the summary (with 'status'). Progress lines go to `cfg.progress`, printed by a thread of their own
    (`ProgressPrinter`), all of them before this returns."""
    say = ProgressPrinter(cfg.progress or (lambda s: None))
    try:
        return _run_session(cfg, say)
    finally:
        say.close()


class ProgressPrinter:
    """The run's progress lines, printed in order by a thread of their own: a terminal that stops reading
    (Ctrl-S, a pipe nobody reads) holds up this thread only. Printed from the run control's listener, a
    line held its lock: the page's state went unanswered and its Stop waited, sending no quick stop, until
    the terminal read again. A terminal that is gone (a broken pipe) ends the printing, not the run."""

    def __init__(self, say):
        import queue

        self._say, self._lines = say, queue.SimpleQueue()
        self._thread = threading.Thread(target=self._print, name="progress", daemon=True)
        self._thread.start()

    def __call__(self, line: str) -> None:
        self._lines.put(line)

    def _print(self) -> None:
        gone = False
        while (line := self._lines.get()) is not None:
            if gone:
                continue
            try:
                self._say(line)
            except OSError:
                gone = True  # a broken pipe: the rest are dropped, the queue still drained
            except Exception:  # noqa: BLE001 - one line that cannot be printed loses that line, not the rest
                pass

    def close(self, timeout_s: float = 10.0) -> None:
        """Every line put so far printed, then the thread ends; a terminal that takes none for `timeout_s` is
        left (its lines with it): the run's report must still come back."""
        self._lines.put(None)
        self._thread.join(timeout_s)


def _run_session(cfg: RunConfig, say) -> dict:
    assembly_path = Path(cfg.assembly) if cfg.assembly else default_assembly_path()
    # the assembly as the recording keeps it (outlines to 4 decimals, Part.to_json): the run and its replay
    # match the same model (a gusset's outline at full precision located it 0.009 deg off in the replay)
    # (no base folder the second time: the first read joined the assembly's own "cell" path onto it)
    assembly = parse_assembly(load_assembly(assembly_path).to_json(), str(assembly_path))
    ids = {p.id for p in assembly.parts}
    for opt, named in (("--sim-miss", cfg.faults.miss), ("--sim-stuck", cfg.faults.stuck),
                       ("--sim-drop", cfg.faults.dropped)):
        unknown = sorted(set(named) - ids)
        if unknown:  # a misspelt fault would be no fault: the run would test nothing it was asked to
            from cell.errors import BadInput

            raise BadInput(f"{opt} {', '.join(unknown)}: no such part in {assembly_path} "
                           f"(parts: {', '.join(sorted(ids))})")
    cell_path = cfg.cell or assembly.cell_path
    cell = load_cell(cell_path)
    require_cell_can_move(cell)
    _require_dropoff_reachable(cell, cell_path)
    _require_dropoff_off_tray(cell, cell_path)
    cal_path, cal = _calibration(cfg, cell)
    if cal_path is None:  # a nominal camera: refused as a recording of it would be, with or without --record
        from cell.recording import nominal_calibration_json

        nominal_calibration_json(cal, cfg.record)
    if (cal.width_px, cal.height_px) != (cell.camera.width_px, cell.camera.height_px):
        from cell.errors import BadInput

        raise BadInput(f"calibration {cal_path} is for {cal.width_px} x {cal.height_px} px, the cell's camera "
                       f"has {cell.camera.width_px} x {cell.camera.height_px} px")
    if cfg.real_cell is None:  # the simulated world lays the parts out as the assembly says
        _require_parts_in_view(assembly, cal, assembly_path)
        _require_parts_on_tray(assembly, cell, assembly_path)
    _require_tray_in_view(cal, cell)
    examples_path = Path(cfg.examples) if cfg.examples else default_examples_path()
    from cell.examples import load_planner_examples

    load_planner_examples(examples_path)  # bad example files are refused before anything moves
    examples_out = None
    if examples_path.resolve() == default_examples_path().resolve():
        # never the shipped file; a fresh file per session (not one an earlier run left here, nor one of a run
        # started in the same second: the process id tells them apart)
        folder = Path(cfg.record) if cfg.record else Path.cwd()
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
        examples_out = folder / ("examples.jsonl" if cfg.record else f"examples-{stamp}-{os.getpid()}.jsonl")
    if cfg.station:  # its rejects and teaching are written there: a read-only file stopped the run at the first
        check_writable(examples_out or examples_path, "the run's example file" if examples_out else "--examples")

    if cfg.record:  # a disk that cannot hold the run is found before anything moves (cell.recording)
        from cell.recording import require_space_for

        require_space_for(cfg.record, len(assembly.parts), cal.width_px, cal.height_px)
    if cfg.save_rrd:  # before the recording is made: a run that cannot start leaves no recording behind
        from cell.cellconfig import default_cell_path

        _check_rrd_path(Path(cfg.save_rrd), [assembly_path, cell_path or default_cell_path(), cal_path, examples_path])
    recorder = None
    options = LoopOptions(on_no_grasp=cfg.on_no_grasp, interactive=cfg.station, stranger_checks=cfg.stranger_checks)
    if cfg.record:
        from cell.recording import RecordingWriter
        from cell.runtime.loop import loop_planner_params
        from cell.runtime.replay import planner_meta

        recorder = RecordingWriter(cfg.record, cell_file=cell_path, calibration_file=cal_path,
                                   nominal_calibration=None if cal_path else cal, examples_file=examples_path,
                                   meta={"assembly": assembly.to_json(), "assembly_path": str(assembly_path),
                                         "seed": cfg.seed, "shift_mm": cfg.shift_mm,
                                         "on_no_grasp": cfg.on_no_grasp,
                                         "lift_check": options.lift_check,
                                         "whole_part_report": options.whole_part_report,
                                         "tray_check": options.tray_check,
                                         "removal_checks": options.removal_checks,
                                         "axis_closed_form": options.axis_closed_form,
                                         "lift_rest_overlap": options.lift_rest_overlap,
                                         "walls_beyond": options.walls_beyond,
                                         "crisp_edges": options.crisp_edges,
                                         "transit_check": options.transit_check,
                                         "common_motion_check": options.common_motion_check,
                                         "stranger_checks": options.stranger_checks,
                                         "grid_ways": options.grid_ways,
                                         "real_cell": None if cfg.real_cell is None else vars(cfg.real_cell),
                                         "planner": planner_meta(loop_planner_params())},
                                   # the examples as they were at the start: replay needs them even after this
                                   # session (or anyone) appended to the file
                                   examples_copy=EXAMPLES_AT_START)
    viz = None
    rrd = cfg.save_rrd or (recorder.rrd_path if recorder else None)
    if rrd or cfg.rerun:
        from cell.viz import Viz

        try:
            viz = Viz("disassembly-cell", spawn=cfg.rerun, save_path=rrd)
        except BaseException as e:
            if recorder is not None:
                recorder.close("incomplete", {"status": "not started", "error": str(e)})
            if isinstance(e, (OSError, RuntimeError)) and rrd:
                from cell.errors import BadInput

                raise BadInput(f"cannot write the rerun recording {rrd}: {e}") from None
            raise

    control = RunControl(require_approval=cfg.require_approval)
    status, summary = None, None
    with HeldInterrupts() as interrupts, contextlib.ExitStack() as stack:
        ending = RecordingEnd(recorder, say)  # the recording's write failures, from here to the drives' shutdown
        stack.push(lambda _t, e, _tb: ending.after_shutdown(e))
        can_log = recorder.can_log_path if recorder else None
        try:
            if cfg.real_cell is not None:
                arm, camera, world = _real_sources(cfg.real_cell, cell, cal, can_log, stack, ending.can_log_failed)
            else:
                arm, camera, world = _simulated_sources(cfg, cell, cal, assembly, can_log, stack,
                                                        ending.can_log_failed)
            loop = CellLoop(cell=cell, calibration=cal, assembly=assembly, camera=camera, arm=arm, control=control,
                            examples_path=examples_path, examples_out=examples_out, sink=recorder, viz=viz,
                            options=options)
        except BaseException as e:  # no camera, bus or loop (a Ctrl-C): nothing ran; the recording says why
            if viz is not None:
                viz.close()
            if recorder is not None:
                recorder.close("incomplete", {"status": "not started", "error": str(e)})
            raise
        _progress(control, say)
        from cell.heap import freeze_startup

        freeze_startup()  # full collections of the start-up objects would stall plans and picks
        interrupted = None
        try:
            # a real cell's arm may stand anywhere: the loop goes home first (up, then across), so that a
            # fault on the way is stopped and recorded as one during the run is
            loop.home_first = home_joints(cell)
            if cfg.station:  # nothing moves before the operator presses Run
                summary = _with_station(loop, control, cfg, say, interrupts)
            else:
                control.run(by="cell run")
                summary = loop.run()
            status = "complete"
        except KeyboardInterrupt as e:
            interrupted = e  # carries the summary out (`cell run --json` prints it as its last line)
            why = interrupt_reason(e)
            # from here on a Ctrl-C is held (the second one used to end this before the status was set: a
            # recording closed as "complete" without its stop); a KeyboardInterrupt raised in the stop itself
            # still gets the stop recorded
            interrupts.hold()
            status = "stopped"
            try:
                arm.stop()  # quick stop of every axis before the drives are disabled
            finally:
                if recorder is not None and (recorder.last_decision or {}).get("type") not in ("stop", "summary"):
                    # where the operator stopped it: replay ends there too instead of diverging (after the
                    # summary the session was over: replay ends there by itself). A full disk: the stop stays the
                    # cause (exit 130), the writer keeps the failure, said beside it (RecordingEnd.settle)
                    with contextlib.suppress(RecordingFailed):
                        recorder.write_decision({"type": "stop", "source": "operator", "reason": why})
            loop.stopped_on(f"operator: {why}")  # the part worked on says so too
            summary = {**loop.summary(), "stopped": f"operator: {why}"}  # (the arm stopped first)
            raise
        except (StopRun, Stopped) as e:
            interrupts.hold()
            status = "stopped"
            why = f"operator: {e}" if isinstance(e, Stopped) else str(e)  # a StopRun names its source
            summary = {**loop.summary(), "stopped": why}
            say(f"stopped: {why}")
        except RecordingFailed as e:  # a full disk: stopped as a stop to ask with nobody there is
            interrupts.hold()
            status = "stopped"
            summary = ending.stopped_by(e, loop, arm)
        except BaseException as e:  # a fault, a bug: the session did not complete
            interrupts.hold()
            status = "failed"
            summary = {**loop.summary(), "error": f"{type(e).__name__}: {e}"}
            raise
        finally:
            interrupts.hold()  # the recording is closed whole: a Ctrl-C now comes after it
            status = status or "failed"
            summary = summary or loop.summary()
            summary.update(status=status)
            summary["can_bus"] = arm.bus_state()  # a shift's error frames, for the cell engineer (drivers.errorframes)
            summary["host_looks"] = arm.look_timing()  # did the host keep the way check's stop lag (drivers.arm)
            if world is not None:
                summary["sim_events"] = list(world.events)
            else:
                summary["real_cell"] = {"interface": cfg.real_cell.interface, "channel": cfg.real_cell.channel,
                                        "camera": cfg.real_cell.camera}
            if recorder is not None:
                summary["recording"] = json_text(str(recorder.dir))  # (printed, stored: bytes not UTF-8 as \xNN)
            if viz is not None:
                viz.close()
                summary["rrd"] = json_text(str(rrd))
            if interrupted is not None:
                interrupted.summary = summary
            status = ending.settle(summary, viz)  # a CAN log, a decision or the .rrd the disk refused: cut short
            if recorder is not None:
                ending.close(status, summary)
    return summary


class _WaitEnded(Exception):  # noqa: N818 - not an error: a signal ended HeldInterrupts.linger's wait
    pass


class HeldInterrupts:
    """Ctrl-C (SIGINT, and SIGTERM where `cell run` makes it one) once the run is ending: the first one
    ends the run (KeyboardInterrupt) as always; those after it, and any while the run is being wound up
    (`hold()`: the arm's stop, the stop decision, the recording's close, the drives' shutdown), are held,
    not raised, so that a second Ctrl-C cannot cut the stop short nor leave a recording that is neither
    closed nor consistent. One held while nothing else ends the run is raised when the `with` ends.
    Only the main thread receives signals; elsewhere, and for signals nobody made an interrupt
    (ignored, or the system's default), this changes nothing."""

    SIGNALS = ("SIGINT", "SIGTERM")

    def __init__(self):
        self.holding = False
        self.held = 0
        self._old: dict = {}
        self._over = False  # the run has ended as it did: a signal only ends the wait after it
        self._lingering = False

    def hold(self) -> None:
        self.holding = True

    def linger(self, seconds: float) -> None:
        """Wait after the run has ended (the station shows how it ended): from now on a Ctrl-C or SIGTERM
        only ends this wait; it is neither raised nor held (the run is over, nothing is to be stopped)."""
        self._over = self._lingering = True
        try:
            time.sleep(seconds)
        except (_WaitEnded, KeyboardInterrupt):  # (the latter where no handler of ours is in place)
            pass
        finally:
            self._lingering = False

    def _on_signal(self, signum, frame) -> None:
        if self._over:
            if self._lingering:
                self._lingering = False
                raise _WaitEnded
            return
        if self.holding:
            self.held += 1
            if self.held == 1:
                import os

                with contextlib.suppress(OSError):  # (a print could meet the stream mid-write: os.write)
                    os.write(2, b"cell: stopping the arm and closing the session; please wait\n")
            return
        self.holding = True  # this one ends the run; the run's end is not cut short by the next
        self._old[signum](signum, frame)

    def __enter__(self) -> HeldInterrupts:
        import signal

        if threading.current_thread() is threading.main_thread():
            for name in self.SIGNALS:
                sig = getattr(signal, name)
                old = signal.getsignal(sig)
                if callable(old):  # default_int_handler, `cell run`'s SIGTERM; not SIG_IGN or SIG_DFL
                    self._old[sig] = old
                    signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        import signal

        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()
        if self.held and exc_type is None:
            raise KeyboardInterrupt


def refuse_parts_at_the_camera(parts, cal, source) -> None:
    """A part reaching the camera's height cannot be seen (nor drawn: the shadow of one 50 m tall took
    minutes)."""
    camera = cal.camera_position_mm()
    for p in parts:
        if camera is not None and p.z_top_mm >= camera[2]:
            from cell.errors import BadInput

            raise BadInput(f"{source}: part {p.id!r} reaches z = {p.z_top_mm:g} mm, at or above the camera "
                           f"(z = {camera[2]:.0f} mm): the camera cannot see it")


def _require_parts_on_tray(assembly: Assembly, cell, assembly_path) -> None:
    """Every part's centre lies on the cell's tray, the work area (`cell hw pick` refuses a target off it: an
    assembly for another place, or a typo in one, would send the arm there; `cell run` picked such a part). For the
    simulated world, which lays the parts out so; on a real cell the assembly's poses are only where to look."""
    for p in assembly.parts:
        outside = cell.tray.outside_text(*p.polygon.centroid.coords[0])
        if outside:
            from cell.errors import BadInput

            raise BadInput(f"{assembly_path}: part {p.id!r} {outside}: nothing moved")


def _require_parts_in_view(assembly: Assembly, cal, assembly_path) -> None:
    """Every part of the assembly lies where the camera sees it whole (its outline at its top, through
    the calibration); one out of view used to stop the run later as 'not found' (exit 1)."""
    refuse_parts_at_the_camera(assembly.parts, cal, assembly_path)  # was "some points are behind the camera"
    for p in assembly.parts:
        px = cal.mm_to_px(p.outline_mm, p.z_top_mm)
        if not (np.isfinite(px).all() and (px >= 0).all() and (px[:, 0] <= cal.width_px).all()
                and (px[:, 1] <= cal.height_px).all()):
            from cell.errors import BadInput

            b = p.polygon.bounds
            raise BadInput(f"{assembly_path}: part {p.id!r} (x {b[0]:.1f}..{b[2]:.1f}, y {b[1]:.1f}..{b[3]:.1f} mm) "
                           f"is not all in the camera's view ({cal.width_px} x {cal.height_px} px)")


def _require_dropoff_reachable(cell, cell_path) -> None:
    """A drop-off the arm cannot reach is a bad cell file, found before anything moves (it used to
    end the run after the first grip, with exit 1)."""
    from cell.errors import BadInput, CellError
    from cell.runtime.motion import DropoffRefused, dropoff_options

    x, y, z = cell.motion.dropoff_mm
    try:
        dropoff_options(cell, home_joints(cell))  # the drop-off the loop will move to, solved as it will be
        return
    except DropoffRefused as e:
        why = f"cannot be sent to the arm: {e.why}"
    except CellError:
        r = float(np.hypot(x, y))
        lo, hi = cell.scara.reach_mm
        why = (f"is {r:.1f} mm from the base, outside the arm's reach {lo:.1f}-{hi:.1f} mm" if not lo <= r <= hi
               else "is not reachable within the joint limits")
    raise BadInput(f"cell file {cell_path or '(default)'}: motion.dropoff_mm {[x, y, z]} {why}")


def _require_dropoff_off_tray(cell, cell_path) -> None:
    """A drop-off over the tray is a bad cell file: the held part was lowered among the parts still there (no
    check looks at the fingers or the part there) and let go on the tray, and the run stopped after the first
    pick with 'did not leave the tray' (exit 1)."""
    x, y, z = cell.motion.dropoff_mm
    if cell.tray.contains(x, y):
        from cell.errors import BadInput

        (x0, x1), (y0, y1) = cell.tray.x_mm, cell.tray.y_mm
        raise BadInput(f"cell file {cell_path or '(default)'}: motion.dropoff_mm {[x, y, z]} lies over the tray "
                       f"(x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm): a part let go there stays among the others")


def _check_rrd_path(path: Path, inputs) -> None:
    from cell.errors import BadInput

    for p in inputs:  # it replaced the assembly or the example file with the .rrd
        if p is not None and Path(p).resolve() == path.resolve():
            raise BadInput(f"--save {path} is one of the run's input files: it would be overwritten; name another")
    if path.is_dir():
        raise BadInput(f"--save {path} is a directory, not a .rrd file")
    from cell.recording import recording_holding

    held_by = recording_holding(path)  # (the run's own --record folder is new or empty here: no manifest yet)
    if held_by is not None:  # it replaced that session's session.rrd (exit 0), or added a file it does not name
        raise BadInput(f"--save {path} lies in the recording {held_by}: a recording is kept as it was made; "
                       "save the rerun recording elsewhere")
    if path.suffix.lower() != ".rrd":  # rerun writes whatever name it is given; the viewer opens .rrd files
        raise BadInput(f"--save {path}: a rerun recording is a .rrd file; name it {path.with_suffix('.rrd').name}")
    check_writable(path, "--save")  # rerun writes it in place: a read-only one was overwritten
    make_folder(path.parent, f"--save {path}")


def _simulated_sources(cfg: RunConfig, cell, cal, assembly: Assembly, can_log, stack: contextlib.ExitStack,
                       can_log_failed=None):
    """The simulated drives on the virtual bus, the simulated world and its camera."""
    from drivers import simulated_cell

    arm, drives = stack.enter_context(simulated_cell(cell, record=can_log, on_record_failed=can_log_failed))
    world = SimWorld(displaced(assembly, cfg.shift_mm, cfg.seed), cell, drives, seed=cfg.seed, faults=cfg.faults)
    stack.callback(world.close)
    if cfg.drive_fault is not None:
        node, kind, kw = cfg.drive_fault
        drives.inject_fault(kind, node, **kw)
    return arm, SimCameraSource(world, cal, cfg.seed), world


def _real_sources(real: RealCell, cell, cal, can_log, stack: contextlib.ExitStack, can_log_failed=None):
    """The drives on the cell's CAN bus and its camera: no world, what the camera shows is the truth.
    The camera is checked (it delivers frames of the calibration's size) before the bus is opened."""
    from cell.vision.sources import open_camera
    from drivers import real_cell

    camera = stack.enter_context(open_camera(real.camera, (cal.width_px, cal.height_px)))
    cal.check_frame(camera.peek(), f"the first frame of camera {real.camera!r}")
    arm = stack.enter_context(real_cell(real.interface, real.channel, cell, record=can_log,
                                             on_record_failed=can_log_failed))
    arm.gripper.require_open()  # a part left between the jaws would be dropped by the first pre-open
    return arm, camera, None


def home_joints(cell):
    from cell.kinematics import Joints

    return Joints.from_dict(cell.motion.home_joints)


def interrupt_reason(e: KeyboardInterrupt) -> str:
    """Why the run stopped: Ctrl-C at the terminal, or SIGTERM (`cell run` raises it as KeyboardInterrupt("SIGTERM"):
    a service manager or `kill`, which was reported as the terminal's)."""
    return "interrupted by SIGTERM" if e.args == ("SIGTERM",) else "interrupted at the terminal"


PROGRESS_EVENTS = ("start", "carried", "lost", "removed", "skip", "miss", "fault", "ask", "example", "vision", "frame")


def _progress(control: RunControl, say) -> None:
    """Print the loop's events as they happen (progress for the operator's terminal)."""
    control.add_listener(lambda e: say(f"[{e['event']}] {e['message']}")
                         if e.get("message") and e["event"] in PROGRESS_EVENTS else None)


def _with_station(loop: CellLoop, control: RunControl, cfg: RunConfig, say, interrupts: HeldInterrupts) -> dict:
    from cell.runtime.backend import LoopBackend
    from cell.station.server import StationServer

    server = StationServer(LoopBackend(loop), control, port=cfg.station_port, token=cfg.station_token)
    result: dict = {}
    # The loop's end, waited for on an event, not by Thread.join: Python 3.11's join interrupted by a signal can
    # mark a thread that still runs as stopped (it releases the thread's own lock), and the next join returns at
    # once. The loop then wrote on after the stop and the recording's close (4 of 14 sessions stopped by a signal
    # could not be replayed), or the process ended under it (SIGABRT).
    finished = threading.Event()

    def work():
        try:
            result["summary"] = loop.run()
        except BaseException as e:  # noqa: BLE001 - reported to the operator and the caller
            result["error"] = e
        finally:
            finished.set()

    with server:
        say(f"operator station: {server.url}  (token {server.token}); press Run on the page")
        threading.Thread(target=work, name="cell-loop", daemon=True).start()
        try:
            while not finished.wait(0.2):
                pass
        except KeyboardInterrupt as e:
            control.stop(interrupt_reason(e))
            loop.arm.stop()  # a pick in progress ends now, not when it is done
            finished.wait()
            control.end()
            # the page shows "stopped" and why, not a cell that stopped answering mid-run (another Ctrl-C
            # ends the wait)
            interrupts.linger(STATION_LINGER_INTERRUPTED_S)
            raise
        control.end()
        # done, stopped or failed: the page polls a few more times and shows how it ended. The run has
        # ended as it did: Ctrl-C here only ends the wait (it made a complete run "stopped", and the quick
        # stop's frames came after the recording's end; a second one lost the summary)
        interrupts.linger(STATION_LINGER_S)
    if "error" in result:
        raise result["error"]
    return result["summary"]

