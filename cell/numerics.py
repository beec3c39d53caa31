"""The same numbers on every machine, and a record of what computed them.

OpenBLAS (numpy's and scipy's linear algebra) picks its kernels by the CPU it finds: the same recording,
replayed with the Haswell kernels where it was made with the SkylakeX ones, diverged (the last digits of
a part's outline moved a registration's search to the other of two equally good poses). `pin_blas` makes
every x86-64 machine use one kernel set all of them run (Nehalem: SSE4.2), on one thread (a sum split over
threads adds in another order). It must run before numpy loads OpenBLAS: `cell/__init__.py` calls it
(`calibration` imports `cell` first; `drivers` does before numpy). A value the user set stays. Measured:
`cell bench grasp` and `cell segment` take the same time with it.

`numeric_platform()` says what computed a recording's numbers (the manifest keeps it; replay names a
difference).
"""

from __future__ import annotations

import os
import platform

BLAS_CORETYPE_X86 = "Nehalem"


def pin_blas() -> None:
    if platform.machine().lower() in ("x86_64", "amd64"):
        os.environ.setdefault("OPENBLAS_CORETYPE", BLAS_CORETYPE_X86)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


# Pixels OpenCV decodes at most (OPENCV_IO_MAX_IMAGE_PIXELS, read when cv2 loads; its own default is 2^30): a
# 30000 x 30000 PNG of 0.9 MB took 5.3 GB to segment and would have the process killed on a smaller machine.
# 2^28 = 268 MP: a 200 MP phone's calibration photos pass (a cell file's camera is 100 MP at most); a user's
# own value stays.
MAX_IMAGE_PIXELS = 2**28


def limit_image_pixels() -> None:
    os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(MAX_IMAGE_PIXELS))


def numeric_platform() -> dict:
    """The libraries and kernels the numbers come from: {"machine", "numpy", "scipy", "scikit-learn", "opencv",
    "shapely", "geos", "blas": [{"library", "version", "architecture", "threads"}, ...]}."""
    from importlib.metadata import PackageNotFoundError, version

    # every library that brings a BLAS, loaded, so that the list is the same whenever it is asked for
    import cv2  # noqa: F401
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401
    import scipy.optimize  # noqa: F401
    import sklearn.tree  # noqa: F401
    import threadpoolctl

    out = {"machine": platform.machine()}
    for dist, key in (("numpy", "numpy"), ("scipy", "scipy"), ("scikit-learn", "scikit-learn"),
                      ("opencv-python-headless", "opencv"), ("shapely", "shapely")):
        try:
            out[key] = version(dist)
        except PackageNotFoundError:
            out[key] = None
    import shapely

    out["geos"] = shapely.geos_version_string
    out["blas"] = sorted(({"library": i.get("internal_api"), "version": i.get("version"),
                           "architecture": i.get("architecture"), "threads": i.get("num_threads")}
                          for i in threadpoolctl.threadpool_info() if i.get("user_api") == "blas"),
                         key=lambda b: (str(b["library"]), str(b["version"]), str(b["architecture"])))
    return out


def platform_difference(recorded: dict | None, here: dict) -> str | None:
    """What differs between a recording's numeric platform and this one, in a line; None when nothing does
    (or the recording did not say)."""
    if not isinstance(recorded, dict):
        return None
    diffs = [f"{k} {recorded.get(k)!s} -> {here.get(k)!s}" for k in here if k != "blas" and recorded.get(k) != here[k]]
    if recorded.get("blas") != here["blas"]:
        def kernels(b):
            return ", ".join(f"{x.get('library')} {x.get('architecture')} x{x.get('threads')}"
                             for x in b or []) or "none"
        diffs.append(f"BLAS {kernels(recorded.get('blas'))} -> {kernels(here['blas'])}")
    return "; ".join(diffs) or None
