"""`cell plan`: one object per step against the parts still present, figures, exit codes."""

import json
from importlib import resources
from pathlib import Path

import pytest
from conftest import run_cli

ASSEMBLIES = Path(str(resources.files("cell") / "data" / "assemblies"))


def test_plan_prints_one_object_per_step_in_sequence(capsys):
    path = ASSEMBLIES / "fig18_product.json"
    seq = json.loads(path.read_text())["sequence"]
    code, out, _ = run_cli("plan", path, "--json", capsys=capsys)
    lines = [json.loads(x) for x in out.splitlines()]
    assert code == 0
    assert [x["step"] for x in lines] == list(range(len(seq)))
    assert [x["target"] for x in lines] == seq
    for x in lines:
        assert set(x) >= {"contacts", "center", "angle_deg", "opening_mm", "grasp_z_mm", "joints", "counts", "time_ms"}
        assert x["lift"] == {"clear": True}
        # Later steps see fewer parts: the removed ones are gone from the scene.
    assert lines[-1]["counts"]["candidates"] > 0


def test_figures_are_written_per_step(tmp_path, capsys):
    path = ASSEMBLIES / "default.json"
    code, out, _ = run_cli("plan", path, "--figures", tmp_path / "figs", capsys=capsys)
    assert code == 0
    pngs = sorted((tmp_path / "figs").glob("step_*.png"))
    assert len(pngs) == len(json.loads(path.read_text())["sequence"])
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 20_000 for p in pngs)


def test_figures_of_an_earlier_plan_are_replaced_as_a_set(tmp_path, capsys):
    """A second plan into the same folder left the first plan's figures of other parts and steps beside its own:
    the folder showed a mix. Its own step_NN_*.png go; other files stay."""
    figs = tmp_path / "figs"
    figs.mkdir()
    (figs / "step_07_old_part.png").write_bytes(b"\x89PNG old")
    (figs / "step_00_other.png").write_bytes(b"\x89PNG old")
    (figs / "notes.txt").write_text("mine")
    (figs / "step_x.png").write_bytes(b"not a figure name")
    path = ASSEMBLIES / "default.json"
    code, out, _ = run_cli("plan", path, "--figures", figs, capsys=capsys)
    assert code == 0
    assert "(2 of an earlier plan removed)" in out
    names = {p.name for p in figs.iterdir()}
    sequence = json.loads(path.read_text())["sequence"]
    assert {n for n in names if n.startswith("step_") and n != "step_x.png"} == {
        f"step_{i:02d}_{pid}.png" for i, pid in enumerate(sequence)}
    assert {"notes.txt", "step_x.png"} <= names


@pytest.mark.parametrize("bad", ["missing", "duplicate"])
def test_a_rejected_assembly_leaves_no_figures_folder_behind(tmp_path, capsys, bad):
    """Bad input writes nothing: the folder (and its missing parents) is made only once the inputs are read."""
    path = tmp_path / "missing.json"
    if bad == "duplicate":
        d = json.loads((ASSEMBLIES / "default.json").read_text())
        d["sequence"] = d["sequence"] + d["sequence"][:1]
        path = tmp_path / "dup.json"
        path.write_text(json.dumps(d))
    code, _, err = run_cli("plan", path, "--figures", tmp_path / "figs" / "deep", capsys=capsys)
    assert code == 2 and "Traceback" not in err
    assert not (tmp_path / "figs").exists()


def _stack(tmp_path, sequence):
    plate = {"id": "plate", "outline": [[300, -30], [370, -30], [370, 30], [300, 30]], "z_top": 5}
    lid = {"id": "lid", "outline": [[325, -10], [345, -10], [345, 10], [325, 10]], "z_bottom": 5, "z_top": 12}
    p = tmp_path / "stack.json"
    p.write_text(json.dumps({"units": "mm", "parts": [plate, lid], "sequence": sequence}))
    return p


