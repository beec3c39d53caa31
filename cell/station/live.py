"""`LiveView`: the StationBackend a cell loop fills in as it goes (frame, outlines, proposal).

The loop calls `show_frame`, `show_parts` and `show_proposal` from its own thread; the
station's HTTP threads read `snapshot()` and `frame_png()`. The PNG is encoded lazily, once
per frame, on the first request for it, so a loop with nobody watching pays nothing. A
teach request is handed to `teach_fn(part_id, p1_px, p2_px) -> dict`, which the loop supplies
(map px -> mm, snap to the outline, build the example with the current configuration,
append it atomically, rebuild the model).
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from cell.runtime.control import InvalidCommand


def _px_list(a, ndigits: int = 1) -> list:
    return np.round(np.asarray(a, dtype=float), ndigits).tolist()


class LiveView:
    """A thread-safe StationBackend fed by the cell loop.

    Parameters
    ----------
    teach_fn : callable(part_id, p1_px, p2_px) -> dict, or None (teaching then answers 409).
    info : free JSON-able keys shown with the state (e.g. {"examples": {"path", "count"}}).
    """

    def __init__(self, teach_fn: Callable[[str, list, list], dict] | None = None, info: dict | None = None):
        self._lock = threading.Lock()
        self._teach_fn = teach_fn
        self._frame: np.ndarray | None = None
        self._frame_index: int | None = None
        self._png: bytes | None = None
        self._parts: list[dict] = []
        self._proposal_px: dict | None = None
        self._info = dict(info or {})

    # -- loop side
    def show_frame(self, index: int, frame_bgr: np.ndarray) -> None:
        """A new camera frame, BGR uint8 (h, w, 3) or grey (h, w); clears outlines and proposal."""
        a = np.asarray(frame_bgr)
        if a.dtype != np.uint8 or a.ndim not in (2, 3):
            raise ValueError(f"frame must be uint8 (h, w[, 3]), got {a.dtype} {a.shape}")
        with self._lock:
            self._frame, self._frame_index, self._png = a, int(index), None
            self._parts, self._proposal_px = [], None

    def show_parts(self, parts: list[dict]) -> None:
        """Segmented parts on the current frame: [{"id", "outline_px": (n, 2), "holes_px": [...]}]."""
        out = [{"id": str(p["id"]), "outline_px": _px_list(p["outline_px"]),
                "holes_px": [_px_list(h) for h in p.get("holes_px", [])]} for p in parts]
        with self._lock:
            self._parts = out

    def show_proposal(self, target: str | None, contacts_px=None, fingers_px=(), palm_px=None) -> None:
        """The grasp waiting for approval (or just chosen), in px; target None clears it."""
        with self._lock:
            if target is None:
                self._proposal_px = None
                return
            self._proposal_px = {"target": str(target), "contacts_px": _px_list(contacts_px),
                                 "fingers_px": [_px_list(f) for f in fingers_px],
                                 "palm_px": _px_list(palm_px) if palm_px is not None else None}

    def set_info(self, **info) -> None:
        with self._lock:
            self._info.update(info)

    # -- StationBackend
    def snapshot(self) -> dict:
        with self._lock:
            h, w = self._frame.shape[:2] if self._frame is not None else (None, None)
            return {"frame": {"index": self._frame_index, "width_px": w, "height_px": h},
                    "parts": list(self._parts), "proposal_px": self._proposal_px, **self._info}

    def frame_png(self) -> bytes | None:
        with self._lock:
            if self._png is None and self._frame is not None:
                import cv2

                ok, png = cv2.imencode(".png", self._frame)
                self._png = png.tobytes() if ok else None
            return self._png

    def teach(self, part_id: str, p1_px, p2_px) -> dict:
        if self._teach_fn is None:
            raise InvalidCommand("this cell does not take taught grasps")
        with self._lock:
            known = {p["id"] for p in self._parts}
        if known and part_id not in known:
            from cell.errors import BadInput

            raise BadInput(f"no part {part_id!r} on the current frame (parts: {', '.join(sorted(known))})")
        return self._teach_fn(part_id, list(p1_px), list(p2_px))
