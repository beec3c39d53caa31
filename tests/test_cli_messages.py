"""Bad input that was refused with a message saying less than it could: each now says what is wrong and,
where there is one, what to give instead (exit 2, one line). And a render that drops a part says so."""

import json

import numpy as np
import pytest
from conftest import ROOT, run_cli

from calibration import save_calibration
from calibration.camera import Calibration

SQUARE = [[300, 0], [340, 0], [340, 40], [300, 40]]
EXAMPLES = ROOT / "cell" / "data" / "default_examples.jsonl"


def _scene(tmp_path, part, **top):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"parts": [{"id": "a", "outline": SQUARE, "z_top": 5, **part}], "target": "a", **top}))
    return path


def _refused(capsys, *argv) -> str:
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and err.startswith("cell: error: ") and err.count("\n") == 1, err
    return err


def test_a_part_without_z_top_is_said_to_miss_it(tmp_path, capsys):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"parts": [{"id": "a", "outline": SQUARE}], "target": "a"}))
    err = _refused(capsys, "grasp", path)
    assert f"{path}: part 'a': 'z_top' is missing" in err  # was "must be a finite number, got None"


@pytest.mark.parametrize("outline", [[[300, 0], [350, 0], [400, 0]], [[300, 0], [350, 10], [400, 20], [320, 4]]])
def test_a_collinear_outline_is_said_to_have_no_area(tmp_path, capsys, outline):
    err = _refused(capsys, "grasp", _scene(tmp_path, {"outline": outline}))
    assert "part 'a' outline: its points all lie on one line" in err and "Self-intersection" not in err


def test_an_assembly_file_given_to_grasp_is_named_as_one(capsys):
    err = _refused(capsys, "grasp", ROOT / "cell" / "data" / "assemblies" / "default.json")
    assert "no 'target'" in err and "looks like an assembly file" in err and "`cell plan`" in err


def test_a_flat_holes_list_shows_the_nested_form(tmp_path, capsys):
    err = _refused(capsys, "grasp", _scene(tmp_path, {"holes": [[310, 10], [320, 10], [320, 20]]}))
    assert "'holes' must be a list of rings" in err and "[[[x, y], [x, y], [x, y], ...], ...]" in err


def test_a_scene_file_given_to_plan_is_named_as_one(tmp_path, capsys):
    err = _refused(capsys, "plan", _scene(tmp_path, {}))
    assert "looks like a scene file" in err and "`cell grasp`" in err  # was "'sequence' must be a list of part ids"


@pytest.mark.parametrize("command", ["rules", "grasp", "run"])
def test_examples_that_are_all_rejected_name_their_file(tmp_path, capsys, command):
    rejected = tmp_path / "rejected.jsonl"
    rejected.write_text("".join(line for line in EXAMPLES.read_text().splitlines(keepends=True)
                                if not json.loads(line)["valid"]))
    scene = [_scene(tmp_path, {})] if command == "grasp" else []
    err = _refused(capsys, command, *scene, "--examples", rejected)
    assert f"example file {rejected} holds no accepted grasp" in err


def test_a_station_on_another_host_names_the_flag_that_allows_it(tmp_path, capsys):
    err = _refused(capsys, "station", "--host", "0.0.0.0", "--examples", tmp_path / "ex.jsonl")
    assert "--host 0.0.0.0" in err and "--allow-remote" in err and "allow_remote" not in err


@pytest.fixture
def plane_calibration(tmp_path):
    """A homography for the table only, named as calibrate plane names it (not the file)."""
    path = tmp_path / "plane.json"
    h = np.array([[0.3, 0, 200], [0, -0.3, 150], [0, 0, 1.0]])
    save_calibration(Calibration(1280, 1024, homography=h, name="plane from markers"), path)
    return path


def test_render_with_a_plane_calibration_names_the_file(tmp_path, capsys, plane_calibration):
    assembly = ROOT / "cell" / "data" / "assemblies" / "default.json"
    err = _refused(capsys, "render", assembly, "--calibration", plane_calibration, "--out", tmp_path / "o.png")
    assert f"calibration file {plane_calibration}" in err and "plane from markers" not in err


def test_run_with_a_plane_calibration_names_the_file(tmp_path, capsys, plane_calibration):
    err = _refused(capsys, "run", "--calibration", plane_calibration)
    assert f"calibration file {plane_calibration}" in err and "plane from markers" not in err


@pytest.mark.parametrize("x, where", [(3000, "outside"), (-300, "partly outside")])
def test_render_warns_of_a_part_out_of_the_cameras_view(tmp_path, capsys, x, where):
    path = tmp_path / "far.json"
    outline = [[x, 0], [x + 600, 0], [x + 600, 40], [x, 40]]
    path.write_text(json.dumps({"parts": [{"id": "far", "outline": outline, "z_top": 5},
                                          {"id": "near", "outline": SQUARE, "z_top": 5}]}))
    code, out, err = run_cli("render", path, "--out", tmp_path / "o.png", capsys=capsys)
    assert code == 0 and (tmp_path / "o.png").is_file()  # still rendered: a frame of the tray has its uses
    assert err.startswith(f"cell: warning: {path}: part 'far' ") and f"lies {where} the camera's view" in err, err
    assert err.count("\n") == 1  # not the part in view


def test_a_station_on_every_interface_prints_an_address_that_opens():
    """`cell station --allow-remote --host 0.0.0.0` printed http://0.0.0.0:8765/, which opens nothing. (Not
    served here: the tests bind 127.0.0.1 only; the address is worked out from the bound host.)"""
    from types import SimpleNamespace

    from cell.station.server import StationServer

    for bound, shown in (("0.0.0.0", "http://127.0.0.1:8765/"), ("::", "http://[::1]:8765/"),
                         ("127.0.0.1", "http://127.0.0.1:8765/"), ("192.168.1.5", "http://192.168.1.5:8765/")):
        assert StationServer.base_url.fget(SimpleNamespace(host=bound, port=8765)) == shown
