"""A small, real cell behind the station for `cell station --demo` and the station's tests.

It is not the cell loop (cell/runtime/loop.py plans with the learned planner and drives the
CANopen nodes); it exercises everything the station touches, for real: a loop thread through
`RunControl` (checkpoints, approval, faults), frames rendered from the parts' outlines with
a fixed px <-> mm mapping, rejected grasps appended as invalid examples and taught grasps as
valid ones with `cell.examples.append_examples` (atomically), the example file re-read after
each append (a "rebuild") and the taught contacts used for the next proposal on that part.

Its proposer is deliberately simple and says so: it closes across the part's minimum
rotated rectangle (short side first, then the long side after a rejection).
"""

from __future__ import annotations

import math
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from cell.cellconfig import Cell, default_cell
from cell.errors import BadInput
from cell.examples import GraspExample, append_examples, load_examples
from cell.kinematics import Joints
from cell.runtime.backend import clicked_on_frame, jaw_pose, taught_contacts
from cell.runtime.control import Faulted, RunControl, Stopped
from cell.scene import Part

FRAME_W_PX, FRAME_H_PX = 640, 512
PX_PER_MM = 1.0
CENTER_MM = (350.0, 0.0)  # the tray point at the image centre
MOVE_POLL_S = 0.05  # a stop during a pick's motion is seen this soon
PART_COLORS_BGR = [(60, 140, 230), (80, 190, 90), (200, 120, 60), (170, 80, 190), (60, 200, 200)]


def mm_to_px(xy_mm) -> np.ndarray:
    """Base frame (x forward, y left) -> image (u right, v down), camera looking down: shape kept."""
    a = np.asarray(xy_mm, dtype=float)
    u = FRAME_W_PX / 2 - (a[..., 1] - CENTER_MM[1]) * PX_PER_MM
    v = FRAME_H_PX / 2 - (a[..., 0] - CENTER_MM[0]) * PX_PER_MM
    return np.stack([u, v], axis=-1)


def px_to_mm(uv_px) -> np.ndarray:
    a = np.asarray(uv_px, dtype=float)
    y = CENTER_MM[1] - (a[..., 0] - FRAME_W_PX / 2) / PX_PER_MM
    x = CENTER_MM[0] - (a[..., 1] - FRAME_H_PX / 2) / PX_PER_MM
    return np.stack([x, y], axis=-1)


def demo_parts() -> list[Part]:
    """A small tray: a cover, a board, a bracket (an L) and a cap."""
    def rect(cx, cy, w, h, angle_deg=0.0):
        t = math.radians(angle_deg)
        r = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
        pts = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
        return pts @ r.T + (cx, cy)

    return [
        Part("cover", rect(300, 120, 60, 40, 15), z_bottom_mm=0.0, z_top_mm=12.0),
        Part("board", rect(400, -40, 70, 45, -10), z_bottom_mm=0.0, z_top_mm=8.0),
        Part("bracket", np.array([[250, -160], [310, -160], [310, -140], [270, -140], [270, -100],
                                  [250, -100]], float), z_bottom_mm=0.0, z_top_mm=15.0),
        Part("cap", rect(430, 150, 36, 30, 30), z_bottom_mm=0.0, z_top_mm=20.0),
    ]


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


