"""Read validation no test pinned before: calibration files (version, rotation, homography,
NaN and Infinity, shapes) and teaching-example files (duplicate ids, wrong types and counts,
format and version, appends that would make the file unloadable, files that are not regular
files). Each is refused with an error that names the problem, and through the CLI with exit 2,
one line on stderr and no traceback."""

import json
import re
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from conftest import ROOT, run_cli
from test_calibration_file import _homography_file, _write
from test_fileio_atomic import _names, _sparse, fifo  # noqa: F401 - the fifo fixture
from test_files import SQUARE, _example

from calibration import default_calibration_path, load_calibration
from cell.cellconfig import default_cell
from cell.errors import BadInput
from cell.examples import append_examples, load_examples
from cell.grasp.height import grasp_z_mm
from cell.kinematics import Joints
from cell.scene import parse_part

NAN, INF = float("nan"), float("inf")
DROP = object()  # in an edit: remove the key


def _refused_by_the_cli(argv, capsys, *needles):
    """`cell ARGV` exits 2 with one line on stderr holding every needle, nothing on stdout."""
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and out == "" and "Traceback" not in err, (code, out, err)
    assert err.startswith("cell: error: ") and err.count("\n") == 1, err
    for needle in needles:
        assert str(needle) in err, (needle, err)


# --- calibration files ----------------------------------------------------------------------------


def _pose_file(tmp_path, edit):
    d = json.loads(default_calibration_path().read_text())
    edit(d)
    return _write(tmp_path, d)  # json.dumps writes NaN and Infinity as the tokens Python reads back


def _set(*keys_and_value):
    """An edit that sets d[k1][k2]...[kn] = value (DROP: removes d[k1]...[kn])."""
    *keys, last, value = keys_and_value

    def edit(d):
        for k in keys:
            d = d[k]
        if value is DROP:
            d.pop(last)
        else:
            d[last] = value
    return edit


def _rotation(transform):
    def edit(d):
        m = np.array(d["pose"]["cam2base"])
        m[:3, :3] = transform(m[:3, :3])
        d["pose"]["cam2base"] = m.tolist()
    return edit


NOT_A_ROTATION = "pose.cam2base rotation part is not a rotation matrix"
POSE_CASES = [
    ("version-0", _set("version", 0),
     "version 0 is not supported (this program reads version 1, and 2 for a tilted plane)"),
    ("version-true", _set("version", True), "'version' must be an integer, got true"),  # true == 1 in Python
    ("version-1.0", _set("version", 1.0), "'version' must be an integer, got 1.0"),
    ("version-string", _set("version", "1"), "'version' must be an integer, got '1'"),
    ("version-missing", _set("version", DROP), "'version' must be an integer, got null"),
    # orthonormal, det -1: a mirror image, not a camera pose
    ("cam2base-reflection", _rotation(lambda r: r * [-1, 1, 1]), NOT_A_ROTATION),
    ("cam2base-minus-rotation", _rotation(lambda r: -r), NOT_A_ROTATION),
    ("cam2base-last-row", _set("pose", "cam2base", 3, 2, 0.5), "pose.cam2base last row must be [0, 0, 0, 1]"),
    ("cam2base-nan", _set("pose", "cam2base", 0, 3, NAN), "pose.cam2base must be a 4 x 4 list of finite numbers"),
    ("cam2base-infinity", _set("pose", "cam2base", 1, 3, INF), "pose.cam2base must be a 4 x 4 list of finite numbers"),
    ("cam2base-3x4", lambda d: d["pose"]["cam2base"].pop(), "pose.cam2base must be a 4 x 4 list of finite numbers"),
    ("cam2base-flat-16", lambda d: d["pose"].update(cam2base=sum(d["pose"]["cam2base"], [])),
     "pose.cam2base must be a 4 x 4 list of finite numbers"),
    ("cam2base-ragged", lambda d: d["pose"]["cam2base"][2].pop(), "pose.cam2base must be a 4 x 4 list of numbers"),
    ("cam2base-missing", _set("pose", "cam2base", DROP), "pose.cam2base must be a 4 x 4 list of finite numbers"),
    ("plane-z-nan", _set("pose", "plane_z_mm", NAN), "pose.plane_z_mm must be a finite number, got NaN"),
    ("fx-nan", _set("intrinsics", "fx", NAN), "intrinsics.fx must be a finite number, got NaN"),
    ("cy-infinity", _set("intrinsics", "cy", INF), "intrinsics.cy must be a finite number, got Infinity"),
    ("dist-nan", _set("intrinsics", "dist", 0, NAN), "intrinsics.dist must be a finite number, got NaN"),
]

