"""Contacts on the closing line: where the pads touch a face square to the closing axis all along
the pad, the contacts are reported where the line through the grasp centre meets that face.

The candidate pair comes from outline samples a step apart, so the two contacts on parallel faces
lie up to half a step either side of the closing line; the pads touch the whole stretch between.
Slid along their pad lines (across the axis, by the same amount in opposite directions), the
contacts keep the grasp centre and the gap along the axis, and their line becomes the closing axis
(`angle_deg` is then the direction from one contact to the other). A contact is slid only along a
straight stretch of the outline square to the axis; on a slanted or curved face both stay where
the contacts stage put them (their line within `max_contact_skew_deg` of the axis). Square to the axis
means within SQUARE_TOL_DEG: a slid contact then lies within micrometres of the outline.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

ON_OUTLINE_MM = 1e-6  # a probe this near the outline is on it (the contacts stage's points: ~1e-12) ...
SQUARE_TOL_DEG = 0.1  # ... or within the slide times tan(this): a face drawn with coordinates rounded to 0.01 mm
PROBE_STEP_MM = 0.05  # the stretch from a contact to the line is looked at this often (a notch narrower: bridged)


def onto_closing_line(boundary, contacts_mm: np.ndarray, centre_mm: np.ndarray, axis_deg: float) -> np.ndarray:
    """The contacts (2, 2) slid across the axis onto the line along `axis_deg` through `centre_mm` (their
    midpoint) where the outline (`boundary`, the target's rings as one shapely geometry) runs straight from
    each contact to that line; else the contacts as they are."""
    c = np.asarray(contacts_mm, float)
    a = math.radians(axis_deg)
    v = np.array([-math.sin(a), math.cos(a)])
    off = (c - centre_mm) @ v  # (opposite, as the centre is their midpoint)
    slide = float(np.abs(off).max())
    if not slide > ON_OUTLINE_MM:  # (on the line already, or NaN: not slid)
        return c
    moved = c - off[:, None] * v
    t = np.linspace(0.0, 1.0, int(np.ceil(slide / PROBE_STEP_MM)) + 1)[1:]
    probes = np.concatenate([ck + np.outer(t, m - ck) for ck, m in zip(c, moved, strict=True)])
    tol = ON_OUTLINE_MM + slide * math.tan(math.radians(SQUARE_TOL_DEG))
    if shapely.distance(boundary, shapely.points(probes)).max() > tol:
        return c
    return moved
