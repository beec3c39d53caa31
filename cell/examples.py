"""Teaching examples: the operator's grasps, one JSON object per line (JSON Lines).

A line (keys marked * are required):

    {"format": "grasp-example", "version": 1,
     "id"*: "op-0007",
     "part"*: {"id", "outline", "holes", "z_bottom", "z_top", ...},   # as in a scene file
     "contacts"*: [[x, y], [x, y]],          # where the pads touched, mm, base frame
     "valid"*: true,                          # the operator accepted (true) or rejected the grasp
     "contact_valid": [true, false],          # optional per-contact verdict (a rejected grasp
                                              #   may have one good and one bad contact)
     "obstacles": [{part}, ...],              # optional: the parts around it at the time
     "grasp_z_mm": 4.0,                       # optional; finger-tip z, from the part's z_bottom to below its z_top
     "joints": {"j1_deg", "j2_deg", "j3_mm", "j4_deg"},   # optional arm configuration
     "source"*: {"kind": "simulated-operator" | "station-teach" | "station-reject" | "manual",
                 "by": "...", "at": "2026-11-23T10:00:00Z", "note": "why"}}

Files are appended atomically (`append_examples`) and validated line by line on read
(`load_examples`): a bad line is refused with its line number, never skipped silently. Refused too,
as no grasp: contacts closer than MIN_CONTACT_SEPARATION_MM, an accepted grasp with a contact marked
bad, a configuration with a revolute joint past MAX_JOINT_TURN_DEG or finger tips below the table.
Doubtful lines are read, and named in warnings (`example_doubts`): a configuration whose jaws are not
along the contacts' line (its configuration is not used), the same grasp on two lines.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from cell.errors import BadInput
from cell.fileio import (
    DuplicateKey,
    append_lines_atomic,
    has_non_number,
    is_finite_number,
    json_loads,
    read_text,
    refuse_lone_surrogates,
    short_repr,
)
from cell.kinematics import Joints, normalize_axis_deg
from cell.scene import MAX_COORD_MM, Part, parse_part

JOINT_KEYS = ("j1_deg", "j2_deg", "j3_mm", "j4_deg")

FORMAT = "grasp-example"
VERSION = 1
SOURCE_KINDS = ("simulated-operator", "station-teach", "station-reject", "manual")
# A contact further than this from the part's outline is not a contact on that part.
MAX_CONTACT_OFFSET_MM = 5.0
# Contacts closer than this are one point: the jaws would not open, no grasp of a two-jaw gripper (the
# simulated operator's smallest opening over the library is 3 mm, the shipped file's 6 mm).
MIN_CONTACT_SEPARATION_MM = 1.0
# The reader does not know the cell (`cell grasp` takes it per scene, after reading the examples): an example's
# configuration is checked against what no arm does, a shoulder, elbow or wrist past a full turn either way.
MAX_JOINT_TURN_DEG = 360.0
# The jaws close along J1 + J2 + J4 (mod 180) whatever the link lengths: an example's configuration further
# than this from its contacts' line is not that grasp's (the planner's contacts lie within 3 degrees of it).
MAX_CONFIGURATION_SKEW_DEG = 5.0
MAX_WARNINGS = 20  # per file read: the rest are counted, not listed
GRASP_Z_DECIMALS = 4  # grasp_z_mm as a line holds it (to_json); the part's z_bottom is written unrounded


def default_examples_path() -> Path:
    return Path(str(resources.files("cell") / "data" / "default_examples.jsonl"))


@dataclass(frozen=True, eq=False)
class GraspExample:
    id: str
    part: Part
    contacts_mm: np.ndarray  # (n, 2)
    valid: bool
    source: dict
    contact_valid: tuple[bool, ...] | None = None
    obstacles: tuple[Part, ...] = ()
    grasp_z_mm: float | None = None
    joints: Joints | None = None
    extra: dict = field(default_factory=dict)

    @property
    def n_contacts(self) -> int:
        return len(self.contacts_mm)

    def to_json(self) -> dict:
        d = {"format": FORMAT, "version": VERSION, "id": self.id, "part": self.part.to_json(),
             "contacts": np.round(self.contacts_mm, 4).tolist(), "valid": bool(self.valid)}
        if self.contact_valid is not None:
            d["contact_valid"] = [bool(v) for v in self.contact_valid]
        if self.obstacles:
            d["obstacles"] = [o.to_json() for o in self.obstacles]
        if self.grasp_z_mm is not None:
            d["grasp_z_mm"] = round(float(self.grasp_z_mm), GRASP_Z_DECIMALS)
        if self.joints is not None:
            d["joints"] = {k: round(v, 4) for k, v in self.joints.as_dict().items()}
        d["source"] = dict(self.source)
        d.update({k: v for k, v in self.extra.items() if k not in d})
        return d


def parse_example(raw, where: str = "example", doubts: list[str] | None = None) -> GraspExample:
    """One line's example (BadInput, naming `where`, when it is no example); what is doubtful about it but
    read goes to `doubts`, when given."""
    if not isinstance(raw, dict):
        raise BadInput(f"{where}: must be a JSON object")
    version = raw.get("version", VERSION)
    if raw.get("format", FORMAT) != FORMAT or isinstance(version, bool) or version != VERSION:
        raise BadInput(f"{where}: not a {FORMAT} v{VERSION} line (format={short_repr(raw.get('format'))}, "
                       f"version={short_repr(raw.get('version'))})")
    eid = raw.get("id")
    if not isinstance(eid, str) or not eid:
        raise BadInput(f"{where}: 'id' must be a non-empty string")
    where = f"{where} ({eid})"
    if "part" not in raw:
        raise BadInput(f"{where}: 'part' is missing")
    part = parse_part(raw["part"], f"{where}: part")
    contacts = raw.get("contacts")
    if has_non_number(contacts):
        raise BadInput(f"{where}: 'contacts' must be a list of [x, y] numbers (true/false and strings are not numbers)")
    try:
        c = np.asarray(contacts, dtype=float)
    except OverflowError:  # an integer literal too large for a float (JSON allows any length)
        raise BadInput(f"{where}: 'contacts' must be at least two finite [x, y] points (one is too large)") from None
    except (TypeError, ValueError):
        raise BadInput(f"{where}: 'contacts' must be a list of [x, y]") from None
    if c.ndim != 2 or c.shape[1] != 2 or len(c) < 2 or not np.all(np.isfinite(c)):
        raise BadInput(f"{where}: 'contacts' must be at least two finite [x, y] points")
    _refuse_one_point(c, where)
    boundary = part.polygon.boundary
    from shapely.geometry import Point

    for i, p in enumerate(c):
        d = boundary.distance(Point(p))
        if d > MAX_CONTACT_OFFSET_MM:
            raise BadInput(f"{where}: contact #{i} {p.tolist()} is {d:.1f} mm from the part's outline "
                           f"(at most {MAX_CONTACT_OFFSET_MM} mm)")
    valid = raw.get("valid")
    if not isinstance(valid, bool):
        raise BadInput(f"{where}: 'valid' must be true or false")
    cv = raw.get("contact_valid")
    if cv is not None:
        if not (isinstance(cv, list) and len(cv) == len(c) and all(isinstance(v, bool) for v in cv)):
            raise BadInput(f"{where}: 'contact_valid' must be one true/false per contact")
        cv = tuple(cv)
        if valid and not all(cv):  # tree 1 would learn the contacts bad and tree 2 the set good
            raise BadInput(f"{where}: an accepted grasp ('valid': true) with a contact marked bad ('contact_valid' "
                           f"{json.dumps(list(cv))}) contradicts itself: reject the grasp or mark its contacts good")
    obstacles = raw.get("obstacles", [])
    if not isinstance(obstacles, list):
        raise BadInput(f"{where}: 'obstacles' must be a list of parts")
    obs = tuple(parse_part(o, f"{where}: obstacle #{i}") for i, o in enumerate(obstacles))
    gz = raw.get("grasp_z_mm")
    if gz is not None and (not is_finite_number(gz) or abs(gz) > MAX_COORD_MM):
        raise BadInput(f"{where}: 'grasp_z_mm' must be a number of mm within {MAX_COORD_MM:g}")
    # The finger tips go no lower than the part rests (CONTRACT: z_bottom <= grasp z), and never into the table
    # (parse_part keeps z_bottom >= 0). Compared as the line holds it: a z the station took at z_bottom is not
    # below it once rounded
    if gz is not None and gz < round(part.z_bottom_mm, GRASP_Z_DECIMALS):
        below = ("the table (z = 0 in the base frame)" if gz < 0
                 else f"the part's bottom (z_bottom {part.z_bottom_mm:g})")
        raise BadInput(f"{where}: 'grasp_z_mm' {gz:g} mm puts the finger tips below {below}: no grasp goes there")
    if gz is not None and gz >= round(part.z_top_mm, GRASP_Z_DECIMALS):  # the pads, above the tips, hold nothing
        raise BadInput(f"{where}: 'grasp_z_mm' {gz:g} mm puts the finger tips at or above the part's top "
                       f"(z_top {part.z_top_mm:g}): the pads would hold nothing")
    joints = raw.get("joints")
    if joints is not None:
        if isinstance(joints, dict) and has_non_number([joints.get(k, 0) for k in JOINT_KEYS]):
            raise BadInput(f"{where}: 'joints' must have numbers j1_deg, j2_deg, j3_mm, j4_deg (true/false and "
                           "strings are not numbers)")
        try:
            joints = Joints.from_dict(joints)
        except OverflowError:  # an integer literal too large for a float
            raise BadInput(f"{where}: 'joints' must be finite") from None
        except (KeyError, TypeError, ValueError):
            raise BadInput(f"{where}: 'joints' must have numbers j1_deg, j2_deg, j3_mm, j4_deg") from None
        if not all(math.isfinite(v) for v in joints.as_array()):
            raise BadInput(f"{where}: 'joints' must be finite")
        if max(abs(v) for v in joints.as_array()) > MAX_COORD_MM:  # 1e308 deg overflowed step 5's distances
            raise BadInput(f"{where}: 'joints' must be within {MAX_COORD_MM:g} (deg, mm)")
        _refuse_no_arm(joints, where)
    source = raw.get("source")
    if not isinstance(source, dict) or source.get("kind") not in SOURCE_KINDS:
        raise BadInput(f"{where}: 'source' must be an object with 'kind' one of {', '.join(SOURCE_KINDS)}")
    known = {"format", "version", "id", "part", "contacts", "valid", "contact_valid", "obstacles",
             "grasp_z_mm", "joints", "source"}
    extra = {k: v for k, v in raw.items() if k not in known}
    if joints is not None and len(c) == 2:
        skew = _configuration_skew_deg(c, joints)
        if skew > MAX_CONFIGURATION_SKEW_DEG:
            if doubts is not None:
                axis_deg = normalize_axis_deg(joints.j1_deg + joints.j2_deg + joints.j4_deg)
                doubts.append(f"'joints' close the jaws along {axis_deg:.1f} deg (J1 + J2 + J4), {skew:.1f} deg "
                              f"off the contacts' line (at most {MAX_CONFIGURATION_SKEW_DEG:g}): not this grasp's "
                              "configuration; step 5 does not use it")
            extra["joints"], joints = raw["joints"], None  # kept as written: to_json gives the line back
    return GraspExample(eid, part, c, valid, dict(source), cv, obs,
                        None if gz is None else float(gz), joints, extra)


def _refuse_one_point(c: np.ndarray, where: str) -> None:
    gaps = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2) + np.diag(np.full(len(c), np.inf))
    i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
    if gaps[i, j] < MIN_CONTACT_SEPARATION_MM:
        raise BadInput(f"{where}: contacts #{min(i, j)} and #{max(i, j)} are {gaps[i, j]:.2f} mm apart (at least "
                       f"{MIN_CONTACT_SEPARATION_MM:g} mm): one point, the jaws would not open; no grasp")


def _refuse_no_arm(j: Joints, where: str) -> None:
    turned = [f"{k} = {v:g}" for k, v in (("j1_deg", j.j1_deg), ("j2_deg", j.j2_deg), ("j4_deg", j.j4_deg))
              if abs(v) > MAX_JOINT_TURN_DEG]
    if turned:
        raise BadInput(f"{where}: 'joints' {', '.join(turned)}: no arm turns a joint past {MAX_JOINT_TURN_DEG:g} deg "
                       "either way")
    if j.j3_mm < 0:
        raise BadInput(f"{where}: 'joints' j3_mm = {j.j3_mm:g} puts the finger tips below the table (z = 0)")


def _configuration_skew_deg(c: np.ndarray, j: Joints) -> float:
    """Degrees between the jaws' closing axis in `j` and the line through the two contacts (mod 180)."""
    line_deg = math.degrees(math.atan2(c[1, 1] - c[0, 1], c[1, 0] - c[0, 0]))
    return abs((j.j1_deg + j.j2_deg + j.j4_deg - line_deg + 90.0) % 180.0 - 90.0)


