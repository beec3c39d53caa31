"""Frame sources: image files (recordings, test photographs) behind a camera-like `read()`.

`read_image` is the one place that turns a file into a BGR frame; every failure (missing,
not an image, truncated, empty) is a `BadInput` naming the file.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
from pathlib import Path

import cv2
import numpy as np

from cell.cellconfig import MAX_CAMERA_SIDE_PX
from cell.errors import BadInput
from cell.fileio import check_readable
from cell.numerics import MAX_IMAGE_PIXELS


def read_image(path: str | Path, grey: bool = False) -> np.ndarray:
    """Read an image file as BGR uint8 (h, w, 3), or grey (h, w) when `grey`."""
    path = Path(path)
    if not path.exists():
        raise BadInput(f"image {path} does not exist")
    check_readable(path, "image")  # a directory, a FIFO (it would block), a device (it would fill the memory)
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        raise BadInput(f"image {path} cannot be read: {e}") from None
    if data.size == 0:
        raise BadInput(f"image {path} is empty (0 bytes)")
    # ANYDEPTH: without it OpenCV keeps the top 8 of 16 bits, and a 10 - 14 bit camera's frame stored in
    # a 16-bit PNG (values up to 1023 - 16383) came out nearly black (pills.png at 12 bits: 4 regions, not 2)
    as_is = False
    try:
        img, noise = _decode_quietly(data, cv2.IMREAD_ANYDEPTH | (cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR))
        if img is None:  # OpenCV decodes a float TIFF as it is only (grey as grey, colour as colour)
            img, noise = _decode_quietly(data, cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
            as_is = True
    except cv2.error as e:  # e.g. a header claiming more pixels than OpenCV decodes (60000 x 60000)
        if "CV_IO_MAX_IMAGE_PIXELS" in str(e):  # (the limit OpenCV loaded with: ours, unless cv2 came first)
            limit = os.environ.get("OPENCV_IO_MAX_IMAGE_PIXELS", str(MAX_IMAGE_PIXELS))
            raise BadInput(f"image {path} has more pixels than OpenCV is set to decode (OPENCV_IO_MAX_IMAGE_PIXELS "
                           f"= {limit}; the cell's limit is {MAX_IMAGE_PIXELS / 1e6:.0f} megapixels): scale or crop "
                           "it") from None
        raise BadInput(f"image {path} cannot be decoded (OpenCV: {getattr(e, 'err', e)})") from None
    if img is None or img.size == 0:
        raise BadInput(f"image {path} is not a readable image (corrupt, truncated or not an image format)")
    damage = [line for line in noise if line.startswith(_DAMAGE) and (_HARMLESS not in line or _BEFORE_END in line)]
    if damage:  # decoded, but with made-up pixels where the data was broken: not a frame to act on
        raise BadInput(f"image {path} is corrupt (the decoder says: {damage[0]})")
    if as_is and img.ndim == 3 and img.shape[2] in (2, 4):  # alpha is no brightness: off before scaling
        img = img[..., :img.shape[2] - 1]  # (a float alpha of 255 made colours in [0, 1] nearly black)
    if max(img.shape[:2]) >= MAX_CAMERA_SIDE_PX:  # (a blank one passed only because nothing was found in it)
        raise BadInput(f"image {path} is {img.shape[1]} x {img.shape[0]} px: a side of more than "
                       f"{MAX_CAMERA_SIDE_PX - 1} px is beyond OpenCV's remap, which the segmentation uses (SHRT_MAX); "
                       "crop or scale it")
    img = _to_uint8(img, path)
    return _with_channels(img, grey, path) if as_is else img


def _with_channels(img: np.ndarray, grey: bool, path: Path) -> np.ndarray:
    """An 8-bit image decoded as it is, as grey (h, w) or BGR (h, w, 3)."""
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    channels = 1 if img.ndim == 2 else img.shape[2]
    convert = {(1, True): None, (1, False): cv2.COLOR_GRAY2BGR, (3, True): cv2.COLOR_BGR2GRAY, (3, False): None}
    if (channels, grey) not in convert:
        raise BadInput(f"image {path} has {channels} channels; grey, colour or colour with alpha images are read")
    code = convert[(channels, grey)]
    return img if code is None else cv2.cvtColor(img, code)


# what libjpeg says when it decodes a damaged file anyway (the missing part grey or smeared)
_DAMAGE = ("Corrupt JPEG data", "Premature end of JPEG file")
# ...except junk between two markers (some cameras and tools write it): libjpeg skips it and the pixels are intact
_HARMLESS = "extraneous bytes before marker"
# ...but not before the end-of-image marker: the scan's data decoded to its last block with bytes left
# over, which is what broken entropy-coded data does (zeroed stretches of wshed.jpg: 23-45 % of the
# pixels wrong, and this the decoder's only word)
_BEFORE_END = "before marker 0xd9"
# libjpeg / libpng write straight to the process's stderr (fd 2), past OpenCV's log level: captured
_DECODER_NOISE = ("Corrupt JPEG data", "Premature end of JPEG", "libpng ", "Invalid JPEG", "Bogus ",
                  "Unsupported marker", "Warning: ", "JPEG datastream", "Not a JPEG file")
_DECODE_LOCK = threading.Lock()


@contextlib.contextmanager
def _opencv_log_level(level: int):
    """OpenCV's own log at `level` for the `with` (its lines, ahead of the one-line message that says the same),
    as it was after."""
    was = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(level)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(was)


def _decode_quietly(data: np.ndarray, flags: int):
    """cv2.imdecode with the image libraries' messages captured: (image or None, their lines). Anything
    else written to stderr meanwhile (another thread) is passed on."""
    # silent: a file OpenCV cannot read is reported by the caller, its own log line was noise on stderr
    with _DECODE_LOCK, tempfile.TemporaryFile() as capture, _opencv_log_level(cv2.utils.logging.LOG_LEVEL_SILENT):
        sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:  # no stderr to guard (a detached process): decode as is
            return cv2.imdecode(data, flags), []
        try:
            os.dup2(capture.fileno(), 2)
            try:
                img = cv2.imdecode(data, flags)
            finally:
                os.dup2(saved, 2)
        finally:
            os.close(saved)
        capture.seek(0)
        lines = capture.read().decode("utf-8", "replace").splitlines()
    noise = [line.strip() for line in lines if line.strip().startswith(_DECODER_NOISE)]
    others = [line for line in lines if line.strip() and not line.strip().startswith(_DECODER_NOISE)]
    if others:
        print("\n".join(others), file=sys.stderr)
    return img, noise


def _to_uint8(img: np.ndarray, path: Path) -> np.ndarray:
    """8-bit as is; 16-bit scaled by the smallest bit depth (8, 10, 12, 14, 16) that holds its maximum,
    so a full-range 16-bit copy of an 8-bit frame gives back exactly that frame; float in [0, 1] x 255."""
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        top = int(img.max())
        depth = next(d for d in (8, 10, 12, 14, 16) if top < 2 ** d)
        if depth == 8:
            return img.astype(np.uint8)
        return cv2.convertScaleAbs(img, alpha=255.0 / (2 ** depth - 1))
    if img.dtype in (np.float32, np.float64):
        if not np.all(np.isfinite(img)):
            raise BadInput(f"image {path} has {img.dtype} pixels that are not finite numbers (nan or inf)")
        img = np.maximum(img, 0.0)  # below black is black (convertScaleAbs took |x|: -0.5 came out mid-grey)
        top = float(img.max())
        return cv2.convertScaleAbs(img, alpha=255.0 if top <= 1.0 else 255.0 / top)
    raise BadInput(f"image {path} has {img.dtype} pixels; 8- or 16-bit integer or float images are read")


DARK_MEAN_DN = 10.0  # a frame darker than this on average shows nothing (lights off, the lens covered)
SATURATED_DN = 250  # a pixel at this or more is saturated
SATURATED_SHARE = 0.95  # ... this share of it at 250 DN or more: overexposed (a lamp into the lens, no iris)
FLAT_SD_DN = 0.5  # ... and a frame this even (at 1/8 size) is one colour: no picture (a test card, no signal)
# (the shared photographs: mean 79 - 147 DN, sd 35 - 95; the simulated camera's empty tray: 106, sd 6.3)


def _grey(frame: np.ndarray) -> np.ndarray:
    return frame if frame.ndim == 2 else cv2.cvtColor(frame[..., :3], cv2.COLOR_BGR2GRAY)


def saturated_share(frame: np.ndarray) -> float:
    """The share of the frame at SATURATED_DN or more."""
    return float((_grey(frame) >= SATURATED_DN).mean())


def blank_frame_reason(frame: np.ndarray, first_saturated: float = 0.0) -> str | None:
    """Why a camera frame cannot show the tray (too dark, overexposed, one flat colour), else None. After a
    pick a frame like that showed "no part" and the part counted as removed (a black frame: 1 of 1 removed).
    `first_saturated`: the share of the run's first frame at 250 or more: a back-lit tray is white, empty or
    not, and is no overexposed frame where the first was so too."""
    grey = _grey(frame)
    h, w = grey.shape[:2]
    small = cv2.resize(grey, (max(1, w // 8), max(1, h // 8)), interpolation=cv2.INTER_AREA).astype(np.float64)
    mean, sd = float(small.mean()), float(small.std())
    if mean < DARK_MEAN_DN:
        return f"the frame is dark (mean {mean:.1f} of 255): lights off, or the lens covered?"
    saturated = saturated_share(grey)
    back_lit = first_saturated >= 0.5
    if saturated >= SATURATED_SHARE and not back_lit:
        return f"the frame is overexposed ({saturated:.0%} of it at {SATURATED_DN} or more)"
    if sd < FLAT_SD_DN and not (back_lit and saturated >= SATURATED_SHARE):
        return f"the frame is one flat colour (mean {mean:.0f}, sd {sd:.2f}): no picture"
    return None


def write_image(path: str | Path, frame: np.ndarray) -> None:
    """Encode and write atomically (the extension chooses the format, e.g. .png)."""
    from cell.fileio import write_atomic

    path = Path(path)
    ok, buf = cv2.imencode(path.suffix or ".png", frame)
    if not ok:
        raise BadInput(f"cannot encode an image as {path.suffix!r} (use .png)")
    write_atomic(path, buf.tobytes())


class FileCamera:
    """A camera that plays image files in order; `read()` returns the next frame.

    Works as a context manager like the other devices; reading past the last file raises
    `BadInput` (there is no next frame), `loop=True` starts again.
    """

    def __init__(self, paths, loop: bool = False):
        self.paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
        if not self.paths:
            raise BadInput("FileCamera needs at least one image file")
        self.loop = loop
        self.index = 0
        self.is_connected = False

    def connect(self) -> FileCamera:
        self.is_connected = True
        return self

    def disconnect(self) -> None:
        self.is_connected = False

    def __enter__(self) -> FileCamera:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.disconnect()

    def read(self) -> np.ndarray:
        if self.index >= len(self.paths):
            if not self.loop:
                raise BadInput(f"no more frames: all {len(self.paths)} image files were read")
            self.index = 0
        path = self.paths[self.index]
        self.index += 1
        return read_image(path)

    def peek(self) -> np.ndarray:
        """The frame `read()` returns next, without moving on."""
        return read_image(self.paths[self.index % len(self.paths)])


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class VideoCamera:
    """A camera OpenCV can open (`cv2.VideoCapture`: a device index, a video file, an RTSP or
    GStreamer URL); `read()` returns the newest frame as BGR uint8.

    The cell wants what the tray looks like now, not a frame queued before the arm moved away:
    the driver's queue is asked to hold one frame, and frames are grabbed until one takes at
    least half a frame period to arrive (it was taken after the read began), at most MAX_GRABS.
    """

    MAX_GRABS = 30
    # a stream URL that does not answer: OpenCV's FFmpeg backend waited its own 30 s, without a word, to open
    # it, and as long for each frame
    STREAM_TIMEOUT_S = 5.0

    def __init__(self, source: int | str, size_px: tuple[int, int] | None = None):
        self.source, self.size_px = source, size_px
        self._cap = None

    def _is_stream(self) -> bool:
        return isinstance(self.source, str) and "://" in self.source

    def connect(self) -> VideoCamera:
        import time

        t0 = time.monotonic()
        # each backend tried logs why it could not open the source ("[ WARN:0@2.1] global cap_v4l.cpp:915 ..."),
        # ahead of the one-line message below that says it
        with _opencv_log_level(cv2.utils.logging.LOG_LEVEL_ERROR):
            if self._is_stream():  # (only there: a backend left with a parameter it does not take refuses to open)
                ms = round(1000 * self.STREAM_TIMEOUT_S)
                cap = cv2.VideoCapture(self.source, cv2.CAP_ANY,
                                       [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms])
            else:
                cap = cv2.VideoCapture(self.source)
        if not cap.isOpened():
            cap.release()
            waited = time.monotonic() - t0 >= 0.9 * self.STREAM_TIMEOUT_S
            why = ("no such device, or OpenCV has no backend for it" if not self._is_stream() else
                   f"no stream OpenCV reads answered within {self.STREAM_TIMEOUT_S:g} s" if waited else
                   "no stream OpenCV reads there: the address refused, unknown, or not a video")
            raise BadInput(f"camera {self.source!r} cannot be opened ({why})")
        if self.size_px is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.size_px[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size_px[1])
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # honoured by some backends only: the grabs below do the rest
        fps = cap.get(cv2.CAP_PROP_FPS)
        self._period_s = 1.0 / fps if fps and 1.0 <= fps <= 1000.0 else 1.0 / 30.0
        self._cap = cap
        return self

    def disconnect(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __enter__(self) -> VideoCamera:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.disconnect()

    def read(self) -> np.ndarray:
        if self._cap is None:
            raise BadInput(f"camera {self.source!r} is not connected")
        import time

        for _ in range(self.MAX_GRABS):
            t0 = time.monotonic()
            if not self._cap.grab():
                within = f" within {self.STREAM_TIMEOUT_S:g} s" if self._is_stream() else ""
                raise BadInput(f"camera {self.source!r} delivered no frame{within}")
            if time.monotonic() - t0 >= 0.5 * self._period_s:  # waited for it: a fresh frame
                break
        ok, frame = self._cap.retrieve()
        if not ok or frame is None or frame.size == 0:
            raise BadInput(f"camera {self.source!r} delivered no frame")
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        return frame

    def peek(self) -> np.ndarray:
        """A frame now (a live camera has no "next" frame to keep)."""
        return self.read()


def open_camera(spec: str, size_px: tuple[int, int] | None = None):
    """The frame source `spec` names: a folder (its images in name order) or one image file
    (played by `FileCamera`), a device index ("0", "/dev/video0"), or anything else
    `cv2.VideoCapture` opens (a video file, an rtsp:// or GStreamer URL). Not yet connected."""
    if "://" in spec:  # rtsp://, http://: a stream, whatever its name ends with
        return VideoCamera(spec, size_px)
    path = Path(spec)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise BadInput(f"camera folder {path} holds no image files ({', '.join(IMAGE_SUFFIXES)})")
        return FileCamera(files)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        if not path.is_file():
            raise BadInput(f"camera image {path} does not exist")
        return FileCamera([path])
    if spec.isdigit():
        return VideoCamera(int(spec), size_px)
    if spec.startswith("/dev/video") and spec[len("/dev/video"):].isdigit():
        return VideoCamera(int(spec[len("/dev/video"):]), size_px)
    return VideoCamera(spec, size_px)
