"""`cell hw status|sim|reset|home|jog|gripper|corner|pick`: hardware-in-loop commands (`pick`:
cell/commands/hw_pick.py).

Each takes `--interface/--channel` (default: the simulated cell on python-can's virtual
bus, served in this process, so every command runs here as is). On any other interface the
commands that move ask for confirmation first (or take `--yes`), and only then enable the drives; Ctrl-C or
SIGTERM quick-stops every axis before exiting (130).
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import sys
import time

JOG_MAX = {"deg": 10.0, "mm": 10.0}  # the largest jog step: "a small step"
CORNERS = ("near-left", "near-right", "far-left", "far-right")  # near = small x, left = +y
STOP_POLL_S = 0.1  # how soon `cell hw sim` notices SIGINT or SIGTERM


def add_arguments(p) -> None:
    words = p.get_default("_words")
    p.add_argument(
        "--interface",
        default="virtual",
        help="python-can interface (default: virtual, with the simulated drives in this process)",
    )
    p.add_argument("--channel", default=None,
                   help="CAN channel (default: cell-sim on virtual, vcan0 on any other interface)" if words[1] == "sim"
                   else "CAN channel (default: a private virtual channel on virtual, can0 on any other interface)")
    p.add_argument("--cell", default=None, help="cell file (default: the shipped cell)")
    if words[1] == "sim":
        p.add_argument(
            "--seconds",
            type=float,
            default=None,
            help="stop after this many seconds (default: until SIGINT/SIGTERM)",
        )
        return
    p.add_argument("--json", action="store_true", help="print JSON (one object per line)")
    p.add_argument(
        "--simulated-time",
        action="store_true",
        help="run the in-process simulated drives in simulated time (fast; for tests and CI)",
    )
    p.add_argument("--record", default=None, help="record the CAN traffic to this python-can log (.asc/.log/.blf)")
    if words[1] != "status":
        p.add_argument("--yes", action="store_true", help="do not ask before moving real hardware")
    if words[1] == "jog":
        p.add_argument("joint", choices=("j1", "j2", "j3", "j4"), help="the joint to jog")
        p.add_argument(
            "step", type=float, help=f"signed step in deg (j1, j2, j4) or mm (j3), at most {JOG_MAX['deg']:g}"
        )
    elif words[1] == "gripper":
        p.add_argument("action", choices=("open", "grip"), help="open the jaws, or grip a part (--width)")
        p.add_argument("--width", type=float, default=None, help="grip: the expected part width, mm")
        p.add_argument("--force", type=float, default=None, help="grip: force limit, N (default: the cell's)")
        p.add_argument(
            "--part",
            type=float,
            default=None,
            help="simulated cell only: width of a part placed between the jaws, mm",
        )
    elif words[1] == "pick":
        from cell.commands.hw_pick import add_arguments as pick_arguments

        pick_arguments(p)
    elif words[1] == "corner":
        p.add_argument("--corner", choices=CORNERS, default="far-right",
                       help="the tray corner to go to (default far-right)")
        p.add_argument("--dwell", type=float, default=0.5, help="seconds to stay at the corner (default 0.5)")


def run(args) -> int:
    from cell.cellconfig import load_cell
    from cell.cellgeometry import require_cell_can_move

    _check_times(args)
    if getattr(args, "simulated_time", False) and not _simulated(args):  # was ignored: the real bus runs in real time
        from cell.errors import BadInput

        raise BadInput(f"--simulated-time is for the simulated drives (--interface virtual), not {args.interface}")
    cell = load_cell(args.cell)
    if args._words[1] == "sim":
        return _serve(args, cell)
    if args._words[1] != "status":  # every other hw command moves the arm, or may
        require_cell_can_move(cell)
    from cell.commands.run import sigterm_as_interrupt

    # SIGTERM (`timeout`, systemd, kill) ends the command as Ctrl-C does: a move is quick-stopped (exit 130); it
    # ended the process mid-move with no stop at all, and the axes ran on to their targets
    with sigterm_as_interrupt():
        return {"status": _status, "reset": _reset, "home": _home, "jog": _jog, "gripper": _gripper,
                "corner": _corner, "pick": _pick}[args._words[1]](args, cell)


MAX_DWELL_S = 600.0  # a SimClock steps through every heartbeat of the dwell: 1e300 s never ended


def _check_times(args) -> None:
    """--dwell / --seconds: a finite time, not negative (NaN would wait forever on a SimClock)."""
    from cell.commands._vision_args import seconds
    from cell.errors import BadInput

    for option in ("dwell", "seconds"):
        seconds(getattr(args, option, None), f"--{option}")
    if getattr(args, "dwell", None) is not None and args.dwell > MAX_DWELL_S:
        raise BadInput(f"--dwell {args.dwell:g}: at most {MAX_DWELL_S:g} s at the corner")


# --- sessions -------------------------------------------------------------------------------
def _simulated(args) -> bool:
    return args.interface == "virtual"


def _real_channel(args) -> str:
    """The channel of a real interface: --channel, else can0 (the confirmation said "socketcan:None")."""
    return args.channel or "can0"


@contextlib.contextmanager
def _session(args, cell, *, enable: bool = False):
    """A connected arm: the in-process simulated cell on 'virtual', else the real bus. Not enabled: a command
    enables the drives once the operator has said yes (`confirm_and_enable`; enabled at connect, the motors
    held torque while the question was asked, and a "no" had energised them for nothing)."""
    from drivers import RealClock, SimClock, real_cell, simulated_cell

    if _simulated(args):
        clock = SimClock() if args.simulated_time else RealClock()
        session = simulated_cell(cell, clock, channel=args.channel, record=args.record, enable=enable)
        try:
            with session as (arm, drives):
                yield arm, drives
        finally:
            clock.close()
    else:
        with real_cell(args.interface, _real_channel(args), cell, record=args.record, enable=enable) as arm:
            yield arm, None


def confirm_motion(args, what: str) -> None:
    """Ask before moving real hardware; the simulated cell needs no confirmation."""
    from cell.errors import BadInput, CellError

    if _simulated(args) or args.yes:
        return
    if sys.stdin is None or sys.stdin.closed or not sys.stdin.isatty():  # (None: started with stdin closed)
        raise BadInput(f"refusing to {what} on {args.interface}:{_real_channel(args)} without confirmation: pass --yes")
    # the question on stderr: stdout may be JSON for a script reading it
    print(f"About to {what} on the REAL cell ({args.interface}:{_real_channel(args)}). Keep clear. "
          "Type 'yes' to continue: ", end="", file=sys.stderr, flush=True)
    try:
        answer = input()
    except EOFError:  # Ctrl-D: no answer is no
        answer = ""
    if answer.strip().lower() != "yes":
        raise CellError("aborted by the operator; nothing moved")


def confirm_and_enable(args, arm, what: str) -> None:
    """Before a command moves the arm: drives that cannot be enabled (in FAULT, past their limits) refused
    first, then the operator asked (`confirm_motion`), then every drive enabled where it stands."""
    arm.require_enableable()
    confirm_motion(args, what)
    arm.enable()


@contextlib.contextmanager
def _stop_on_interrupt(arm):
    """Ctrl-C (or SIGTERM) during a move: quick-stop every axis, then leave with exit 130."""
    try:
        yield
    except KeyboardInterrupt:
        arm.stop()
        print("cell hw: interrupted, all axes quick-stopped", file=sys.stderr)
        raise


def _emit(args, obj: dict, text: str) -> None:
    print(json.dumps(obj) if args.json else text)


def _joints_text(j) -> str:
    return f"j1 {j.j1_deg:.3f} deg, j2 {j.j2_deg:.3f} deg, j3 {j.j3_mm:.3f} mm, j4 {j.j4_deg:.3f} deg"


# --- commands -------------------------------------------------------------------------------
def _status(args, cell) -> int:
    from drivers import Arm, SimClock, open_bus, sim
    from drivers.record import BusRecorder

    code, states, error = 0, None, None
    if _simulated(args):
        with contextlib.ExitStack() as stack:
            from drivers.clock import RealClock

            clock = SimClock() if args.simulated_time else RealClock()
            stack.callback(clock.close)
            channel = args.channel or "cell-hw-status"
            if args.record is not None:
                tap = open_bus("virtual", channel)
                stack.callback(tap.shutdown)
                stack.enter_context(BusRecorder(tap, args.record, clock=clock if clock.simulated else None))
            sim_bus = open_bus("virtual", channel)
            stack.callback(sim_bus.shutdown)
            stack.enter_context(sim.serve(sim_bus, cell, clock=clock))
            bus = open_bus("virtual", channel)
            stack.callback(bus.shutdown)
            states, bus_state, error = _bring_up(Arm(bus, cell, clock=clock))
    else:
        with contextlib.ExitStack() as stack:
            channel = _real_channel(args)
            if args.record is not None:
                tap = open_bus(args.interface, channel, cell.can.bitrate)
                stack.callback(tap.shutdown)
                stack.enter_context(BusRecorder(tap, args.record))
            bus = open_bus(args.interface, channel, cell.can.bitrate)
            stack.callback(bus.shutdown)
            states, bus_state, error = _bring_up(Arm(bus, cell))
    for s in states.values():
        row = {k: s[k] for k in ("node_id", "name", "state", "position", "unit", "nmt", "fault", "emcy")}
        pos = "-" if s["position"] is None else f"{s['position']:.3f} {s['unit']}"
        _emit(
            args,
            row,
            f"{s['name']:8s} node {s['node_id']:3d}  {s['nmt']:16s} {s['state']:24s} {pos}"
            + (f"  FAULT: {s['fault']}" if s["fault"] else ""),
        )
    # stdout stays one JSON object per node (CONTRACT); with --json the bus line goes to stderr
    print(_bus_text(bus_state), file=sys.stderr if args.json else sys.stdout)
    if error is not None:
        print(f"cell: error: {error}", file=sys.stderr)
        code = 1
    elif any(s["fault"] for s in states.values()) or bus_state["fault"]:
        print("cell: error: some nodes or the bus are faulted (see 'fault'); reset before moving", file=sys.stderr)
        code = 1
    return code


def _bus_text(b: dict) -> str:
    """The bus line of `hw status`: error frames in all (per class) and the policy's window."""
    from drivers.errorframes import by_class_text

    classes = by_class_text(b["by_class"])
    text = (f"bus      error frames {b['error_frames']}{f' ({classes})' if classes else ''}; "
            f"more than {b['error_frames_max']} within {b['error_window_ms']} ms, or one saying the host is off "
            "the bus, stop the arm")
    return text + (f"  FAULT: {b['fault']}" if b["fault"] else "")