def print_warning(message: str) -> None:
    print(f"cell: warning: {message}", file=sys.stderr)


def load_examples(path: str | Path | None = None, *, allow_empty: bool = False,
                  warn: Callable[[str], None] | None = None) -> list[GraspExample]:
    """Read and validate an example file (None: the shipped default); its doubtful lines to `warn`, when given."""
    path = Path(path) if path is not None else default_examples_path()
    doubts: list[str] | None = [] if warn else None
    examples = _parse_examples(read_text(path, "example file"), path, allow_empty, doubts)
    for message in (doubts or ())[:MAX_WARNINGS]:
        warn(message)
    if doubts and len(doubts) > MAX_WARNINGS:
        warn(f"example file {path}: {len(doubts) - MAX_WARNINGS} more doubtful lines like these (not listed)")
    return examples


def load_planner_examples(path: str | Path | None = None,
                          warn: Callable[[str], None] | None = print_warning) -> list[GraspExample]:
    """`load_examples` for a planner, its warnings on stderr: refused, naming the file, without an accepted
    grasp (the planner refuses them too, but knows no file to name)."""
    path = Path(path) if path is not None else default_examples_path()
    examples = load_examples(path, warn=warn)
    if not any(ex.valid for ex in examples):
        raise BadInput(f"example file {path} holds no accepted grasp (all {len(examples)} were rejected): the "
                       "planner needs at least one to imitate")
    return examples


