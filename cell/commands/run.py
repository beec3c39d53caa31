"""`cell run [ASSEMBLY] [--record DIR] [--json] [--rerun | --save FILE.rrd] [--station] ...`.

Runs the disassembly in the simulated cell (the default on this machine: simulated world,
simulated camera rendering frames through the calibration, simulated CANopen drives on
python-can's virtual bus). With no arguments: the shipped default assembly. With
`--interface I [--channel C] --camera SPEC` the real cell instead: the drives on that CAN bus,
frames from that camera (asks before the arm moves, or `--yes`).
Exit 0 when the whole sequence was removed, 1 when the run stopped or skipped a part (the summary's
status is then "stopped", or "complete" with `parts_skipped`; also when the recording's disk is full:
docs/station.md), 2 on bad input (a --record disk too small for the run, refused before anything moves),
130 on Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import contextlib
import json
import sys


def add_arguments(p):
    p.add_argument("assembly", nargs="?", help="assembly JSON file (default: the shipped default assembly)")
    p.add_argument("--sim", action="store_true",
                   help="simulated cell: world, camera and CANopen drives on the virtual bus (the default; "
                        "not with --interface or --camera)")
    p.add_argument("--record", metavar="DIR", help="record the session into DIR (e.g. recordings/<name>)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on the last stdout line")
    p.add_argument("--rerun", action="store_true", help="show the run live in a rerun viewer")
    p.add_argument("--save", metavar="FILE.rrd", help="write the rerun recording to FILE.rrd")
    p.add_argument("--examples", metavar="FILE", help="teaching-example file (default: the shipped one)")
    p.add_argument("--cell", metavar="FILE", help="cell file (default: the assembly's or the embedded default)")
    p.add_argument("--calibration", metavar="FILE", help="camera calibration (default: the default cell's; "
                   "the simulated cell of a cell file with another camera or tray: a nominal camera of its own; "
                   "a real camera or bus with such a cell file: required); its view must cover the tray")
    p.add_argument("--on-no-grasp", choices=("stop", "skip"), default="stop",
                   help="when a part has no feasible grasp: stop and ask (default) or skip it")
    p.add_argument("--approve", "--approve-each", dest="approve", action="store_true",
                   help="ask the operator to approve each grasp (station)")
    p.add_argument("--no-stranger-check", dest="stranger_check", action="store_false",
                   help="a region no part explains that reaches in across the frame's or the tray's edge (an arm, "
                        "a cable) does not stop the run: it is an obstacle (default: it stops, but what the first "
                        "frame shows there is taken as a fixture; README, Recordings)")
    p.add_argument("--station", action="store_true", help="serve the operator station on 127.0.0.1")
    p.add_argument("--port", type=int, default=8765, help="station port (default 8765)")
    p.add_argument("--token", help="station token, at least 8 characters (default: a random one, printed)")
    p.add_argument("--seed", type=int, default=None,
                   help="simulated world: seed of part displacement and noise (default 0)")
    p.add_argument("--shift-mm", type=float, default=None,
                   help="simulated world: parts lie up to this far from their nominal poses (default 2)")
    p.add_argument("--sim-miss", metavar="PART[:N]", action="append", default=[],
                   help="simulated world: the next N (default 1) grips of PART slide off it")
    p.add_argument("--sim-stuck", metavar="PART", action="append", default=[],
                   help="simulated world: PART never leaves the tray (the jaws slide off it as they lift)")
    p.add_argument("--sim-drop", metavar="PART", action="append", default=[],
                   help="simulated world: PART falls out of the jaws on the carry, back onto the tray")
    p.add_argument("--sim-bad-frames", metavar="N", type=int, default=0,
                   help="simulated camera: the next N reads deliver a corrupt frame (default 0)")
    real = p.add_argument_group("the real cell (instead of the simulated one)")
    real.add_argument("--interface", help="python-can interface of the cell's CAN bus (e.g. socketcan; default: "
                      "none, the simulated cell)")
    real.add_argument("--channel", help="CAN channel (default can0)")
    real.add_argument("--camera", metavar="SPEC",
                      help="the camera: a device index (0, /dev/video0) or a stream URL; on the virtual bus also "
                           "image files or a folder of them (tests)")
    real.add_argument("--yes", action="store_true", help="do not ask before moving the real arm")


def run(args) -> int:
    with sigterm_as_interrupt():  # from the start: the imports and the set-up take seconds (was killed, 143)
        return _run(args)


def _run(args) -> int:
    from cell.errors import BadInput
    from cell.runtime.session import RunConfig, run_session
    from cell.runtime.simworld import WorldFaults

    world_options = {"--seed": args.seed is not None, "--shift-mm": args.shift_mm is not None}  # given?
    args.seed = 0 if args.seed is None else args.seed
    args.shift_mm = 2.0 if args.shift_mm is None else args.shift_mm
    if args.approve and not args.station:
        raise BadInput("--approve needs --station: someone must be there to approve")
    if args.token is not None and not args.station:  # was dropped without a word
        raise BadInput("--token is the operator station's: give --station too")
    if args.seed < 0:
        raise BadInput("--seed must not be negative")
    if not 0 <= args.port <= 65535:
        raise BadInput(f"--port must be 0..65535, not {args.port}")
    if args.station:  # before the recording is made: refused later, they left it a recording of nothing
        from cell.station.server import check_port_free, check_token

        check_token(args.token)
        check_port_free(args.port)
    if args.sim_bad_frames < 0:
        raise BadInput("--sim-bad-frames must not be negative")
    if not 0.0 <= args.shift_mm <= 20.0:
        raise BadInput("--shift-mm must be within 0..20 mm")
    miss = {}
    for m in args.sim_miss:
        pid, _, n = m.partition(":")
        try:
            miss[pid] = int(n or 1)
        except ValueError:
            raise BadInput(f"--sim-miss {m!r}: expected PART or PART:N") from None
        if miss[pid] < 1:
            raise BadInput(f"--sim-miss {m!r}: N must be at least 1")
    if args.rerun:  # before the recording is made
        from cell.viz import check_display

        check_display()
    real_cell = _real_cell(args, world_options)
    out = sys.stderr if args.json else sys.stdout
    cfg = RunConfig(assembly=args.assembly, cell=args.cell, calibration=args.calibration, examples=args.examples,
                    record=args.record, rerun=args.rerun, save_rrd=args.save, seed=args.seed,
                    shift_mm=args.shift_mm, on_no_grasp=args.on_no_grasp, require_approval=args.approve,
                    station=args.station, station_port=args.port, station_token=args.token,
                    stranger_checks=args.stranger_check,
                    faults=WorldFaults(miss=miss, stuck=set(args.sim_stuck), dropped=set(args.sim_drop),
                                       bad_frames=args.sim_bad_frames),
                    progress=lambda s: print(s, file=out, flush=True), real_cell=real_cell)
    try:
        summary = run_session(cfg)
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM: every axis stopped; what was done is still reported
        if getattr(e, "summary", None) is not None:
            _report(e.summary, args.json, out)
        raise
    _report(summary, args.json, out)
    return 0 if summary["status"] == "complete" and summary["parts_removed"] == summary["parts_total"] else 1


@contextlib.contextmanager
def sigterm_as_interrupt():
    """SIGTERM (a service manager, `kill`) ends the run as Ctrl-C does: every axis quick-stopped, the
    recording closed as incomplete; not killed mid-pick with the recording saying "recording"."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _on_sigterm(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    old = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _real_cell(args, world_options: dict):
    """--interface and --camera together select the real cell; the simulated world's options do not
    apply to it. Moving the real arm is confirmed first (or --yes)."""
    from cell.errors import BadInput
    from cell.runtime.session import RealCell

    if args.sim and (args.interface is not None or args.camera is not None):
        raise BadInput("--sim is the simulated cell; --interface and --camera select the real one: give one or "
                       "the other")
    if args.interface is None and args.camera is None:
        if args.channel or args.yes:
            raise BadInput("--channel and --yes are for the real cell: give --interface and --camera too")
        return None
    if args.interface is None or args.camera is None:
        raise BadInput("the real cell needs both --interface (its CAN bus) and --camera")
    sim = [o for o, v in (("--sim-miss", args.sim_miss), ("--sim-stuck", args.sim_stuck), ("--sim-drop", args.sim_drop),
                          ("--sim-bad-frames", args.sim_bad_frames), *world_options.items()) if v]
    if sim:
        raise BadInput(f"{', '.join(sim)}: options of the simulated world, not of the real cell")
    from pathlib import Path

    from cell.commands.hw import confirm_motion

    recorded = Path(args.camera).is_file() or Path(args.camera).is_dir()  # images, a folder, a video file
    if recorded and args.interface != "virtual":
        # old frames show where parts were, and the next file "shows" a pick worked whether or not it did
        raise BadInput(f"--camera {args.camera}: recorded frames drive only the virtual bus (tests); the real arm "
                       "needs a live camera")

    args.channel = args.channel or "can0"
    confirm_motion(args, "run the disassembly (the arm moves over the whole tray)")
    return RealCell(args.interface, args.channel, args.camera)


