"""A pick's ways round what the drivers refuse (cell.runtime.ways with a leg check, as `pickway` passes one):
the grid's way when the few simple ones fail (a longer arm's elbow flip), every move checked as the drivers will
and by the leg check; a start whose grid reaches no way is searched once."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cell_files import cell_file_with

from cell.cellconfig import load_cell
from cell.errors import CellError
from cell.kinematics import Joints
from cell.runtime.motion import Command, dropoff_options
from cell.runtime.ways import _pick_grid_way, routed, way_to
from drivers.limits import command_violations


def _cell(tmp_path, name, **sections):
    return load_cell(cell_file_with(tmp_path / f"{name}.json", **sections))


@pytest.fixture(scope="module")
def long_arm(tmp_path_factory):
    """L1 400, L2 250 in the default workspace: the stretched arm (650 mm) lies inside it only for J1 in about
    30.5..43.8 deg, where no J1 the simple ways try takes the elbow flip."""
    return _cell(tmp_path_factory.mktemp("cell"), "long_arm", scara={"l1_mm": 400.0, "l2_mm": 250.0})


def _flip(cell):
    """From the drop-off (elbow left) to above the pulley with the elbow right (the hunter's case)."""
    d = dropoff_options(cell, Joints(0.0, 90.0, 200.0, 0.0))[0]
    z = cell.motion.safe_z_mm
    return Joints(d.j1_deg, d.j2_deg, z, d.j4_deg), Joints(43.094, -101.921, z, -63.183)


class Recorded:
    """A leg check refusing a move that passes through `box` ((J1 lo, hi), (J2 lo, hi), deg) on the straight line
    between its ends (the links over a tall part there), keeping every move it was asked about."""

    def __init__(self, box=None, key=()):
        self.box, self.asked, self.key = box, [], key

    def __call__(self, a: Joints, b: Joints) -> list[str]:
        self.asked.append((a, b))
        if self.box is not None:
            t = np.linspace(0.0, 1.0, 50)
            j1, j2 = a.j1_deg + t * (b.j1_deg - a.j1_deg), a.j2_deg + t * (b.j2_deg - a.j2_deg)
            (lo1, hi1), (lo2, hi2) = self.box
            if ((lo1 <= j1) & (j1 <= hi1) & (lo2 <= j2) & (j2 <= hi2)).any():
                return ["the arm's links would hit column"]
        return []


def _taken(cell, start, moves, leg):
    """Every move from the one before: the drivers take it and the leg check lets it."""
    at = start
    for m in moves:
        assert command_violations(cell, m, None) == [] and command_violations(cell, m, at) == [], (at, m)
        assert leg(at, m) == [], (at, m)
        at = m


def test_a_long_arms_elbow_flip_has_a_grid_way_for_a_pick_and_none_without(long_arm):
    start, target = _flip(long_arm)
    assert command_violations(long_arm, target, start)  # the direct way leaves the workspace
    with pytest.raises(CellError, match="no way to 'approach'.*leave the workspace"):
        way_to(long_arm, start, target, "approach", Recorded(), grid=False)  # as recordings made before ran
    leg = Recorded()
    moves = way_to(long_arm, start, target, "approach", leg)
    assert moves[-1] == target
    _taken(long_arm, start, moves, leg)
    assert len(moves) <= 5  # the grid's staircase (11 moves) cut short where one move takes a run of them
    assert all(m.j3_mm == target.j3_mm for m in moves)  # across at one height


def test_the_grid_way_goes_round_what_the_leg_check_refuses(long_arm):
    start, target = _flip(long_arm)
    free = way_to(long_arm, start, target, "approach", Recorded())
    box = ((33.0, 38.0), (-40.0, 20.0))  # where the free way flips the elbow (J2 through 0 at J1 35)
    assert Recorded(box)(start, free[0]) or any(Recorded(box)(a, b) for a, b in zip(free, free[1:]))
    leg = Recorded(box, key=None)
    moves = way_to(long_arm, start, target, "approach", leg)
    assert moves[-1] == target
    _taken(long_arm, start, moves, leg)  # flipped at J1 38..43.8 or 30.5..33 instead
    # the elbow flip refused everywhere (J2 through 0): no way
    with pytest.raises(CellError, match="no way to 'approach'"):
        way_to(long_arm, start, target, "approach", Recorded(((-180.0, 180.0), (-20.0, 20.0)), key=None))


def test_a_start_whose_grid_reaches_no_way_is_searched_once(tmp_path):
    """y within +-300: the stretched long arm lies inside the workspace at no J1, no elbow flips. Many targets
    from one start (a plan's grasps): the first search sees all the start reaches, later ones look up its
    corners; a target it reaches is still found."""
    cell = _cell(tmp_path, "no_flip", scara={"l1_mm": 400.0, "l2_mm": 250.0},
                 workspace={"y_mm": [-300.0, 300.0]}, motion={"dropoff_mm": [330.0, 280.0, 120.0]})
    start = Joints(0.0, 60.0, 150.0, 0.0)
    flipped = [Joints(-30.0, -130.0, 150.0, j4) for j4 in (0.0, 45.0)] + [Joints(-25.0, -125.0, 150.0, 0.0)]
    for t in flipped:
        assert not command_violations(cell, t, None)
    asked = []
    for t in flipped:
        leg = Recorded(key=("a key",))
        with pytest.raises(CellError, match="no way"):
            way_to(cell, start, t, "approach", leg)
        asked.append(len(leg.asked))
    assert asked[0] > 200 and max(asked[1:]) < 0.2 * asked[0], asked  # (the simple ways' tries remain)
    # a target the start reaches, its grid searched from there after the failures kept (the simple ways aside)
    same_elbow = Joints(10.0, 50.0, 150.0, 0.0)
    assert not command_violations(cell, same_elbow, None)
    leg = Recorded(key=("a key",))
    moves = _pick_grid_way(cell, start, same_elbow, leg)
    assert moves and moves[-1] == same_elbow
    _taken(cell, start, moves, leg)
    # without a key nothing is kept: each search is whole
    legs = [Recorded(key=None) for _ in range(2)]
    for leg in legs:
        with pytest.raises(CellError):
            way_to(cell, start, flipped[0], "approach", leg)
    assert len(legs[1].asked) == len(legs[0].asked) > 200


def test_a_move_the_links_refuse_refuses_the_list_before_a_later_way_is_searched(long_arm):
    start, target = _flip(long_arm)
    first = Joints(start.j1_deg + 10.0, start.j2_deg, start.j3_mm, start.j4_deg)
    commands = [Command("move", "hop", joints=first), Command("move", "approach", joints=target)]
    box = ((start.j1_deg + 5.0, start.j1_deg + 6.0), (-180.0, 180.0))
    leg = Recorded(box)
    with pytest.raises(CellError, match="on the way to 'hop' the arm's links would hit column"):
        routed(commands, start, long_arm, leg)
    assert len(leg.asked) == 1  # no way round the approach was looked for
    # as recordings made before ran: the approach's way is searched (the simple ones; no grid) and refused
    with pytest.raises(CellError, match="no way to 'approach'"):
        routed(commands, start, long_arm, Recorded(box), grid=False)


def test_a_long_arm_run_removes_every_part_and_replays(tmp_path, capsys):
    from conftest import run_cli

    # the tray from x 225: its corners nearer the base need J2 past 150 deg on this arm (refused before a run)
    cell = _cell(tmp_path, "long_arm", scara={"l1_mm": 400.0, "l2_mm": 250.0}, tray={"x_mm": [225.0, 500.0]})
    del cell
    rec = tmp_path / "rec"
    code, out, err = run_cli("run", "--cell", tmp_path / "long_arm.json", "--record", rec, "--json", capsys=capsys)
    summary = json.loads(out.strip().splitlines()[-1])
    assert code == 0 and summary["parts_removed"] == summary["parts_total"] == 6, err  # was 1 of 6, exit 1
    meta = json.loads((rec / "manifest.json").read_text())["meta"]
    assert meta["grid_ways"] is True
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, out + err
