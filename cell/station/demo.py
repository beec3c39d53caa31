"""A small, real cell behind the station for `cell station [--cell F]` and the station's tests.

It is not the cell loop (cell/runtime/loop.py plans with the learned planner and drives the
CANopen nodes); it exercises everything the station touches, for real: a loop thread through
`RunControl` (checkpoints, approval, faults), frames rendered from the parts' outlines with
a fixed px <-> mm mapping (`TrayView`: the cell's camera frame looking straight down at the
cell's tray), rejected grasps appended as invalid examples and taught grasps as
valid ones with `cell.examples.append_examples` (atomically), the example file re-read after
each append (a "rebuild") and the taught contacts used for the next proposal on that part.
Everything comes from the cell given (`cell station --cell F`; default: the shipped cell): the tray
and the parts laid out on it, the frame's size (its camera), the jaws' stroke that proposals and
taught grasps must fit, the footprints drawn, the home joints and the arm configurations.

Its proposer is deliberately simple and says so: it closes across the part's minimum
rotated rectangle (short side first, then the long side after a rejection), within the jaws' stroke.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from functools import cache
from pathlib import Path

import numpy as np

from cell.cellconfig import Cell, default_cell
from cell.configuration import choose_configuration
from cell.errors import BadInput
from cell.examples import GraspExample, append_examples, load_examples
from cell.kinematics import Joints
from cell.runtime.backend import clicked_on_frame, jaw_pose, taught_contacts
from cell.runtime.control import Faulted, RunControl, Stopped
from cell.scene import Part

DEMO_TRAY_CENTRE_MM = (350.0, 0.0)  # the tray demo_parts() are laid out on: the default cell's
DEMO_TRAY_SPAN_MM = (300.0, 500.0)
TRAY_FILL = 0.78125  # the tray's share of the frame along its tighter side (the default cell: 2 px a mm)
TEACH_OFF_MAX_MM = 15.0  # a teach tap this far off the outline still counts (the drawn frame is coarse)
MOVE_POLL_S = 0.05  # a stop during a pick's motion is seen this soon
PART_COLORS_BGR = [(60, 140, 230), (80, 190, 90), (200, 120, 60), (170, 80, 190), (60, 200, 200)]


@dataclass(frozen=True)
class TrayView:
    """The demo's camera: the cell's frame size, looking straight down at the centre of the cell's tray,
    scaled so the tray fills TRAY_FILL of the frame. Base frame (x forward, y left) -> image (u right,
    v down)."""

    width_px: int
    height_px: int
    centre_mm: tuple[float, float]
    px_per_mm: float

    @classmethod
    def of(cls, cell: Cell) -> TrayView:
        w, h = cell.camera.width_px, cell.camera.height_px
        (x0, x1), (y0, y1) = cell.tray.x_mm, cell.tray.y_mm
        scale = TRAY_FILL * min(w / (y1 - y0), h / (x1 - x0))  # y runs along u, x along v
        return cls(w, h, ((x0 + x1) / 2, (y0 + y1) / 2), scale)

    def mm_to_px(self, xy_mm) -> np.ndarray:
        """Shape kept: (..., 2) mm -> (..., 2) px."""
        a = np.asarray(xy_mm, dtype=float)
        u = self.width_px / 2 - (a[..., 1] - self.centre_mm[1]) * self.px_per_mm
        v = self.height_px / 2 - (a[..., 0] - self.centre_mm[0]) * self.px_per_mm
        return np.stack([u, v], axis=-1)

    def px_to_mm(self, uv_px) -> np.ndarray:
        a = np.asarray(uv_px, dtype=float)
        y = self.centre_mm[1] - (a[..., 0] - self.width_px / 2) / self.px_per_mm
        x = self.centre_mm[0] - (a[..., 1] - self.height_px / 2) / self.px_per_mm
        return np.stack([x, y], axis=-1)


@cache
def _default_view() -> TrayView:
    return TrayView.of(default_cell())


def mm_to_px(xy_mm) -> np.ndarray:
    """mm -> px in the default cell's demo frame (a DemoCell of another cell: its `.view`)."""
    return _default_view().mm_to_px(xy_mm)


