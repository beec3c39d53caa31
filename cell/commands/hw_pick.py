"""`cell hw pick SCENE.json [--place-back]`: one pick planned on a scene file and carried out on the arm.

The hardware-in-loop trial of the whole chain, scene -> grasp -> configuration -> commands -> CAN: the
grasp as `cell grasp` plans it (with the loop's 1 mm margin round the other parts: their poses here are
measured by hand), the arm home first (it may stand anywhere), then the loop's pick with its grip check
after the lift, by a way whose links clear the parts on the tray, to the drop-off or, with `--place-back`,
back down where the part lay. On the simulated cell (the default) the scene's parts lie on the simulated
tray, so the jaws close on the part. Exit 0 when the part was held through the check (and carried off or
put back), 1 when the grip missed or was blocked or the part slipped out (the jaws open, go up and open fully), or,
put back, the check found it moved in the jaws (it stays held, up), and on a drive fault or a "no" at the
confirmation; 3 when no grasp is feasible or none can be carried out (no way whose links clear the other
parts, no travel height over them); 2 on bad input (a target off the tray among it). The jaws must stand
open at the start: a part left between them would be dropped by the pre-open.
"""

from __future__ import annotations

import contextlib


def add_arguments(p) -> None:
    p.add_argument("scene", metavar="SCENE", help="scene JSON file (CONTRACT.md): the part and its neighbours")
    p.add_argument("--examples", metavar="FILE", help="teaching-example file (default: the shipped one)")
    p.add_argument("--place-back", action="store_true",
                   help="put the part back where it lay instead of carrying it to the drop-off")


def run_pick(args, cell, session, confirm_and_enable, stop_on_interrupt, emit) -> int:
    """`session(args, cell)` (connected, not enabled), `confirm_and_enable(args, arm, what)`,
    `stop_on_interrupt(arm)` and `emit(args, obj, text)`: the `cell hw` command's own (cell/commands/hw.py)."""
    from cell.commands.grasp import load_planner_inputs
    from cell.disassembly import lift_blocked_reason, parts_on_top
    from cell.errors import CellError, NoFeasibleGrasp
    from cell.grasp.synthesis import GraspPlanner
    from cell.kinematics import Joints
    from cell.runtime.loop import loop_planner_params
    from cell.scene import load_scene

    scene = load_scene(args.scene)
    if getattr(args, "cell", None) is None and scene.cell_path:  # as `cell grasp`: the scene's own cell
        from cell.cellconfig import load_cell
        from cell.cellgeometry import require_cell_can_move

        cell = load_cell(scene.cell_path)
        require_cell_can_move(cell)
    _require_on_tray(scene, cell)
    planner = GraspPlanner(cell, load_planner_inputs(args.examples), loop_planner_params())
    try:
        blockers = parts_on_top(scene.target_part, scene.obstacles)
        if blockers:  # lifting the target would carry them along (as `cell plan` and the loop say)
            raise NoFeasibleGrasp(lift_blocked_reason(scene, blockers))
        ranked = planner.plan(scene).ranked
    except NoFeasibleGrasp as e:
        emit(args, {"target": scene.target, "error": "no_feasible_grasp", "reason": e.reason},
             f"no feasible grasp for {scene.target!r}: {e.reason}; nothing moved")
        return 3
    home = Joints.from_dict(cell.motion.home_joints)
    with _world(args, cell, session, scene) as (arm, world):
        try:
            grasp, commands = _first_clear(arm, cell, scene, ranked, args.place_back, home, planner)
        except CellError as e:  # no way whose links clear the parts, or no travel height over them
            emit(args, {"target": scene.target, "error": "no_feasible_grasp", "reason": str(e)},
                 f"no grasp of {scene.target!r} can be carried out: {e}; nothing moved")
            return 3
        arm.gripper.require_open()  # a part left between them would be dropped by the pre-open
        where = "put it back" if args.place_back else "carry it to the drop-off"
        confirm_and_enable(args, arm, f"home the arm, pick {scene.target!r} at ({grasp.center_mm[0]:.1f}, "
                                      f"{grasp.center_mm[1]:.1f}) mm, z {grasp.grasp_z_mm:.1f} mm, and {where}")
        t0 = arm.clock.now()
        with stop_on_interrupt(arm):
            records = _carry_out(arm, cell, grasp, commands, home, args.place_back)
        outcome = _outcome(records, args.place_back)
        obj = {"target": scene.target, "grasp": grasp.to_json(), "outcome": outcome,
               "place_back": bool(args.place_back), "records": records,
               "time_s": round(arm.clock.now() - t0, 4)}
        if world is not None:
            obj["sim_events"] = list(world.events)
        emit(args, obj, _text(scene.target, grasp, outcome, records, obj["time_s"]))
    return 0 if outcome == "held" else 1


def _require_on_tray(scene, cell) -> None:
    """The target lies on the cell's tray (a scene for another place, or a typo in one, would send a real arm
    there): bad input otherwise."""
    from cell.errors import BadInput

    outside = cell.tray.outside_text(*scene.target_part.polygon.centroid.coords[0])
    if outside:
        raise BadInput(f"{scene.target!r} {outside}: nothing moved")


@contextlib.contextmanager
def _world(args, cell, session, scene):
    """The arm; on the simulated cell with the scene's parts on its tray (a `SimWorld`), else no world."""
    with session(args, cell) as (arm, drives):
        if drives is None:
            yield arm, None
            return
        from cell.runtime.simworld import SimWorld

        world = SimWorld(scene.parts, cell, drives)
        try:
            yield arm, world
        finally:
            world.close()


