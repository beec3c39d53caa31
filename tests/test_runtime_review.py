"""Findings of the runtime review (cell/runtime, `cell run`, `cell replay`): each test reproduces one through
the real code paths."""

import json

import numpy as np
import pytest
from conftest import run_cli


def test_a_run_without_record_refuses_the_nominal_camera_a_recording_would_refuse(tmp_path, capsys):
    """A cell file's camera 900 m above the tray gives the simulated camera a nominal fx of 1.8e6 px, which the
    calibration reader refuses: `cell run --record` refused it (exit 2), plain `cell run` ran the whole
    disassembly through it (exit 0)."""
    from cell.cellconfig import default_cell_path

    cell = json.loads(default_cell_path().read_text())
    cell["camera"]["height_mm"] = 900_000.0
    (tmp_path / "cell.json").write_text(json.dumps(cell))
    code, out, err = run_cli("run", "--cell", tmp_path / "cell.json", "--json", capsys=capsys)
    assert code == 2 and out == "", err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "intrinsics.fx and fy must be between 1 and 1e+06 px" in lines[0], err
    assert "the calibration file's reader refuses" in lines[0]


def test_a_part_with_another_still_lying_on_it_is_not_picked(tmp_path, capsys):
    """An assembly listing the base plate before the PCB lying on it (`cell plan` says: no_feasible_grasp, the
    lift blocked by 'pcb'): `cell run` planned a grasp on the base all the same, and the jaws came down around
    the PCB and closed on it, twice. Now the step stops before anything moves towards the base, as a part with
    no feasible grasp does."""
    from cell.runtime.session import default_assembly_path

    assembly = json.loads((default_assembly_path().parent / "fig18_product.json").read_text())
    assembly["sequence"] = ["nut", "washer", "base", "pcb", "shaft", "motor"]
    (tmp_path / "a.json").write_text(json.dumps(assembly))
    code, out, err = run_cli("run", tmp_path / "a.json", "--json", capsys=capsys)
    summary = json.loads(out.strip().splitlines()[-1])
    assert code == 1, err
    assert [(p["part"], p["outcome"], p["attempts"]) for p in summary["parts"]] == [
        ("nut", "removed", 1), ("washer", "removed", 1), ("base", "stopped", 0)]  # the run stopped on the base
    assert "'base' cannot be lifted straight up: 'pcb' still lies on it" in summary["stopped"]
    assert not [e for e in summary["sim_events"] if "pcb" in e or "base" in e], summary["sim_events"]


def _decisions(recording) -> list[dict]:
    return [json.loads(line) for line in (recording / "decisions.jsonl").read_text().splitlines()]


def test_after_a_missed_grip_the_next_grasp_is_planned_on_a_new_frame(tmp_path, capsys):
    """The jaws closed through where the nut was thought to lie and missed it: the part was not there, or they
    pushed it. The retry took the next grasp ranked on the frame from before the miss, whatever had moved since;
    now it is planned on a new frame (and not on the contacts that missed), and the session still replays."""
    rec = tmp_path / "rec"
    code, out, err = run_cli("run", "--sim-miss", "nut", "--record", rec, "--json", capsys=capsys)
    assert code == 0, err
    decisions = _decisions(rec)
    missed = next(i for i, d in enumerate(decisions) if d["type"] == "executed"
                  and any(r.get("holding") is False for r in d["records"]))
    retry = next(i for i in range(missed + 1, len(decisions)) if decisions[i]["type"] == "commands")
    between = [d["type"] for d in decisions[missed + 1:retry]]
    assert "perception" in between and "grasp" in between, between
    tried = [d["commands"][2]["joints"] for d in (decisions[missed - 1], decisions[retry])]
    assert tried[0] != tried[1]
    nut = next(p for p in json.loads(out.strip().splitlines()[-1])["parts"] if p["part"] == "nut")
    assert nut["attempts"] == 2 and nut["outcome"] == "removed"
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err + out


def test_a_drop_off_over_the_tray_is_refused_before_anything_moves(tmp_path, capsys):
    """A cell file's drop-off over the tray: the arm lowered the first part it carried onto the tray, among the
    others (nothing checks the fingers or the held part there), let go, and the run stopped with 'nut did not
    leave the tray' (exit 1). A bad cell file, found before anything moves, as an unreachable drop-off is."""
    from cell.cellconfig import default_cell_path

    cell = json.loads(default_cell_path().read_text())
    cell["motion"]["dropoff_mm"] = [420.0, -200.0, 60.0]
    (tmp_path / "cell.json").write_text(json.dumps(cell))
    code, out, err = run_cli("run", "--cell", tmp_path / "cell.json", "--json", capsys=capsys)
    assert code == 2 and out == "", err
    assert "motion.dropoff_mm [420.0, -200.0, 60.0] lies over the tray" in err, err


