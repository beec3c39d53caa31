"""Vision: camera frames -> part contours (pixels, and mm through a calibration).

    segment.py       segment_frame, Segment, SegmentList, SegmentParams, segment_to_mm: the steps below in order
    detection.py     a frame's detection copies (reduced, blurred, coarse), the tray's field at their sizes
    background.py    the empty tray's colour field, estimated from the frame
    tray_checks.py   whether a reading took the tray for a part, and which of two readings explains the frame
    part_mask.py     the part pixels: colour_change.py inside work_boxes.py's boxes, and shadow-like pixels
                     that are material (shadowlike.py, by sharp_edges.py)
    regions.py       the mask's regions: labelled, specks dropped, touching parts split (touching.py)
    outlines.py      regions -> segments: outlines and holes (holes.py), refined (subpixel.py, rings.py)
    outside.py       regions outside the tray (the surround of a tray that does not fill the view)
    walls.py         segment_to_mm: segments -> mm, the walls the camera sees taken into account
    touching.py      touching parts: split at necks or flag as merged
    topface.py       the top face of a tall part inside its silhouette (walls hide fins, deep holes)
    simcamera.py     SimCamera: realistic frames of parts with known ground truth
    sources.py       FileCamera, VideoCamera, open_camera, read_image
    sample_parts.py  a few realistic outlines for tests and the benchmark
"""

from cell.vision.segment import Segment, SegmentList, SegmentParams, segment_frame, segment_to_mm
from cell.vision.simcamera import SimCamera, SimCameraOptions
from cell.vision.sources import FileCamera, VideoCamera, open_camera, read_image

__all__ = ["FileCamera", "Segment", "SegmentList", "SegmentParams", "SimCamera", "SimCameraOptions", "VideoCamera",
           "open_camera", "read_image", "segment_frame", "segment_to_mm"]
