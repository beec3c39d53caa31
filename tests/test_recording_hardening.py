"""Bad recording directories, damaged recordings and concurrent example appends: each is a
clear error (exit 2), never a traceback, a wrong exit code or a lost or mixed-up file."""

import json
import shutil
from pathlib import Path

import pytest
from conftest import run_cli

from cell.recording import RecordingReader


def test_cell_run_refuses_to_record_into_a_non_empty_directory_and_leaves_it_alone(tmp_path, capsys):
    d = tmp_path / "notes"
    (d / "frames").mkdir(parents=True)
    (d / "decisions.jsonl").write_text('{"type": "mine"}\n')
    (d / "frames" / "000009.png").write_bytes(b"not a recording's frame")
    before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    code, _, err = run_cli("run", "--record", d, capsys=capsys)
    assert code == 2 and "not empty" in err and "Traceback" not in err
    assert {p: p.read_bytes() for p in d.rglob("*") if p.is_file()} == before


def test_cell_run_record_where_nothing_can_be_written_is_bad_input(tmp_path, capsys):
    f = tmp_path / "a-file"
    f.write_text("x")
    code, _, err = run_cli("run", "--record", f / "session", capsys=capsys)
    assert code == 2 and "cannot write the recording" in err and "Traceback" not in err
    assert f.read_text() == "x"


def _append_same_ids(args):
    import dataclasses

    from cell.errors import BadInput
    from cell.examples import append_examples, load_examples

    path, n = args
    src = load_examples(None)[:3]
    refused = 0
    for i in range(n):
        try:
            append_examples(path, [dataclasses.replace(src[i % 3], id=f"same-{i}")])
        except BadInput as e:
            assert "already in" in str(e)
            refused += 1
    return refused


def test_concurrent_appenders_of_the_same_ids_never_write_a_duplicate(tmp_path):
    """The id check runs under the file's lock: two processes adding the same next id (two
    stations, or a station and a run) add it once, the other is refused; the file stays readable."""
    import multiprocessing

    from cell.examples import load_examples

    path = tmp_path / "examples.jsonl"
    with multiprocessing.get_context("fork").Pool(6) as pool:
        refused = pool.map(_append_same_ids, [(path, 6)] * 6)
    ids = [e.id for e in load_examples(path)]
    assert sorted(ids) == [f"same-{i}" for i in range(6)]
    assert sum(refused) == 6 * 6 - 6


SHIPPED = Path(__file__).resolve().parent.parent / "recordings" / "shipped"


def _copy_of_shipped(tmp_path) -> Path:
    d = tmp_path / "copy"
    shutil.copytree(SHIPPED, d)
    return d


