"""Frame sources: image files (recordings, test photographs) behind a camera-like `read()`.

`read_image` is the one place that turns a file into a BGR frame; every failure (missing,
not an image, truncated, empty) is a `BadInput` naming the file.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cell.errors import BadInput


def read_image(path: str | Path, grey: bool = False) -> np.ndarray:
    """Read an image file as BGR uint8 (h, w, 3), or grey (h, w) when `grey`."""
    path = Path(path)
    if not path.exists():
        raise BadInput(f"image {path} does not exist")
    if path.is_dir():
        raise BadInput(f"image {path} is a directory, not an image file")
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        raise BadInput(f"image {path} cannot be read: {e}") from None
    if data.size == 0:
        raise BadInput(f"image {path} is empty (0 bytes)")
    img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR)
    if img is None or img.size == 0:
        raise BadInput(f"image {path} is not a readable image (corrupt, truncated or not an image format)")
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
    return img


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
