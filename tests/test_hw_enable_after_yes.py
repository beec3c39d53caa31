"""The `cell hw` commands that move ask the operator before the drives are enabled: while the question is
asked, and after a "no", no motor holds torque (they enabled every drive first, then asked)."""

import contextlib
import json
import types
from pathlib import Path

import pytest

from cell.cellconfig import default_cell
from cell.commands import hw
from cell.errors import CellError

SCENE = Path(__file__).resolve().parent.parent / "cell" / "data" / "scenes" / "default_step0.json"
COMMANDS = {
    "home": dict(),
    "jog": dict(joint="j1", step=5.0),
    "gripper": dict(action="open", width=None, force=None, part=None),
    "corner": dict(corner="near-left", dwell=0.0),
    "pick": dict(scene=str(SCENE), examples=None, place_back=False),
}


def _args(**kw):
    return types.SimpleNamespace(interface="virtual", channel=None, simulated_time=True, record=None, yes=False,
                                 json=True, **kw)


def _states(arm):
    return {name: s["state"] for name, s in arm.state().items()}


@pytest.fixture
def watched(monkeypatch):
    """The command's own session, watched: the drives' states when the operator is asked and at the end."""
    seen = {}
    own_session = hw._session

    @contextlib.contextmanager
    def session(args, cell, **kw):
        with own_session(args, cell, **kw) as (arm, drives):
            seen["arm"], seen["start"] = arm, drives.positions()
            try:
                yield arm, drives
            finally:
                seen["end"], seen["states_at_end"] = drives.positions(), _states(arm)

    def answer(yes):
        def confirm(args, what):
            seen["states_at_question"] = _states(seen["arm"])
            if not yes:
                raise CellError("aborted by the operator; nothing moved")

        monkeypatch.setattr(hw, "confirm_motion", confirm)

    monkeypatch.setattr(hw, "_session", session)
    seen["answer"] = answer
    return seen


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_no_leaves_every_drive_disabled_and_where_it_stood(watched, command):
    watched["answer"](yes=False)
    with pytest.raises(CellError, match="aborted by the operator"):
        getattr(hw, f"_{command}")(_args(**COMMANDS[command]), default_cell())
    assert "OPERATION_ENABLED" not in watched["states_at_question"].values(), watched["states_at_question"]
    assert "OPERATION_ENABLED" not in watched["states_at_end"].values()
    assert watched["end"] == pytest.approx(watched["start"])


def test_a_yes_enables_the_drives_and_the_jog_runs(watched, capsys):
    watched["answer"](yes=True)
    assert hw._jog(_args(**COMMANDS["jog"]), default_cell()) == 0
    assert "OPERATION_ENABLED" not in watched["states_at_question"].values()
    out = json.loads(capsys.readouterr().out)
    assert out["to"]["j1_deg"] - out["from"]["j1_deg"] == pytest.approx(5.0, abs=0.01)
