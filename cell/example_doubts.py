"""The same grasp on two lines of an example file: warnings, not refusals.

An operator's file may hold a changed mind (accepted once, rejected later) or a grasp taught twice:
both lines are read and both count (the learner weighs every line alike; a later line does not
replace an earlier one), and the warning says so, naming both lines, so the operator can remove
the one not meant.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import numpy as np

# Two examples are the same grasp when their parts have the same id and outlines within this of each
# other (the same part in the same pose) and their contacts, in either order, are each within it.
SAME_GRASP_MM = 1.0


def _within(a: np.ndarray, b: np.ndarray) -> bool:
    return len(a) == len(b) and bool(np.all(np.linalg.norm(a - b, axis=1) <= SAME_GRASP_MM))


def _verdict(ex, flipped: bool = False) -> str:
    """What the line says of the grasp; `flipped`: its contacts in the other line's order."""
    if ex.valid or ex.contact_valid is None:
        return "accepted" if ex.valid else "rejected"
    cv = ex.contact_valid[::-1] if flipped else ex.contact_valid
    return "rejected (contacts " + ", ".join("good" if v else "bad" for v in cv) + ")"


def same_grasp_pairs(examples: Sequence) -> list[tuple[int, int]]:
    """Index pairs (i < j) of examples that are the same grasp. Bucketed by part id and the contacts'
    midpoint on a SAME_GRASP_MM grid: a file of thousands of lines is not compared pair by pair."""
    cells: dict[tuple, list[int]] = defaultdict(list)
    pairs = []
    for j, ex in enumerate(examples):
        mid = np.floor(ex.contacts_mm.mean(axis=0) / SAME_GRASP_MM).astype(int)
        near = {i for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                for i in cells.get((ex.part.id, int(mid[0]) + dx, int(mid[1]) + dy), ())}
        for i in sorted(near):
            other = examples[i]
            if ((_within(other.contacts_mm, ex.contacts_mm) or _within(other.contacts_mm, ex.contacts_mm[::-1]))
                    and other.part.polygon.exterior.hausdorff_distance(ex.part.polygon.exterior) <= SAME_GRASP_MM):
                pairs.append((i, j))
        cells[(ex.part.id, int(mid[0]), int(mid[1]))].append(j)
    return pairs


def same_grasp_doubts(examples: Sequence, lines: Sequence[int], where: str) -> list[str]:
    """Warnings for the same grasp on two lines (`lines[k]` is example k's line number)."""
    out = []
    for i, j in same_grasp_pairs(examples):
        a, b = examples[i], examples[j]
        head = (f"{where} lines {lines[i]} ({a.id}) and {lines[j]} ({b.id}): the same grasp of part {a.part.id!r} "
                f"(contacts within {SAME_GRASP_MM:g} mm)")
        va, vb = _verdict(a), _verdict(b, flipped=not _within(a.contacts_mm, b.contacts_mm))
        if va == vb:
            out.append(f"{head}, {va} twice under two ids: both count, it weighs twice in the trees")
        else:
            out.append(f"{head}, {va} on line {lines[i]} and {vb} on line {lines[j]}: both count (the later line does "
                       "not replace the earlier), the trees learn both verdicts; remove the line you no longer mean")
    return out