def _bring_up(arm):
    """Connect, one more round of heartbeats and TPDOs, disconnect: (node states, bus state, error or None)."""
    from drivers import DriverError

    try:
        arm.connect()
    except DriverError as e:
        return arm.state_at_failure or arm.state(), arm.bus_state(), e
    try:
        arm.clock.sleep(0.05)
        return arm.state(), arm.bus_state(), None
    finally:
        arm.disconnect()


def _serve(args, cell) -> int:
    """Serve the simulated drives until SIGINT/SIGTERM (or --seconds)."""
    from drivers import open_bus, sim

    # a plain flag, polled: a handler that sets a threading.Event can deadlock when the signal comes while the
    # main thread holds that Event's lock inside wait() (seen once in 400 SIGTERMs under load)
    stopped = []

    def _on_signal(signum, frame):
        stopped.append(signum)

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    bus = open_bus(args.interface, args.channel or ("cell-sim" if _simulated(args) else "vcan0"), cell.can.bitrate)
    try:
        with sim.serve(bus, cell) as drives:
            names = ", ".join(f"{n['name']}={n['node_id']}" for n in drives.nodes)
            # python-can's virtual bus lives in this process: no other command reaches drives served on it
            reach = ((" (python-can's virtual bus is in-process only: no other process reaches these drives; "
                      "for another process serve them with --interface socketcan --channel vcan0, docs/drivers.md)")
                     if _simulated(args) else "")
            print(
                f"cell hw sim: simulated drives ({names}) on {args.interface}:{bus.channel_info}{reach}; "
                "Ctrl-C or SIGTERM stops",
                file=sys.stderr,
                flush=True,
            )
            end_s = math.inf if args.seconds is None else time.monotonic() + args.seconds
            while not stopped and time.monotonic() < end_s:
                time.sleep(min(STOP_POLL_S, max(0.0, end_s - time.monotonic())))
    finally:
        bus.shutdown()
        for s, h in old.items():
            signal.signal(s, h)
    print("cell hw sim: stopped", file=sys.stderr)
    return 0


