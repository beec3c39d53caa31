"""What the operator station sees of the cell loop, and teaching from the station.

`LoopBackend(loop)` implements the station's `StationBackend`: the current frame, the parts
seen in it (outlines in image px, mapped from their measured poses at their top's height),
the proposed grasp, and `teach`: two clicked points on a part become a valid example with
the configuration the cell would use for them (paper step 5 over the IK solutions), appended
atomically; the model is rebuilt at once, so the next plan uses it.
"""

from __future__ import annotations

from datetime import UTC, datetime

import cv2
import numpy as np
from shapely.geometry import Point

from cell.configuration import choose_configuration
from cell.errors import BadInput
from cell.examples import GraspExample
from cell.grasp.height import grasp_z_mm
from cell.kinematics import inverse


class LoopBackend:
    def __init__(self, loop):
        self.loop = loop

    def snapshot(self) -> dict:
        lp, st = self.loop, self.loop.state
        to_px = lp.cal.mm_to_px
        parts = []
        for pid, p in dict(st.seen).items():
            parts.append({"id": pid, "outline_px": to_px(p.outline_mm, p.z_top_mm).round(2).tolist(),
                          "holes_px": [to_px(h, p.z_top_mm).round(2).tolist() for h in p.holes_mm]})
        return {"frame": {"index": st.frame_index, "width_px": lp.cal.width_px, "height_px": lp.cal.height_px},
                "parts": parts, "proposal_px": st.proposal,
                "examples": {"path": str(lp.examples_path), "count": len(lp.examples)},
                "remaining": list(lp.remaining),
                **_parts_by_outcome(lp.part_reports(), ("removed", "skipped", "carried"))}

    def stop(self) -> None:
        """The page's Stop (after RunControl.stop): quick-stop every axis now, mid-pick too."""
        self.loop.arm.stop()

    def frame_png(self) -> bytes | None:
        frame = self.loop.state.frame
        if frame is None:
            return None
        ok, png = cv2.imencode(".png", frame)
        return png.tobytes() if ok else None

    def teach(self, part_id: str, p1_px, p2_px) -> dict:
        lp = self.loop
        index, seen = lp.state.frame_index, dict(lp.state.seen)  # one frame's parts: the loop may move on meanwhile
        part = seen.get(part_id)
        if part is None:
            raise BadInput(f"part {part_id!r} is not in the current frame")
        px = np.array([p1_px, p2_px], float)
        clicked = lp.cal.px_to_mm(px, part.z_top_mm)
        boundary = part.polygon.boundary
        contacts = np.array([boundary.interpolate(boundary.project(Point(c))).coords[0] for c in clicked])
        off = [float(np.linalg.norm(a - b)) for a, b in zip(contacts, clicked, strict=True)]
        if max(off) > 5.0:
            raise BadInput(f"the clicked points are {max(off):.1f} mm from {part_id}'s outline: click on its edge")
        d = contacts[1] - contacts[0]
        opening = float(np.hypot(*d))
        lo, hi = lp.cell.gripper.opening_mm
        if not lo < opening <= hi:
            raise BadInput(f"the two contacts are {opening:.1f} mm apart; the jaws open {lo:g} to {hi:g} mm")
        z = grasp_z_mm(part.z_bottom_mm, part.z_top_mm, lp.cell.gripper, lp.cell.scara.j3_mm)
        centre = contacts.mean(axis=0)
        axis = float(np.degrees(np.arctan2(d[1], d[0])))
        others = tuple(p for p in seen.values() if p.id != part_id)
        joints = choose_configuration(inverse(centre[0], centre[1], z, axis, lp.cell.scara), lp.examples, lp.cell,
                                      (part, *others))
        now = datetime.now(UTC)
        ex = GraspExample(f"teach-{now.strftime('%Y%m%dT%H%M%S%f')}", part, contacts, True,
                          {"kind": "station-teach", "by": "operator", "at": now.isoformat(),
                           "note": f"taught on frame {index}"},
                          obstacles=others, grasp_z_mm=z, joints=joints)
        n_examples = lp.teach(ex)
        return {"ok": True, "example_id": ex.id, "n_examples": n_examples,
                "contacts_mm": np.round(contacts, 2).tolist(),
                "opening_mm": round(opening, 2), "joints": None if joints is None else joints.rounded(3).as_dict(),
                }


def _parts_by_outcome(reports, outcomes) -> dict:
    """outcome -> the ids of the parts with it: removed (a frame showed them gone), skipped, carried (let go at
    the drop-off, no frame since); the part being worked on is in none of them."""
    return {o: [r.part for r in reports if r.outcome == o] for o in outcomes}