def _first_clear(arm, cell, scene, ranked, place_back: bool, home, planner):
    """The first of the best ranked grasps (`MAX_GRASPS_TRIED`, in the loop's order) with a configuration (step
    5, `planner.choose_for`: the best one has it already) whose pick, from home, keeps the links clear of the
    other parts; LinksWouldHit (the first one's reason) when none does, CellError when no travel height
    passes over the other parts."""
    from cell.runtime.motion import pick_commands, place_back_commands
    from cell.runtime.pickway import LinksWouldHit, clear_commands, clear_way, travel_z_mm

    others = list(scene.obstacles)
    safe_z = travel_z_mm(cell, scene.target_part, others, ranked[0].grasp_z_mm)  # (one plan: one grasp z)
    first = None
    for grasp in ranked[:MAX_GRASPS_TRIED]:
        if grasp.joints is None and planner.choose_for(grasp, scene) is None:
            continue  # no configuration whose links clear the parts at the grasp
        try:
            if place_back:  # (checked from home, where the pick starts)
                return grasp, clear_commands(arm, cell, others, place_back_commands(
                    grasp.joints, grasp.opening_mm, cell, safe_z), "", start=home)
            return grasp, clear_way(arm, cell, others, grasp.joints, "", lambda drop, g=grasp, z=safe_z: pick_commands(
                g.joints, g.opening_mm, cell, safe_z_mm=z, drop=drop, check_in_transit=True), start=home)
        except LinksWouldHit as e:
            first = first or e
    raise first or LinksWouldHit(f"none of the best {min(len(ranked), MAX_GRASPS_TRIED)} grasps has a "
                                 "configuration whose links clear the parts")


MAX_GRASPS_TRIED = 10  # of the ranked grasps, for a way whose links clear the tray (each try takes milliseconds)


def _carry_out(arm, cell, grasp, commands, home, place_back: bool) -> list[dict]:
    """Home, then the pick; a grip that missed or a part that slipped out: the jaws open to the approach
    opening (no wider: the planner cleared them up to it), go up to the travel height and open fully there (the
    next `hw pick` refuses jaws that do not stand open). Put back: a part
    that moved in the jaws at the check (`moved_mm`: turned, pressed) hangs lower than where it lay, so it is
    not set down there: the arm stays up holding it."""
    from cell.runtime.motion import above, retreat_opening_mm
    from cell.runtime.ways import go_to
    from drivers.execute import run_commands

    go_to(arm, home)
    k = next(i for i, c in enumerate(commands) if c.action == "check") + 1
    records = run_commands(arm, commands[:k], stop_on_miss=True)
    if records[-1]["action"] == "check" and records[-1].get("holding") and not (place_back and _moved(records)):
        records += run_commands(arm, commands[k:], stop_on_miss=True)
    if records and records[-1].get("holding") is False:
        arm.gripper.open(retreat_opening_mm(grasp.opening_mm, arm.gripper.width_mm, cell))
        travel = next(c.joints.j3_mm for c in commands if c.label == "approach")
        at = arm.joints()
        if at.j3_mm < travel:
            arm.move_joints(above(at, travel))
        arm.gripper.open()
    return records


def _moved(records: list[dict]) -> float | None:
    """How much narrower than its grip the check found the part (mm), when more than the grip's tolerance."""
    return next((r["moved_mm"] for r in records if r["action"] == "check" and "moved_mm" in r), None)


def _outcome(records: list[dict], place_back: bool = False) -> str:
    """held, missed (closed past the part), blocked (stopped wider than it), slipped (lost on the lift), lost (on
    the way to the drop-off: not let go there), or moved (put back: still held at the travel height, not set
    down)."""
    from cell.runtime.motion import TRANSIT_CHECK

    last = records[-1] if records else {}
    if last.get("holding") is False:
        if last.get("action") == "check":
            return "lost" if last.get("label") == TRANSIT_CHECK else "slipped"
        return "blocked" if last.get("blocked") else "missed"
    if place_back and last.get("action") == "check":
        return "moved"
    return "held"


def _text(target, grasp, outcome, records, time_s) -> str:
    c = grasp.contacts_mm
    lines = [f"{target}: grasp at ({grasp.center_mm[0]:.1f}, {grasp.center_mm[1]:.1f}) mm, axis "
             f"{grasp.to_json()['angle_deg']:.1f} deg, opening {grasp.opening_mm:.1f} mm, z {grasp.grasp_z_mm:.1f} mm "
             f"(contacts ({c[0][0]:.1f}, {c[0][1]:.1f}), ({c[1][0]:.1f}, {c[1][1]:.1f}))"]
    for r in records:
        extra = ""
        if "width_mm" in r:
            extra = f" {r['width_mm']:.2f} mm" + ("" if "holding" not in r else " holding" if r["holding"] else
                                                   " NOT holding")
        if "moved_mm" in r:
            extra += f", {r['moved_mm']:.1f} mm narrower than gripped"
        lines.append(f"  {r['label']:<12} {r['action']:<6}{extra}")
    if outcome == "moved":
        verdict = (f"MOVED {_moved(records):.1f} mm in the jaws at the check: not put back down (it would hang "
                   "lower than where it lay); still held at the travel height: take it out by hand, or open the "
                   "jaws over a safe place (`cell hw gripper open`)")
    else:
        verdict = {"held": "held through the check", "missed": "MISSED: the jaws closed past it",
                   "blocked": "BLOCKED: the jaws stopped wider than the part",
                   "slipped": "SLIPPED out of the jaws on the lift",
                   "lost": "LOST on the way to the drop-off (the jaws were empty above it): find it"}[outcome]
    lines.append(f"{target}: {verdict} ({time_s:.2f} s)")
    return "\n".join(lines)
