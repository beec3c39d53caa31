"""A frame's detection copies, and the tray's colour field at their sizes.

The detection runs on a copy reduced to 1 / scale (a detection pixel about the default camera's
size in the scene) and on its blurred and coarse copies; they do not depend on what the tray is
taken to be, so a frame read with two trays makes them once. The tray's field (background.py) is
fitted on a small copy and taken to the detection copy's size and to 1 / COARSE of it.
"""

from __future__ import annotations

import os
from concurrent.futures import Future
from typing import TYPE_CHECKING, NamedTuple

import cv2
import numpy as np

from cell.errors import BadInput
from cell.vision.background import field_at, fit_copy_of_whole_dn, fit_tray_field, reference_background

if TYPE_CHECKING:
    from cell.vision.segment import SegmentParams


SMALL_FRAME_PX = 960  # narrower frames are detected at full resolution
BLUR_TAPS = 5  # of the detection blur (sigma 0.8 detection px)
COARSE = 4  # the search for where anything differs from the tray runs at 1 / COARSE of detection


class Detection(NamedTuple):
    """A frame's detection copies: the same whatever the tray is taken to be."""

    scale: int  # the detection runs at 1 / scale
    det_u8: np.ndarray  # (h // scale, w // scale, 3) uint8
    det: np.ndarray  # ... float32
    smoothed: Future  # of `smoothed_copies(det)`


def detection_scale(frame_shape, p: SegmentParams) -> int:
    """1 / the resolution a frame of `frame_shape` is detected at with `p` (its sizes set: `for_frame`)."""
    s = max(1, int(p.scale)) if frame_shape[1] >= SMALL_FRAME_PX else 1  # small frames: at full resolution
    # a strip of a frame (3 x 5000 px) keeps a few detection pixels across (it was reduced to none)
    return max(1, min(s, min(frame_shape[:2]) // MIN_DETECTION_PX))


MIN_DETECTION_PX = 4  # the fewest detection pixels across a frame


def detection_copies(frame: np.ndarray, p: SegmentParams) -> Detection:
    h, w = frame.shape[:2]
    s = detection_scale(frame.shape, p)
    dw, dh = w // s, h // s
    # the last w % s columns and h % s rows are left out, so that each detection pixel is s x s
    # frame pixels exactly (outlines.py's `_to_full`; 4000 px / 6 would stretch by 6.006, 4 px at the far border)
    det_u8 = cv2.resize(frame[:dh * s, :dw * s], (dw, dh), interpolation=cv2.INTER_AREA) if s > 1 else frame
    det = det_u8.astype(np.float32)
    # the blurred copies do not depend on the tray: made in a helper thread while the tray is fitted
    # (OpenCV releases the GIL; the fit is mostly Python and small numpy calls)
    return Detection(s, det_u8, det, _helper().submit(smoothed_copies, det))


def fitted_field(d: Detection, tray: str, seed: np.ndarray | None = None) -> np.ndarray:
    """The tray's colour field fitted to the detection copy (`fit_tray_field`), on its small copy."""
    return fit_tray_field(d.det, tray, fit_copy_of_whole_dn(d.det_u8), seed)[0]


def field_tray(field: np.ndarray, d: Detection) -> tuple[np.ndarray, np.ndarray]:
    """The fitted field at detection size and at 1 / COARSE of it."""
    dh, dw = d.det.shape[:2]
    # the coarse copy straight from the fitted field, not by averaging the other (the same smooth field)
    return field_at(field, (dw, dh)), field_at(field, (max(1, dw // COARSE), max(1, dh // COARSE)))


def reference_tray(reference_bgr: np.ndarray, frame: np.ndarray, d: Detection) -> tuple[np.ndarray, None]:
    """The empty tray's image at detection size (the coarse copy: averaged from it later)."""
    ref = as_bgr(reference_bgr)
    if ref.shape != frame.shape:
        raise BadInput(f"the reference image is {ref.shape[1]} x {ref.shape[0]} px, "
                       f"the frame {frame.shape[1]} x {frame.shape[0]} px")
    dh, dw = d.det.shape[:2]
    return reference_background(ref[:dh * d.scale, :dw * d.scale], (dw, dh)), None


_HELPER: list = []
os.register_at_fork(after_in_child=_HELPER.clear)  # a forked child makes its own (threads do not survive a fork)


def _helper():
    """One helper thread for work that overlaps the main thread's (made on first use)."""
    if not _HELPER:
        from concurrent.futures import ThreadPoolExecutor

        _HELPER.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="segment"))
    return _HELPER[0]


def smoothed_copies(det: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The detection image blurred (noise), its every 4th pixel (to measure the noise on) and
    its coarse copy (to find where anything differs from the tray), float32."""
    # 5 taps: for float32 OpenCV would take 7, whose outer two weigh 0.04 % each (twice the time)
    sm = cv2.GaussianBlur(det, (BLUR_TAPS, BLUR_TAPS), 0.8)
    h, w = sm.shape[:2]
    coarse = cv2.resize(sm, (max(1, w // COARSE), max(1, h // COARSE)), interpolation=cv2.INTER_AREA)
    return sm, np.ascontiguousarray(sm[::4, ::4]), coarse


def as_bgr(img: np.ndarray) -> np.ndarray:
    """The frame as 8-bit BGR (grey and BGRA converted); BadInput for anything else."""
    if not isinstance(img, np.ndarray) or img.size == 0:
        raise BadInput("the frame is empty or not an image")
    if img.dtype != np.uint8:
        raise BadInput(f"the frame must be 8-bit, got {img.dtype}")
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if img.ndim == 3 and img.shape[2] == 3:
        return img
    raise BadInput(f"the frame must be (h, w, 3) BGR, got shape {img.shape}")
