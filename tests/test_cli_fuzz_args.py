"""Command-line values that argparse or numpy mishandled: found by trying bad inputs on every command."""

import json

import pytest
from conftest import run_cli


@pytest.mark.parametrize("argv, message", [
    # a negative number in exponent form was taken for an option
    (["segment", "nowhere.png", "--z", "-1e5"], "--z is the height"),
    (["calibrate", "plane", "nowhere.png", "--markers", "m.json", "--out", "o.json", "--camera-matrix", "-1,-1,5,5"],
     "fx and fy must be positive"),
])
def test_negative_values_in_exponent_form_are_values_not_options(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    if argv[0] == "calibrate":
        import cv2
        import numpy as np

        cv2.imwrite("nowhere.png", np.zeros((48, 64, 3), np.uint8))
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and message in err and "expected one argument" not in err, err
    assert not (tmp_path / "o.json").exists()


def test_a_negative_jog_in_exponent_form_moves(capsys):
    code, out, err = run_cli("hw", "jog", "j1", "-1e0", "--simulated-time", capsys=capsys)
    assert code == 0 and "j1:" in out, err


@pytest.mark.parametrize("argv", [
    ["render", "scene.json", "--out", "o.png", "--seed", "-1"],
    ["examples", "generate", "--out", "e.jsonl", "--count", "1", "--seed", "-1"],
    ["study", "--budget", "tiny", "--out", "st", "--seed", "-1"],
    ["bench", "vision", "--frames", "1", "--repeats", "1", "--seed", "-1"],
    ["bench", "stability", "--poses", "1", "--seed", "-1"],
])
def test_a_negative_seed_is_bad_input_not_an_internal_error(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and "--seed must be 0 or more" in err and "internal error" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["map", "CAL", "--mm", "300,0", "1e30,1e30"], "--mm 1e30,1e30: coordinates must be within 1e+06 mm"),  # was:
    # mapped to 1.1e13 px, exit 0
    (["map", "CAL", "--px", "100,100", "--z", "-1e300"], "--z must be within 1e+06 mm of the table"),
    (["segment", "nowhere.png", "--calibration", "CAL", "--z", "1e300"], "--z must be within 1e+06 mm"),
])
def test_heights_and_points_a_kilometre_off_are_bad_input(capsys, argv, message):
    from calibration import default_calibration_path

    argv = [default_calibration_path() if a == "CAL" else a for a in argv]
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and message in err and out == "", err


@pytest.mark.parametrize("argv, name", [
    (["run", "", "--json"], "ASSEMBLY"),  # was: the shipped default assembly, exit 0
    (["run", "--record", ""], "--record"),  # was: a run with no recording, exit 0
    (["run", "--save", ""], "--save"),
    (["grasp", "scene.json", "--cell", ""], "--cell"),  # was: the default cell
    (["study", "--budget", "tiny", "--out", ""], "--out"),  # was: the study written into the current folder
    (["plan", "asm.json", "--figures", ""], "--figures"),  # was: no figures
    (["render", "scene.json", "--out", "f.png", "--truth", ""], "--truth"),  # was: no truth file
    (["segment", "frame.png", "--calibration", ""], "--calibration"),  # was: no mm
    (["hw", "status", "--simulated-time", "--channel", ""], "--channel"),
    (["examples", "generate", "--out", "e.jsonl", "--families", ""], "--families"),  # was: the whole library
])
def test_an_empty_value_is_bad_input_not_the_default(tmp_path, monkeypatch, capsys, argv, name):
    """`--record "$DIR"` with DIR unset must not quietly run without a recording."""
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and err.strip().splitlines()[-1] == f"cell: error: {name} is empty: give a value", err
    assert out == "" and list(tmp_path.iterdir()) == []


def test_a_camera_matrix_of_1e300_pixels_is_named(tmp_path, capsys):
    """It was refused as 'the plane z = 0.0 mm is not in front of the camera for some pixels'."""
    import json

    import cv2
    import numpy as np

    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((480, 640, 3), np.uint8))
    points = {"points": [{"px": [100 * i + 50, 80 * j + 40], "mm": [200 + 10 * i, -50 + 10 * j, 0]}
                         for i in range(3) for j in range(3)]}
    (tmp_path / "p.json").write_text(json.dumps(points))
    code, out, err = run_cli("calibrate", "plane", tmp_path / "f.png", "--points", tmp_path / "p.json", "--out",
                             tmp_path / "o.json", "--camera-matrix", "1e300,1e300,320,240", capsys=capsys)
    assert code == 2 and "--camera-matrix 1e300,1e300,320,240: pixels, each within 1e6" in err, err
    assert not (tmp_path / "o.json").exists()


def _box_scene(path):
    from cell.grasp import shapes
    from cell.scene import Scene

    path.write_text(json.dumps(Scene((shapes.rectangle("box", 50, 30, (300, 100), 30),), "box").to_json()))


def test_an_empty_scene_among_several_gets_its_own_line(tmp_path, monkeypatch, capsys):
    """CONTRACT's batch form: one line per scene. An empty name aborted the whole batch with no line;
    before that it read the current folder ("scene file . is a directory")."""
    monkeypatch.chdir(tmp_path)
    _box_scene(tmp_path / "a.json")
    code, out, err = run_cli("grasp", "a.json", "", "a.json", "--json", capsys=capsys)
    lines = [json.loads(line) for line in out.splitlines()]
    assert code == 2 and [x["scene"] for x in lines] == ["a.json", "", "a.json"]
    assert "contacts" in lines[0] and lines[0]["contacts"] == lines[2]["contacts"]
    assert lines[1] == {"scene": "", "error": "bad_input", "reason": "scene file name is empty: give a path"}