def _reset(args, cell, session=None) -> int:
    """Clear the drives' faults and enable them once, holding where they stand, to see them stay clear (the
    session's end disables them again; the next command enables them): the station's Reset, for a cell run
    without one (every command said "call reset_faults() first", and nothing on the command line did). A drive
    standing past its joint's limits is not enabled: it says where it stands (move it back by hand first)."""
    from drivers import DriverError

    with (session or _session)(args, cell, enable=False) as (arm, _):
        faulted = {name: s["fault"] for name, s in arm.state().items() if s["fault"]}
        what = ", ".join(faulted) if faulted else "no drive in fault"
        confirm_motion(args, f"reset the drives ({what}) and enable them, holding where they stand")
        try:
            arm.reset_faults()
        except DriverError as e:
            print(f"cell: error: {e}", file=sys.stderr)
            return 1
        # (the session's end disables them again, as every hw command does: the next command enables them)
        _emit(args, {"reset": sorted(faulted), "joints": arm.joints().as_dict()},
              (f"faults cleared: {', '.join(faulted)}" if faulted else "no drive was in fault")
              + f"; every drive enabled and clear at {_joints_text(arm.joints())}")
    return 0


def _home(args, cell) -> int:
    from cell.kinematics import Joints
    from cell.runtime.ways import go_to

    home = Joints.from_dict(cell.motion.home_joints)
    with _session(args, cell) as (arm, _):
        confirm_and_enable(args, arm, f"home the arm from {_joints_text(arm.joints())}")
        start = arm.joints()  # (where it stands now: the motors held no torque while the operator was asked)
        t0 = arm.clock.now()
        with _stop_on_interrupt(arm):
            go_to(arm, home)  # lifts first, then swings
        end = arm.joints()
        _emit(
            args,
            {"from": start.as_dict(), "to": end.as_dict(), "time_s": round(arm.clock.now() - t0, 4)},
            f"homed: {_joints_text(end)} ({arm.clock.now() - t0:.2f} s)",
        )
    return 0


