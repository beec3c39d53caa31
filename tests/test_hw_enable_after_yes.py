"""The `cell hw` commands that move ask the operator before the drives are enabled: while the question is
asked, and after a "no", no motor holds torque (they enabled every drive first, then asked). What cannot be
enabled is said before the question; what moves is worked out from where the arm stands after the yes."""

import contextlib
import json
import types
from pathlib import Path

import pytest

from cell.cellconfig import default_cell
from cell.commands import hw
from cell.errors import CellError
from drivers import FaultLatched

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


class Watched:
    """The command's own session, watched: the drives' states when the operator is asked and at the end; `fault`
    injects a drive fault first; `on_question` runs as the operator is asked; `yes` is the answer."""

    def __init__(self, monkeypatch):
        self.yes, self.fault, self.on_question, self.asked = False, None, None, []
        own_session = hw._session

        @contextlib.contextmanager
        def session(args, cell, **kw):
            with own_session(args, cell, **kw) as (arm, drives):
                self.arm, self.drives, self.start = arm, drives, drives.positions()
                if self.fault is not None:
                    drives.inject_fault(*self.fault)
                    arm.clock.sleep(0.1)
                try:
                    yield arm, drives
                finally:
                    self.end, self.states_at_end = drives.positions(), _states(arm)

        def confirm(args, what):
            self.asked.append(what)
            self.states_at_question = _states(self.arm)
            if self.on_question is not None:
                self.on_question()
            if not self.yes:
                raise CellError("aborted by the operator; nothing moved")

        monkeypatch.setattr(hw, "_session", session)
        monkeypatch.setattr(hw, "confirm_motion", confirm)


@pytest.fixture
def watched(monkeypatch):
    return Watched(monkeypatch)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_no_leaves_every_drive_disabled_and_where_it_stood(watched, command):
    with pytest.raises(CellError, match="aborted by the operator"):
        getattr(hw, f"_{command}")(_args(**COMMANDS[command]), default_cell())
    assert "OPERATION_ENABLED" not in watched.states_at_question.values(), watched.states_at_question
    assert "OPERATION_ENABLED" not in watched.states_at_end.values()
    assert watched.end == pytest.approx(watched.start)


def test_a_yes_enables_the_drives_and_the_jog_runs(watched, capsys):
    watched.yes = True
    assert hw._jog(_args(**COMMANDS["jog"]), default_cell()) == 0
    assert "OPERATION_ENABLED" not in watched.states_at_question.values()
    out = json.loads(capsys.readouterr().out)
    assert out["to"]["j1_deg"] - out["from"]["j1_deg"] == pytest.approx(5.0, abs=0.01)


def test_a_jog_steps_from_where_the_joint_stands_after_the_yes(watched, capsys):
    """A joint pushed by hand while the operator was asked (no torque) is jogged by the confirmed step from where
    it stands then: a target taken before the question moved J1 by -3 deg after a confirmed +5, pushed 8."""
    def pushed_by_hand():
        watched.drives.drives["j1"].position_counts += 8000  # 8 deg at 1000 counts a degree
        watched.arm.clock.sleep(0.05)  # (the drive reports it)

    watched.yes, watched.on_question = True, pushed_by_hand
    assert hw._jog(_args(**COMMANDS["jog"]), default_cell()) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["from"]["j1_deg"] == pytest.approx(8.0, abs=0.01) and out["to"]["j1_deg"] == pytest.approx(13.0,
                                                                                                          abs=0.01)


def test_a_drive_in_fault_is_named_before_the_question_and_nothing_is_enabled(watched):
    watched.yes, watched.fault = True, ("emcy", "j2")
    with pytest.raises(FaultLatched, match=r"reset first: cell hw reset.*j2 \(node 2\): in FAULT, error code 0x2310"):
        hw._home(_args(), default_cell())
    assert watched.asked == [] and "OPERATION_ENABLED" not in watched.states_at_end.values()