def px_to_mm(uv_px) -> np.ndarray:
    return _default_view().px_to_mm(uv_px)


def demo_parts(cell: Cell | None = None) -> list[Part]:
    """A small tray: a cover, a board, a bracket (an L) and a cap, on `cell`'s tray (default: the default
    cell's) where they lie on the default tray relative to its size; BadInput when they do not fit on it."""
    def rect(cx, cy, w, h, angle_deg=0.0):
        t = math.radians(angle_deg)
        r = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
        pts = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
        return pts @ r.T + (cx, cy)

    parts = [
        Part("cover", rect(300, 120, 60, 40, 15), z_bottom_mm=0.0, z_top_mm=12.0),
        Part("board", rect(400, -40, 70, 45, -10), z_bottom_mm=0.0, z_top_mm=8.0),
        Part("bracket", np.array([[250, -160], [310, -160], [310, -140], [270, -140], [270, -100],
                                  [250, -100]], float), z_bottom_mm=0.0, z_top_mm=15.0),
        Part("cap", rect(430, 150, 36, 30, 30), z_bottom_mm=0.0, z_top_mm=20.0),
    ]
    return parts if cell is None else _on_tray(parts, cell)


def _on_tray(parts: list[Part], cell: Cell) -> list[Part]:
    """`parts` (laid out on the default tray) moved onto `cell`'s tray: each part's centroid at the same place
    relative to the tray's centre and size, the part itself unscaled."""
    from shapely.geometry import box

    (x0, x1), (y0, y1) = cell.tray.x_mm, cell.tray.y_mm
    centre, span = np.array([(x0 + x1) / 2, (y0 + y1) / 2]), np.array([x1 - x0, y1 - y0])
    dc, ds = np.array(DEMO_TRAY_CENTRE_MM), np.array(DEMO_TRAY_SPAN_MM)
    moved = []
    for p in parts:
        c = np.array(p.polygon.centroid.coords[0])
        shift = (c - dc) * (span / ds - 1.0) + (centre - dc)  # (exactly 0 on the default tray)
        moved.append(replace(p, outline_mm=p.outline_mm + shift, holes_mm=tuple(h + shift for h in p.holes_mm)))
    tray = box(x0, y0, x1, y1)
    where = f"the tray of cell {cell.source} (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm)"
    for i, p in enumerate(moved):
        if not tray.contains(p.polygon):
            raise BadInput(f"the demo cell's {p.id} does not fit on {where}: give a larger tray")
        for q in moved[i + 1:]:
            if p.polygon.intersects(q.polygon):
                raise BadInput(f"the demo cell's {p.id} and {q.id} overlap on {where}: give a larger tray")
    return moved


def _footprints(contacts_mm: np.ndarray, cell: Cell) -> tuple[list[np.ndarray], np.ndarray]:
    """Finger pads (outside each contact, along the closing axis) and the palm, mm."""
    g = cell.gripper
    c1, c2 = contacts_mm
    axis = (c2 - c1) / max(np.linalg.norm(c2 - c1), 1e-9)
    normal = np.array([-axis[1], axis[0]])
    fingers = []
    for c, out in ((c1, -axis), (c2, axis)):
        a, b = c, c + out * g.pad_thickness_mm
        w = normal * g.pad_width_mm / 2
        fingers.append(np.array([a - w, b - w, b + w, a + w]))
    mid = (c1 + c2) / 2
    la, lw = axis * g.palm_length_mm / 2, normal * g.palm_width_mm / 2
    palm = np.array([mid - la - lw, mid + la - lw, mid + la + lw, mid - la + lw])
    return fingers, palm


def _across_rectangle(part: Part) -> list[np.ndarray]:
    """Two contacts across the part's minimum rotated rectangle, across its short side first, then its long
    side: the rectangle's side midpoints moved onto the outline (a non-convex part's edge may lie inside its
    rectangle)."""
    from shapely.geometry import Point
    from shapely.ops import nearest_points

    rect = np.asarray(part.polygon.minimum_rotated_rectangle.exterior.coords)[:4]
    sides = [np.linalg.norm(rect[(i + 1) % 4] - rect[i]) for i in range(2)]  # side i and i+2 are parallel
    boundary = part.polygon.boundary
    out = []
    for i in (int(np.argmin(sides)), int(np.argmax(sides))):
        a, b = (rect[(i + 1) % 4] + rect[(i + 2) % 4]) / 2, (rect[(i + 3) % 4] + rect[i]) / 2
        out.append(np.array([nearest_points(boundary, Point(q))[0].coords[0] for q in (a, b)]))
    return out


