"""The CiA 402 option codes the host sets at connect, and what it accepts of a drive that will not take them.

The host wants a quick stop (0x605A) on the quick stop ramp that stays in QUICK STOP ACTIVE (6), a
fault reaction (0x605E) on the quick stop ramp (2), and a fault when the connection is lost (0x6007 = 1:
the host's heartbeat missed, which the host sets the drive to watch, 0x1016; the fault reaction then stops
the axis). Many drives ship others (0x605A = 2, then SWITCH ON DISABLED, is common; 0x6007 = 0, no action,
too), some lack the objects (all are optional in CiA 402), some refuse a value.

What is safe:
- a quick stop that stops the axis under control (1-8: a ramp, or the current or voltage limit) is
  accepted with a warning: the host copes whether it ends in QUICK STOP ACTIVE or SWITCH ON DISABLED (it
  waits for standstill and re-enables from either);
- a drive without 0x605A stops as it is built (often 2); accepted with a warning;
- a quick stop that lets the axis coast (0, disable drive function) or that the host cannot know (a
  manufacturer's value) is refused: bring-up fails with a `DriveFault` naming the node;
- the fault reaction is the drive's own once it has faulted (some faults cut the power stage whatever
  0x605E says): any value, or none, is accepted with a warning;
- on a lost connection, a quick stop (3) is accepted with a warning; no action (0: a host that dies
  mid-move leaves the axis running its move to the end), disable voltage (2: the axis coasts) or a
  manufacturer's value are refused; a drive without 0x6007 does what it is built to do when its heartbeat
  consumer times out (accepted with a warning: look it up in its manual).
"""

from __future__ import annotations

from drivers.errors import DriveFault

ABORT_CONNECTION, QUICK_STOP, FAULT_REACTION = 0x6007, 0x605A, 0x605E
WANTED = {ABORT_CONNECTION: 1, QUICK_STOP: 6, FAULT_REACTION: 2}
OBJECT_DOES_NOT_EXIST = 0x06020000  # SDO abort code

_LIMIT = {1: "the slow-down ramp", 2: "the quick stop ramp", 3: "the current limit", 4: "the voltage limit"}
QUICK_STOP_TEXT = {
    0: "disable drive function: the axis coasts",
    **{k: f"{how}, then SWITCH ON DISABLED" for k, how in _LIMIT.items()},
    **{k + 4: f"{how}, staying in QUICK STOP ACTIVE" for k, how in _LIMIT.items()},
}
FAULT_REACTION_TEXT = {0: "disable drive function: the axis coasts", **_LIMIT}
ABORT_CONNECTION_TEXT = {0: "no action: the axis runs on", 1: "fault: the fault reaction stops the axis",
                         2: "disable voltage: the axis coasts", 3: "quick stop, as 0x605A says"}
TEXTS = {ABORT_CONNECTION: ABORT_CONNECTION_TEXT, QUICK_STOP: QUICK_STOP_TEXT, FAULT_REACTION: FAULT_REACTION_TEXT}
NAMES = {ABORT_CONNECTION: "abort connection option code", QUICK_STOP: "quick stop option code",
         FAULT_REACTION: "fault reaction option code"}


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
    if index == ABORT_CONNECTION:
        return _review_abort_connection(name, node_id, what, have, refused)
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


def _review_abort_connection(name: str, node_id: int, what: str, have: int | None, refused: int | None) -> str:
    """`review` of 0x6007: what the drive does when the host falls silent (its heartbeat consumer, 0x1016)."""
    wanted = WANTED[ABORT_CONNECTION]
    if have is None:
        return (f"{what} missing (SDO abort 0x{OBJECT_DOES_NOT_EXIST:08X}, object does not exist): when the host "
                "falls silent this drive does what it is built to do on a heartbeat consumer timeout (its manual "
                "says; many fault, some only send an EMCY)")
    how = f"refused with SDO abort 0x{refused:08X}" if refused is not None else f"not taken (read back {have})"
    if have != 3:
        why = {0: "a host that dies mid-move would leave the axis running its move to the end",
               2: "a host that dies would let the axis coast"}.get(have, "the host cannot know what it does")
        raise DriveFault(f"{what} is {describe(ABORT_CONNECTION, have)} and writing {wanted} was {how}: {why}, so "
                         "the host will not drive it (set 0x6007 to 1 or 3 on the drive)", node=name, node_id=node_id)
    return (f"{what} stays {describe(ABORT_CONNECTION, have)}: writing {wanted} was {how}; when the host falls silent "
            "the drive quick-stops instead of faulting")