SINGULAR = "homography.px_to_mm is singular (or too badly conditioned to invert)"
NOT_3X3 = "homography.px_to_mm must be a 3 x 3 list of finite numbers"
HOMOGRAPHY_CASES = [
    ("rank-2", [[1, 2, 3], [2, 4, 6], [0, 0, 1]], SINGULAR),
    ("all-zero", [[0, 0, 0]] * 3, SINGULAR),
    ("condition-1e13", [[1, 0, 0], [0, 1e-13, 0], [0, 0, 1]], SINGULAR),
    ("nan", [[NAN, 0, 0], [0, 1, 0], [0, 0, 1]], NOT_3X3),
    ("infinity", [[1, 0, INF], [0, 1, 0], [0, 0, 1]], NOT_3X3),
    ("minus-infinity", [[1, 0, 0], [0, 1, 0], [0, 0, -INF]], NOT_3X3),
    ("2x2", [[1, 0], [0, 1]], NOT_3X3),
    ("3x4", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], NOT_3X3),
    ("flat-9", [1, 0, 0, 0, 1, 0, 0, 0, 1], NOT_3X3),
    ("ragged", [[1, 0, 0], [0, 1], [0, 0, 1]], "homography.px_to_mm must be a 3 x 3 list of numbers"),
    ("null", None, NOT_3X3),
]


def _calibration_case(tmp_path, which, change):
    return _pose_file(tmp_path, change) if which == "pose" else _homography_file(tmp_path, change)


@pytest.mark.parametrize("which, change, message",
                         [pytest.param("pose", e, m, id=i) for i, e, m in POSE_CASES]
                         + [pytest.param("homography", h, m, id=f"homography-{i}") for i, h, m in HOMOGRAPHY_CASES])
def test_a_bad_calibration_is_refused_naming_the_problem(tmp_path, capsys, which, change, message):
    path = _calibration_case(tmp_path, which, change)
    with pytest.raises(BadInput, match=f"^{re.escape(f'calibration file {path}: {message}')}$"):
        load_calibration(path)
    _refused_by_the_cli(("map", path, "--px", "1,2"), capsys, path, message)


@pytest.mark.parametrize("h", [[[0.5, 0, 100], [0, -0.5, 200], [0, 0, 1]],
                               [[1, 0, 0], [0, -1e-11, 0], [0, 0, 1]]],  # condition 1e11: under the 1e12 limit
                         ids=["plain", "condition-1e11"])
def test_a_well_conditioned_homography_is_read(tmp_path, capsys, h):
    path = _homography_file(tmp_path, h)
    assert np.allclose(load_calibration(path).homography, h)
    code, out, _ = run_cli("map", path, "--px", "1,2", "--json", capsys=capsys)
    assert code == 0 and len(json.loads(out)["mm"]) == 1


def test_the_default_pose_with_its_rotation_turned_is_read(tmp_path):
    # the rotation check refuses mirror images, not poses: the same camera turned 90 degrees about z
    turn = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    cal = load_calibration(_pose_file(tmp_path, _rotation(lambda r: turn @ r)))
    assert np.linalg.det(cal.cam2base[:3, :3]) == pytest.approx(1.0)


# --- teaching-example files -----------------------------------------------------------------------


def _edit(**changes):
    """An edit of an example line's JSON: set keys (DROP: remove the key)."""
    def edit(d):
        for k, v in changes.items():
            if v is DROP:
                d.pop(k)
            else:
                d[k] = v
    return edit