def test_a_ctrl_c_while_the_loop_is_being_built_closes_the_recording(tmp_path, monkeypatch):
    """Ctrl-C in the moment the loop fits its trees (after the drives came up, before anything moved) left the
    recording saying "recording", as a crashed session's does: now it is closed as not started, and says why."""
    import pytest

    from cell.runtime import loop
    from cell.runtime.session import RunConfig, run_session

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(loop, "GraspPlanner", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_session(RunConfig(record=tmp_path / "rec"))
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    assert manifest["status"] == "incomplete" and manifest["summary"]["status"] == "not started", manifest


def _cover_sunk_into_base(tmp_path, sunk_mm: float):
    """A cover resting on a base 10 mm tall with its bottom `sunk_mm` under the base's top (the assembly files
    allow 0.5 mm for parts resting on each other), listed after the base: the base cannot come off first."""
    assembly = {"units": "mm", "name": "sunk", "sequence": ["base", "cover"], "parts": [
        {"id": "base", "outline": [[300, -30], [360, -30], [360, 30], [300, 30]], "z_bottom": 0, "z_top": 10},
        {"id": "cover", "outline": [[310, -20], [350, -20], [350, 20], [310, 20]], "z_bottom": 10 - sunk_mm,
         "z_top": 15}]}
    (tmp_path / "sunk.json").write_text(json.dumps(assembly))
    return tmp_path / "sunk.json"


@pytest.mark.parametrize("sunk_mm", [0.0, 0.3, 0.5])
def test_a_part_resting_within_the_files_height_overlap_blocks_the_lift(tmp_path, capsys, sunk_mm):
    """`cell plan` said "lift clear" (exit 0) for the base with the cover at 9.7 mm on it; at 10 mm it said no."""
    code, out, err = run_cli("plan", _cover_sunk_into_base(tmp_path, sunk_mm), "--json", capsys=capsys)
    assert code == 3, out
    step = json.loads(out.splitlines()[0])
    assert step["target"] == "base" and step["error"] == "no_feasible_grasp"
    assert step["lift"] == {"clear": False, "blocked_by": ["cover"]} and "'cover' still lies on it" in step["reason"]


def test_a_part_beside_the_target_touching_its_edge_does_not_block_it(tmp_path):
    """Within the files' touch (1 mm2 of plan overlap), a clip on a plate beside the base, 0.3 mm under the base's
    top, is beside it, not on it (the 0.5 mm rest allowance took it for lying on the base)."""
    from cell.disassembly import parts_on_top
    from cell.scene import Part

    base = Part("base", np.array([[300, -30], [360, -30], [360, 30], [300, 30]], float), z_top_mm=10.0)
    clip = Part("clip", np.array([[359.99, 0], [380, 0], [380, 40], [359.99, 40]], float), z_bottom_mm=9.7,
                z_top_mm=14.0)  # 0.01 x 30 mm over the base: 0.3 mm2
    assert parts_on_top(base, (clip,)) == []
    on = Part("cover", np.array([[310, -20], [350, -20], [350, 20], [310, 20]], float), z_bottom_mm=9.7, z_top_mm=15)
    assert parts_on_top(base, (clip, on)) == ["cover"]


def test_the_loop_stops_on_it_and_older_recordings_replay_as_they_ran(tmp_path):
    from cell.disassembly import parts_on_top
    from cell.errors import NoFeasibleGrasp
    from cell.runtime.loop import _require_lift_clear
    from cell.scene import REST_MM, Scene, load_assembly

    assembly = load_assembly(_cover_sunk_into_base(tmp_path, 0.3))
    scene = Scene(assembly.parts, "base")
    assert parts_on_top(scene.target_part, scene.obstacles) == ["cover"]
    with pytest.raises(NoFeasibleGrasp, match="'cover' still lies on it"):
        _require_lift_clear(scene, REST_MM)
    _require_lift_clear(scene, 1e-9)  # `meta.lift_rest_overlap` absent: as the loop ran then


def test_the_loop_records_the_setting_and_replays_a_recording_without_it_as_it_ran(tmp_path, capsys):
    """meta.lift_rest_overlap is what the replay does: the session stops on the base (the cover on it), and the
    same recording without the key (a session made before it) replays with the base planned, so it diverges."""
    import shutil

    from cell.runtime.session import RunConfig, run_session

    assembly = {"units": "mm", "name": "sunk", "sequence": ["base", "cover"], "parts": [
        {"id": "base", "outline": [[300, -30], [380, -30], [380, 30], [300, 30]], "z_bottom": 0, "z_top": 10},
        {"id": "cover", "outline": [[305, -10], [325, -10], [325, 10], [305, 10]], "z_bottom": 9.7, "z_top": 15}]}
    (tmp_path / "sunk.json").write_text(json.dumps(assembly))
    rec = tmp_path / "rec"
    s = run_session(RunConfig(assembly=tmp_path / "sunk.json", record=rec, seed=1))
    assert s["status"] == "stopped" and "'cover' still lies on it" in s["stopped"], s
    manifest = json.loads((rec / "manifest.json").read_text())
    assert manifest["meta"]["lift_rest_overlap"] is True
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
    old = tmp_path / "old"
    shutil.copytree(rec, old)
    del manifest["meta"]["lift_rest_overlap"]
    (old / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli("replay", old, capsys=capsys)
    assert code == 1 and "no_grasp" in out + err, out + err
