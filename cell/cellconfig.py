"""The cell file: the SCARA, the gripper, the tray, the camera and the CAN nodes.

A readable JSON file (`cell/data/default_cell.json` is the default cell of CONTRACT.md).
`load_cell(path)` validates every key and raises `BadInput` naming the key; `--cell FILE`
anywhere in the CLI replaces the default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from cell.cellgeometry import check_cell_geometry
from cell.errors import BadInput
from cell.fileio import is_finite_number, read_json, short_repr, short_text

FORMAT = "disassembly-cell/cell"
# Joints nearer the contacts say more about the kind of grasp (paper section 7): the wrist
# J4 fixes how the jaws sit, the elbow J2 which side the arm comes from, the shoulder J1
# mostly follows the part's position. J3 is the same for every solution (the grasp z).
DEFAULT_JOINT_WEIGHTS = {"j1": 0.25, "j2": 0.5, "j3": 0.0, "j4": 1.0}
JOINTS = ("j1", "j2", "j3", "j4")
NODE_UNITS = {"j1": "deg", "j2": "deg", "j3": "mm", "j4": "deg", "gripper": "mm"}  # the units CONTRACT fixes
# Bounds past which a cell file is not a cell: a pad 1e9 mm wide or J4 up to 1e9 deg made `cell grasp` run
# without end (1e308: an OverflowError), a camera of 1e9 px asked for terabytes.
MAX_VALUE = 1e6  # any number in the file (mm, deg, s, ms, bit/s) but counts_per_unit (a 23-bit encoder behind
# an 80:1 gear is 1.9e6 counts/deg): its bound is what the drives' 32-bit objects hold (_check_drive_counts)
# the smallest side, the most pixels (100 MP: above any machine-vision camera a cell would use)
CAMERA_PX = (16, 100_000_000)
MAX_CAMERA_SIDE_PX = 32767  # OpenCV's remap (segmentation samples the frames with it): sides under SHRT_MAX
# How the drivers derive the drives' settings from the cell file (here, so the file's checks see them too)
HEARTBEAT_DEADLINE_FACTOR = 3.0  # a node is silent after this many of its heartbeat periods
GRIPPER_ACCEL_FACTOR = 10.0  # gripper acceleration = this x its speed, per second
QUICK_STOP_DECEL_FACTOR = 2.0  # quick stop / fault reaction deceleration = this x the max acceleration
# Error frames (drivers.errorframes): a sporadic one is counted; more than can.error_frames_max within
# can.error_window_ms mean a disturbed bus losing frames (bad termination, a loose connector, interference)
DEFAULT_ERROR_FRAMES_MAX = 10
DEFAULT_ERROR_WINDOW_MS = 1000
MIN_ERROR_WINDOW_MS = 100  # 10 frames within 1 ms would never trip on one error frame every ms
MAX_ERROR_WINDOW_MS = 60_000  # a window of minutes would add up sporadic frames into a stop
# The burst limit is a rate: error_frames_max within error_window_ms. At most this many a second (one every 10 ms of
# the window; the default is 10 a second): the cell sends about 320 frames a second during a pick (docs/drivers.md,
# figures), so 100 a second is about a third of them destroyed and sent again. A limit past that lets a bus losing
# frames run on (CAN's fault confinement need not catch it: a receiver's error counter goes down one for every
# good frame), and 1000000 in a second, more error frames than a bus can carry, turned the check off.
MAX_ERROR_FRAMES_PER_S = 100
# How late the host may stop the other axes after one stopped on its own (its fault reaction, its quick stop
# input): the way check (drivers.limits) follows such stops. The host looks at the drives every
# HOST_POLL_MS during a move; the frames that tell it and the stop frames add a few ms at 125 kbit/s and up.
HOST_POLL_MS = 10
DEFAULT_STOP_LAG_MS = 20
MIN_STOP_LAG_MS = HOST_POLL_MS + 5
MAX_STOP_LAG_MS = 1000  # a second: ways near the edge would all be refused long before
# The gripper's force limit 0x2100 (drivers.eds, drivers.gripper): UNSIGNED16 in 0.1 N, written as
# round(force_n * GRIP_FORCE_PER_N) at connect (gripper.grip_force_n) and by grip() (any force up to
# gripper.max_force_n)
GRIP_FORCE_PER_N = 10
MAX_GRIP_FORCE_UNITS = 0xFFFF


def grip_force_units(force_n: float) -> int:
    """A force as the drive's force limit 0x2100 holds it (rounded, half to even: 0.05 N is 0)."""
    return round(force_n * GRIP_FORCE_PER_N)
