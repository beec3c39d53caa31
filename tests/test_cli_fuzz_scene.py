"""Scene heights no part on the tray has: bad input naming the part, as outline coordinates that far are."""

import json

import pytest
from conftest import run_cli

from cell.examples import append_examples
from cell.grasp import shapes
from cell.scene import Scene


@pytest.mark.parametrize("z_top", [1e308, 2e6])
def test_a_part_taller_than_a_kilometre_is_bad_input(tmp_path, capsys, z_top):
    """It was planned: exit 3, 'the grasp z is 1e+308 mm'; `cell render` drew its shadow without end."""
    raw = Scene((shapes.rectangle("box", 50, 30, (300, 100), 30),), "box").to_json()
    raw["parts"][0]["z_top"] = z_top
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(raw))
    examples = tmp_path / "ex.jsonl"
    append_examples(examples, shapes.hand_made_examples())
    code, out, err = run_cli("grasp", scene, "--json", "--examples", examples, capsys=capsys)
    assert code == 2 and out == "" and "part 'box': z_bottom and z_top must be within 1e+06 mm" in err, err


@pytest.mark.parametrize("z_top", [800.0, 2000.0])
def test_cell_run_names_a_part_that_reaches_the_camera(tmp_path, capsys, z_top):
    """It said only 'some points are behind the camera'."""
    from cell.runtime.session import default_assembly_path

    raw = json.loads(default_assembly_path().read_text())
    raw["parts"][0]["z_top"] = z_top
    assembly = tmp_path / "asm.json"
    assembly.write_text(json.dumps(raw))
    code, out, err = run_cli("run", assembly, "--record", tmp_path / "rec", capsys=capsys)
    pid = raw["parts"][0]["id"]
    assert code == 2 and f"part {pid!r} reaches z = {z_top:g} mm, at or above the camera (z = 800 mm)" in err, err
    assert not (tmp_path / "rec").exists()


def test_an_empty_cell_key_is_named(tmp_path, capsys):
    """It was read as the scene's own folder: 'cell file /tmp/... is a directory, not a file'."""
    raw = Scene((shapes.rectangle("box", 50, 30, (300, 100), 30),), "box").to_json()
    raw["cell"] = ""
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(raw))
    code, out, err = run_cli("grasp", scene, "--json", capsys=capsys)
    assert code == 2 and f"{scene}: 'cell' must be a path string, got ''" in err, err