def _jog(args, cell) -> int:
    from cell.errors import BadInput
    from cell.kinematics import Joints

    unit = cell.can.nodes[args.joint].unit
    if not math.isfinite(args.step):
        raise BadInput(f"jog step {args.step}: a number of {unit}, at most {JOG_MAX[unit]:g} either way")
    if abs(args.step) > JOG_MAX[unit]:
        raise BadInput(f"jog step {args.step} {unit} too large: at most {JOG_MAX[unit]:g} {unit}")
    with _session(args, cell) as (arm, _):
        confirm_and_enable(args, arm, f"jog {args.joint} by {args.step:+g} {unit}")
        # the step from where the joint stands now: the motors held no torque while the operator was asked, and a
        # target taken before moved J1 by -3 deg after a confirmed +5 (pushed 8 deg by hand meanwhile)
        start = arm.joints()
        d = start.as_dict()
        field = {"j1": "j1_deg", "j2": "j2_deg", "j3": "j3_mm", "j4": "j4_deg"}[args.joint]
        d[field] += args.step
        with _stop_on_interrupt(arm):
            sent = arm.move_joints(Joints.from_dict(d))
        end = arm.joints()
        _emit(
            args,
            {"joint": args.joint, "from": start.as_dict(), "sent": sent.as_dict(), "to": end.as_dict()},
            f"{args.joint}: {getattr(start, field):.3f} -> {getattr(end, field):.3f} {unit}",
        )
    return 0