BOOL_MEANT = "'valid' must be true or false"
TWO_POINTS = "'contacts' must be at least two finite [x, y] points"
PER_CONTACT = "'contact_valid' must be one true/false per contact"
EXAMPLE_CASES = [
    # (id, edit of line 2's JSON, what the message says after "example file PATH line 2")
    ("duplicate-id", _edit(id="a"), ": duplicate example id 'a'"),
    ("valid-string-yes", _edit(valid="yes"), f" (b): {BOOL_MEANT}"),
    ("valid-1", _edit(valid=1), f" (b): {BOOL_MEANT}"),
    ("valid-null", _edit(valid=None), f" (b): {BOOL_MEANT}"),
    ("one-contact", _edit(contacts=[[300, 20]]), f" (b): {TWO_POINTS}"),
    ("no-contacts", _edit(contacts=[]), f" (b): {TWO_POINTS}"),
    ("contacts-missing", _edit(contacts=DROP), f" (b): {TWO_POINTS}"),
    ("contacts-3d", _edit(contacts=[[300, 20, 0], [340, 20, 0]]), f" (b): {TWO_POINTS}"),
    ("contact-nan", _edit(contacts=[[NAN, 20], [340, 20]]), f" (b): {TWO_POINTS}"),
    ("contact-infinity", _edit(contacts=[[300, 20], [340, -INF]]), f" (b): {TWO_POINTS}"),
    ("contact-null", _edit(contacts=[[None, 20], [340, 20]]), f" (b): {TWO_POINTS}"),
    # [340, true] would be read as (340, 1): a point on the square's edge
    ("contact-true", _edit(contacts=[[340, True], [300, 20]]),
     " (b): 'contacts' must be a list of [x, y] numbers (true/false and strings are not numbers)"),
    ("contact-object", _edit(contacts=[{"x": 300, "y": 20}, [340, 20]]), " (b): 'contacts' must be a list of [x, y]"),
    ("contact_valid-short", _edit(contact_valid=[True]), f" (b): {PER_CONTACT}"),
    ("contact_valid-long", _edit(contact_valid=[True, False, True]), f" (b): {PER_CONTACT}"),
    ("contact_valid-numbers", _edit(contact_valid=[1, 0]), f" (b): {PER_CONTACT}"),
    ("contact_valid-strings", _edit(contact_valid=["yes", "no"]), f" (b): {PER_CONTACT}"),
    ("format-unknown", _edit(format="grasp-example-v2"),
     ": not a grasp-example v1 line (format='grasp-example-v2', version=1)"),
    ("format-null", _edit(format=None), ": not a grasp-example v1 line (format=null, version=1)"),
    ("version-2", _edit(version=2), ": not a grasp-example v1 line (format='grasp-example', version=2)"),
    ("version-0", _edit(version=0), ": not a grasp-example v1 line (format='grasp-example', version=0)"),
    # a bool is not a version, though True == 1 (calibration and cell files refuse it too)
    ("version-true", _edit(version=True), ": not a grasp-example v1 line (format='grasp-example', version=true)"),
    # integer literals no float holds, and numbers no arm has: were internal errors (OverflowError) or, for
    # 1e308 deg, overflow warnings in step 5's joint distances
    ("contact-huge-integer", _edit(contacts=[[10**400, 20], [340, 20]]), f" (b): {TWO_POINTS} (one is too large)"),
    ("grasp_z-huge-integer", _edit(grasp_z_mm=10**400), " (b): 'grasp_z_mm' must be a number of mm within 1e+06"),
    ("grasp_z-1e308", _edit(grasp_z_mm=1e308), " (b): 'grasp_z_mm' must be a number of mm within 1e+06"),
    ("joints-huge-integer", _edit(joints={"j1_deg": 10**400, "j2_deg": 0, "j3_mm": 0, "j4_deg": 0}),
     " (b): 'joints' must be finite"),
    ("joints-1e308", _edit(joints={"j1_deg": 0, "j2_deg": 0, "j3_mm": 0, "j4_deg": 1e308}),
     " (b): 'joints' must be within 1e+06 (deg, mm)"),
    # lines that contradict themselves or are no grasp of two jaws: were read and taught (an accepted grasp with
    # both contacts bad made tree 1 refuse every point; two contacts at one point taught a zero opening)
    ("accepted-with-a-bad-contact", _edit(contact_valid=[True, False]),
     " (b): an accepted grasp ('valid': true) with a contact marked bad ('contact_valid' [true, false]) "
     "contradicts itself"),
    ("contacts-at-one-point", _edit(contacts=[[300, 20], [300, 20]]),
     " (b): contacts #0 and #1 are 0.00 mm apart (at least 1 mm): one point, the jaws would not open"),
    ("contacts-0.9-mm-apart", _edit(contacts=[[300, 20], [300, 20.9]]), " (b): contacts #0 and #1 are 0.90 mm apart"),
    ("contacts-three-two-at-one-point", _edit(contacts=[[300, 20], [340, 20], [340.5, 20]]),
     " (b): contacts #1 and #2 are 0.50 mm apart"),
    # configurations no arm takes (the reader does not know the cell: a full turn either way is the bound)
    ("joints-past-a-turn", _edit(joints={"j1_deg": 900, "j2_deg": -700, "j3_mm": 5, "j4_deg": 3000}),
     " (b): 'joints' j1_deg = 900, j2_deg = -700, j4_deg = 3000: no arm turns a joint past 360 deg either way"),
    ("joints-j4-360.5", _edit(joints={"j1_deg": 0, "j2_deg": 0, "j3_mm": 5, "j4_deg": -360.5}),
     " (b): 'joints' j4_deg = -360.5: no arm"),
    ("joints-tips-below-the-table", _edit(joints={"j1_deg": 0, "j2_deg": 0, "j3_mm": -0.1, "j4_deg": 0}),
     " (b): 'joints' j3_mm = -0.1 puts the finger tips below the table (z = 0)"),
    # finger tips no grasp can have: were accepted and taught
    ("grasp_z-below-the-table", _edit(grasp_z_mm=-0.5),
     " (b): 'grasp_z_mm' -0.5 mm puts the finger tips below the table (z = 0 in the base frame)"),
    ("grasp_z-below-the-part", lambda d: d.update(grasp_z_mm=4.0, part={**d["part"], "z_bottom": 5.0, "z_top": 15.0}),
     " (b): 'grasp_z_mm' 4 mm puts the finger tips below the part's bottom (z_bottom 5)"),
    ("grasp_z-at-the-top", lambda d: d.update(grasp_z_mm=15.0, part={**d["part"], "z_bottom": 5.0, "z_top": 15.0}),
     " (b): 'grasp_z_mm' 15 mm puts the finger tips at or above the part's top (z_top 15): the pads would hold"),
]