def _how_it_ended(s: dict) -> str:
    """The status, and with skipped parts why a complete sequence still exits 1: not everything was removed."""
    skipped = s.get("parts_skipped") or []
    if s["status"] != "complete" or not skipped:
        return s["status"]
    return f"sequence complete, {len(skipped)} skipped: {', '.join(skipped)}"


def _report(summary: dict, as_json: bool, out) -> None:
    """The summary as text on `out`, and with --json as the last stdout line."""
    _print_summary(summary, out)
    if as_json:
        print(json.dumps(summary), flush=True)


def _per_joint(values: dict, per: str) -> str:
    """{"j1": 180.0, "j3": 400.0} -> "j1 180 deg/s, j3 400 mm/s" (J3 moves in mm, the others turn)."""
    return ", ".join(f"{j} {x:g} {'mm' if j == 'j3' else 'deg'}{per}" for j, x in values.items())


def _print_summary(s: dict, out) -> None:
    print(f"\n{s['assembly']}: {s['parts_removed']} of {s['parts_total']} parts removed "
          f"({_how_it_ended(s)}), {s['grasps']} grasps", file=out)
    for r in s["parts"]:
        planning = f"planning {r['planning_s'] * 1000:.0f} ms" if r["planning_s"] > 0 else "not planned"
        print(f"  {r['part']:<12} {r['outcome']:<8} attempts {r['attempts']}  cycle {r['cycle_s']:.2f} s "
              f"(motion {r['motion_s']:.2f} s, {planning}) {r['reason']}", file=out)
    if s["parts_removed"]:
        print(f"  mean cycle {s['cycle_s_mean']:.2f} s, {s['picks_per_hour']:.0f} picks/hour, planning share "
              f"{100 * s['planning_share']:.1f}%", file=out)
        v, a = s["motion_limits"]["max_velocity"], s["motion_limits"]["max_acceleration"]
        print(f"  motion limits (cell file): velocity {_per_joint(v, '/s')}; acceleration {_per_joint(a, '/s2')}",
              file=out)
    bus = s.get("can_bus") or {}
    if bus.get("errors"):  # a healthy bus shows none (lost arbitration is no error): say so when it did not
        from drivers.errorframes import by_class_text

        classes = by_class_text(bus["by_class"])
        print(f"  CAN bus: {bus['error_frames']} error frame(s) ({classes}), {bus['errors']} counted"
              + (f"; {bus['fault']}" if bus.get("fault") else ""), file=out)
    looks = s.get("host_looks") or {}
    if looks.get("late"):  # a loaded host: a drive stopping on its own then was answered late
        print(f"  host: {looks['late']} of {looks['looks']} looks at the drives during moves came later than "
              f"{looks['allowed_gap_ms']:g} ms after the one before (worst {looks['worst_gap_ms']:g} ms): the way "
              "check's stop model (can.stop_lag_ms) did not hold then", file=out)
    for k in ("recording", "rrd", "stopped", "recording_not_closed", "can_log_failed"):
        if k in s:
            print(f"  {k}: {s[k]}", file=out)
