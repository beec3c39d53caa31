"""Figures of the driver layer over python-can's virtual bus: command round trip and the bus
load of one pick cycle. Used by `cell bench can`; every figure is measured in one run."""

from __future__ import annotations

import statistics
import time

from cell.errors import BadInput
from drivers import codec
from drivers.clock import SimClock
from drivers.pump import BusPump
from drivers.session import simulated_cell


def _summary_ms(samples_s: list[float]) -> dict:
    ms = sorted(s * 1000.0 for s in samples_s)
    return {
        "n": len(ms),
        "median_ms": round(statistics.median(ms), 4),
        "p95_ms": round(ms[min(len(ms) - 1, int(0.95 * len(ms)))], 4),
        "max_ms": round(ms[-1], 4),
    }


def round_trips(cell=None, n: int = 200) -> dict:
    """Wall-clock round trips host -> drive -> host on the virtual bus (drives in this process):

    - `sdo_read`: an expedited SDO upload of the statusword (request and answer);
    - `set_point_ack`: RPDO1 with the new set-point bit until the TPDO1 that acknowledges it;
    - `move_handshake`: the whole set-point handshake of one axis (target, set-point, ack,
      clear, ack cleared: 3 frames out, 2 in).
    """
    sdo, ack, hand = [], [], []
    with simulated_cell(cell, SimClock()) as (arm, _):
        ax = arm.axes["j1"]
        for _ in range(n):
            t0 = time.perf_counter()
            ax.sdo_read(0x6041)
            sdo.append(time.perf_counter() - t0)
        base = ax.status.position_counts
        step = _step_within_limits(arm.cell, ax, base, 10)
        for i in range(n):
            target = base + (i % 2) * step  # 10 counts there and back: the move itself is instant
            ax.send_target(target)
            t0 = time.perf_counter()
            seq = ax.send_controlword(codec.CW_ENABLE_OPERATION | codec.CW_NEW_SET_POINT)
            ax.wait_status(lambda s: s.ack, seq, "ack")
            ack.append(time.perf_counter() - t0)
            seq = ax.send_controlword(codec.CW_ENABLE_OPERATION)
            ax.wait_status(lambda s: not s.ack, seq, "ack cleared")
            arm.clock.sleep(0.01)
        for i in range(n):
            t0 = time.perf_counter()
            ax.start_move(base + ((i + 1) % 2) * step)
            hand.append(time.perf_counter() - t0)
            arm.clock.sleep(0.01)
    return {
        "sdo_read": _summary_ms(sdo),
        "set_point_ack": _summary_ms(ack),
        "move_handshake": _summary_ms(hand),
    }


def _step_within_limits(cell, ax, base_counts: int, counts: int) -> int:
    """+counts, or -counts where that would pass J1's upper limit: these targets go straight to the drive (not
    through `Arm.move_joints`' checks), and a home at the limit had the bench send 132.01 deg."""
    lo, hi = (v * ax.counts_per_unit for v in cell.scara.j1_deg)
    for step in (counts, -counts):
        if lo <= base_counts + step <= hi:
            return step
    raise BadInput(f"J1's limits {cell.scara.j1_deg} leave no room for a {counts}-count step from its home")


def pick_cycle(cell=None, part_xy_mm=(380.0, -60.0), grasp_z_mm: float = 10.0, width_mm: float = 30.0) -> dict:
    """One pick in simulated time with a tap counting every frame on the bus.

    From home, the cell loop's pick (`cell.runtime.motion.pick_commands`: approach, pre-open,
    descend, grip, lift, carry, lower, release, retreat), then back home. Returns the cycle
    time, frames by kind, bits on the wire (worst-case stuffing) and the bus load at the
    cell's bitrate (1 Mbit/s in the default cell).
    """
    from cell.kinematics import Joints, inverse
    from cell.runtime.motion import pick_commands
    from drivers.execute import run_commands

    clock = SimClock()
    frames = []
    with simulated_cell(cell, clock) as (arm, drives):
        tap_bus = _tap(arm)
        tap = BusPump(tap_bus, [frames.append], name="bench-tap")
        clock.add_settler(tap.settle)
        try:
            c = arm.cell
            home = Joints.from_dict(c.motion.home_joints)
            x, y = part_xy_mm
            grasp = min(
                inverse(x, y, grasp_z_mm, 0.0, c.scara), key=lambda q: float(abs(q.as_array() - home.as_array()).max())
            )
            t0 = clock.now()
            n0 = len(frames)
            drives.gripper_object_width_mm = width_mm

            def world(step):  # the part leaves the jaws at the drop-off
                if step["label"] == "release":
                    drives.gripper_object_width_mm = None

            records = run_commands(arm, pick_commands(grasp, width_mm, c), on_step=world)
            held = next(r["holding"] for r in records if r["action"] == "grip")
            arm.move_joints(home)
            cycle_s = clock.now() - t0
            tap.settle()
            pick = frames[n0:]
        finally:
            clock.remove_settler(tap.settle)
            tap.stop()
            tap_bus.shutdown()
    kinds: dict[str, int] = {}
    bits = 0
    for m in pick:
        kinds[_kind(m)] = kinds.get(_kind(m), 0) + 1
        bits += codec.frame_bits(m.dlc, extended=m.is_extended_id)
    bitrate = arm.cell.can.bitrate
    return {
        "held": held,
        "cycle_s": round(cycle_s, 4),
        "frames": len(pick),
        "frames_by_kind": kinds,
        "bits": bits,
        "bitrate": bitrate,
        "bus_load_percent": round(100.0 * bits / (cycle_s * bitrate), 3),
        "command_frames": sum(v for k, v in kinds.items() if k in ("RPDO", "SDO request", "NMT")),
    }


def _tap(arm):
    from drivers.bus import open_bus

    return open_bus("virtual", arm.bus.channel_info.split("channel ")[-1])


def _kind(m) -> str:
    if m.is_error_frame:
        return "error"
    cob = m.arbitration_id
    fn = cob & 0x780
    if cob == 0:
        return "NMT"
    if fn == 0x080:
        return "EMCY" if cob != 0x80 else "SYNC"
    if fn in (0x180, 0x280, 0x380, 0x480):
        return "TPDO"
    if fn in (0x200, 0x300, 0x400, 0x500):
        return "RPDO"
    if fn == 0x580:
        return "SDO answer"
    if fn == 0x600:
        return "SDO request"
    if fn == 0x700:
        return "heartbeat"
    return "other"
