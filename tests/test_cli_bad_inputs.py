"""Bad inputs found by fuzzing the command line (a driver writing damaged files and running `cell ...`):
each is refused with exit 2 and one `cell: error:` line naming the file, never an internal error."""

import json

import pytest
from conftest import run_cli
from test_files import _example

from cell.examples import load_examples

DEEP = "[" * 100000 + "]" * 100000  # json's decoder recurses per level: RecursionError
DEEP_OBJECT = '{"a":' * 50000 + "1" + "}" * 50000


@pytest.mark.parametrize("line", [DEEP, DEEP_OBJECT], ids=["array", "object"])
def test_an_example_line_nested_too_deeply_is_bad_input(tmp_path, capsys, line):
    """Was: internal error (RecursionError), exit 1."""
    path = tmp_path / "ex.jsonl"
    path.write_text(json.dumps(_example("a").to_json()) + "\n" + line + "\n")
    code, out, err = run_cli("rules", "--examples", path, capsys=capsys)
    assert code == 2 and out == "" and "internal error" not in err, err
    assert err.strip() == f"cell: error: example file {path} line 2: not valid JSON (nested too deeply)"


def test_an_example_line_holding_an_integer_of_too_many_digits_is_bad_input(tmp_path, capsys):
    """Was: internal error (ValueError: Exceeds the limit (4300 digits) for integer string conversion), exit 1."""
    path = tmp_path / "ex.jsonl"
    big = json.dumps(_example("b").to_json())
    big = '{"grasp_z_mm": ' + "9" * 5000 + ", " + big[1:]
    path.write_text(json.dumps(_example("a").to_json()) + "\n" + big + "\n")
    code, out, err = run_cli("rules", "--examples", path, capsys=capsys)
    assert code == 2 and out == "", err
    assert err.strip() == (f"cell: error: example file {path} line 2: not valid JSON (a number too large: "
                           "5000 digits, at most 4300)")


@pytest.mark.parametrize("command", [["grasp"], ["plan"], ["run"], ["grasp", "SIMPLE", "--cell"],
                                     ["run", "--cell"]])
def test_a_json_integer_of_too_many_digits_is_bad_input(tmp_path, capsys, command):
    """A scene, assembly or cell file with an integer of 5000 digits: was an internal error (json.loads' plain
    ValueError), exit 1."""
    simple = tmp_path / "simple.json"
    simple.write_text(json.dumps({"units": "mm", "parts": [{"id": "box", "outline": [[330, -20], [370, -20],
                                  [370, 20], [330, 20]], "z_bottom": 0, "z_top": 12}], "target": "box"}))
    path = tmp_path / "big.json"
    path.write_text('{"units": "mm", "parts": [{"id": "a", "outline": [[' + "9" * 5000 + ", -20]]}]}")
    args = [simple if a == "SIMPLE" else a for a in command]
    code, out, err = run_cli(*args, path, capsys=capsys)
    assert code == 2 and "internal error" not in err, err
    assert f"{path} is not valid JSON: a number too large: 5000 digits, at most 4300 at line 1 column 52" in err


@pytest.mark.parametrize("char", ["\u2028", "\u2029", "\x85"])
def test_an_example_line_holding_a_unicode_line_separator_is_one_line(tmp_path, char):
    """JSON strings may hold U+2028, U+2029 and U+0085 unescaped; str.splitlines() cut the line there and
    the file was refused as 'not valid JSON (Unterminated string ...)'."""
    a = _example("a").to_json()
    a["source"]["note"] = f"held{char}here"
    path = tmp_path / "ex.jsonl"
    path.write_text(json.dumps(a, ensure_ascii=False) + "\r\n" + json.dumps(_example("b").to_json()) + "\n",
                    encoding="utf-8")
    got = load_examples(path)
    assert [e.id for e in got] == ["a", "b"] and got[0].source["note"] == f"held{char}here"