def _parse_examples(text: str, path: Path, allow_empty: bool, doubts: list[str] | None = None) -> list[GraspExample]:
    out: list[GraspExample] = []
    lines: list[int] = []
    seen: set[str] = set()
    # split at newlines only: str.splitlines() also splits at U+2028, U+0085, ..., which a JSON string may hold
    for lineno, line in enumerate(text.split("\n"), 1):
        if not line.strip():
            continue
        try:
            raw = json_loads(line)
        except json.JSONDecodeError as e:
            raise BadInput(f"example file {path} line {lineno}: not valid JSON ({e.msg})") from None
        except DuplicateKey as e:
            raise BadInput(f"example file {path} line {lineno}: {e}") from None
        except RecursionError:  # json's decoder recurses per nesting level: [[[[...]]]] 100000 deep
            raise BadInput(f"example file {path} line {lineno}: not valid JSON (nested too deeply)") from None
        refuse_lone_surrogates(line, raw, f"example file {path} line {lineno}")
        where, line_doubts = f"example file {path} line {lineno}", []
        ex = parse_example(raw, where, line_doubts)
        if ex.id in seen:
            raise BadInput(f"example file {path} line {lineno}: duplicate example id {ex.id!r}")
        seen.add(ex.id)
        out.append(ex)
        lines.append(lineno)
        if doubts is not None:
            doubts.extend(f"{where} ({ex.id}): {d}" for d in line_doubts)
    if not out and not allow_empty:
        raise BadInput(f"example file {path} holds no examples: the planner learns only from examples")
    if doubts is not None:
        from cell.example_doubts import same_grasp_doubts

        doubts.extend(same_grasp_doubts(out, lines, f"example file {path}"))
    return out


def examples_appended_to(old: bytes, path: Path) -> list[GraspExample]:
    """The examples of a file to append to (it may be empty); BadInput where it is not a valid example file."""
    try:
        text = old.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise BadInput(f"example file {path} cannot be read: {e}") from None
    return _parse_examples(text, path, allow_empty=True)


def append_examples(path: str | Path, examples: list[GraspExample]) -> None:
    """Append examples atomically (ids must be new in the file)."""
    path = Path(path)
    for e in examples:  # refuse a line that load_examples would refuse: it would lock the whole file
        parse_example(e.to_json(), f"new example {e.id}")
    def check(old: bytes) -> None:  # under the file's lock: a concurrent appender's ids are in `old`
        existing = {e.id for e in examples_appended_to(old, path)}
        for e in examples:
            if e.id in existing:
                raise BadInput(f"example id {e.id!r} is already in {path}")
            existing.add(e.id)

    if path.is_dir():
        raise BadInput(f"example file {path} is a directory, not a file")
    append_lines_atomic(path, [json.dumps(e.to_json(), separators=(",", ":")) for e in examples], check)


