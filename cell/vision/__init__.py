"""Vision: camera frames -> part contours (pixels, and mm through a calibration).

    background.py    the empty tray's colour field, estimated from the frame
    segment.py       segment_frame, Segment, SegmentList, SegmentParams, segment_to_mm
    outside.py       regions outside the tray (the surround of a tray that does not fill the view)
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