def _cut_off_mid_session(d: Path, keep: int = 7) -> None:
    """What a session killed mid-way leaves: the manifest still says "recording", the decision
    lines up to `keep`, then half a line; the frames up to the last perception."""
    lines = (d / "decisions.jsonl").read_text().splitlines()
    (d / "decisions.jsonl").write_text("\n".join(lines[:keep]) + "\n" + lines[keep][: len(lines[keep]) // 2])
    frames = {json.loads(x)["frame"] for x in lines[:keep] if json.loads(x)["type"] == "perception"}
    for f in (d / "frames").iterdir():
        if int(f.stem) not in frames:
            f.unlink()
    m = json.loads((d / "manifest.json").read_text())
    m.update(status="recording", closed=None, counts={"frames": 0, "decisions": 0})
    m.pop("summary", None)
    (d / "manifest.json").write_text(json.dumps(m))


def test_replay_of_a_session_killed_mid_way_says_incomplete_not_divergence(tmp_path, capsys):
    d = _copy_of_shipped(tmp_path)
    _cut_off_mid_session(d)
    assert RecordingReader(d).status == "incomplete"
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2, err
    assert "incomplete" in err and "7 recorded decisions match" in err and "divergence" not in err


def test_replay_json_of_a_session_killed_mid_way_says_how_far_it_matched_on_stdout(tmp_path, capsys):
    # the verdict was on stderr only, stdout empty: a script could not tell "7 matched, then killed" from a
    # corrupt folder
    d = _copy_of_shipped(tmp_path)
    _cut_off_mid_session(d)
    code, out, err = run_cli("replay", d, "--json", capsys=capsys)
    verdict = json.loads(out.strip().splitlines()[-1])
    assert code == 2 and "7 recorded decisions match" in err
    assert verdict["incomplete"] is True and verdict["matched"] == 7 and verdict["match"] is None
    assert "is torn" in " ".join(verdict["problems"]) and verdict["session"]["recording"] == "recording"
    (d / "manifest.json").write_text("{")  # a corrupt folder says so: nothing matched, not incomplete
    code, out, _ = run_cli("replay", d, "--json", capsys=capsys)
    verdict = json.loads(out.strip().splitlines()[-1])
    assert code == 2 and verdict["incomplete"] is False and verdict["matched"] is None and verdict["error"]


def test_replay_json_takes_how_far_it_matched_from_the_error_not_its_wording(tmp_path, capsys, monkeypatch):
    """`matched` was read back from the message with a regex: reworded, it said null. The error carries it."""
    from cell.runtime import replay as replay_module

    d = _copy_of_shipped(tmp_path)
    _cut_off_mid_session(d)

    def reworded(*a, **kw):
        raise replay_module.RecordingIncomplete("the end of this recording is missing (seven matched)", matched=7)

    monkeypatch.setattr(replay_module, "replay", reworded)
    code, out, _ = run_cli("replay", d, "--json", capsys=capsys)
    verdict = json.loads(out.strip().splitlines()[-1])
    assert code == 2 and verdict["incomplete"] is True and verdict["matched"] == 7


def test_replay_of_a_killed_session_still_names_a_divergence_within_what_was_recorded(tmp_path, capsys):
    d = _copy_of_shipped(tmp_path)
    _cut_off_mid_session(d)
    lines = (d / "decisions.jsonl").read_text().split("\n")
    g = json.loads(lines[1])
    g["opening_mm"] += 3.0
    lines[1] = json.dumps(g)
    (d / "decisions.jsonl").write_text("\n".join(lines))
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 1 and "decision #1 (grasp, nut): opening_mm" in err


def _torn_can_log(d: Path) -> None:
    raw = (d / "can.log").read_bytes()
    (d / "can.log").write_bytes(raw[: len(raw) // 2 + 7])


def _empty_can_log(d: Path) -> None:
    (d / "can.log").write_bytes(b"")


@pytest.mark.parametrize("damage, match", [
    (lambda d: (d / "can.log").unlink(), "can.log is missing"),
    (_torn_can_log, "can.log is cut off"),
    (_empty_can_log, "can.log holds no CAN traffic"),
    (lambda d: (d / "can.log").write_text("this is no candump log\n"), "not a readable candump log"),
])
def test_replay_refuses_a_complete_recording_whose_can_log_is_damaged(tmp_path, capsys, damage, match):
    d = _copy_of_shipped(tmp_path)
    damage(d)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and match in err and "Traceback" not in err


@pytest.mark.parametrize("where", ["a-dir", "a-file/x.rrd"])
def test_cell_run_save_where_no_rrd_can_be_written_is_bad_input_and_leaves_no_recording(tmp_path, capsys, where):
    (tmp_path / "a-dir").mkdir()
    (tmp_path / "a-file").write_text("x")
    rec = tmp_path / "session"
    code, _, err = run_cli("run", "--record", rec, "--save", tmp_path / where, capsys=capsys)
    assert code == 2 and "--save" in err and "Traceback" not in err
    assert not rec.exists()  # not a recording that says "recording" forever, as if the run had crashed


DEFAULT_CELL = Path(__file__).resolve().parent.parent / "cell" / "data" / "default_cell.json"


def _without_sha256(d: Path) -> None:
    """The manifest as recordings made before its sha256 key have it."""
    m = json.loads((d / "manifest.json").read_text())
    assert m.pop("sha256")
    (d / "manifest.json").write_text(json.dumps(m))


def _edit_manifest(**changes):
    def damage(d: Path) -> None:
        m = json.loads((d / "manifest.json").read_text())
        for k, v in changes.items():
            if "." in k:
                outer, inner = k.split(".")
                m[outer][inner] = v
            else:
                m[k] = v
        (d / "manifest.json").write_text(json.dumps(m))
    return damage


def _middle_frame_lost_in_a_crash(d: Path) -> None:
    _edit_manifest(status="recording")(d)  # an unclosed manifest states no counts to check against
    (d / "frames" / "000001.png").unlink()


@pytest.mark.parametrize("damage, match", [
    (_edit_manifest(counts="x"), "'counts' must be an object"),
    (_edit_manifest(**{"files.calibration": 7}), "'files.calibration' must be a file name or null"),
    (_edit_manifest(meta=5), "'meta' must be an object"),
    (_edit_manifest(**{"meta.on_no_grasp": "explode"}), "meta.on_no_grasp must be 'stop' or 'skip'"),
    (_edit_manifest(**{"meta.lift_check": 1}), "meta.lift_check must be true or false"),
    (_edit_manifest(**{"meta.whole_part_report": "yes"}), 'meta.whole_part_report must be true or false, not \'yes\''),
    (_middle_frame_lost_in_a_crash, "frame 1 (frames/000001.png) is missing"),
])
def test_replay_refuses_a_malformed_manifest_or_a_lost_frame(tmp_path, capsys, damage, match):
    d = _copy_of_shipped(tmp_path)
    damage(d)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and match in err and "Traceback" not in err


@pytest.mark.parametrize("argv, match", [
    (["--sim-miss", "nutt"], "--sim-miss nutt: no such part"),
    (["--sim-stuck", "washr"], "--sim-stuck washr: no such part"),
    (["--sim-drop", "pbc"], "--sim-drop pbc: no such part"),
    (["--sim-miss", "nut:0"], "N must be at least 1"),
])
def test_cell_run_refuses_a_simulated_fault_on_a_part_that_is_not_there(tmp_path, capsys, argv, match):
    code, _, err = run_cli("run", *argv, capsys=capsys)
    assert code == 2 and match in err and "Traceback" not in err


def test_replay_with_a_bad_example_file_names_that_file(tmp_path, capsys):
    bad = tmp_path / "mine.jsonl"
    bad.write_text("{not json\n")
    code, _, err = run_cli("replay", SHIPPED, "--examples", bad, capsys=capsys)
    assert code == 2 and f"example file {bad} line 1" in err


def _a_directory_instead_of(name):
    def damage(d: Path) -> None:
        (d / name).unlink()
        (d / name).mkdir()
    return damage


def _a_fifo_instead_of(name):
    def damage(d: Path) -> None:
        import os
        import threading

        (d / name).unlink()
        os.mkfifo(d / name)

        def unblock():  # should the check go, a read that waits gets an end of file (no hang)
            for _ in range(600):
                try:
                    os.close(os.open(d / name, os.O_WRONLY | os.O_NONBLOCK))
                except OSError:  # nobody is reading yet
                    pass
                threading.Event().wait(0.05)

        threading.Thread(target=unblock, daemon=True).start()
    return damage


def _nan_in_a_decision(d: Path) -> None:
    lines = (d / "decisions.jsonl").read_text().splitlines()
    lines[1] = lines[1].replace('"opening_mm":', '"opening_mm":NaN,"was":', 1)
    (d / "decisions.jsonl").write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("damage, match", [
    (_a_directory_instead_of("decisions.jsonl"), "decisions.jsonl is a directory, not a file"),
    (_a_directory_instead_of("can.log"), "can.log is a directory, not a file"),
    (_a_fifo_instead_of("decisions.jsonl"), "decisions.jsonl is not a regular file"),
    (_a_fifo_instead_of("can.log"), "can.log is not a regular file"),
    (_nan_in_a_decision, "decisions.jsonl line 2: not valid JSON (NaN is not JSON)"),
])
def test_replay_refuses_unreadable_recording_files(tmp_path, capsys, damage, match):
    d = _copy_of_shipped(tmp_path)
    damage(d)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and match in err and "Traceback" not in err


def test_sigterm_ends_cell_run_like_ctrl_c_and_the_recording_replays_to_there(tmp_path, capsys):
    """SIGTERM quick-stops the arm and closes the recording as incomplete, with the stop in it
    (it used to kill the run outright: a recording still saying "recording", like a crash); a
    recording stopped at the terminal replays up to the stop (it used to 'diverge' there)."""
    import signal
    import subprocess
    import sys
    from importlib import resources

    d = json.loads((resources.files("cell") / "data" / "assemblies" / "default.json").read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] in ("nut", "washer", "pcb")]
    d["sequence"] = ["nut", "washer", "pcb"]
    asm = tmp_path / "short.json"
    asm.write_text(json.dumps(d))
    rec = tmp_path / "session"
    proc = subprocess.Popen([sys.executable, "-m", "cell", "run", str(asm), "--record", str(rec), "--seed", "3",
                             "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stderr:  # (--json: the progress on stderr, the summary alone on stdout)
            if line.startswith("[removed]"):
                proc.send_signal(signal.SIGTERM)
                break
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err, err
    # the summary is still the last stdout line: what was removed before the stop, and why it stopped
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["status"] == "stopped" and summary["parts_removed"] >= 1
    assert summary["stopped"] == "operator: interrupted by SIGTERM"  # (it said "at the terminal")
    stopped = [p for p in summary["parts"] if p["outcome"] == "stopped"]  # the part worked on says why too
    assert all(p["reason"] == "operator: interrupted by SIGTERM" for p in stopped), stopped
    r = RecordingReader(rec)
    assert r.manifest["status"] == "incomplete" and r.decisions[-1]["type"] == "stop"
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0, err
    # matched to the stop, and said to have ended there (it used to read like a whole session)
    assert "the recorded session was stopped (incomplete) after " in out, out
    assert out.rstrip().endswith("operator: interrupted by SIGTERM"), out


def test_examples_generate_overwrite_waits_for_an_append_in_progress(tmp_path, capsys):
    """--overwrite takes the appenders' lock: an appender that read the old file and is writing
    it back with its line would otherwise put the old lines over the new file (the overwrite lost)."""
    import fcntl
    import threading
    import time

    from cell.examples import load_examples

    out = tmp_path / "examples.jsonl"
    shutil.copyfile(SHIPPED / "examples_at_start.jsonl", out)
    before = out.read_bytes()
    done = {}
    with open(tmp_path / ".examples.jsonl.lock", "w") as lock:  # as append_examples holds it
        fcntl.flock(lock, fcntl.LOCK_EX)
        t = threading.Thread(target=lambda: done.setdefault("code", run_cli(
            "examples", "generate", "--out", out, "--overwrite", "--count", "1")))
        t.start()
        time.sleep(3.0)
        assert out.read_bytes() == before  # still waiting for the appender
    t.join(60)
    assert done["code"] == 0 and out.read_bytes() != before and len(load_examples(out)) >= 1


def test_the_manifest_states_the_can_frames_logged_at_close(tmp_path):
    import time

    import can

    from cell.recording import RecordingWriter

    w = RecordingWriter(tmp_path / "r")
    with can.Bus(interface="virtual", channel="hardening-can-count") as bus, \
            can.Bus(interface="virtual", channel="hardening-can-count") as sender:
        w.attach_can_logger(bus)
        for i in range(25):
            sender.send(can.Message(arbitration_id=0x600 + i, data=[i], is_extended_id=False))
        t0 = time.monotonic()
        while (w.can_log_path.read_bytes().count(b"\n") if w.can_log_path.exists() else 0) < 25:
            assert time.monotonic() - t0 < 5
            time.sleep(0.02)
        w.close("complete")
    assert json.loads((tmp_path / "r" / "manifest.json").read_text())["can_frames_at_close"] == 25
    assert len(RecordingReader(tmp_path / "r").can_messages()) == 25


def test_replay_refuses_a_can_log_cut_off_at_a_line_boundary(tmp_path, capsys):
    """Cut at a line boundary, the log reads as whole: the count at close says it was longer."""
    d = _copy_of_shipped(tmp_path)
    n = (d / "can.log").read_bytes().count(b"\n")
    _edit_manifest(can_frames_at_close=n)(d)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 0, err  # all there
    lines = (d / "can.log").read_bytes().split(b"\n")
    (d / "can.log").write_bytes(b"\n".join(lines[: n // 2]) + b"\n")
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and f"holds {n // 2} CAN frames, the manifest says it held {n}" in err


@pytest.mark.parametrize("value, shown", [('"many"', "'many'"), ("1e300", "1e+300"), ("NaN", "NaN"), ("-1", "-1"),
                                          ("3151.5", "3151.5"), ("true", "true"), ("null", "null")])
@pytest.mark.parametrize("cut", [False, True], ids=["whole-log", "cut-log"])
def test_replay_refuses_a_manifest_whose_can_frames_at_close_is_not_a_count(tmp_path, capsys, value, shown, cut):
    """Was: the truncation check skipped; a log cut at a line boundary replayed as a divergence (exit 1), a whole
    one was accepted without a word."""
    d = _copy_of_shipped(tmp_path)
    text = (d / "manifest.json").read_text()
    held = f'"can_frames_at_close": {json.loads(text)["can_frames_at_close"]}'  # (heartbeats: it varies by recording)
    assert held in text
    (d / "manifest.json").write_text(text.replace(held, f'"can_frames_at_close": {value}'))
    if cut:
        lines = (d / "can.log").read_bytes().split(b"\n")
        (d / "can.log").write_bytes(b"\n".join(lines[:3000]) + b"\n")
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2, err
    assert err.strip() == (f"cell: error: {d / 'manifest.json'}: 'can_frames_at_close' must be a whole number of "
                           f"CAN frames (0 or more), not {shown}")


def test_replay_takes_a_manifest_without_can_frames_at_close_as_made_before_the_key(tmp_path, capsys):
    """Recordings made before the manifest counted the CAN frames (and sessions that crashed before the close
    wrote it) have no key: replayed without the truncation check, as before."""
    d = _copy_of_shipped(tmp_path)
    m = json.loads((d / "manifest.json").read_text())
    del m["can_frames_at_close"]
    (d / "manifest.json").write_text(json.dumps(m))
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 0, err


@pytest.mark.parametrize("damage, match", [
    (lambda d: (d / "session.rrd").unlink(), "session.rrd is missing"),
    (lambda d: (d / "session.rrd").write_bytes(b"\x00" * 64), "session.rrd is not a rerun recording"),
])
def test_replay_refuses_a_complete_recording_that_lost_its_rrd(tmp_path, capsys, damage, match):
    d = _copy_of_shipped(tmp_path)
    damage(d)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and match in err


def test_a_run_that_fails_mid_way_is_recorded_as_failed_and_replays_as_incomplete(tmp_path, capsys, monkeypatch):
    # a full disk after the first part (seen on a 3 MB tmpfs): the run ends with exit 1 (not bad input), and its
    # recording used to be closed as "complete", which replay then called a divergence (exit 1)
    import errno

    from cell.runtime.loop import CellLoop

    plan, calls = CellLoop._plan, []

    def plan_until_the_disk_fills(self, scene, part_id):
        calls.append(part_id)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return plan(self, scene, part_id)

    monkeypatch.setattr(CellLoop, "_plan", plan_until_the_disk_fills)
    # the default assembly's first two parts: the fewer parts to locate in every frame, run and replay, the
    # sooner (the whole assembly: 16 s)
    from importlib import resources

    two = json.loads((resources.files("cell") / "data" / "assemblies" / "default.json").read_text())
    two["parts"] = [p for p in two["parts"] if p["id"] in two["sequence"][:2]]
    two["sequence"] = two["sequence"][:2]
    (tmp_path / "two.json").write_text(json.dumps(two))
    d = tmp_path / "rec"
    code, _, err = run_cli("run", tmp_path / "two.json", "--record", d, "--json", capsys=capsys)
    assert code == 1 and "No space left on device" in err
    m = json.loads((d / "manifest.json").read_text())
    assert m["status"] == "incomplete" and m["summary"]["status"] == "failed"
    assert m["summary"]["parts_removed"] == 1 and "No space left" in m["summary"]["error"]
    monkeypatch.setattr(CellLoop, "_plan", plan)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and "incomplete" in err and "divergence" not in err


def test_replay_names_a_host_can_frame_that_differs_from_the_recording(tmp_path, capsys):
    # a target position the host sent changed in the CAN log: the decisions still match, the commands on
    # the bus do not (replay used to look only at whether the log was whole: exit 0)
    d = _copy_of_shipped(tmp_path)
    log = d / "can.log"
    lines = log.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if " 302#" in line)
    head, tail = lines[k].split(" 302#")
    recorded = tail.split()[0]
    lines[k] = f"{head} 302#10270000 {' '.join(tail.split()[1:])}".rstrip()
    log.write_text("\n".join(lines) + "\n")
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 1 and "divergence: CAN id 0x302: the host's frame #0" in err
    assert recorded.lower() in err and "10270000" in err


@pytest.mark.parametrize("damage, match", [
    (lambda d: (d / "examples_at_start.jsonl").write_bytes(  # cut short: 13 of 13 decisions still matched
        b"".join((SHIPPED / "examples_at_start.jsonl").read_bytes().splitlines(keepends=True)[:70])),
     "examples_at_start.jsonl is not the example file the session started with (sha256 "),
    (lambda d: (d / "examples_at_start.jsonl").unlink(), "the examples the session started with, "
     "examples_at_start.jsonl, are missing"),
    (lambda d: shutil.copyfile(DEFAULT_CELL, d / "cell.json"),  # another session's cell file
     "cell.json is not the cell file the session ran with (sha256 "),
    (lambda d: (_without_sha256(d), shutil.copyfile(DEFAULT_CELL, d / "cell.json")),  # made before the sha256 key:
     # its camera is 1280 x 1024 px, the frames' 640 x 512
     "frame 0 is 640 x 512 px, the camera of its cell file cell.json 1280 x 1024 px: not the cell file"),
], ids=["examples-cut-short", "examples-missing", "cell-file-swapped", "cell-file-swapped-before-sha256"])
def test_replay_refuses_a_recording_file_that_is_not_what_the_manifest_says(tmp_path, capsys, damage, match):
    """Replay compared only the decisions: a recording whose examples_at_start.jsonl lost its last lines, or
    that held another session's cell.json, replayed with exit 0 ("13 of 13 decisions match")."""
    d = _copy_of_shipped(tmp_path)
    damage(d)
    code, out, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and match in err and "Traceback" not in err, err
    assert "decisions match" not in out


def test_replay_with_other_examples_does_not_need_the_recorded_ones(tmp_path, capsys):
    """--examples FILE replays with that file: the copy of the session's examples is not read, nor held to."""
    d = _copy_of_shipped(tmp_path)
    (d / "examples_at_start.jsonl").write_text("")
    code, out, err = run_cli("replay", d, "--examples", SHIPPED / "examples_at_start.jsonl", capsys=capsys)
    assert code == 0, err


@pytest.fixture(scope="module")
def fresh_recording(tmp_path_factory) -> Path:
    """A recording made now (its manifest holds the sha256 of its cell.json and calibration.json), of a one-part
    assembly: the recording is what is looked at, not the parts."""
    from cell.runtime.session import default_assembly_path

    tmp = tmp_path_factory.mktemp("fresh")
    one = json.loads(default_assembly_path().read_text())
    one["parts"], one["sequence"] = [p for p in one["parts"] if p["id"] == one["sequence"][0]], one["sequence"][:1]
    (tmp / "one.json").write_text(json.dumps(one))
    assert run_cli("run", tmp / "one.json", "--record", tmp / "rec") == 0
    return tmp / "rec"


def _neutral_edit(name):
    def damage(d: Path) -> None:  # a key no reader looks at: the file still loads, as the one the session ran with
        data = json.loads((d / name).read_text())
        data["comment"] = "edited after the session"
        (d / name).write_text(json.dumps(data, indent=2))
    return damage


def test_a_new_recording_holds_the_sha256_of_its_cell_and_calibration_files_and_replays(tmp_path, capsys,
                                                                                          fresh_recording):
    from cell.fileio import file_sha256

    d = tmp_path / "copy"
    shutil.copytree(fresh_recording, d)
    m = json.loads((d / "manifest.json").read_text())
    assert m["sha256"] == {"cell": file_sha256(d / "cell.json"), "calibration": file_sha256(d / "calibration.json")}
    code, out, err = run_cli("replay", d, capsys=capsys)
    assert code == 0 and "decisions match" in out, err


@pytest.mark.parametrize("damage, match", [
    (_neutral_edit("cell.json"), "cell.json is not the cell file the session ran with (sha256 "),
    (_neutral_edit("calibration.json"), "calibration.json is not the calibration the session ran with (sha256 "),
], ids=["cell-file-edited", "calibration-edited"])
def test_replay_refuses_a_cell_or_calibration_file_that_is_not_the_one_the_session_ran_with(
        tmp_path, capsys, fresh_recording, damage, match):
    """The manifest held no sha256 of them: an edited cell.json or calibration.json (or another session's, of the
    same camera size) replayed with exit 0 ("7 of 7 decisions match")."""
    d = tmp_path / "copy"
    shutil.copytree(fresh_recording, d)
    damage(d)
    code, out, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and match in err and str(d) in err
    assert "decisions match" not in out


@pytest.mark.parametrize("sha256, match", [
    ("x", "'sha256' must be an object, not 'x'"),
    ({"cell": "c443dc17"}, "'sha256.cell' must be a sha256 (64 hex digits), not 'c443dc17'"),
    ({"cell": "z" * 64}, "'sha256.cell' must be a sha256 (64 hex digits), not 'zzzz"),
    ({"calibration": 5}, "'sha256.calibration' must be a sha256 (64 hex digits), not 5"),
    ({"calibration": None}, "'sha256.calibration' must be a sha256 (64 hex digits), not null"),
], ids=["not-an-object", "cell-short", "cell-not-hex", "calibration-a-number", "calibration-null"])
def test_replay_refuses_a_manifest_whose_sha256_entry_is_not_a_sha256(tmp_path, capsys, sha256, match):
    d = _copy_of_shipped(tmp_path)
    _edit_manifest(sha256=sha256)(d)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and "Traceback" not in err, err
    assert err.strip().startswith(f"cell: error: {d / 'manifest.json'}: {match}")


def test_replay_takes_a_recording_without_sha256_as_made_before_the_key(tmp_path, capsys):
    """Recordings made before the manifest held the sha256 of their cell and calibration files are replayed
    as before, by the decisions, the frames' size and the examples' sha256."""
    d = _copy_of_shipped(tmp_path)
    _without_sha256(d)
    code, out, err = run_cli("replay", d, capsys=capsys)
    assert code == 0 and "decisions match" in out, err


def test_replay_refuses_a_manifest_with_the_sha256_of_a_calibration_the_recording_does_not_hold(tmp_path, capsys):
    d = _copy_of_shipped(tmp_path)
    _edit_manifest(**{"files.calibration": None})(d)
    _edit_manifest(sha256={"calibration": "0" * 64})(d)
    code, _, err = run_cli("replay", d, capsys=capsys)
    assert code == 2 and "'sha256.calibration' is given, but the recording holds no calibration" in err, err


def test_a_recording_under_a_name_that_is_not_utf8_replays(tmp_path, capsys):
    """`cell run --record $'r\\xff'` wrote the name into the manifest as a lone surrogate, which the reader
    refuses (replay exit 2), and OpenCV's imread crashed on the frames' names (SIGSEGV). The name's bytes are
    kept as \\xff in the manifest, and frames are read by Python and decoded by OpenCV."""
    import os

    rec = tmp_path / os.fsdecode(b"r\xff")
    examples = tmp_path / os.fsdecode(b"e\xfe.jsonl")
    shutil.copyfile(Path(__file__).resolve().parents[1] / "cell" / "data" / "default_examples.jsonl", examples)
    code, _, err = run_cli("run", "--record", rec, "--examples", examples, capsys=capsys)
    assert code == 0, err
    manifest = json.loads((rec / "manifest.json").read_bytes())  # valid JSON, valid UTF-8
    assert manifest["summary"]["recording"].endswith("r\\xff") and manifest["examples"]["path"].endswith("e\\xfe.jsonl")
    code, out, err = run_cli("replay", rec, capsys=capsys)
    assert code == 0 and "match the recording" in out, err


def test_replay_tells_true_from_one():
    """A recorded `"holding": true` edited to 1 matched: a yes/no is compared as one, numbers within the
    tolerance as before."""
    from cell.runtime.replay import differences

    assert differences({"holding": True}, {"holding": 1}) == ["holding: recorded true, replayed 1"]
    assert differences({"holding": 1}, {"holding": True}) == ["holding: recorded 1, replayed true"]
    assert differences({"holding": False}, {"holding": 0.0}) != []
    assert differences({"holding": True, "x": 2}, {"holding": True, "x": 2.0 + 1e-6}) == []
