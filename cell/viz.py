"""The one module that talks to rerun (imported lazily): what the cell sees and decides, per frame.

Entity paths mirror the pipeline:

    camera/frame            the camera image (px; 2D view "camera")
    vision/contours         segmented outlines, px, drawn over the frame
    camera/candidates       candidate points in px (when the caller has them in px)
    vision/parts            part outlines in the base frame (mm, z = part top; 3D view "base frame")
    grasp/candidates        candidate contact points, green = valid, red = refused by the point tree
    grasp/pairs             reachable pairs (segments between the two contacts)
    grasp/selected/...      the chosen grasp: contacts, finger footprints, palm footprint
    arm/links               base -> elbow -> wrist -> finger tip
    arm/joints/j1..j4       joint values as time series (deg, deg, mm, deg)
    gripper/width           gripper opening as a time series (mm)
    can/tx, can/rx          CAN frames sent / received per frame
    log/events              text events (state changes, decisions)

Every method takes plain data (numpy arrays, lists, `cell.kinematics.Joints`); the time of a
call is the frame last set with `frame(i, ...)` (timeline "frame"), plus wall-clock time.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

VALID_RGB = (40, 190, 80)
INVALID_RGB = (220, 50, 50)
PAIR_RGB = (90, 140, 230)
SELECTED_RGB = (255, 200, 0)
FINGER_RGB = (255, 140, 0)
PALM_RGB = (180, 120, 255)
CONTOUR_RGB = (0, 220, 255)
ARM_RGB = (200, 200, 200)
JOINT_NAMES = ("j1", "j2", "j3", "j4")
FLUSH_TIMEOUT_S = 5.0  # for the viewer's gRPC sink to take what was logged (a file sink is quicker)


DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")


def check_display() -> None:
    """On Linux the viewer needs an X or Wayland display: without one it started, failed, and filled the run's
    stderr with its own errors (winit, then the stream's gRPC) while the run went on. Commands ask before they
    make anything."""
    import sys

    from cell.errors import BadInput

    if sys.platform.startswith("linux") and not any(os.environ.get(k) for k in DISPLAY_VARIABLES):
        raise BadInput("--rerun: no display here (DISPLAY and WAYLAND_DISPLAY are not set), the viewer cannot open "
                       "its window; --save FILE.rrd writes the recording for a viewer elsewhere")


def _spawn_viewer(rr, rec) -> None:
    """Start a rerun viewer for `rec`: the `rerun` next to this Python (its venv's, found without the
    venv on PATH) or on PATH. None found, or one that cannot start, is a clear error."""
    import shutil
    import sys

    from cell.errors import BadInput

    check_display()
    beside = Path(sys.executable).with_name("rerun")
    exe = str(beside) if beside.exists() else shutil.which("rerun")
    if exe is None:
        raise BadInput("--rerun: no rerun viewer found (the `rerun` executable of rerun-sdk); "
                       "--save FILE.rrd writes the recording for a viewer elsewhere")
    try:
        rr.spawn(connect=False, hide_welcome_screen=True, recording=rec, executable_path=exe)
    except (RuntimeError, OSError) as e:
        raise BadInput(f"--rerun: the rerun viewer {exe} did not start ({str(e).splitlines()[0]}); "
                       "--save FILE.rrd writes the recording instead") from None


def _xy(points, what: str) -> np.ndarray:
    a = np.asarray(points, dtype=float)
    if a.ndim != 2 or a.shape[1] not in (2, 3):
        raise ValueError(f"{what} must have shape (n, 2) or (n, 3), got {a.shape}")
    return a


def _at_z(points, z_mm: float, what: str) -> np.ndarray:
    """(n, 2) -> (n, 3) at height z_mm; (n, 3) is kept."""
    a = _xy(points, what)
    if a.shape[1] == 3:
        return a
    return np.column_stack([a, np.full(len(a), float(z_mm))])


def _closed(ring: np.ndarray) -> np.ndarray:
    return np.vstack([ring, ring[:1]]) if len(ring) and not np.allclose(ring[0], ring[-1]) else ring


def blueprint():
    """The default layout: camera view with outlines, the base frame in 3D, time series."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="camera (px)", origin="/",
                                  contents=["+ /camera/**", "+ /vision/contours/**"]),
                rrb.Spatial3DView(name="base frame (mm)", origin="/",
                                  contents=["+ /vision/parts/**", "+ /grasp/**", "+ /arm/links/**"]),
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="joints (deg, J3 mm)", origin="/arm/joints"),
                rrb.TimeSeriesView(name="gripper width (mm)", origin="/gripper"),
                rrb.TimeSeriesView(name="CAN frames per frame", origin="/can"),
                rrb.TextLogView(name="events", origin="/log"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class Viz:
    """A rerun recording of the cell.

    Parameters
    ----------
    app_id : rerun application id.
    spawn : start (or connect to) a rerun viewer on this machine.
    save_path : write the recording to this .rrd file (streamed as it goes, so a crash leaves
        every chunk flushed so far).
    jpeg_quality : frames are JPEG-compressed at this quality (None: stored raw, ~4 MB each).
    """

    def __init__(self, app_id: str = "disassembly-cell", *, spawn: bool = False,
                 save_path: str | Path | None = None, jpeg_quality: int | None = 85,
                 recording_id: str | None = None):
        import rerun as rr

        self._rr = rr
        self.jpeg_quality = jpeg_quality
        self.save_path = Path(save_path) if save_path is not None else None
        self.rec = rr.RecordingStream(app_id, recording_id=recording_id)
        sinks = []
        if self.save_path is not None:
            self.save_path.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.save_path)))
        if spawn:  # this stream's viewer (the module-level default stream is never set up: spawn would skip it)
            _spawn_viewer(rr, self.rec)
            sinks.append(rr.GrpcSink())
        if sinks:
            self.rec.set_sinks(*sinks)
        self.rec.send_blueprint(blueprint())
        self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for name, unit in zip(JOINT_NAMES, ("deg", "deg", "mm", "deg"), strict=True):
            self.rec.log(f"arm/joints/{name}", rr.SeriesLines(names=f"{name} ({unit})"), static=True)
        self.rec.log("gripper/width", rr.SeriesLines(names="opening (mm)"), static=True)
        self.frame_index: int | None = None
        self._viewer_gone = False
        self._viewer = spawn
        self.failed = None  # RecordingFailed: rerun stopped writing save_path (a full disk); the rest is not in it

    # -- per frame
    def frame(self, i: int, frame_bgr: np.ndarray) -> None:
        """Start frame i (timeline "frame") and log the camera image, BGR uint8 (h, w, 3) or (h, w).
        Without a viewer, what was logged so far is first flushed to save_path: a file rerun stopped writing is
        a RecordingFailed here (a few ms a frame), not found only at the close."""
        rr = self._rr
        if self.save_path is not None and not self._viewer:
            self.flush()
            if self.failed is not None:
                raise self.failed
        self.frame_index = int(i)
        self.rec.set_time("frame", sequence=int(i))
        a = np.asarray(frame_bgr)
        if a.dtype != np.uint8 or a.ndim not in (2, 3):
            raise ValueError(f"frame must be uint8 (h, w[, 3]), got {a.dtype} {a.shape}")
        img = rr.Image(a, color_model="BGR") if a.ndim == 3 else rr.Image(a, color_model="L")
        if self.jpeg_quality is not None:
            img = img.compress(jpeg_quality=int(self.jpeg_quality))
        self.rec.log("camera/frame", img)

    def contours(self, segments_px) -> None:
        """Segmented outlines in px: a list of (n_i, 2) arrays (closed rings, first point not repeated)."""
        strips = [_closed(_xy(s, "a contour")) for s in segments_px]
        self.rec.log("vision/contours", self._rr.LineStrips2D(strips, colors=CONTOUR_RGB, radii=1.5))

    def parts(self, outlines_mm, z_top_mm=None, labels=None) -> None:
        """Part outlines in the base frame: a list of (n_i, 2) arrays (mm), drawn at their top z."""
        zs = z_top_mm if z_top_mm is not None else [0.0] * len(outlines_mm)
        strips = [_closed(_at_z(o, z, "a part outline")) for o, z in zip(outlines_mm, zs, strict=True)]
        self.rec.log("vision/parts", self._rr.LineStrips3D(strips, colors=CONTOUR_RGB, radii=0.8,
                                                            labels=labels))

    def candidates(self, points, valid_mask, *, space: str = "mm", z_mm: float = 0.0) -> None:
        """Candidate contact points, coloured by the point tree's verdict.

        points : array of shape (n, 2) (or (n, 3) in mm); valid_mask : bool array of shape (n,).
        space : "mm" (base frame, grasp/candidates) or "px" (over the frame, camera/candidates).
        """
        rr = self._rr
        valid = np.asarray(valid_mask, dtype=bool)
        pts = _xy(points, "candidate points")
        if valid.shape != (len(pts),):
            raise ValueError(f"valid_mask must have shape ({len(pts)},), got {valid.shape}")
        colors = np.where(valid[:, None], VALID_RGB, INVALID_RGB).astype(np.uint8)
        if space == "px":
            self.rec.log("camera/candidates", rr.Points2D(pts[:, :2], colors=colors, radii=3.0))
        elif space == "mm":
            self.rec.log("grasp/candidates", rr.Points3D(_at_z(pts, z_mm, "candidate points"),
                                                         colors=colors, radii=1.2))
        else:
            raise ValueError(f"space must be 'mm' or 'px', not {space!r}")

    def pairs(self, pairs, *, z_mm: float = 0.0) -> None:
        """Reachable contact pairs: array of shape (n, 2, 2) (mm), one segment per pair."""
        a = np.asarray(pairs, dtype=float).reshape(-1, 2, 2) if len(pairs) else np.zeros((0, 2, 2))
        strips = [_at_z(p, z_mm, "a pair") for p in a]
        self.rec.log("grasp/pairs", self._rr.LineStrips3D(strips, colors=PAIR_RGB, radii=0.3))

    def grasp(self, contacts, finger_footprints=(), palm_footprint=None, *, grasp_z_mm: float = 0.0,
              palm_z_mm: float | None = None, label: str | None = None) -> None:
        """The selected grasp: contacts (2, 2) mm, finger footprints (list of (k, 2) rectangles)
        drawn at the grasp z, the palm footprint (k, 2) at palm_z_mm (default grasp z + 40)."""
        rr = self._rr
        c = _at_z(contacts, grasp_z_mm, "contacts")
        self.rec.log("grasp/selected/contacts", rr.Points3D(c, colors=SELECTED_RGB, radii=2.0,
                                                            labels=[label] * len(c) if label else None))
        self.rec.log("grasp/selected/axis", rr.LineStrips3D([c], colors=SELECTED_RGB, radii=0.6))
        fingers = [_closed(_at_z(f, grasp_z_mm, "a finger footprint")) for f in finger_footprints]
        self.rec.log("grasp/selected/fingers", rr.LineStrips3D(fingers, colors=FINGER_RGB, radii=0.6))
        if palm_footprint is not None:
            pz = grasp_z_mm + 40.0 if palm_z_mm is None else palm_z_mm
            self.rec.log("grasp/selected/palm", rr.LineStrips3D([_closed(_at_z(palm_footprint, pz, "palm"))],
                                                                colors=PALM_RGB, radii=0.6))

    def arm(self, base_elbow_wrist_points, joints=None, *, link_z_mm: float = 300.0) -> None:
        """The arm: base, elbow and wrist (3, 2) mm (cell.kinematics.elbow_points) drawn at the
        links' height, and the tool from the wrist down to the finger tip (joints.j3_mm).
        With `joints` the joint time series are logged too."""
        rr = self._rr
        pts = _at_z(base_elbow_wrist_points, link_z_mm, "arm points")
        strip = [np.array([pts[0, 0], pts[0, 1], 0.0]), *pts]
        if joints is not None:
            strip.append(np.array([pts[-1, 0], pts[-1, 1], float(joints.j3_mm)]))
            self.joints(joints)
        self.rec.log("arm/links", rr.LineStrips3D([np.array(strip)], colors=ARM_RGB, radii=4.0))

    # -- time series
    def joints(self, j) -> None:
        """Joint values (cell.kinematics.Joints) as scalars arm/joints/j1..j4."""
        for name, v in zip(JOINT_NAMES, (j.j1_deg, j.j2_deg, j.j3_mm, j.j4_deg), strict=True):
            self.rec.log(f"arm/joints/{name}", self._rr.Scalars(float(v)))

    def gripper_width(self, opening_mm: float) -> None:
        self.rec.log("gripper/width", self._rr.Scalars(float(opening_mm)))

    def can(self, tx: int, rx: int) -> None:
        """CAN frames sent and received since the last call."""
        self.rec.log("can/tx", self._rr.Scalars(float(tx)))
        self.rec.log("can/rx", self._rr.Scalars(float(rx)))

    def event(self, text: str, level: str = "INFO") -> None:
        self.rec.log("log/events", self._rr.TextLog(str(text), level=level))

    # -- end
    def _file_failed(self, e: RuntimeError):
        """rerun's file writer stopped (its thread logs why on stderr; Python hears "File-writer thread shut down
        prematurely"): a RecordingFailed naming the file, ENOSPC when its disk is full."""
        import errno

        from cell.recording import CLOSE_RESERVE_MB, RecordingFailed, free_mb

        free = free_mb(self.save_path.parent)
        full = free < CLOSE_RESERVE_MB
        self.failed = RecordingFailed(errno.ENOSPC if full else errno.EIO,
                                      f"rerun stopped writing it ({e}); {free:.1f} MB free on its disk"
                                      + (": the disk is full" if full else ""), str(self.save_path))
        return self.failed

    def flush(self) -> None:
        """Push what was logged to the sinks. A viewer that never came up (no display) or went away does
        not hold the run: the flush gives up after FLUSH_TIMEOUT_S, says so once on stderr, and the
        later ones do not wait again. A file rerun stopped writing is kept in `failed` (the session says so)."""
        if self._viewer_gone or self.failed is not None:
            return
        try:
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except RuntimeError as e:  # rerun's "Flush timed out", or its file writer gone
            if self.save_path is not None and "file" in str(e).lower():  # (the viewer's: "Flush timed out")
                self._file_failed(e)
                return
            import sys

            self._viewer_gone = True
            print(f"cell: warning: the rerun viewer did not take the recording ({e}); the run goes on without it"
                  + (f", {self.save_path} is written" if self.save_path is not None else ""), file=sys.stderr)

    def close(self) -> None:
        """Flush and close the sinks (the .rrd file gets its footer). rerun's disconnect waits on its file writer,
        and once that writer died (a reader gone from a pipe, a failing disk) it waited for ever now and then (a
        CI run hung in test_recording_rrd_failure): it runs in a thread of its own, and one that has not returned
        within FLUSH_TIMEOUT_S is given up, the file counted as failed."""
        import threading

        self.flush()
        done = threading.Thread(target=self.rec.disconnect, name="rerun-disconnect", daemon=True)
        done.start()
        done.join(FLUSH_TIMEOUT_S)
        if done.is_alive() and self.save_path is not None and self.failed is None:
            self._file_failed(RuntimeError(f"its close did not return within {FLUSH_TIMEOUT_S:g} s"))

    def __enter__(self) -> Viz:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