def _gripper(args, cell) -> int:
    from cell.errors import BadInput

    if args.action == "grip" and args.width is None:
        raise BadInput("gripper grip needs --width (the expected part width, mm)")
    if args.action == "open" and (args.width is not None or args.force is not None):
        raise BadInput("--width and --force are for grip; open takes neither")
    if args.part is not None and not _simulated(args):
        raise BadInput("--part places a part in the simulated cell only")
    top = cell.gripper.opening_mm[1]
    if args.part is not None and not 0 < args.part <= top:  # NaN fails too
        raise BadInput(f"--part {args.part:g}: the width of a part between the jaws, more than 0 and at most "
                       f"the opening, {top:g} mm")
    with _session(args, cell) as (arm, drives):
        if drives is not None:
            drives.gripper_object_width_mm = args.part
        confirm_and_enable(args, arm, f"{args.action} the gripper")
        with _stop_on_interrupt(arm):
            if args.action == "open":
                width = arm.gripper.open()
                _emit(args, {"action": "open", "width_mm": width}, f"gripper open: {width:.2f} mm")
            else:
                r = arm.gripper.grip(args.width, args.force)
                _emit(
                    args,
                    {
                        "action": "grip",
                        "width_mm": r.width_mm,
                        "holding": r.holding,
                        "expected_width_mm": r.expected_width_mm,
                        "blocked": r.blocked,
                    },
                    f"gripper closed at {r.width_mm:.2f} mm: "
                    + ("holding" if r.holding else "BLOCKED (wider than expected)" if r.blocked else "MISSED"),
                )
                return 0 if r.holding else 1  # as `hw pick` ends a miss: a script tells the two apart
    return 0


def _pick(args, cell) -> int:
    from cell.commands.hw_pick import run_pick

    return run_pick(args, cell, _session, confirm_and_enable, _stop_on_interrupt, _emit)


def _corner(args, cell) -> int:
    from cell.errors import CellError
    from cell.kinematics import inverse
    from cell.runtime.ways import go_to

    x = cell.tray.x_mm[0] if args.corner.startswith("near") else cell.tray.x_mm[1]
    y = cell.tray.y_mm[1] if args.corner.endswith("left") else cell.tray.y_mm[0]
    z = cell.motion.safe_z_mm
    with _session(args, cell) as (arm, _):
        def nearest_solution():
            # every elbow and J4 turn within the limits; the one nearest to where the arm stands (J4 turned the
            # least: the jaws' direction does not matter here). Wrapping J4 to the nearest turn went past its
            # limit from a J4 near it, and the corner was refused
            here = arm.joints()
            solutions = inverse(x, y, z, here.j1_deg + here.j2_deg + here.j4_deg, cell.scara)
            if not solutions:
                raise CellError(f"tray corner ({x:g}, {y:g}) is out of reach")
            return here, min(solutions, key=lambda q: float(abs(q.as_array() - here.as_array()).max()))

        nearest_solution()  # (out of reach: said before the question)
        confirm_and_enable(args, arm, f"move to the {args.corner} tray corner ({x:g}, {y:g}) at z {z:g} and back")
        start, corner = nearest_solution()  # from where it stands now (no torque while the operator was asked)
        t0 = arm.clock.now()
        with _stop_on_interrupt(arm):
            go_to(arm, corner)
            at_corner = arm.joints()
            arm.clock.sleep(args.dwell)
            go_to(arm, start)
        end = arm.joints()
        _emit(
            args,
            {
                "corner": args.corner,
                "corner_mm": [x, y, z],
                "at_corner": at_corner.as_dict(),
                "back": end.as_dict(),
                "time_s": round(arm.clock.now() - t0, 4),
            },
            f"{args.corner} corner ({x:g}, {y:g}, {z:g}) reached at {_joints_text(at_corner)}; "
            f"back at {_joints_text(end)}",
        )
    return 0
