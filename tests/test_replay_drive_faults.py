"""Replay of grips whose jaws stopped wider than expected: the replay's jaws stop where the recorded ones did
(the recording is the world). A blocked grip (the jaws stopped at 29 mm on a 24 mm part) closed on nothing in
the replay: "records.5.blocked: missing in replay"."""

import json

from conftest import run_cli
from test_cell_loop import short_assembly  # noqa: F401 - the fixture: a nut, a washer and the PCB

from cell.runtime.session import RunConfig, run_session

CARRY_S = 0.15  # how far into the carry the fault comes (after the check's closing of the jaws)


def at_clock(clock, t_s: float, fn) -> None:
    """fn() once, on the drives' clock, at t_s (a fault mid-move, as the hardware brings it)."""
    def once():
        job.cancel()
        fn()

    job = clock.every(t_s - clock.now(), once, name="test-fault")


def record(tmp_path, monkeypatch, assembly, on_drives, *, after_grip: int = 2, delay_s: float = CARRY_S,
           world_setup=None):
    """A recorded session in which `on_drives(drives)` runs `delay_s` into the step after the first pick's
    `after_grip`-th closing of the jaws (1: the grip, so during the lift; 2: the check, so during the carry).
    Returns (recording, summary)."""
    from cell.runtime import session

    sources = session._simulated_sources

    def faulting(*a, **kw):
        arm, camera, world = sources(*a, **kw)
        grip, calls = arm.gripper.grip, []

        def grip_then_fault(*ga, **gk):
            result = grip(*ga, **gk)
            calls.append(1)
            if on_drives is not None and len(calls) == after_grip:
                at_clock(world.drives.clock, world.drives.clock.now() + delay_s, lambda: on_drives(world.drives))
            return result

        arm.gripper.grip = grip_then_fault
        if world_setup is not None:
            world_setup(world)
        return arm, camera, world

    monkeypatch.setattr(session, "_simulated_sources", faulting)
    rec = tmp_path / "rec"
    summary = run_session(RunConfig(assembly=assembly, record=rec, seed=3))
    monkeypatch.undo()
    return rec, summary


def decisions(rec) -> list[dict]:
    return [json.loads(line) for line in (rec / "decisions.jsonl").read_text().splitlines()]


def test_a_grip_whose_jaws_stopped_wider_than_expected_replays(tmp_path, monkeypatch, capsys,
                                                                short_assembly):  # noqa: F811
    """The jaws stop 5 mm wider than the part on every grip (a chip on a pad): the live run stops, missed
    twice; the replay's jaws stop where they stopped, blocked, as recorded."""
    def wide(world):
        jaws = world.drives.drives["gripper"]
        part_mm = jaws.object_width_fn
        jaws.object_width_fn = lambda: None if part_mm() is None else part_mm() + 5.0

    rec, s = record(tmp_path, monkeypatch, short_assembly, None, world_setup=wide)
    grips = [r for d in decisions(rec) if d["type"] == "executed" for r in d["records"] if r["action"] == "grip"]
    assert grips and all(g.get("blocked") and not g["holding"] for g in grips), grips
    assert s["status"] == "stopped" and "missed" in s["stopped"], s
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