def test_a_part_with_another_on_it_cannot_be_lifted(tmp_path, capsys):
    code, out, _ = run_cli("plan", _stack(tmp_path, ["plate", "lid"]), "--json", capsys=capsys)
    lines = [json.loads(x) for x in out.splitlines()]
    assert code == 3
    assert lines[0]["error"] == "no_feasible_grasp" and "'lid'" in lines[0]["reason"]  # CONTRACT's error value
    assert lines[0]["lift"] == {"clear": False, "blocked_by": ["lid"]}
    assert "error" not in lines[1]  # the lid alone is still planned


def test_the_right_order_plans_both(tmp_path, capsys):
    code, out, _ = run_cli("plan", _stack(tmp_path, ["lid", "plate"]), "--json", capsys=capsys)
    assert code == 0, out


@pytest.mark.parametrize("edit,match", [
    (lambda d: d["parts"][0].__setitem__("direction", [0, 1, 0]), "straight up"),
    (lambda d: d.__setitem__("sequence", ["plate"]), "exactly once"),
    (lambda d: d["parts"][1].__setitem__("outline", [[0, 0], [1, 1], [1, 0], [0, 1]]), "valid polygon"),
])
def test_bad_assemblies_exit_2(tmp_path, capsys, edit, match):
    p = _stack(tmp_path, ["lid", "plate"])
    d = json.loads(p.read_text())
    edit(d)
    p.write_text(json.dumps(d))
    code, out, err = run_cli("plan", p, "--json", capsys=capsys)
    assert code == 2 and match in err and "Traceback" not in err and out == ""


def test_figure_names_stay_in_the_folder_whatever_the_part_ids(tmp_path, capsys):
    """Part ids are free strings: 'cover/top' made a sub-folder, '../x' wrote beside the folder,
    a 300-character id crashed with 'File name too long' (a traceback)."""
    ids = ["cover/top", "../escaped", "x" * 300]
    parts = [{"id": pid, "outline": [[300 + 60 * i, 0], [340 + 60 * i, 0], [340 + 60 * i, 30], [300 + 60 * i, 30]],
              "z_top": 12} for i, pid in enumerate(ids)]
    path = tmp_path / "ids.json"
    path.write_text(json.dumps({"units": "mm", "parts": parts, "sequence": ids}))
    figs = tmp_path / "figs"
    code, out, err = run_cli("plan", path, "--json", "--figures", figs, capsys=capsys)
    assert code == 0 and "Traceback" not in err, err
    assert [json.loads(x)["target"] for x in out.splitlines()] == ids
    written = sorted(p.name for p in figs.iterdir())
    assert len(written) == 3 and all(figs.joinpath(n).is_file() and n.endswith(".png") for n in written)
    assert written[0].startswith("step_00_") and written[2].startswith("step_02_")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figs", "ids.json"]


def test_figures_draw_part_ids_that_look_like_tex(tmp_path, capsys):
    """matplotlib read '$...$' in a title as TeX: '$\\frac{$' and '$x^$' ended in an internal error
    (ParseSyntaxException) after the steps' lines were printed, with the later figures missing. The second part
    has no grasp (it lies under the first), so the no-grasp title is drawn too."""
    ids = ["$\\frac{$", "$x^$"]
    plate = {"id": ids[1], "outline": [[300, -30], [370, -30], [370, 30], [300, 30]], "z_top": 5}
    top = {"id": ids[0], "outline": [[320, -10], [350, -10], [350, 10], [320, 10]], "z_bottom": 5, "z_top": 17}
    path = tmp_path / "tex.json"
    path.write_text(json.dumps({"units": "mm", "parts": [plate, top], "sequence": ids[::-1]}))
    figs = tmp_path / "figs"
    code, out, err = run_cli("plan", path, "--json", "--figures", figs, capsys=capsys)
    assert code == 3 and "internal error" not in err, err
    assert [json.loads(x)["target"] for x in out.splitlines()] == ids[::-1]
    assert sorted(p.name for p in figs.iterdir()) == ["step_00__x_.png", "step_01__frac_.png"]