def test_min_area_mm2_without_a_calibration_is_bad_input(tmp_path, capsys):
    """It was ignored without a word (the regions were filtered by the pixel default), exit 0."""
    import cv2
    import numpy as np

    cv2.imwrite(str(tmp_path / "f.png"), np.full((64, 80, 3), 200, np.uint8))
    code, out, err = run_cli("segment", tmp_path / "f.png", "--min-area-mm2", "10", "--json", capsys=capsys)
    assert code == 2 and out == "" and "--min-area-mm2 is an area on the table: it needs --calibration" in err, err


def _points(uv_mm):
    return {"points": [{"px": list(px), "mm": list(mm)} for px, mm in uv_mm]}


GRID = [((100 * i + 50, 80 * j + 40), (200 + 10 * i, -50 + 10 * j, 0)) for i in range(3) for j in range(3)]


@pytest.mark.parametrize("points, message", [
    # integer literals no float holds: were internal errors (OverflowError)
    (_points([((10**400, 40), (200, -50, 0))] + GRID[1:]), "point #0 needs 'px': [u, v] and 'mm': [x, y, z] "
                                                            "(finite numbers; one is too large)"),
    (_points(GRID[:8] + [((250, 200), (10**400, 0, 0))]), "point #8 needs 'px'"),
    (_points(GRID[:8] + [((250, 200), (1e300, 0, 0))]), "point #8 'mm' must be within 1e+06 mm of the base"),
])
def test_calibrate_plane_refuses_points_no_float_or_table_holds(tmp_path, capsys, points, message):
    import cv2
    import numpy as np

    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((480, 640, 3), np.uint8))
    (tmp_path / "p.json").write_text(json.dumps(points))
    code, out, err = run_cli("calibrate", "plane", tmp_path / "f.png", "--points", tmp_path / "p.json", "--out",
                             tmp_path / "o.json", capsys=capsys)
    assert code == 2 and out == "" and message in err and "internal error" not in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "o.json").exists()


def _asm(tmp_path, **first_part_keys):
    from cell.runtime.session import default_assembly_path

    raw = json.loads(default_assembly_path().read_text())
    raw["parts"][0].update(first_part_keys)
    path = tmp_path / "asm.json"
    path.write_text(json.dumps(raw))
    return path, raw["parts"][0]["id"]


@pytest.mark.parametrize("value", [float("nan"), [1.0, float("inf")], {"a": float("-inf")}])
def test_nan_in_a_free_part_key_is_bad_input(tmp_path, capsys, value):
    """Free keys are kept and written again: `cell run --record` ended in an internal error ('a non-finite
    number (nan): JSON cannot store it') and left a recording folder without a manifest."""
    path, pid = _asm(tmp_path, family=value)
    code, out, err = run_cli("run", path, "--record", tmp_path / "rec", capsys=capsys)
    assert code == 2 and "internal error" not in err, err
    assert err.strip() == f"cell: error: {path}: part {pid!r}: 'family' holds NaN or Infinity, which JSON cannot store"
    assert not (tmp_path / "rec").exists()


LONE = '"\\udc80"'  # a JSON escape of half a UTF-16 pair: no character


def test_a_lone_surrogate_in_a_json_file_is_bad_input(tmp_path, capsys):
    """As a part id it ended `cell plan --figures` in an internal error (the font cannot draw it)."""
    from cell.runtime.session import default_assembly_path

    raw = json.loads(default_assembly_path().read_text())
    old = raw["parts"][2]["id"]
    text = json.dumps(raw).replace(f'"{old}"', LONE)
    path = tmp_path / "asm.json"
    path.write_text(text)
    code, out, err = run_cli("plan", path, "--json", "--figures", tmp_path / "figs", capsys=capsys)
    assert code == 2 and out == "" and "internal error" not in err, err
    assert err.strip() == (f"cell: error: assembly file {path}: parts[2].id holds a lone UTF-16 surrogate escape "
                           "(\\udc80): no character")


