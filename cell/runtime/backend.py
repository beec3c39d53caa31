"""What the operator station sees of the cell loop, and teaching from the station.

`LoopBackend(loop)` implements the station's `StationBackend`: the current frame, the parts
seen in it (outlines in image px, mapped from their measured poses at their top's height),
the proposed grasp, and `teach`: two clicked points on a part become a valid example with
the configuration the cell would use for them (paper step 5 over the IK solutions), appended
atomically; the model is rebuilt at once, so the next plan uses it.
"""

from __future__ import annotations

import math
import threading
from datetime import UTC, datetime
from typing import NamedTuple

import cv2
import numpy as np
from shapely.geometry import Point

from cell.configuration import choose_configuration
from cell.errors import BadInput
from cell.examples import GraspExample
from cell.grasp.height import grasp_z_mm
from cell.kinematics import Joints, inverse, normalize_axis_deg


class LoopBackend:
    def __init__(self, loop):
        self.loop = loop
        # what the page asks for every poll, worked out once per frame (each tab polls each frame): the PNG of the
        # frame (1.84 MB, 45-880 ms to encode beside the loop) and each seen part's outline in px
        self._png_lock, self._outline_lock = threading.Lock(), threading.Lock()  # a poll waits not on an encode
        self._png_of: tuple = (None, None)  # (the frame it encodes, its PNG)
        self._outlines: dict = {}  # part id -> (the Part it projects, its outline and holes in px)

    def snapshot(self) -> dict:
        lp, st = self.loop, self.loop.state
        seen = dict(st.seen)
        parts = [{"id": pid, **self._outline_px(pid, p)} for pid, p in seen.items()]
        with self._outline_lock:  # only what this frame shows: a part that has left is not held on to
            for pid in self._outlines.keys() - seen.keys():
                del self._outlines[pid]
        return {"frame": {"index": st.frame_index, "width_px": lp.cal.width_px, "height_px": lp.cal.height_px},
                "parts": parts, "proposal_px": st.proposal,
                "examples": _examples_info(lp),
                "remaining": list(lp.remaining),
                **_parts_by_outcome(lp.part_reports(), ("removed", "skipped", "carried"))}

    def stop(self) -> None:
        """The page's Stop (after RunControl.stop): quick-stop every axis now, mid-pick too."""
        self.loop.arm.stop()

    def _outline_px(self, pid: str, part) -> dict:
        """The part's outline and holes in image px, at its top; projected again only when the loop saw it anew
        (a new Part: each frame's measured pose is one)."""
        with self._outline_lock:
            held = self._outlines.get(pid)
            if held is not None and held[0] is part:
                return held[1]
        to_px = self.loop.cal.mm_to_px
        px = {"outline_px": to_px(part.outline_mm, part.z_top_mm).round(2).tolist(),
              "holes_px": [to_px(h, part.z_top_mm).round(2).tolist() for h in part.holes_mm]}
        with self._outline_lock:
            self._outlines[pid] = (part, px)
        return px

    def frame_png(self) -> bytes | None:
        """The current frame as PNG, encoded once for the frame (the loop sets a new array for each one)."""
        frame = self.loop.state.frame
        if frame is None:
            return None
        with self._png_lock:  # a second GET of the frame waits for the first one's encoding, not encodes it again
            if self._png_of[0] is frame:
                return self._png_of[1]
            ok, png = cv2.imencode(".png", frame)
            self._png_of = (frame, png.tobytes() if ok else None)
            return self._png_of[1]

    def teach(self, part_id: str, p1_px, p2_px) -> dict:
        lp = self.loop
        index, seen = lp.state.frame_index, dict(lp.state.seen)  # one frame's parts: the loop may move on meanwhile
        part = seen.get(part_id)
        if part is None:
            raise BadInput(f"part {part_id!r} is not in the current frame")
        px = clicked_on_frame(p1_px, p2_px, lp.cal.width_px, lp.cal.height_px)
        contacts = taught_contacts(part, lp.cal.px_to_mm(px, part.z_top_mm), lp.cell.gripper.opening_mm)
        opening = float(np.linalg.norm(contacts[1] - contacts[0]))
        pose = jaw_pose(part, contacts, lp.cell)
        others = tuple(p for p in seen.values() if p.id != part_id)
        joints = choose_configuration(pose.solutions, lp.examples, lp.cell, (part, *others))
        now = datetime.now(UTC)
        ex = GraspExample(f"teach-{now.strftime('%Y%m%dT%H%M%S%f')}", part, contacts, True,
                          {"kind": "station-teach", "by": "operator", "at": now.isoformat(),
                           "note": f"taught on frame {index}"},
                          obstacles=others, grasp_z_mm=pose.z_mm, joints=joints)
        n_examples = lp.teach(ex)
        return {"ok": True, "example_id": ex.id, "n_examples": n_examples,
                "contacts_mm": np.round(contacts, 2).tolist(),
                "opening_mm": round(opening, 2), "joints": None if joints is None else joints.rounded(3).as_dict(),
                }


