"""Run a pick's command list on the arm: the arrow "commands -> CAN" of the data flow.

Commands are duck-typed like `cell.runtime.motion.Command`: `action` ('move', 'open',
'grip', 'check'), `label`, and `joints` / `width_mm` / `force_n`. Each step returns a record of what
was actually sent and when (on the arm's clock: simulated seconds in simulation), so the
cell can log decisions, compare a replay, and report the cycle time.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from cell.errors import BadInput


def run_commands(
    arm, commands: Iterable, *, stop_on_miss: bool = True, on_step: Callable[[dict], None] | None = None
) -> list[dict]:
    """Execute `commands` in order; returns one record per executed step:
    `{"label", "action", "t_start_s", "t_end_s", ...}` plus `"joints"` (the command sent) for a
    move, `"width_mm"` for open/grip/check and `"holding"` for a grip or check (`"blocked": true` when the
    jaws stopped wider than expected). With `stop_on_miss`, a grip that closes past the expected width
    ends the list there (the record says holding=False), a check whose jaws close fully too (the part
    slipped out);
    driver errors propagate (the arm has already stopped every axis)."""
    records = []
    for cmd in commands:
        t0 = arm.clock.now()
        rec = {"label": cmd.label, "action": cmd.action}
        if cmd.action == "move":
            rec["joints"] = {k: round(v, 4) for k, v in arm.move_joints(cmd.joints).as_dict().items()}
        elif cmd.action == "open":
            rec["width_mm"] = round(arm.gripper.open(cmd.width_mm), 4)
        elif cmd.action == "grip":
            r = arm.gripper.grip(cmd.width_mm, getattr(cmd, "force_n", None))
            rec.update(width_mm=round(r.width_mm, 4), holding=r.holding)
            if r.blocked:
                rec["blocked"] = True
        elif cmd.action == "check":
            # the grip again: jaws that stop on something still hold the part, pressed further or turned between
            # them (`moved_mm`: how much narrower than where this list gripped it, or than `width_mm`); jaws
            # that close past it have lost it. (Opening them then would drop a part still held.)
            held = [x["width_mm"] for x in records if x["action"] == "grip" and x.get("holding")]
            expected = held[-1] if held else cmd.width_mm
            r = arm.gripper.grip(expected, getattr(cmd, "force_n", None))
            rec.update(width_mm=round(r.width_mm, 4), holding=r.stopped)
            if r.stopped and not r.holding:
                rec["moved_mm"] = round(expected - r.width_mm, 4)
        else:
            raise BadInput(f"unknown command action {cmd.action!r} (step {cmd.label!r})")
        rec.update(t_start_s=round(t0, 6), t_end_s=round(arm.clock.now(), 6))
        records.append(rec)
        if on_step is not None:
            on_step(rec)
        if stop_on_miss and rec.get("holding") is False:
            break
    return records