def _example_file(tmp_path, edit):
    """Line 1 a good example 'a', line 2 example 'b' with `edit` applied to its JSON."""
    bad = _example("b").to_json()
    edit(bad)
    path = tmp_path / "ex.jsonl"
    path.write_text(json.dumps(_example("a").to_json()) + "\n" + json.dumps(bad) + "\n")
    return path


def _case_ids(cases):
    return [c.id if hasattr(c, "id") else c[0] for c in cases]


@pytest.mark.parametrize("case, edit, message", EXAMPLE_CASES, ids=_case_ids(EXAMPLE_CASES))
def test_a_bad_example_line_is_refused_naming_file_and_line(tmp_path, capsys, case, edit, message):
    path = _example_file(tmp_path, edit)
    where = f"example file {path} line 2{message}"
    with pytest.raises(BadInput, match="^" + re.escape(where)):
        load_examples(path)
    _refused_by_the_cli(("rules", "--examples", path), capsys, where)


def test_cell_grasp_refuses_a_bad_example_file_naming_file_and_line(tmp_path, capsys):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"units": "mm", "parts": [{"id": "sq", "outline": SQUARE, "z_top": 10}],
                                 "target": "sq"}))
    path = _example_file(tmp_path, _edit(valid="yes"))
    _refused_by_the_cli(("grasp", scene, "--examples", path), capsys, f"example file {path} line 2 (b): {BOOL_MEANT}")


def test_three_contacts_are_refused_by_the_two_jaw_gripper(tmp_path, capsys):
    # a line with three contacts (and a verdict for each) is a valid line; the planner, whose
    # gripper has two jaws, refuses it when it learns, naming the example
    path = _example_file(tmp_path, _edit(contacts=[[300, 20], [340, 20], [320, 0]],
                                         contact_valid=[True, True, True]))
    assert [e.n_contacts for e in load_examples(path)] == [2, 3]
    _refused_by_the_cli(("rules", "--examples", path), capsys, "example 'b' has 3 contacts")


# --- appends that would make the file unloadable ---------------------------------------------------


def _off_the_part(e):
    return replace(e, contacts_mm=np.array([[100.0, 100.0], [340.0, 20.0]]))


APPEND_CASES = [
    ("id-already-in-the-file", lambda: [_example("a")], "example id 'a' is already in"),
    ("id-twice-in-the-batch", lambda: [_example("n"), _example("n")], "example id 'n' is already in"),
    ("contact-off-the-part", lambda: [_off_the_part(_example("n"))],
     "contact #0 [100.0, 100.0] is 208.8 mm from the part's outline"),
    ("one-contact", lambda: [replace(_example("n"), contacts_mm=np.array([[300.0, 20.0]]))], TWO_POINTS),
    ("contact_valid-wrong-length", lambda: [replace(_example("n"), contact_valid=(True,))], PER_CONTACT),
    ("unknown-source-kind", lambda: [replace(_example("n"), source={"kind": "robot"})], "'source' must be an object"),
    ("grasp_z-nan", lambda: [replace(_example("n"), grasp_z_mm=NAN)], "'grasp_z_mm' must be a number"),
    ("joints-nan", lambda: [replace(_example("n"), joints=Joints(NAN, 0.0, 0.0, 0.0))], "'joints' must be finite"),
    ("grasp_z-below-the-table", lambda: [replace(_example("n"), grasp_z_mm=-1.0)], "below the table"),
    # all or nothing: the good example before the bad one is not written either
    ("good-then-bad", lambda: [_example("n"), _off_the_part(_example("m"))], "new example m"),
]