def clicked_on_frame(p1_px, p2_px, width_px: int, height_px: int) -> np.ndarray:
    """The two clicked points (px), which must lie on the frame: one far off it was mapped through the
    calibration and refused for the calibration's sake ("the plane z = 4 mm is not in front of the camera")."""
    px = np.array([p1_px, p2_px], float)
    for i, (u, v) in enumerate(px, start=1):
        if not (0.0 <= u <= width_px and 0.0 <= v <= height_px):
            raise BadInput(f"clicked point {i} ({u:g}, {v:g}) px is not on the {width_px} x {height_px} px frame")
    return px


TAUGHT_FACING_MAX_DEG = 45.0  # a taught contact's outline may face this far off the jaws' line (a careless tap)


def taught_contacts(part, clicked_mm: np.ndarray, opening_mm: tuple[float, float], off_max_mm: float = 5.0):
    """The operator's two taps on a part (mm, on its top) -> the contacts of a valid example: the nearest points
    of its outline, within `off_max_mm` of the taps, as far apart as the jaws open, facing away from each other."""
    boundary = part.polygon.boundary
    contacts = np.array([boundary.interpolate(boundary.project(Point(c))).coords[0] for c in clicked_mm])
    off = [float(np.linalg.norm(a - b)) for a, b in zip(contacts, clicked_mm, strict=True)]
    if max(off) > off_max_mm:
        raise BadInput(f"a clicked point is {max(off):.1f} mm from the outline of {part.id}: click on its edge")
    opening = float(np.linalg.norm(contacts[1] - contacts[0]))
    lo, hi = opening_mm
    if not lo < opening <= hi:
        raise BadInput(f"the two contacts are {opening:.1f} mm apart; the jaws open {lo:g} to {hi:g} mm")
    _require_facing(part, contacts)
    return contacts


class JawPose(NamedTuple):
    z_mm: float
    centre_mm: np.ndarray
    axis_deg: float
    solutions: list[Joints]


def jaw_pose(part, contacts: np.ndarray, cell) -> JawPose:
    """Two contacts on `part` -> where the jaws go: the grasp z, the tips' centre between the contacts, the
    closing axis along their line (folded into (-90, 90]) and every IK solution (step 5 chooses among them)."""
    z = grasp_z_mm(part.z_bottom_mm, part.z_top_mm, cell.gripper, cell.scara.j3_mm)
    centre = contacts.mean(axis=0)
    d = contacts[1] - contacts[0]
    axis_deg = normalize_axis_deg(math.degrees(math.atan2(d[1], d[0])))
    return JawPose(z, centre, axis_deg, inverse(float(centre[0]), float(centre[1]), z, axis_deg, cell.scara))


def _require_facing(part, contacts: np.ndarray) -> None:
    """A taught grasp is a valid example: the jaws close along the line through the contacts, so each contact's
    outline must face away from the other one (within TAUGHT_FACING_MAX_DEG). Two taps on one edge, or on
    faces turned along the line, would teach a grasp no pad can hold."""
    from cell.physics import outline_normal_and_turn

    rings = [part.polygon.exterior, *part.polygon.interiors]
    for i, (c, other) in enumerate(((contacts[0], contacts[1]), (contacts[1], contacts[0])), start=1):
        normal, _ = outline_normal_and_turn(rings, c)
        away = (c - other) / np.linalg.norm(c - other)
        off_deg = 180.0 if normal is None else float(np.degrees(np.arccos(np.clip(normal @ away, -1.0, 1.0))))
        if off_deg > TAUGHT_FACING_MAX_DEG:
            raise BadInput(f"at contact {i} the outline faces {off_deg:.0f} deg off the jaws' line (at most "
                           f"{TAUGHT_FACING_MAX_DEG:g}): a pad there would push along the edge, not against it; "
                           "tap two faces that face away from each other")


def _parts_by_outcome(reports, outcomes) -> dict:
    """outcome -> the ids of the parts with it: removed (a frame showed them gone), skipped, carried (let go at
    the drop-off, no frame since); the part being worked on is in none of them."""
    return {o: [r.part for r in reports if r.outcome == o] for o in outcomes}


def _examples_info(lp) -> dict:
    """The page's line on the examples: how many, the file they are in, and where a taught or rejected grasp goes
    when that is another file (the first one starts it as a copy): the shipped file was named until then, though
    the README says it is never written."""
    info = {"path": str(lp.examples_path), "count": len(lp.examples)}
    if lp.examples_out != lp.examples_path:
        info["new_to"] = str(lp.examples_out)
    return info