def test_scenes_after_an_option_are_scenes_too(tmp_path, monkeypatch, capsys):
    """CONTRACT's batch form with the files among the options: `grasp a.json --json b.json` was refused
    as 'unrecognized arguments: b.json' (argparse took positionals before the first option only)."""
    monkeypatch.chdir(tmp_path)
    for name in ("a.json", "b.json", "c.json", "-d.json"):
        _box_scene(tmp_path / name)
    code, out, err = run_cli("grasp", "a.json", "--json", "b.json", "--step-mm", "2", "c.json", capsys=capsys)
    lines = [json.loads(line) for line in out.splitlines()]
    assert code == 0 and [x["scene"] for x in lines] == ["a.json", "b.json", "c.json"], err
    assert lines[0]["contacts"] == lines[1]["contacts"] == lines[2]["contacts"]
    # "--" still ends the options: a file named like one comes after it
    code, out, err = run_cli("grasp", "--json", "--", "-d.json", capsys=capsys)
    assert code == 0 and json.loads(out)["target"] == "box", err
    # ... also after files and options (it was "unrecognized arguments: -- -d.json")
    code, out, err = run_cli("grasp", "a.json", "--json", "--", "-d.json", "b.json", capsys=capsys)
    assert code == 0 and [json.loads(x)["scene"] for x in out.splitlines()] == ["a.json", "-d.json", "b.json"], err
    code, out, err = run_cli("grasp", "--json", "--", capsys=capsys)
    assert code == 2 and "the following arguments are required: SCENE" in err


def test_images_after_an_option_are_images_too(tmp_path, monkeypatch, capsys):
    """`segment` and `calibrate intrinsics` take several images the same way."""
    import cv2
    import numpy as np

    monkeypatch.chdir(tmp_path)
    for name in ("a.png", "b.png", "c.png"):
        cv2.imwrite(name, np.zeros((48, 64, 3), np.uint8))
    code, out, err = run_cli("segment", "a.png", "--json", "b.png", capsys=capsys)
    assert code == 0 and [json.loads(line)["image"] for line in out.splitlines()] == ["a.png", "b.png"], err
    code, out, err = run_cli("calibrate", "intrinsics", "a.png", "--pattern", "9x6", "b.png", "--square", "1",
                             "c.png", "--out", "o.json", capsys=capsys)
    assert code == 2 and "the board was found in 0 of 3 images" in err, err


@pytest.mark.parametrize("argv, message", [
    (["grasp", "a.json", "--bogus", "b.json"], "unrecognized arguments: --bogus b.json"),
    (["grasp", "--json"], "the following arguments are required: SCENE"),
    (["segment", "a.png", "--json", "--z"], "argument --z: expected one argument"),
    # a command taking one file still takes one
    (["plan", "a.json", "--json", "b.json"], "unrecognized arguments: b.json"),
    (["render", "a.json", "--out", "o.png", "b.json"], "unrecognized arguments: b.json"),
])
def test_unknown_or_extra_arguments_among_positionals_are_still_named(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and out == "" and err.strip().splitlines()[-1] == f"cell: error: {message}", err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["bench", "can", "--n", "99999999999999"], "--n must be 1..100000, got 99999999999999"),
    (["bench", "can", "--n", "0"], "--n must be 1..100000, got 0"),
    (["bench", "grasp", "--repeat", "99999999999999"], "--repeat must be 1..1000"),
    (["bench", "vision", "--frames", "99999999999999"], "--frames and --repeats must be at most 1000"),
    (["bench", "vision", "--frames", "1", "--repeats", "99999999999999"],
     "--frames and --repeats must be at most 1000"),
    (["bench", "stability", "--poses", "99999999999999"], "--poses must be 1..100"),
])
def test_benchmark_counts_that_would_never_end_are_bad_input(capsys, argv, message):
    """`bench can --n 99999999999999` ran without end (every round trip's time kept in memory)."""
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and out == "" and message in err, err


def test_a_bad_photo_is_refused_before_the_benchmark(tmp_path, monkeypatch, capsys):
    """It was refused after the whole benchmark had run (80 s)."""
    import cell.vision.bench

    def no_benchmark(*a, **k):
        raise AssertionError("the benchmark ran before the photos were read")

    monkeypatch.setattr(cell.vision.bench, "run_benchmark", no_benchmark)
    (tmp_path / "bad.png").write_text("not an image")
    code, out, err = run_cli("bench", "vision", "--frames", "1", "--repeats", "1", "--photos", tmp_path / "bad.png",
                             capsys=capsys)
    assert code == 2 and out == "" and "is not a readable image" in err, err


def test_an_unknown_family_is_refused_before_the_stability_benchmark(monkeypatch, capsys):
    """It was refused after the whole library, the clutter and the simple shapes had been planned (9 s)."""
    import cell.study.stability

    def no_benchmark(*a, **k):
        raise AssertionError("the benchmark ran before --families was checked")

    monkeypatch.setattr(cell.study.stability, "evaluate", no_benchmark)
    code, out, err = run_cli("bench", "stability", "--families", "gear,nosuch", capsys=capsys)
    assert code == 2 and out == "" and "unknown part families: nosuch" in err, err