@pytest.mark.parametrize("case, new, message", APPEND_CASES, ids=_case_ids(APPEND_CASES))
def test_an_append_that_would_make_the_file_unloadable_is_refused_before_writing(tmp_path, case, new, message):
    path = tmp_path / "ex.jsonl"
    append_examples(path, [_example("a"), _example("b")])
    before, inode = path.read_bytes(), path.stat().st_ino
    with pytest.raises(BadInput, match=re.escape(message)):
        append_examples(path, new())
    assert path.read_bytes() == before and path.stat().st_ino == inode  # not even rewritten
    assert _names(tmp_path) == ["ex.jsonl"]  # no temp file left
    assert [e.id for e in load_examples(path)] == ["a", "b"]


def test_a_grasp_z_at_the_parts_bottom_is_kept(tmp_path):
    """CONTRACT's lowest grasp z is z_bottom itself (the station takes it for a part under 2 mm tall): the
    line's 4 decimals must not put it below a z_bottom written with more."""
    part = parse_part({"id": "shim", "outline": SQUARE, "z_bottom": 0.12344, "z_top": 1.5})
    z = grasp_z_mm(part.z_bottom_mm, part.z_top_mm, default_cell().gripper)
    assert z == part.z_bottom_mm
    path = tmp_path / "ex.jsonl"
    append_examples(path, [replace(_example("n"), part=part, grasp_z_mm=z), replace(_example("m"), grasp_z_mm=0.0)])
    assert [e.grasp_z_mm for e in load_examples(path)] == [0.1234, 0.0]


def test_an_append_to_a_file_that_is_already_unloadable_is_refused(tmp_path):
    # appending would bury the bad line under good ones; the file is left for the user to mend
    path = tmp_path / "ex.jsonl"
    path.write_text(json.dumps(_example("a").to_json()) + "\n{broken\n")
    before = path.read_bytes()
    with pytest.raises(BadInput, match=re.escape(f"example file {path} line 2: not valid JSON")):
        append_examples(path, [_example("n")])
    assert path.read_bytes() == before and _names(tmp_path) == ["ex.jsonl"]


# --- example files that are not regular files (known bugs) -------------------------------------------

def test_an_example_file_that_is_a_fifo_is_refused(fifo):  # noqa: F811 - the imported fixture
    # (it was read like a file: the read blocked until the fixture's helper opened and closed the FIFO)
    with pytest.raises(BadInput, match="is not a regular file"):
        load_examples(fifo)


def test_examples_are_not_appended_to_a_fifo(fifo):  # noqa: F811 - the imported fixture
    # (the appender read the FIFO like a file, then replaced it with a regular file)
    import stat

    with pytest.raises(BadInput, match="is not a regular file"):
        append_examples(fifo, [_example("a")])
    assert stat.S_ISFIFO(fifo.stat().st_mode)


# The child maps the planner's libraries first, then may take 512 MB more: were a file read, it
# would get a MemoryError there, not fill the machine's memory. It runs `cell rules --examples P`
# for each path P and prints [[exit code, stderr], ...].
CHILD = """
import contextlib, io, json, resource, sys
from cell.cli import main
import cell.commands.rules, cell.grasp.synthesis  # noqa: F401
vm = next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith("VmSize:"))
resource.setrlimit(resource.RLIMIT_AS, (vm + 2**29,) * 2)
runs = []
for path in sys.argv[1:]:
    with contextlib.redirect_stderr(io.StringIO()) as err:
        runs.append([main(["rules", "--examples", path]), err.getvalue()])
print(json.dumps(runs))
"""


def test_an_example_file_too_big_to_read_is_exit_2(tmp_path):
    big = _sparse(tmp_path / "big.jsonl", 2 * 2**30)
    done = subprocess.run([sys.executable, "-c", CHILD, "/dev/zero", str(big)], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    (zero_code, zero_err), (big_code, big_err) = json.loads(done.stdout)
    assert (zero_code, big_code) == (2, 2), (zero_err, big_err)  # it was 1, 1: "internal error: MemoryError"
    assert "example file /dev/zero is not a regular file" in zero_err
    assert f"example file {big} is 2048 MB: more than the 256 MB" in big_err
