"""Contacts on the closing line: where the pads touch a face square to the closing axis all along
the pad, the contacts are reported where the line through the grasp centre meets that face.

The candidate pair comes from outline samples a step apart, so the two contacts on parallel faces
lie up to half a step either side of the closing line; the pads touch the whole stretch between.
Slid along their pad lines (across the axis, by the same amount in opposite directions), the
contacts keep the grasp centre and the gap along the axis, and their line becomes the closing axis
(`angle_deg` is then the direction from one contact to the other). A contact is slid only along a
straight stretch of the outline square to the axis; on a slanted or curved face both stay where
the contacts stage put them (their line within `max_contact_skew_deg` of the axis).
"""

from __future__ import annotations

import math

import numpy as np
import shapely

ON_OUTLINE_MM = 1e-6  # a probe this near the outline is on it (the contacts stage's points: ~1e-12)
PROBES = (0.25, 0.5, 0.75, 1.0)  # of the way from a contact to the closing line: the stretch must be outline


def onto_closing_line(boundary, contacts_mm: np.ndarray, centre_mm: np.ndarray, axis_deg: float) -> np.ndarray:
    """The contacts (2, 2) slid across the axis onto the line along `axis_deg` through `centre_mm` (their
    midpoint) where the outline (`boundary`, the target's rings as one shapely geometry) runs straight from
    each contact to that line; else the contacts as they are."""
    c = np.asarray(contacts_mm, float)
    a = math.radians(axis_deg)
    v = np.array([-math.sin(a), math.cos(a)])
    off = (c - centre_mm) @ v  # (opposite, as the centre is their midpoint)
    if np.abs(off).max() <= ON_OUTLINE_MM:
        return c
    moved = c - off[:, None] * v
    probes = np.concatenate([c + t * (moved - c) for t in PROBES])
    if shapely.distance(boundary, shapely.points(probes)).max() > ON_OUTLINE_MM:
        return c
    return moved