class DemoCell:
    """A StationBackend with its own loop thread.

    Parameters
    ----------
    control : the RunControl the station drives.
    examples_path : the example file taught and rejected grasps are appended to.
    cell : the cell (default: the shipped one): its tray, camera, gripper, arm and home joints.
    parts : the parts on the tray (default: demo_parts(cell); BadInput when they do not fit on its tray).
    motion_s : simulated duration of one pick (the loop is busy meanwhile).
    """

    def __init__(self, control: RunControl, examples_path: str | Path, *, cell: Cell | None = None,
                 parts: list[Part] | None = None, motion_s: float = 0.5):
        self.control = control
        self.cell = cell or default_cell()
        self.view = TrayView.of(self.cell)
        self.examples_path = Path(examples_path)
        self.motion_s = float(motion_s)
        self._lock = threading.Lock()
        self._parts = list(parts if parts is not None else demo_parts(self.cell))
        # each part keeps its colour when others leave the tray (by position, the cap turned blue and
        # the bracket green when the cover was taken: the operator looked for the wrong colour)
        ids = list(dict.fromkeys(p.id for p in [*demo_parts(), *self._parts]))  # the demo's first, as before
        self._colors = {pid: PART_COLORS_BGR[k % len(PART_COLORS_BGR)] for k, pid in enumerate(ids)}
        self._removed: list[str] = []
        self._frame_index: int | None = None
        self._png: bytes | None = None
        self._proposal_px: dict | None = None
        self._taught: dict[str, np.ndarray] = {}
        self._rejected: dict[str, int] = {}
        self._examples: list[GraspExample] = []  # (a configuration is chosen nearest to theirs, as the loop does)
        self._n_examples = self._reload_examples()
        self._counter = 0
        self.joints = Joints(**self.cell.motion.home_joints)
        self._thread: threading.Thread | None = None
        self._closing = False
        self._render()

    # ------------------------------------------------------------------ StationBackend
    def snapshot(self) -> dict:
        with self._lock:
            return {
                "frame": {"index": self._frame_index, "width_px": self.view.width_px,
                          "height_px": self.view.height_px},
                "parts": [{"id": p.id, "outline_px": np.round(self.view.mm_to_px(p.outline_mm), 1).tolist(),
                           "holes_px": [np.round(self.view.mm_to_px(h), 1).tolist() for h in p.holes_mm]}
                          for p in self._parts],
                "proposal_px": self._proposal_px,
                "removed": list(self._removed),
                "examples": {"path": str(self.examples_path), "count": self._n_examples},
                "joints": {k: round(v, 2) for k, v in self.joints.as_dict().items()},
                "cell_file": {"name": self.cell.name, "path": self.cell.source,
                              "jaws_mm": list(self.cell.gripper.opening_mm),
                              "tray_mm": {"x_mm": list(self.cell.tray.x_mm), "y_mm": list(self.cell.tray.y_mm)}},
            }

    def frame_png(self) -> bytes | None:
        with self._lock:
            return self._png

    def teach(self, part_id: str, p1_px, p2_px) -> dict:
        """Two clicks on the frame -> a valid example on `part_id` (appended, then re-read)."""
        with self._lock:
            part = next((p for p in self._parts if p.id == part_id), None)
            if part is None:
                raise BadInput(f"no part {part_id!r} on the current frame "
                               f"(parts: {', '.join(p.id for p in self._parts) or 'none'})")
            others = tuple(p for p in self._parts if p.id != part_id)
            examples = list(self._examples)
        v = self.view
        snapped = taught_contacts(part, v.px_to_mm(clicked_on_frame(p1_px, p2_px, v.width_px, v.height_px)),
                                  self.cell.gripper.opening_mm, off_max_mm=TEACH_OFF_MAX_MM)
        opening = float(np.linalg.norm(snapped[1] - snapped[0]))
        z, _, _, sols = jaw_pose(part, snapped, self.cell)
        joints = choose_configuration(sols, examples, self.cell, (part, *others))
        with self._lock:
            self._counter += 1
            eid = f"station-teach-{datetime.now(UTC).strftime('%Y%m%dT%H%M%S%f')}-{self._counter}"
        ex = GraspExample(eid, part, snapped, True,
                          {"kind": "station-teach", "by": "operator", "at": _now_iso(),
                           "note": f"taught on frame {self._frame_index}"},
                          obstacles=others, grasp_z_mm=z, joints=joints.rounded() if joints else None)
        append_examples(self.examples_path, [ex])
        n = self._reload_examples()  # the "model rebuild": re-read and validate the whole file
        with self._lock:
            self._n_examples = n
            self._taught[part_id] = snapped
        return {"example_id": eid, "part": part_id, "contacts_mm": np.round(snapped, 2).tolist(),
                "opening_mm": round(opening, 2), "grasp_z_mm": z, "n_examples": n,
                "reachable": joints is not None}

    # ------------------------------------------------------------------ the loop
    def start(self) -> DemoCell:
        self._thread = threading.Thread(target=self._loop, name="demo-cell-loop", daemon=True)
        self._thread.start()
        return self

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the sequence and end the loop thread."""
        self._closing = True
        self.control.stop("demo cell closed", by="demo")
        self.control.reset(by="demo")  # wakes the loop, which sees _closing and ends
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

    def _loop(self) -> None:
        rc = self.control
        while not self._closing:
            try:
                self._sequence()
                rc.wait_for_state("idle")  # after done: Reset starts the tray again
            except Stopped:
                rc.log("loop", "sequence abandoned; press Reset, then Run to start again")
                rc.wait_for_state("idle")
            except Faulted:
                rc.wait_for_state("idle")
            if self._closing:
                break
            with self._lock:
                self._parts = demo_parts(self.cell) if not self._parts else self._parts
                self._removed = []
                self._rejected = {}
            self._render()

    def _move(self, part: Part, step: int) -> None:
        """The pick's motion (motion_s). A stop meanwhile ends it there, the part left on the tray (it was logged
        as removed a second after the stop)."""
        rc = self.control
        deadline = time.monotonic() + self.motion_s
        while (left := deadline - time.monotonic()) > 0:
            if rc.stop_requested:
                rc.checkpoint("move", step=step, part=part.id)  # (raises Stopped)
            time.sleep(min(MOVE_POLL_S, left))

    def _sequence(self) -> None:
        rc = self.control
        step = 0
        while True:
            with self._lock:
                remaining = list(self._parts)
            if not remaining:
                break
            part = remaining[0]
            rc.checkpoint("perceive", step=step, part=part.id)
            self._render()
            proposal = self._propose(part)
            if proposal is None:
                # nothing to propose: hold for the operator to teach a grasp (or stop)
                rc.log("teach", f"no grasp left for {part.id} (its proposals rejected or wider than the jaws' "
                                f"{self.cell.gripper.opening_mm[1]:g} mm): teach one", part=part.id)
                rc.pause(by="loop")
                rc.checkpoint("teach", step=step, part=part.id)
                continue
            rc.checkpoint("plan", step=step, part=part.id)
            with self._lock:
                self._proposal_px = proposal.pop("_px")
            decision = rc.request_approval(proposal)
            if not decision.approved:
                self._record_rejection(part, proposal, decision.reason)
                with self._lock:
                    self._proposal_px = None
                continue
            rc.checkpoint("move", step=step, part=part.id)
            self._move(part, step)
            j = proposal.get("joints")
            if j:
                self.joints = Joints.from_dict(j)
            with self._lock:
                self._parts = [p for p in self._parts if p.id != part.id]
                self._removed.append(part.id)
                self._proposal_px = None
            rc.log("removed", f"{part.id} removed", part=part.id)
            step += 1
        self._render()
        rc.done({"parts_removed": len(self._removed), "examples": self._n_examples})

    def _propose(self, part: Part) -> dict | None:
        with self._lock:
            taught = self._taught.get(part.id)
            n_rejected = self._rejected.get(part.id, 0)
            others = tuple(p for p in self._parts if p.id != part.id)
            examples = list(self._examples)
        if taught is not None:
            contacts, how = taught, "taught by the operator"
        else:
            # the jaws close only across what they open to: a side wider than the cell's stroke is no proposal
            lo, hi = self.cell.gripper.opening_mm
            fits = [c for c in _across_rectangle(part) if lo < np.linalg.norm(c[1] - c[0]) <= hi]
            if n_rejected >= len(fits):
                return None
            contacts, how = fits[n_rejected], "across the minimum rectangle"
        opening = float(np.linalg.norm(contacts[1] - contacts[0]))
        z, centre, axis, sols = jaw_pose(part, contacts, self.cell)
        joints = choose_configuration(sols, examples, self.cell, (part, *others))
        fingers, palm = _footprints(contacts, self.cell)
        to_px = self.view.mm_to_px
        px = {"target": part.id, "contacts_px": np.round(to_px(contacts), 1).tolist(),
              "fingers_px": [np.round(to_px(f), 1).tolist() for f in fingers],
              "palm_px": np.round(to_px(palm), 1).tolist()}
        return {"target": part.id, "how": how, "contacts": np.round(contacts, 2).tolist(),
                "center": np.round(centre, 2).tolist(), "angle_deg": round(axis, 2),
                "opening_mm": round(opening, 2), "grasp_z_mm": z,
                "joints": {k: round(v, 2) for k, v in joints.as_dict().items()} if joints else None,
                "_px": px}

    def _record_rejection(self, part: Part, proposal: dict, reason: str) -> None:
        with self._lock:
            self._counter += 1
            eid = f"station-reject-{datetime.now(UTC).strftime('%Y%m%dT%H%M%S%f')}-{self._counter}"
            others = tuple(p for p in self._parts if p.id != part.id)
            self._rejected[part.id] = self._rejected.get(part.id, 0) + 1
            self._taught.pop(part.id, None)
        ex = GraspExample(eid, part, np.asarray(proposal["contacts"], float), False,
                          {"kind": "station-reject", "by": "operator", "at": _now_iso(), "note": reason},
                          obstacles=others, grasp_z_mm=proposal["grasp_z_mm"],
                          joints=Joints.from_dict(proposal["joints"]) if proposal.get("joints") else None)
        try:
            append_examples(self.examples_path, [ex])
        except BadInput as e:  # keep running: the operator sees why nothing was recorded
            self.control.log("example", f"rejection on {part.id} not recorded: {e}", part=part.id)
            return
        n = self._reload_examples()
        with self._lock:
            self._n_examples = n
        self.control.log("example", f"invalid example {eid} on {part.id}: {reason}", part=part.id)

    # ------------------------------------------------------------------ helpers
    def _reload_examples(self) -> int:
        examples = load_examples(self.examples_path, allow_empty=True) if self.examples_path.exists() else []
        with self._lock:
            self._examples = examples
        return len(examples)

    def _render(self) -> None:
        """Draw the tray as the camera would see it: a grey tray, parts filled, PNG encoded."""
        import cv2

        to_px = self.view.mm_to_px
        img = np.full((self.view.height_px, self.view.width_px, 3), (70, 70, 70), np.uint8)
        x0, x1 = self.cell.tray.x_mm
        y0, y1 = self.cell.tray.y_mm
        tray = to_px(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
        cv2.fillPoly(img, [np.round(tray).astype(np.int32)], (105, 105, 100))
        with self._lock:
            parts = list(self._parts)
        for p in parts:
            color = self._colors.get(p.id, PART_COLORS_BGR[0])
            cv2.fillPoly(img, [np.round(to_px(p.outline_mm) - 0.5).astype(np.int32)], color)
        ok, png = cv2.imencode(".png", img)
        with self._lock:
            self._png = png.tobytes() if ok else None
            self._frame_index = 0 if self._frame_index is None else self._frame_index + 1


def _now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")
