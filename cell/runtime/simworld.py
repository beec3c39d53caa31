"""The simulated world of `cell run --sim`: parts on the tray that the simulated gripper can
really pick, and a camera that renders them.

The world watches the simulated drives, not the cell loop: when the jaws start closing it
computes from the joint positions (forward kinematics) what lies between them
(`cell.physics.close_jaws`) and tells the simulated gripper where to stop; a part held by
a grasp that the physical check (`cell.physics.check_grasp`) finds unstable slips out as
the arm lifts and falls back a little shifted (the loop's grip check after the lift then closes past it);
a held part released away from the tray has left the world. Nothing in the loop knows about
this: it sees frames and the bus.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import numpy as np

from cell.cellconfig import Cell
from cell.kinematics import Joints, forward
from cell.physics import check_grasp, close_jaws
from cell.scene import Part

TRACK_PERIOD_S = 0.02
LIFTED_MM = 10.0  # the part is off the tray once the tips are this far above where it was gripped
CARRIED_MM = 20.0  # a part that falls on the carry (WorldFaults.dropped) falls this far from where it was gripped


@dataclass
class WorldFaults:
    """Misbehaviour for tests: parts whose next grips miss, parts stuck to the tray, things on the
    tray that the assembly does not know."""

    miss: dict = field(default_factory=dict)  # part id -> how many grips slide off it
    stuck: set = field(default_factory=set)  # part ids that never leave the tray (the jaws slide off on the lift)
    dropped: set = field(default_factory=set)  # part ids that fall out of the jaws on the carry, back onto the tray
    bad_frames: int = 0  # the camera's next reads that deliver no usable frame
    extra: tuple = ()  # parts on the tray that are not in the assembly (a tool left there)


class SimWorld:
    def __init__(self, parts, cell: Cell, drives, *, seed: int = 0, faults: WorldFaults | None = None):
        self.faults = faults or WorldFaults()
        self.parts: dict[str, Part] = {p.id: p for p in [*parts, *self.faults.extra]}
        self.cell = cell
        self.drives = drives
        self.rng = np.random.default_rng(seed)
        self.held: str | None = None
        self.removed: list[str] = []
        self.events: list[str] = []
        self._lock = threading.Lock()
        self._held_width = 0.0
        self._closest = 0.0
        self._held_z = 0.0
        self._held_xy = (0.0, 0.0)
        self._stable = True
        drives.drives["gripper"].object_width_fn = self._between_jaws
        self._job = drives.clock.every(TRACK_PERIOD_S, self._track, name="sim-world")

    def close(self) -> None:
        self._job.cancel()
        self.drives.drives["gripper"].object_width_fn = None

    def visible_parts(self) -> list[Part]:
        """The parts the camera sees (a held part is above the tray, out of the frame's way
        once the arm has carried it off)."""
        with self._lock:  # the drives' clock thread changes the world meanwhile
            return [p for pid, p in self.parts.items() if pid != self.held]

    def take_out_of_jaws(self) -> str | None:
        """The operator takes the held part out of the jaws by hand (off the tray); its id."""
        with self._lock:
            pid, self.held = self.held, None
            if pid is not None:
                self.parts.pop(pid)
                self.removed.append(pid)
                self.events.append(f"{pid} taken out of the jaws by hand")
            return pid

    def _pose(self):
        pos = self.drives.positions()
        j = Joints(pos["j1"], pos["j2"], pos["j3"], pos["j4"])
        return forward(j, self.cell.scara), pos["gripper"]

    def _between_jaws(self) -> float | None:
        with self._lock:
            return self._between_jaws_locked()

    def _between_jaws_locked(self) -> float | None:
        if self.held is not None:  # closing again on the part they hold, the jaws stop on it (they went
            return self._held_width  # through it: it was left out as an obstacle to itself)
        tool, opening = self._pose()
        centre = np.array([tool.x_mm, tool.y_mm])
        for part in sorted(self.parts.values(), key=lambda p: -p.z_top_mm):
            w = close_jaws(part, centre, tool.axis_deg, opening, tool.z_mm, self.cell)
            if w is None:
                continue
            if self.faults.miss.get(part.id, 0) > 0:
                self.faults.miss[part.id] -= 1
                self.events.append(f"the jaws slid off {part.id}")
                return None
            a = np.array([math.cos(math.radians(tool.axis_deg)), math.sin(math.radians(tool.axis_deg))])
            others = [p for p in self.parts.values() if p.id != part.id]
            verdict = check_grasp(part, [centre - a * w / 2, centre + a * w / 2], tool.axis_deg, tool.z_mm,
                                  others, self.cell)
            self.held, self._held_width, self._held_z = part.id, w, tool.z_mm
            self._held_xy = (tool.x_mm, tool.y_mm)
            self._closest = opening
            self._stable = verdict.ok and part.id not in self.faults.stuck
            self.events.append(f"gripped {part.id} at {w:.2f} mm" + ("" if self._stable else
                                                                     f" (will not hold: {verdict.reasons})"))
            return w
        return None

    def _track(self) -> None:
        with self._lock:
            self._track_locked()

    def _track_locked(self) -> None:
        if self.held is None:
            return
        tool, opening = self._pose()
        self._closest = min(self._closest, opening)  # the jaws are still closing onto it at first
        if opening > self._closest + 1.0:  # the jaws opened again: the part is let go
            pid, self.held = self.held, None
            if self.cell.tray.contains(tool.x_mm, tool.y_mm):
                self.events.append(f"released {pid} on the tray")
            else:
                self.parts.pop(pid)
                self.removed.append(pid)
                self.events.append(f"dropped {pid} off the tray")
        elif ((not self._stable and tool.z_mm > self._held_z + LIFTED_MM)
              or (self.held in self.faults.dropped
                  and math.dist((tool.x_mm, tool.y_mm), self._held_xy) > CARRIED_MM)):
            self._fall_back_locked()

    def slip_out(self) -> str | None:
        """The held part falls out of the jaws now (a jolt at a quick stop): onto the tray under the jaws, or,
        away from the tray, out of the world; its id."""
        with self._lock:
            if self.held is None:
                return None
            tool, _ = self._pose()
            if not self.cell.tray.contains(tool.x_mm, tool.y_mm):
                pid, self.held = self.held, None
                self.parts.pop(pid)
                self.removed.append(pid)
                self.events.append(f"{pid} fell out of the jaws off the tray")
                return pid
            p = self.parts[self.held]
            cx, cy = p.polygon.centroid.coords[0]
            self.parts[self.held] = p.moved(tool.x_mm - cx, tool.y_mm - cy)  # under the jaws, then a little shifted
            return self._fall_back_locked()

    def _fall_back_locked(self) -> str:
        pid, self.held = self.held, None
        p = self.parts[pid]
        self.parts[pid] = p.moved(*self.rng.normal(0, 1.5, 2), self.rng.normal(0, 3))
        self.events.append(f"{pid} slipped out of the jaws and fell back")
        return pid