# The drives' heartbeat period (can.heartbeat_ms, 0x1017; the host finds a node silent HEARTBEAT_DEADLINE_FACTOR
# periods after its last heartbeat). Under the host's poll (HOST_POLL_MS, its watch of the drives) the watch could
# not tell a silent drive from its own late run, and the heartbeats alone load the bus (5 drives at 1 ms: 5000
# frames/s, 33 % of 1 Mbit/s; at 10 ms 3.3 %, 26 % at 125 kbit/s). Over a second a dead drive goes unnoticed for
# more than 3 s (at 65535, the 16-bit object's top, 197 s), where a move takes a second or two.
MIN_HEARTBEAT_MS = HOST_POLL_MS
MAX_HEARTBEAT_MS = 1000  # the host finds a silent drive within 3 s; well within 0x1017's UNSIGNED16
HEARTBEAT_FRAME_BITS = 65  # a heartbeat frame (1 data byte), worst-case stuffing and interframe space: as
# drivers.codec.frame_bits(1)
# The host's heartbeat period (can.host_heartbeat_ms; the drives' consumer deadline 0x1016 is
# HEARTBEAT_DEADLINE_FACTOR periods, 16 bits). The host sends it from the same thread as its watch of the drives
# (every HOST_POLL_MS): under that, the drives' deadline is under three of the host's looks and any hiccup of the
# host faults every drive. Over a second a dead host leaves every drive enabled, a move running on, for more than
# 3 s (at 21845, the 16-bit deadline's top, 65 s).
MIN_HOST_HEARTBEAT_MS = HOST_POLL_MS
MAX_HOST_HEARTBEAT_MS = 1000


def default_cell_path() -> Path:
    return Path(str(resources.files("cell") / "data" / "default_cell.json"))


@dataclass(frozen=True)
class Scara:
    l1_mm: float
    l2_mm: float
    j1_deg: tuple[float, float]
    j2_deg: tuple[float, float]
    j3_mm: tuple[float, float]
    j4_deg: tuple[float, float]
    link1_width_mm: float
    link2_width_mm: float
    link1_bottom_z_mm: float
    link2_bottom_z_mm: float
    max_velocity: dict  # per joint, unit/s (deg/s or mm/s)
    max_acceleration: dict  # per joint, unit/s^2
    max_step: dict  # per joint, the largest change one move command may ask for

    def limits(self, joint: str) -> tuple[float, float]:
        return {"j1": self.j1_deg, "j2": self.j2_deg, "j3": self.j3_mm, "j4": self.j4_deg}[joint]

    @property
    def reach_mm(self) -> tuple[float, float]:
        return abs(self.l1_mm - self.l2_mm), self.l1_mm + self.l2_mm


@dataclass(frozen=True)
class Gripper:
    opening_mm: tuple[float, float]
    pad_width_mm: float  # tangential, across the closing axis
    pad_thickness_mm: float  # along the closing axis
    pad_height_mm: float
    finger_length_mm: float  # pad bottom (finger tip) to palm bottom
    approach_clearance_mm: float  # each side, before descending
    palm_length_mm: float  # along the closing axis
    palm_width_mm: float
    palm_offset_mm: float  # palm bottom above the finger tip
    grip_force_n: float
    max_force_n: float
    speed_mm_s: float


