"""What `cell run` reports about a run that did not remove everything, and what `cell replay` says
of it: through the real CLI on the simulated cell, with real recordings."""

import json
from importlib import resources
from pathlib import Path

import pytest
from conftest import run_cli

from cell.recording import RecordingReader

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))


@pytest.fixture(scope="module")
def short_assembly(tmp_path_factory):
    """Three parts of the default assembly: a nut, a washer and the PCB."""
    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] in ("nut", "washer", "pcb")]
    d["sequence"], d["name"] = ["nut", "washer", "pcb"], "short"
    p = tmp_path_factory.mktemp("asm") / "short.json"
    p.write_text(json.dumps(d))
    return p


@pytest.fixture(scope="module")
def dropped(short_assembly, tmp_path_factory):
    """`cell run --sim-drop nut --record R --json`: the nut falls out of the jaws on the carry, after the grip
    check: the check above the drop-off finds the jaws empty (nothing is let go there), and the nut lies on the
    tray."""
    rec = tmp_path_factory.mktemp("dropped") / "r"  # (capsys is per test: captured by hand)
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = run_cli("run", short_assembly, "--sim-drop", "nut", "--seed", "3", "--record", rec, "--json")
    return rec, code, out.getvalue(), err.getvalue()


def test_a_part_dropped_on_the_carry_is_not_logged_as_removed(dropped):
    rec, code, _, err = dropped
    assert code == 1, err
    assert "[removed] nut" not in err and "[carried] nut" not in err and "[lost] nut lost on the way" in err, err
    assert "nut did not leave the tray" in err
    kinds = [(d["type"], d.get("outcome")) for d in RecordingReader(rec).decisions
             if d["type"] in ("outcome", "stop")]
    # the record above the drop-off says "lost"; the next frame's verdict follows it, before the stop
    assert kinds == [("outcome", "lost"), ("outcome", "not removed"), ("stop", None)]


def test_the_summary_lists_the_part_the_run_stopped_on(dropped):
    _, _, out, _ = dropped
    s = json.loads(out.strip().splitlines()[-1])
    assert s["parts_removed"] == 0 and s["grasps"] == 1
    [nut] = s["parts"]
    assert (nut["part"], nut["outcome"], nut["attempts"]) == ("nut", "stopped", 1)
    assert "nut did not leave the tray" in nut["reason"]


def test_missed_grips_are_counted_on_the_part_the_run_stopped_on(short_assembly, capsys):
    code, out, err = run_cli("run", short_assembly, "--sim-miss", "nut:2", "--seed", "3", "--json", capsys=capsys)
    assert code == 1 and err.count("[miss] nut") == 2, err
    s = json.loads(out.strip().splitlines()[-1])
    assert s["parts_removed"] == 0 and s["grasps"] == 2
    assert [(r["part"], r["outcome"], r["attempts"]) for r in s["parts"]] == [("nut", "stopped", 2)]
    assert "missed 2 times" in s["parts"][0]["reason"]
    assert "nut          stopped  attempts 2" in err  # the text summary lists it too


def test_replay_of_a_stopped_session_matches_and_says_it_was_stopped(dropped, capsys):
    rec = dropped[0]
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
    assert "decisions match the recording" in out
    assert "the recorded session was stopped (incomplete) after 0 of 3 parts removed" in out, out
    assert "nut did not leave the tray" in out
    code, out, _ = run_cli("replay", rec, "--json", capsys=capsys)
    session = json.loads(out.strip().splitlines()[-1])["session"]
    assert session["status"] == "stopped" and session["parts_removed"] == 0 and session["parts_total"] == 3


def test_a_stopped_session_recorded_without_the_not_removed_record_still_replays(short_assembly, tmp_path,
                                                                               monkeypatch, capsys):
    """Recordings made before the 'not removed' outcome was recorded hold the stop right after the frame
    that saw the part again: the replay, which writes it, still matches them."""
    from cell.runtime.loop import CellLoop
    from cell.runtime.session import RunConfig, run_session
    from cell.runtime.simworld import WorldFaults

    with monkeypatch.context() as m:
        m.setattr(CellLoop, "_record_not_removed", lambda self, report: None)  # as the older versions
        run_session(RunConfig(assembly=short_assembly, seed=3, faults=WorldFaults(dropped={"nut"}),
                              record=tmp_path / "old"))
    assert "not removed" not in (tmp_path / "old" / "decisions.jsonl").read_text()
    code, out, err = run_cli("replay", tmp_path / "old", capsys=capsys)
    assert code == 0 and "decisions match the recording" in out, err


def test_a_skipped_part_says_why_the_run_exits_1(tmp_path, capsys):
    """`--on-no-grasp skip` ran the sequence to its end (JSON status "complete", as before) but did not remove
    everything, so exit 1 (README, CONTRACT: 0 only when the whole sequence was removed); the text said
    "(complete)" and left the reader to wonder why."""
    d = json.loads(DEFAULT.read_text())
    nut = next(p for p in d["parts"] if p["id"] == "nut")
    plate = {"id": "plate", "outline": [[300, 60], [400, 60], [400, 160], [300, 160]], "z_top": 3.0}
    p = tmp_path / "wide.json"
    p.write_text(json.dumps({"units": "mm", "name": "wide", "parts": [nut, plate], "sequence": ["plate", "nut"]}))
    code, out, err = run_cli("run", p, "--seed", "1", "--on-no-grasp", "skip", "--json", capsys=capsys)
    s = json.loads(out.strip().splitlines()[-1])
    assert code == 1 and s["status"] == "complete" and s["parts_skipped"] == ["plate"]
    assert "1 of 2 parts removed (sequence complete, 1 skipped: plate)" in err, err
    assert "(complete)" not in err
    # the plate was planned (and found without a grasp): its report keeps that time (it read 0 ms)
    plate_report = next(r for r in s["parts"] if r["part"] == "plate")
    assert plate_report["planning_s"] > 0 and plate_report["attempts"] == 0
    assert "not planned" not in err
