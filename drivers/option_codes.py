"""The CiA 402 option codes the host sets at connect, and what it accepts of a drive that will not take them.

The host wants a quick stop (0x605A) on the quick stop ramp that stays in QUICK STOP ACTIVE (6), and a
fault reaction (0x605E) on the quick stop ramp (2). Many drives ship others (0x605A = 2, then SWITCH ON
DISABLED, is common), some lack the objects (both are optional in CiA 402), some refuse a value.

What is safe:
- a quick stop that stops the axis under control (1-8: a ramp, or the current or voltage limit) is
  accepted with a warning: the host copes whether it ends in QUICK STOP ACTIVE or SWITCH ON DISABLED (it
  waits for standstill and re-enables from either);
- a drive without 0x605A stops as it is built (often 2); accepted with a warning;
- a quick stop that lets the axis coast (0, disable drive function) or that the host cannot know (a
  manufacturer's value) is refused: bring-up fails with a `DriveFault` naming the node;
- the fault reaction is the drive's own once it has faulted (some faults cut the power stage whatever
  0x605E says): any value, or none, is accepted with a warning.
"""

from __future__ import annotations

from drivers.errors import DriveFault

QUICK_STOP, FAULT_REACTION = 0x605A, 0x605E
WANTED = {QUICK_STOP: 6, FAULT_REACTION: 2}
OBJECT_DOES_NOT_EXIST = 0x06020000  # SDO abort code

_LIMIT = {1: "the slow-down ramp", 2: "the quick stop ramp", 3: "the current limit", 4: "the voltage limit"}
QUICK_STOP_TEXT = {
    0: "disable drive function: the axis coasts",
    **{k: f"{how}, then SWITCH ON DISABLED" for k, how in _LIMIT.items()},
    **{k + 4: f"{how}, staying in QUICK STOP ACTIVE" for k, how in _LIMIT.items()},
}
FAULT_REACTION_TEXT = {0: "disable drive function: the axis coasts", **_LIMIT}
TEXTS = {QUICK_STOP: QUICK_STOP_TEXT, FAULT_REACTION: FAULT_REACTION_TEXT}
NAMES = {QUICK_STOP: "quick stop option code", FAULT_REACTION: "fault reaction option code"}


# the way check (drivers.limits) follows each axis' stop on the quick stop ramp 0x6085 (2 x its max acceleration)
# (J1 and J2 place the tool: the other axes' stops leave it where it is across the tray)
OFF_THE_CHECKED_STOP = ("the way check's quick stops (drivers.limits) assume the quick stop ramp 0x6085: this axis "
                        "may stop further off the way")
CHECKED_STOP_AXES = ("j1", "j2")


def describe(index: int, value: int) -> str:
    """'2 (the quick stop ramp, then SWITCH ON DISABLED)'."""
    return f"{value} ({TEXTS[index].get(value, 'manufacturer specific or reserved')})"


def review(name: str, node_id: int, index: int, have: int | None, refused: int | None) -> str | None:
    """What the host makes of a drive's option code `index` after trying to set it: None when the drive has
    the wanted value, else a warning to log. `have` is the value read back (None: the object does not
    exist), `refused` the abort code of the refused write (None: the write was taken, or not needed).
    Raises DriveFault for a quick stop that does not stop the axis under control."""
    wanted = WANTED[index]
    if have == wanted:
        return None
    what = f"{name} (node {node_id}): {NAMES[index]} 0x{index:04X}"
    if have is None:
        return f"{what} missing (SDO abort 0x{OBJECT_DOES_NOT_EXIST:08X}, object does not exist): " + (
            "its quick stop is the drive's own (often the quick stop ramp, then SWITCH ON DISABLED); "
            "the host waits for standstill and re-enables from QUICK STOP ACTIVE or SWITCH ON DISABLED"
            if index == QUICK_STOP else "a fault on this drive stops its axis as the drive is built") + (
            f"; {OFF_THE_CHECKED_STOP}" if name in CHECKED_STOP_AXES else "")
    how = f"refused with SDO abort 0x{refused:08X}" if refused is not None else f"not taken (read back {have})"
    if index == QUICK_STOP and have not in range(1, 9):
        why = "would let the axis coast" if have == 0 else "may not stop the axis under control"
        raise DriveFault(
            f"{what} is {describe(index, have)} and writing {wanted} was {how}: its quick stop {why}, so the "
            f"host will not drive it (set 0x605A to 1, 2, 5 or 6 on the drive)",
            node=name,
            node_id=node_id,
        )
    then = ("after a quick stop the host waits for standstill and re-enables from there" if index == QUICK_STOP
            else "a fault on this drive stops its axis that way")
    if have not in (2, 6) and name in CHECKED_STOP_AXES:  # not on the quick stop ramp 0x6085
        then += f"; {OFF_THE_CHECKED_STOP}"
    return f"{what} stays {describe(index, have)}: writing {wanted} was {how}; {then}"