@dataclass(frozen=True)
class Box2D:
    x_mm: tuple[float, float]
    y_mm: tuple[float, float]

    def contains(self, x: float, y: float) -> bool:
        return self.x_mm[0] <= x <= self.x_mm[1] and self.y_mm[0] <= y <= self.y_mm[1]

    def contains_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """`contains` for arrays of points, the same comparisons."""
        return (self.x_mm[0] <= x) & (x <= self.x_mm[1]) & (self.y_mm[0] <= y) & (y <= self.y_mm[1])

    def outside_text(self, x: float, y: float) -> str | None:
        """'outside ... (x a to b, y c to d mm)' where (x, y) lies outside the box, else None."""
        if self.contains(x, y):
            return None
        return (f"lies at ({x:.1f}, {y:.1f}) mm, outside the cell's tray (x {self.x_mm[0]:g} to {self.x_mm[1]:g}, "
                f"y {self.y_mm[0]:g} to {self.y_mm[1]:g} mm)")

    def overshoot_xy(self, x, y) -> np.ndarray:
        """(..., 4) how far each point lies past each side (x low, x high, y low, y high; 0 where inside it)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        return np.stack([np.maximum(self.x_mm[0] - x, 0.0), np.maximum(x - self.x_mm[1], 0.0),
                         np.maximum(self.y_mm[0] - y, 0.0), np.maximum(y - self.y_mm[1], 0.0)], axis=-1)

    def depth_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """How far inside the box each point lies (mm to the nearest side); negative: that far outside it."""
        return np.minimum(np.minimum(x - self.x_mm[0], self.x_mm[1] - x),
                          np.minimum(y - self.y_mm[0], self.y_mm[1] - y))


@dataclass(frozen=True)
class Motion:
    safe_z_mm: float
    dropoff_mm: tuple[float, float, float]
    home_joints: dict


@dataclass(frozen=True)
class Camera:
    width_px: int
    height_px: int
    height_mm: float


@dataclass(frozen=True)
class CanNode:
    name: str
    node_id: int
    unit: str
    counts_per_unit: float


@dataclass(frozen=True)
class CanConfig:
    bitrate: int
    heartbeat_ms: int
    host_heartbeat_ms: int
    nodes: dict  # name -> CanNode
    # more error frames than this within the window latch a bus fault (drivers.errorframes); optional keys
    error_frames_max: int = DEFAULT_ERROR_FRAMES_MAX
    error_window_ms: int = DEFAULT_ERROR_WINDOW_MS
    # the axes of a move take their set-points under halt and are released together (drivers.Arm); false:
    # each starts at its own set-point handshake, for drives that do not hold a set-point under halt
    coordinated_start: bool = True
    # how late the host may stop the other axes after one stopped on its own (the way check follows that)
    stop_lag_ms: float = DEFAULT_STOP_LAG_MS


@dataclass(frozen=True)
class Cell:
    name: str
    scara: Scara
    gripper: Gripper
    tray: Box2D
    workspace: Box2D
    motion: Motion
    camera: Camera
    can: CanConfig
    # Paper step 5: weights of the joint-space distance to the examples' configurations.
    joint_weights: dict = field(default_factory=lambda: dict(DEFAULT_JOINT_WEIGHTS))
    source: str = field(default="<default>", compare=False)


_DEFAULT: Cell | None = None


def default_cell() -> Cell:
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = load_cell(default_cell_path())
    return _DEFAULT


def load_cell(path: str | Path | None = None) -> Cell:
    """Read and validate a cell file; None means the shipped default cell."""
    if path is None:
        return default_cell()
    raw = read_json(path, "cell file")
    return parse_cell(raw, source=str(path))


# Every key a cell file may hold, per object: a misspelt key ("pad_widht_mm", "configuraton") would
# otherwise be ignored and leave the default in place without a word.
_SCARA_KEYS = ("l1_mm", "l2_mm", "j1_deg", "j2_deg", "j3_mm", "j4_deg", "link1_width_mm", "link2_width_mm",
               "link1_bottom_z_mm", "link2_bottom_z_mm", "max_velocity", "max_acceleration", "max_step")
_GRIPPER_KEYS = ("opening_mm", "pad_width_mm", "pad_thickness_mm", "pad_height_mm", "finger_length_mm",
                 "approach_clearance_mm", "palm_length_mm", "palm_width_mm", "palm_offset_mm", "grip_force_n",
                 "max_force_n", "speed_mm_s")
_KEYS = {
    "": ("format", "version", "name", "scara", "gripper", "tray", "workspace", "motion", "configuration",
         "camera", "can"),
    "scara": _SCARA_KEYS, "gripper": _GRIPPER_KEYS,
    "scara.max_velocity": JOINTS, "scara.max_acceleration": JOINTS, "scara.max_step": JOINTS,
    "tray": ("x_mm", "y_mm"), "workspace": ("x_mm", "y_mm"),
    "motion": ("safe_z_mm", "dropoff_mm", "home_joints"),
    "motion.home_joints": ("j1_deg", "j2_deg", "j3_mm", "j4_deg"),
    "configuration": ("joint_weights",), "configuration.joint_weights": JOINTS,
    "camera": ("width_px", "height_px", "height_mm"),
    "can": ("bitrate", "heartbeat_ms", "host_heartbeat_ms", "nodes", "error_frames_max", "error_window_ms",
            "coordinated_start", "stop_lag_ms"),
    "can.nodes": (*JOINTS, "gripper"),
    **{f"can.nodes.{n}": ("node_id", "unit", "counts_per_unit") for n in (*JOINTS, "gripper")},
}


def parse_cell(raw, source: str = "<dict>") -> Cell:
    r = _Reader(raw, source)
    _check_keys(raw, "", source)
    if raw.get("format", FORMAT) != FORMAT:
        raise BadInput(f"cell file {source}: 'format' must be {FORMAT!r}")
    if r.num(raw, "version") != 1:
        raise BadInput(f"cell file {source}: unsupported version {short_repr(raw.get('version'))} (this build reads 1)")
    s = r.obj(raw, "scara")
    scara = Scara(
        l1_mm=r.pos(s, "l1_mm", "scara"),
        l2_mm=r.pos(s, "l2_mm", "scara"),
        j1_deg=r.range(s, "j1_deg", "scara"),
        j2_deg=r.range(s, "j2_deg", "scara"),
        j3_mm=r.range(s, "j3_mm", "scara"),
        j4_deg=r.range(s, "j4_deg", "scara"),
        link1_width_mm=r.pos(s, "link1_width_mm", "scara"),
        link2_width_mm=r.pos(s, "link2_width_mm", "scara"),
        link1_bottom_z_mm=r.num(s, "link1_bottom_z_mm", "scara"),
        link2_bottom_z_mm=r.num(s, "link2_bottom_z_mm", "scara"),
        max_velocity=r.per_joint(s, "max_velocity"),
        max_acceleration=r.per_joint(s, "max_acceleration"),
        max_step=r.per_joint(s, "max_step"),
    )
    g = r.obj(raw, "gripper")
    gripper = Gripper(
        opening_mm=r.range(g, "opening_mm", "gripper"),
        **{k: r.pos(g, k, "gripper") for k in (
            "pad_width_mm", "pad_thickness_mm", "pad_height_mm", "finger_length_mm", "palm_length_mm",
            "palm_width_mm", "palm_offset_mm", "grip_force_n", "max_force_n", "speed_mm_s")},
        approach_clearance_mm=r.num(g, "approach_clearance_mm", "gripper"),  # > 0: cellgeometry says why
    )
    if gripper.opening_mm[0] < 0:
        raise BadInput(f"cell file {source}: gripper.opening_mm must not be negative")
    _check_grip_forces(gripper, source)
    tray = Box2D(r.range(r.obj(raw, "tray"), "x_mm", "tray"), r.range(raw["tray"], "y_mm", "tray"))
    ws = Box2D(r.range(r.obj(raw, "workspace"), "x_mm", "workspace"), r.range(raw["workspace"], "y_mm", "workspace"))
    if not (ws.contains(tray.x_mm[0], tray.y_mm[0]) and ws.contains(tray.x_mm[1], tray.y_mm[1])):
        raise BadInput(f"cell file {source}: the tray must lie inside the workspace")
    m = r.obj(raw, "motion")
    home = r.obj(m, "home_joints", "motion")
    motion = Motion(
        safe_z_mm=r.num(m, "safe_z_mm", "motion"),
        dropoff_mm=tuple(r.vec(m, "dropoff_mm", 3, "motion")),
        home_joints={k: r.num(home, k, "motion.home_joints") for k in ("j1_deg", "j2_deg", "j3_mm", "j4_deg")},
    )
    _check_motion_within_limits(motion, scara, source)
    c = r.obj(raw, "camera")
    camera = Camera(r.count(c, "width_px", "camera"), r.count(c, "height_px", "camera"),
                    r.pos(c, "height_mm", "camera"))
    if min(camera.width_px, camera.height_px) < CAMERA_PX[0] or camera.width_px * camera.height_px > CAMERA_PX[1]:
        raise BadInput(f"cell file {source}: camera {camera.width_px} x {camera.height_px} px: each side at least "
                       f"{CAMERA_PX[0]} px, at most {CAMERA_PX[1] / 1e6:g} MP in all")
    if max(camera.width_px, camera.height_px) >= MAX_CAMERA_SIDE_PX:
        raise BadInput(f"cell file {source}: camera {camera.width_px} x {camera.height_px} px: each side must be "
                       f"less than {MAX_CAMERA_SIDE_PX} px (OpenCV's remap limit; segmentation samples the frames "
                       "with remap)")
    cn = r.obj(raw, "can")
    nodes_raw = r.obj(cn, "nodes", "can")
    nodes = {}
    for name in (*JOINTS, "gripper"):
        n = r.obj(nodes_raw, name, "can.nodes")
        node_id = r.integer(n, "node_id", f"can.nodes.{name}")
        if not 1 <= node_id <= 127:
            raise BadInput(f"cell file {source}: can.nodes.{name}.node_id must be 1..127, got {node_id}")
        unit = n.get("unit")
        if unit != NODE_UNITS[name]:  # CONTRACT: J1, J2, J4 in degrees, J3 and the gripper in mm
            kind = "a revolute joint" if NODE_UNITS[name] == "deg" else "a linear axis"
            raise BadInput(f"cell file {source}: can.nodes.{name}.unit must be {NODE_UNITS[name]!r} ({kind}), "
                           f"got {short_repr(unit)}")
        nodes[name] = CanNode(name, node_id, unit, r.pos(n, "counts_per_unit", f"can.nodes.{name}", cap=math.inf))
    if len({n.node_id for n in nodes.values()}) != len(nodes):
        raise BadInput(f"cell file {source}: can.nodes have duplicate node ids")
    _check_drive_counts(scara, gripper, nodes, source)
    _check_moves_end(scara, gripper, source)
    can = CanConfig(r.count(cn, "bitrate", "can"), r.count(cn, "heartbeat_ms", "can"),
                    r.count(cn, "host_heartbeat_ms", "can"), nodes, *_error_frame_window(r, cn, source),
                    r.flag(cn, "coordinated_start", "can", default=True), _stop_lag_ms(r, cn, source))
    _check_heartbeat_ms(can, source)
    _check_host_heartbeat_ms(can, source)
    weights = dict(DEFAULT_JOINT_WEIGHTS)
    if "configuration" in raw:
        w = r.obj(r.obj(raw, "configuration"), "joint_weights", "configuration")
        weights = {j: r.nonneg(w, j, "configuration.joint_weights") for j in JOINTS}
        if not any(weights.values()):
            raise BadInput(f"cell file {source}: configuration.joint_weights must not all be zero")
    check_cell_geometry(source, scara, gripper, camera)
    name = raw.get("name", Path(source).stem)
    if not isinstance(name, str) or not name.strip():
        raise BadInput(f"cell file {source}: 'name' must be a non-empty text, got {short_repr(name)}")
    return Cell(name, scara, gripper, tray, ws, motion, camera, can, weights, source=source)


def _check_heartbeat_ms(can: CanConfig, source: str) -> None:
    """can.heartbeat_ms, the drives' heartbeat period: no shorter than the host's poll, no longer than a second."""
    hb = can.heartbeat_ms
    if hb < MIN_HEARTBEAT_MS:
        frames = len(can.nodes) * 1000.0 / hb
        load = 100.0 * frames * HEARTBEAT_FRAME_BITS / can.bitrate
        raise BadInput(f"cell file {source}: can.heartbeat_ms = {hb} is less than {MIN_HEARTBEAT_MS} ms: the host "
                       f"looks at the drives every {HOST_POLL_MS} ms and could not tell a silent drive from its own "
                       f"late look, and the {len(can.nodes)} drives' heartbeats alone would be {frames:g} frames/s, "
                       f"{load:.3g} % of can.bitrate {can.bitrate} bit/s")
    if hb > MAX_HEARTBEAT_MS:
        raise BadInput(f"cell file {source}: can.heartbeat_ms = {hb} is more than {MAX_HEARTBEAT_MS} ms: the host "
                       f"would find a silent drive only {HEARTBEAT_DEADLINE_FACTOR:g} periods after its last "
                       f"heartbeat, {HEARTBEAT_DEADLINE_FACTOR * hb / 1000:g} s, where a move takes a second or two")


def _check_host_heartbeat_ms(can: CanConfig, source: str) -> None:
    """can.host_heartbeat_ms, the host's heartbeat period the drives watch: no shorter than the host's poll, no
    longer than a second."""
    hb = can.host_heartbeat_ms
    deadline_ms = HEARTBEAT_DEADLINE_FACTOR * hb
    if hb < MIN_HOST_HEARTBEAT_MS:
        raise BadInput(f"cell file {source}: can.host_heartbeat_ms = {hb} is less than {MIN_HOST_HEARTBEAT_MS} ms: "
                       f"the drives would fault on a host heartbeat {deadline_ms:g} ms late "
                       f"({HEARTBEAT_DEADLINE_FACTOR:g} periods), under three of the host's looks at the drives "
                       f"(every {HOST_POLL_MS} ms, from the thread that sends it): any hiccup of the host would stop "
                       "every drive")
    if hb > MAX_HOST_HEARTBEAT_MS:
        raise BadInput(f"cell file {source}: can.host_heartbeat_ms = {hb} is more than {MAX_HOST_HEARTBEAT_MS} ms: "
                       f"a drive would find a dead host only {HEARTBEAT_DEADLINE_FACTOR:g} periods after its last "
                       f"heartbeat, {deadline_ms / 1000:g} s, and run on enabled meanwhile, where a move takes a "
                       "second or two")


def _stop_lag_ms(r: _Reader, cn: dict, source: str) -> float:
    """can.stop_lag_ms, optional: no less than the host takes to see a stop and answer it, no more than a second."""
    if "stop_lag_ms" not in cn:
        return DEFAULT_STOP_LAG_MS
    lag = r.num(cn, "stop_lag_ms", "can")
    if not MIN_STOP_LAG_MS <= lag <= MAX_STOP_LAG_MS:
        raise BadInput(f"cell file {source}: can.stop_lag_ms = {lag:g} must be {MIN_STOP_LAG_MS} to {MAX_STOP_LAG_MS} "
                       f"ms (the host looks at the drives every {HOST_POLL_MS} ms during a move, and the frames take "
                       "a few ms more)")
    return lag


def _error_frame_window(r: _Reader, cn: dict, source: str) -> tuple[int, int]:
    """can.error_frames_max (0: the first error frame of a counted class stops the arm) and can.error_window_ms,
    both optional."""
    most = DEFAULT_ERROR_FRAMES_MAX
    if "error_frames_max" in cn:
        most = r.integer(cn, "error_frames_max", "can")
        if most < 0:
            raise BadInput(f"cell file {source}: can.error_frames_max must be 0 or more error frames, got {most}")
    window_ms = DEFAULT_ERROR_WINDOW_MS
    if "error_window_ms" in cn:
        window_ms = r.count(cn, "error_window_ms", "can")
        if window_ms < MIN_ERROR_WINDOW_MS:
            raise BadInput(f"cell file {source}: can.error_window_ms = {window_ms} is less than {MIN_ERROR_WINDOW_MS}"
                           " ms (a window that short lets a steady stream of error frames through)")
        if window_ms > MAX_ERROR_WINDOW_MS:
            raise BadInput(f"cell file {source}: can.error_window_ms = {window_ms} is more than {MAX_ERROR_WINDOW_MS}"
                           " ms (a window that long adds up sporadic error frames into a stop)")
    top = window_ms * MAX_ERROR_FRAMES_PER_S // 1000
    if most > top:
        raise BadInput(f"cell file {source}: can.error_frames_max = {most} is more than {top} for can.error_window_ms "
                       f"= {window_ms}: at most {MAX_ERROR_FRAMES_PER_S} error frames a second of the window (about "
                       "a third of the frames the cell sends during a pick destroyed); a higher limit lets a bus "
                       "losing frames run on")
    return most, window_ms


def _check_grip_forces(gripper: Gripper, source: str) -> None:
    """The forces as the drivers send them to the drive's force limit 0x2100 (UNSIGNED16 in 0.1 N, rounded): the
    most grip() may send fits 16 bits, the grip force connect writes is within the most and not rounded to 0."""
    top = grip_force_units(gripper.max_force_n)
    if top > MAX_GRIP_FORCE_UNITS:
        raise BadInput(f"cell file {source}: gripper.max_force_n = {gripper.max_force_n:g} N is {top} in the drive's "
                       f"force limit 0x2100 (0.1 N, sent rounded): more than its UNSIGNED16 holds (at most "
                       f"{MAX_GRIP_FORCE_UNITS / GRIP_FORCE_PER_N:g} N)")
    if gripper.grip_force_n > gripper.max_force_n:
        raise BadInput(f"cell file {source}: gripper.grip_force_n = {gripper.grip_force_n:g} N is more than "
                       f"gripper.max_force_n = {gripper.max_force_n:g} N: connect would set the drive's force limit "
                       "0x2100 past the gripper's most, and every grip at the cell's force be refused")
    if grip_force_units(gripper.grip_force_n) < 1:
        raise BadInput(f"cell file {source}: gripper.grip_force_n = {gripper.grip_force_n:g} N is 0 in the drive's "
                       f"force limit 0x2100 (0.1 N, sent rounded): the jaws would close with no force; more than "
                       f"{0.5 / GRIP_FORCE_PER_N:g} N")


def _check_motion_within_limits(motion: Motion, scara: Scara, source: str) -> None:
    """Home and the heights the arm travels at must lie within the joint limits: the drives would
    start outside their own software limits, or the first move of a run be refused."""
    checks = [(f"home_joints.{k}", v, k) for k, v in motion.home_joints.items()]
    checks += [("safe_z_mm", motion.safe_z_mm, "j3_mm"), ("dropoff_mm z", motion.dropoff_mm[2], "j3_mm")]
    for key, v, limit in checks:
        lo, hi = scara.limits(limit[:2])
        if not lo <= v <= hi:
            raise BadInput(f"cell file {source}: motion.{key} = {v:g} is outside scara.{limit} [{lo:g}, {hi:g}]")


# A move across an axis' whole range at its cell-file speed and acceleration must end within this: 0.01 deg/s took
# the first move of `cell run` about 4000 s, with no word (a cell that seems to hang; the drives' own figures are
# degrees or mm per second by the hundred)
MAX_FULL_RANGE_MOVE_S = 60.0


def _full_range_move_s(distance: float, velocity: float, acceleration: float) -> float:
    """A trapezoid (or triangle) profile's time over `distance` (drivers.profile.trapezoid, the drives' own)."""
    if distance * acceleration >= velocity * velocity:
        return distance / velocity + velocity / acceleration
    return 2.0 * math.sqrt(distance / acceleration)


def _check_moves_end(scara: Scara, gripper: Gripper, source: str) -> None:
    """Every axis crosses its range (a revolute joint at most a turn: a wrist that turns without end is given
    limits of a million degrees) within MAX_FULL_RANGE_MOVE_S."""
    axes = [(f"scara.max_velocity.{j} = {scara.max_velocity[j]:g} and max_acceleration.{j} = "
             f"{scara.max_acceleration[j]:g}", j.upper(), scara.limits(j), scara.max_velocity[j],
             scara.max_acceleration[j], NODE_UNITS[j]) for j in JOINTS]
    axes.append((f"gripper.speed_mm_s = {gripper.speed_mm_s:g}", "the gripper", gripper.opening_mm,
                 gripper.speed_mm_s, GRIPPER_ACCEL_FACTOR * gripper.speed_mm_s, "mm"))
    for what, name, (lo, hi), v, a, unit in axes:
        distance = min(hi - lo, 360.0) if unit == "deg" else hi - lo
        t = _full_range_move_s(distance, v, a)
        if t > MAX_FULL_RANGE_MOVE_S:
            raise BadInput(f"cell file {source}: {what}: a move across {name}'s range ({distance:g} {unit}) would "
                           f"take {t:.3g} s, more than {MAX_FULL_RANGE_MOVE_S:g} s (the cell would seem to hang)")


def _check_drive_counts(scara: Scara, gripper: Gripper, nodes: dict, source: str) -> None:
    """What the drives get in counts must be sendable. Positions, speeds and accelerations are 32-bit counts (a
    joint limit of 360 deg at 1e9 counts per degree was an internal error at the first move); speeds and
    accelerations go in whole counts/s (counts/s^2) rounded down to stay within the limits, so one under a
    count would leave none to send."""
    gripper_accel = GRIPPER_ACCEL_FACTOR * gripper.speed_mm_s
    rates = [(f"scara.max_velocity.{j}", scara.max_velocity[j], j) for j in JOINTS]
    rates += [(f"scara.max_acceleration.{j}", scara.max_acceleration[j], j) for j in JOINTS]
    rates += [("gripper.speed_mm_s", gripper.speed_mm_s, "gripper"),
              (f"gripper's acceleration ({GRIPPER_ACCEL_FACTOR:g} x speed_mm_s)", gripper_accel, "gripper")]
    for key, limit, node in rates:
        if limit * nodes[node].counts_per_unit < 1:
            raise BadInput(f"cell file {source}: {key} = {limit:g} is under one count "
                           f"(can.nodes.{node}.counts_per_unit = {nodes[node].counts_per_unit:g})")
    positions = [(f"scara.{j}{'_mm' if j == 'j3' else '_deg'}", max(map(abs, scara.limits(j))), j) for j in JOINTS]
    positions += [("gripper.opening_mm", max(map(abs, gripper.opening_mm)), "gripper")]
    quick_stops = [(f"the quick stop's deceleration ({QUICK_STOP_DECEL_FACTOR:g} x {key})",
                    QUICK_STOP_DECEL_FACTOR * v, node) for key, v, node in rates if "acceleration" in key]
    # as the drivers send them: positions and the quick stop's deceleration rounded to the nearest count, so
    # half a count under the top is the top (2147483647.75 counts was an internal error at bring-up); the
    # other rates rounded down
    for values, top, kind in ((positions, 2**31 - 0.5, "INTEGER32 position"), (rates, 2**32, "UNSIGNED32 rate"),
                              (quick_stops, 2**32 - 0.5, "UNSIGNED32 rate")):
        for key, v, node in values:
            if v * nodes[node].counts_per_unit >= top:
                raise BadInput(f"cell file {source}: {key} = {v:g} is {v * nodes[node].counts_per_unit:.3g} counts "
                               f"(can.nodes.{node}.counts_per_unit = {nodes[node].counts_per_unit:g}): more than "
                               f"a drive's {kind} holds")


NOTE_KEYS = ("comment", "description", "notes")  # free text anywhere, as are keys starting with "_"


def _is_note(key) -> bool:
    """A key for people, not the cell (JSON has no comments): allowed in every object."""
    return isinstance(key, str) and (key.startswith("_") or key in NOTE_KEYS)


def _check_keys(d, where: str, source: str) -> None:
    """Refuse a key the cell file does not know, in `d` and the objects below it."""
    if not isinstance(d, dict) or where not in _KEYS:
        return  # a wrong type is reported by the reader, with the key
    unknown = sorted(k for k in set(d) - set(_KEYS[where]) if not _is_note(k))
    if unknown:
        at = f"{where}." if where else ""
        raise BadInput(f"cell file {source}: unknown key {at}{short_text(unknown[0])} (known: "
                       f"{', '.join(_KEYS[where])})")
    for k, v in d.items():
        _check_keys(v, f"{where}.{k}" if where else k, source)


class _Reader:
    """Typed access to the raw JSON with messages that name the file and the key."""

    def __init__(self, raw, source: str):
        if not isinstance(raw, dict):
            raise BadInput(f"cell file {source}: top level must be a JSON object")
        self.source = source

    def _fail(self, where: str, key: str, why: str):
        raise BadInput(f"cell file {self.source}: {where + '.' if where else ''}{key} {why}")

    def obj(self, d, key, where=""):
        v = d.get(key) if isinstance(d, dict) else None
        if not isinstance(v, dict):
            self._fail(where, key, "is missing or not an object")
        return v

    def num(self, d, key, where="", cap: float = MAX_VALUE):
        v = d.get(key)
        if not is_finite_number(v):
            self._fail(where, key, f"must be a finite number, got {short_repr(v)}")
        if abs(v) > cap:
            self._fail(where, key, f"must be within +-{cap:g}, got {v:g}")
        return float(v)

    def integer(self, d, key, where=""):
        """A whole number (1280 or 1280.0); 0.5 is not silently cut to 0."""
        v = self.num(d, key, where)
        if not v.is_integer():
            self._fail(where, key, f"must be a whole number, got {short_repr(v)}")
        return int(v)

    def count(self, d, key, where=""):
        v = self.integer(d, key, where)
        if v <= 0:
            self._fail(where, key, f"must be positive, got {short_repr(v)}")
        return v

    def pos(self, d, key, where="", cap: float = MAX_VALUE):
        v = self.num(d, key, where, cap)
        if v <= 0:
            self._fail(where, key, f"must be positive, got {short_repr(v)}")
        return v

    def flag(self, d, key, where="", *, default: bool) -> bool:
        """An optional true or false (not 1, "yes" or null: a typo must not pick a behaviour)."""
        if key not in d:
            return default
        v = d[key]
        if not isinstance(v, bool):
            self._fail(where, key, f"must be true or false, got {short_repr(v)}")
        return v

    def nonneg(self, d, key, where=""):
        v = self.num(d, key, where)
        if v < 0:
            self._fail(where, key, f"must not be negative, got {short_repr(v)}")
        return v

    def vec(self, d, key, n, where=""):
        v = d.get(key)
        if not isinstance(v, list) or len(v) != n:
            self._fail(where, key, f"must be a list of {n} numbers, got {short_repr(v)}")
        return [self.num({f"{key}[{i}]": x}, f"{key}[{i}]", where) for i, x in enumerate(v)]

    def range(self, d, key, where=""):
        lo, hi = self.vec(d, key, 2, where)
        if not lo < hi:
            self._fail(where, key, f"must be [low, high] with low < high, got {short_repr([lo, hi])}")
        return (lo, hi)

    def per_joint(self, d, key):
        o = self.obj(d, key, "scara")
        return {j: self.pos(o, j, f"scara.{key}") for j in JOINTS}
