"""Replay of sessions that stopped on a drive or bus fault mid-pick, and of grips whose jaws stopped wider than
expected: the replay re-creates what the hardware did (the recording is the world) and matches up to the stop.

Before, only an EMCY was injected again; a lost heartbeat, bus-off, a lost SDO answer, STO or a reboot were
not, so the replayed pick ran to its end and the replay reported "decision #4 (stop): attempt: not in the
recording" (exit 1), which reads like a planning difference. A blocked grip (the jaws stopped at 29 mm on a
24 mm part) closed on nothing in the replay: "records.5.blocked: missing in replay"."""

import json

import pytest
from conftest import run_cli
from test_cell_loop import short_assembly  # noqa: F401 - the fixture: a nut, a washer and the PCB

from cell.runtime.replay import at_clock
from cell.runtime.session import RunConfig, run_session

CARRY_S = 0.15  # how far into the carry the fault comes (after the check's closing of the jaws)


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


FAULTS = {  # what the hardware did mid-carry, and what the stop says of it
    "heartbeat lost": (lambda d: d.inject_fault("silent", "j1"), "j1", "no heartbeat for"),
    "bus-off": (lambda d: d.inject_fault("error_frames", error_class="bus_off", count=1), "cell", "bus-off"),
    "STO": (lambda d: d.inject_fault("disable", "j2"), "j2", "now in SWITCH_ON_DISABLED"),
    "quick stop input": (lambda d: d.inject_fault("quick_stop", "j2"), "j2", "left OPERATION ENABLED"),
    "reboot mid-move": (lambda d: d.inject_fault("reboot", "j2"), "j2", "j2 (node 2) rebooted (boot-up message)"),
    "gripper reboot": (lambda d: d.inject_fault("reboot", "gripper"), "gripper",
                       "gripper (node 5) rebooted (boot-up message)"),
    "EMCY": (lambda d: d.inject_fault("emcy", "j4", code=0x4310), "j4", "EMCY 0x4310"),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_session_stopped_by_a_drive_or_bus_fault_mid_carry_replays_to_its_stop(tmp_path, monkeypatch, capsys,
                                                                                  short_assembly, fault):  # noqa: F811
    inject, source, says = FAULTS[fault]
    rec, s = record(tmp_path, monkeypatch, short_assembly, inject)
    stop = decisions(rec)[-1]
    assert s["status"] == "stopped" and stop["type"] == "stop", s
    assert stop["source"] == source and says in stop["reason"], stop
    cut = [d for d in decisions(rec) if d["type"] == "interrupted"]
    assert cut and "check" in [r["label"] for r in cut[0]["records"]], cut  # it came after the check
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
    compared = len(decisions(rec)) - len(cut)  # (the steps of a pick cut short are not compared)
    assert f"{compared} of {compared} decisions match" in out, out
    assert "re-created" in out and "taken from the recording" not in out, out


def test_a_loop_that_no_longer_stops_on_the_re_created_fault_diverges(tmp_path, monkeypatch, capsys,
                                                                       short_assembly):  # noqa: F811
    """The replay sends the recorded reboot again but the loop goes on (here: the fault never reaches the drive, as
    a loop that ignored it would behave): the pick runs to its end, which is a divergence (exit 1), not a match
    with a note (it was: "5 of 5 decisions match", exit 0)."""
    from cell.runtime import replay

    rec, _ = record(tmp_path, monkeypatch, short_assembly, lambda d: d.inject_fault("reboot", "j2"))
    monkeypatch.setattr(replay, "inject_again", lambda drives, fault: None)
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 1, out
    assert "did not stop on the re-created fault" in err + out and "its next decision: executed" in err + out


def test_an_sdo_answer_lost_replays_to_its_stop(tmp_path, monkeypatch, capsys, short_assembly):  # noqa: F811
    # lost from the lift on: J1's next SDO request is the carry's first
    rec, s = record(tmp_path, monkeypatch, short_assembly, lambda d: d.inject_fault("drop_sdo", "j1"),
                    after_grip=1, delay_s=0.05)
    stop = decisions(rec)[-1]
    assert stop["source"] == "j1" and "no SDO answer" in stop["reason"], stop
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
    assert "re-created" in out, out


def test_a_stop_the_replay_cannot_re_create_is_taken_from_the_recording_and_said(tmp_path, monkeypatch, capsys,
                                                                                 short_assembly):  # noqa: F811
    """A move timeout with nothing in the CAN log to say why (a recording made before the host named a reboot,
    whose stop said "target not reached in time", and the node's boot-up frame cut out of the log as a real
    bus may lose it): the replay compares up to the stop and says the stop itself was a hardware fault taken
    from the recording, not re-run; no planning divergence."""
    rec, _ = record(tmp_path, monkeypatch, short_assembly, lambda d: d.inject_fault("reboot", "j2"))
    lines = (rec / "decisions.jsonl").read_text().splitlines()
    stop = json.loads(lines[-1])
    assert stop["type"] == "stop" and "j2 (node 2) rebooted" in stop["reason"], stop
    lines[-1] = json.dumps({**stop, "reason": "j2: target not reached in time"})
    (rec / "decisions.jsonl").write_text("".join(line + "\n" for line in lines))
    log = (rec / "can.log").read_text().splitlines()
    boot_ups = [i for i, line in enumerate(log) if line.endswith(" 702#00 R")]
    del log[boot_ups[-1]]  # the boot-up mid-carry (the first is the power-on's)
    (rec / "can.log").write_text("".join(line + "\n" for line in log))
    manifest = json.loads((rec / "manifest.json").read_text())
    manifest["can_frames_at_close"] -= 1
    (rec / "manifest.json").write_text(json.dumps(manifest))
    code, out, err = run_cli("replay", rec, "--json", capsys=capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["match"] and result["matched"] == result["decisions"], result
    assert any("taken from the recording, not re-run" in n and "j2: target not reached in time" in n
               for n in result["notes"]), result


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


@pytest.mark.parametrize("kind", ["emcy", "disable", "silent"])
def test_a_fault_on_the_way_up_after_a_miss_is_re_created_by_the_replay(kind, tmp_path, monkeypatch, capsys):
    """J3 faults as the empty jaws go up after a missed grip (the retreat, after the pick's `executed`). Was: the
    replay went on to the next frame and diverged ('decision #5 (stop): reason: recorded ..., replayed no readable
    frame ...', exit 1); the fault is now brought again at the replay's next move, and said so."""
    from cell.runtime import session
    from cell.runtime.simworld import WorldFaults

    sources = session._simulated_sources

    def faulting(*a, **kw):
        arm, camera, world = sources(*a, **kw)
        opened, calls = arm.gripper.open, []

        def open_then_fault(*oa, **ok):
            result = opened(*oa, **ok)
            calls.append(1)
            if len(calls) == 2:  # the pre-open, then the retreat's: j3 faults 50 ms into the way up
                d = world.drives
                if kind == "emcy":
                    d.inject_fault("emcy", "j3", after_s=0.05)
                else:
                    at_clock(d.clock, d.clock.now() + 0.05, lambda: d.inject_fault(kind, "j3"))
            return result

        arm.gripper.open = open_then_fault
        return arm, camera, world

    monkeypatch.setattr(session, "_simulated_sources", faulting)
    rec = tmp_path / "rec"
    from test_recording_interrupts import _two_parts

    s = run_session(RunConfig(assembly=_two_parts(tmp_path), record=rec, seed=3, faults=WorldFaults(miss={"nut": 1})))
    monkeypatch.undo()
    kinds = [d["type"] for d in decisions(rec)]
    assert s["stopped"].startswith("j3: ") and kinds[-3:] == ["commands", "executed", "stop"], (s["stopped"], kinds)
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
    assert "a hardware fault, re-created" in out and "after the pick ended (the way up after a miss)" in out, out