def test_a_surrogate_pair_is_one_character_and_passes(tmp_path, capsys):
    from cell.fileio import read_json

    path = tmp_path / "x.json"
    path.write_text('{"id": "\\ud83d\\ude00"}')
    assert read_json(path, "x file") == {"id": "\U0001F600"}


def test_a_lone_surrogate_in_an_example_line_is_bad_input(tmp_path):
    from cell.errors import BadInput

    path = tmp_path / "ex.jsonl"
    path.write_text(json.dumps(_example("a").to_json()) + "\n"
                    + json.dumps(_example("b").to_json()).replace('"b"', LONE, 1) + "\n")
    with pytest.raises(BadInput, match=r"^example file .* line 2: id holds a lone UTF-16 surrogate escape"):
        load_examples(path)


def test_an_output_folder_that_is_not_writable_is_refused_before_the_work(tmp_path, monkeypatch, capsys):
    """`render --out o.png --truth ro/t.json` wrote o.png, then failed on the truth file naming its temp file
    ('Permission denied: .../ro/.t.json.8dtisxls.tmp'). (Tests run as root, who may write anywhere: the
    folder's verdict is stubbed.)"""
    import os

    from cell.grasp import shapes
    from cell.scene import Scene

    ro = tmp_path / "ro"
    ro.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if str(p) == str(ro) else real_access(p, mode, **kw))
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps(Scene((shapes.rectangle("box", 50, 30, (300, 100), 30),), "box").to_json()))
    code, out, err = run_cli("render", scene, "--out", tmp_path / "o.png", "--truth", ro / "t.json", capsys=capsys)
    assert code == 2 and out == ""
    assert err.strip() == f"cell: error: --truth {ro / 't.json'}: the folder {ro} is not writable"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ro", "s.json"]


def test_a_write_that_cannot_start_names_the_file_not_its_temp_file(tmp_path, monkeypatch):
    import errno
    import tempfile

    from cell.fileio import write_atomic

    def denied(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / ".o.json.x1y2z3.tmp"))

    monkeypatch.setattr(tempfile, "mkstemp", denied)
    with pytest.raises(PermissionError) as e:
        write_atomic(tmp_path / "o.json", "{}")
    assert e.value.filename == str(tmp_path / "o.json") and ".tmp" not in str(e.value)


@pytest.mark.parametrize("shape", [(1, 20000, 3), (3, 8000), (1, 1, 3), (20000, 1, 3)])
def test_a_frame_one_pixel_thin_is_segmented_not_an_internal_error(tmp_path, capsys, shape):
    """A 20000 x 1 px image was detected on a copy of 0 rows: internal error (cv2.error in resize)."""
    import cv2
    import numpy as np

    path = tmp_path / "thin é.png"  # and a name with a space and an accent
    cv2.imwrite(str(path), np.full(shape, 180, np.uint8))
    code, out, err = run_cli("segment", path, "--json", capsys=capsys)
    assert code == 0 and "internal error" not in err, err
    assert json.loads(out)["parts"] == [] and json.loads(out)["width_px"] == shape[1]


@pytest.mark.parametrize("depth, code", [(400, 0), (5000, 2)])
def test_a_deeply_nested_free_part_key(tmp_path, capsys, depth, code):
    """The NaN check walked a free key recursively: nested 330 deep or more it ended in an internal error
    (RecursionError) although JSON's reader took it; now it is checked like any other key. Nesting JSON's
    reader refuses (about 990 deep from the command line, less under pytest's deeper stack) is bad input
    naming the file."""
    path, _ = _asm(tmp_path)
    text = path.read_text().replace('"z_top"', '"deep": ' + "[" * depth + "1.0" + "]" * depth + ', "z_top"', 1)
    path.write_text(text)
    got, out, err = run_cli("plan", path, "--json", capsys=capsys)
    assert got == code and "internal error" not in err, err
    if code == 2:
        assert err.startswith("cell: error: ") and "nested too deeply" in err