class DemoCell:
    """A StationBackend with its own loop thread.

    Parameters
    ----------
    control : the RunControl the station drives.
    examples_path : the example file taught and rejected grasps are appended to.
    motion_s : simulated duration of one pick (the loop is busy meanwhile).
    """

    def __init__(self, control: RunControl, examples_path: str | Path, *, cell: Cell | None = None,
                 parts: list[Part] | None = None, motion_s: float = 0.5):
        self.control = control
        self.cell = cell or default_cell()
        self.examples_path = Path(examples_path)
        self.motion_s = float(motion_s)
        self._lock = threading.Lock()
        self._parts = list(parts if parts is not None else demo_parts())
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
                "frame": {"index": self._frame_index, "width_px": FRAME_W_PX, "height_px": FRAME_H_PX},
                "parts": [{"id": p.id, "outline_px": np.round(mm_to_px(p.outline_mm), 1).tolist(),
                           "holes_px": [np.round(mm_to_px(h), 1).tolist() for h in p.holes_mm]}
                          for p in self._parts],
                "proposal_px": self._proposal_px,
                "removed": list(self._removed),
                "examples": {"path": str(self.examples_path), "count": self._n_examples},
                "joints": {k: round(v, 2) for k, v in self.joints.as_dict().items()},
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
        snapped = taught_contacts(part, px_to_mm(clicked_on_frame(p1_px, p2_px, FRAME_W_PX, FRAME_H_PX)),
                                  self.cell.gripper.opening_mm, off_max_mm=15.0)
        opening = float(np.linalg.norm(snapped[1] - snapped[0]))
        z, _, _, sols = jaw_pose(part, snapped, self.cell)
        with self._lock:
            self._counter += 1
            eid = f"station-teach-{datetime.now(UTC).strftime('%Y%m%dT%H%M%S%f')}-{self._counter}"
        ex = GraspExample(eid, part, snapped, True,
                          {"kind": "station-teach", "by": "operator", "at": _now_iso(),
                           "note": f"taught on frame {self._frame_index}"},
                          obstacles=others, grasp_z_mm=z, joints=sols[0].rounded() if sols else None)
        append_examples(self.examples_path, [ex])
        n = self._reload_examples()  # the "model rebuild": re-read and validate the whole file
        with self._lock:
            self._n_examples = n
            self._taught[part_id] = snapped
        return {"example_id": eid, "part": part_id, "contacts_mm": np.round(snapped, 2).tolist(),
                "opening_mm": round(opening, 2), "grasp_z_mm": z, "n_examples": n,
                "reachable": bool(sols)}

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
                self._parts = demo_parts() if not self._parts else self._parts
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
                rc.log("teach", f"no grasp left for {part.id} (both proposals rejected): teach one",
                       part=part.id)
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
        if taught is not None:
            contacts, how = taught, "taught by the operator"
        else:
            if n_rejected >= 2:
                return None
            rect = np.asarray(part.polygon.minimum_rotated_rectangle.exterior.coords)[:4]
            sides = [np.linalg.norm(rect[(i + 1) % 4] - rect[i]) for i in range(4)]
            # close across the short side first (side i and i+2 are parallel)
            i = int(np.argmin(sides[:2])) if n_rejected == 0 else int(np.argmax(sides[:2]))
            a = (rect[(i + 1) % 4] + rect[(i + 2) % 4]) / 2
            b = (rect[(i + 3) % 4] + rect[i]) / 2
            # the rectangle's side midpoints, moved onto the outline (a non-convex part's edge
            # may lie inside its rectangle)
            from shapely.geometry import Point
            from shapely.ops import nearest_points

            boundary = part.polygon.boundary
            contacts = np.array([nearest_points(boundary, Point(q))[0].coords[0] for q in (a, b)])
            how = "across the minimum rectangle"
        opening = float(np.linalg.norm(contacts[1] - contacts[0]))
        z, centre, axis, sols = jaw_pose(part, contacts, self.cell)
        fingers, palm = _footprints(contacts, self.cell)
        px = {"target": part.id, "contacts_px": np.round(mm_to_px(contacts), 1).tolist(),
              "fingers_px": [np.round(mm_to_px(f), 1).tolist() for f in fingers],
              "palm_px": np.round(mm_to_px(palm), 1).tolist()}
        return {"target": part.id, "how": how, "contacts": np.round(contacts, 2).tolist(),
                "center": np.round(centre, 2).tolist(), "angle_deg": round(axis, 2),
                "opening_mm": round(opening, 2), "grasp_z_mm": z,
                "joints": {k: round(v, 2) for k, v in sols[0].as_dict().items()} if sols else None,
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
        if not self.examples_path.exists():
            return 0
        return len(load_examples(self.examples_path, allow_empty=True))

    def _render(self) -> None:
        """Draw the tray as the camera would see it: a grey tray, parts filled, PNG encoded."""
        import cv2

        img = np.full((FRAME_H_PX, FRAME_W_PX, 3), (70, 70, 70), np.uint8)
        x0, x1 = self.cell.tray.x_mm
        y0, y1 = self.cell.tray.y_mm
        tray = mm_to_px(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
        cv2.fillPoly(img, [np.round(tray).astype(np.int32)], (105, 105, 100))
        with self._lock:
            parts = list(self._parts)
        for p in parts:
            color = self._colors.get(p.id, PART_COLORS_BGR[0])
            cv2.fillPoly(img, [np.round(mm_to_px(p.outline_mm) - 0.5).astype(np.int32)], color)
        ok, png = cv2.imencode(".png", img)
        with self._lock:
            self._png = png.tobytes() if ok else None
            self._frame_index = 0 if self._frame_index is None else self._frame_index + 1


def _now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")
