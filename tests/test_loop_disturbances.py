"""The world disturbed during a run, in the simulated cell (rendered frames segmented for real, the simulated
drives on the virtual bus): a part lost on the way to the drop-off, a knocked camera, a person's arm reaching in.
Each is noticed by the loop and told to the operator, and the session replays."""

import json

import pytest
from conftest import run_cli
from test_cell_loop import DEFAULT, interactive_run

from cell.recording import RecordingReader
from cell.runtime import session
from cell.runtime.session import RunConfig, run_session


@pytest.fixture(scope="module")
def short_assembly(tmp_path_factory):
    """Three parts of the default assembly: a nut, a washer and the PCB."""
    d = json.loads(DEFAULT.read_text())
    keep = ["nut", "washer", "pcb"]
    d["parts"], d["sequence"], d["name"] = [p for p in d["parts"] if p["id"] in keep], keep, "short"
    p = tmp_path_factory.mktemp("asm") / "short.json"
    p.write_text(json.dumps(d))
    return p


def replays(rec, capsys) -> None:
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0 and "decisions match the recording" in out, err


def with_world(monkeypatch, arrange) -> None:
    """`run_session`'s simulated sources, with `arrange(arm, world)` run once the world is made."""
    sources = session._simulated_sources

    def arranged(*a, **kw):
        arm, camera, world = sources(*a, **kw)
        arrange(arm, world)
        return arm, camera, world

    monkeypatch.setattr(session, "_simulated_sources", arranged)


def lose_off_the_tray(part_id: str):
    """`arrange` for `with_world`: `part_id` falls out of the jaws once they carry it past the tray's edge (onto the
    floor: it leaves the world)."""

    def arrange(arm, world):
        def tick():
            tool, _ = world._pose()
            with world._lock:
                if world.held == part_id and not world.cell.tray.contains(tool.x_mm, tool.y_mm):
                    world.held = None
                    world.parts.pop(part_id)
                    world.events.append(f"{part_id} fell out of the jaws off the tray")

        world.drives.clock.every(0.01, tick, name="test-loss")

    return arrange


# ---------------------------------------------------------------- A: a part lost on the way to the drop-off
def test_a_part_lost_off_the_tray_on_the_carry_is_lost_not_removed_and_replays(short_assembly, monkeypatch, tmp_path,
                                                                             capsys):
    """The nut falls out of the jaws past the tray's edge. It counted as removed (the next frame showed it gone);
    the grip checked above the drop-off finds the jaws empty: nothing is lowered or let go there, the nut is
    "lost", and the run stops telling the operator to find it."""
    with_world(monkeypatch, lose_off_the_tray("nut"))
    s = run_session(RunConfig(assembly=short_assembly, seed=3, record=tmp_path / "r"))
    monkeypatch.undo()
    assert "nut fell out of the jaws off the tray" in s["sim_events"]
    assert s["status"] == "stopped" and s["parts_removed"] == 0
    assert "nut fell out of the jaws on the way to the drop-off and is not on the tray" in s["stopped"]
    nut = s["parts"][0]
    assert (nut["part"], nut["outcome"]) == ("nut", "lost") and "when checked above it" in nut["reason"]
    decisions = RecordingReader(tmp_path / "r").decisions
    assert RecordingReader(tmp_path / "r").manifest["meta"]["transit_check"] is True
    records = next(d["records"] for d in decisions if d["type"] == "executed")
    assert [x["label"] for x in records][-2:] == ["carry", "check at drop-off"] and not records[-1]["holding"]
    replays(tmp_path / "r", capsys)  # the replay's jaws find nothing above the drop-off, as the recording did


def test_a_part_lost_on_the_carry_goes_on_after_the_operator_s_reset(short_assembly):
    """At the station the stop is a question: after the reset the run goes on with the next parts, and the
    summary keeps the nut lost."""
    asked = []
    s, world = interactive_run(short_assembly, lambda loop, arm, drives, w: lose_off_the_tray("nut")(arm, w),
                               lambda loop, w, fault: asked.append(fault))
    assert asked[0]["asking"] and "nut fell out of the jaws on the way to the drop-off" in asked[0]["why"]
    assert [(r["part"], r["outcome"]) for r in s["parts"]] == [("nut", "lost"), ("washer", "removed"),
                                                               ("pcb", "removed")]
    assert (s["parts_total"], s["parts_removed"]) == (3, 2)
    assert not any(e.startswith("dropped nut") for e in world.events)
