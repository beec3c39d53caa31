"""`cell replay` on recordings damaged in ways the hardening tests did not try: exit 2, one clear line."""

import json
import shutil
import struct
import zlib
from pathlib import Path

import pytest
from conftest import run_cli

SHIPPED = Path(__file__).resolve().parent.parent / "recordings" / "shipped"


def _png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header claims width x height pixels (more than OpenCV decodes) with little data."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 1000))
            + chunk(b"IEND", b""))


def _cut_short_frame(d):
    f = d / "frames" / "000001.png"
    f.write_bytes(f.read_bytes()[:5000])


def _damage_frame(d: Path):
    (d / "frames" / "000001.png").write_bytes(_png_header_only(60000, 60000))


def _counts_as_strings(d: Path):
    m = json.loads((d / "manifest.json").read_text())
    m["counts"] = {k: str(v) for k, v in m["counts"].items()}
    (d / "manifest.json").write_text(json.dumps(m))


def _planner_a_list(d: Path):
    m = json.loads((d / "manifest.json").read_text())
    m["meta"]["planner"] = []
    (d / "manifest.json").write_text(json.dumps(m))


def _deep_decision_line(d: Path):
    lines = (d / "decisions.jsonl").read_text().splitlines()
    lines.insert(3, "[" * 100000 + "]" * 100000)  # json's decoder recurses per level
    (d / "decisions.jsonl").write_text("\n".join(lines) + "\n")


def _big_integer_in_manifest(d: Path):
    text = (d / "manifest.json").read_text()
    (d / "manifest.json").write_text(text.replace('"version": 1,', '"version": 1, "zz": ' + "9" * 5000 + ",", 1))


def _big_integer_in_a_decision(d: Path):
    lines = (d / "decisions.jsonl").read_text().splitlines()
    lines[0] = '{"zz": ' + "9" * 5000 + ", " + lines[0][1:]
    (d / "decisions.jsonl").write_text("\n".join(lines) + "\n")


def _twice_in_a_decision(line: int, pair: str, newline: bool = True):
    """Decision line `line` (1-based; -1 the last) ends with `pair` ('"key":value'), a key it already has."""
    def damage(d: Path):
        lines = (d / "decisions.jsonl").read_text().splitlines()
        lines[line if line < 0 else line - 1] = lines[line if line < 0 else line - 1][:-1] + f",{pair}}}"
        (d / "decisions.jsonl").write_text("\n".join(lines) + ("\n" if newline else ""))
    return damage


def _lone_surrogate_in_a_decision(d: Path):
    lines = (d / "decisions.jsonl").read_text().splitlines()
    lines[2] = lines[2][:-1] + ',"note":"\\udc80"}'
    (d / "decisions.jsonl").write_text("\n".join(lines) + "\n")


def _twice_in_the_manifest(d: Path):
    text = (d / "manifest.json").read_text()
    (d / "manifest.json").write_text(text.replace('"version": 1,', '"version": 1, "version": 1,', 1))


@pytest.mark.parametrize("damage, message", [
    # a decision naming a key twice: was read with the last value, a divergence (exit 1) ...
    (_twice_in_a_decision(2, '"part":"pcb"'), "decisions.jsonl line 2: key 'part' appears twice in one object"),
    # ... or, the last value the recorded one, a match (exit 0)
    (_twice_in_a_decision(1, '"type":"perception"'), "decisions.jsonl line 1: key 'type' appears twice"),
    # a whole last line without its newline is no line a crash cut short: corrupt, not dropped as torn
    (_twice_in_a_decision(-1, '"type":"summary"', newline=False), "decisions.jsonl line 14: key 'type' appears"),
    # half a UTF-16 pair: no writer of ours writes one (was: a divergence, exit 1)
    (_lone_surrogate_in_a_decision, "decisions.jsonl line 3: note holds a lone UTF-16 surrogate escape"),
    (_twice_in_the_manifest, "manifest.json: key 'version' appears twice in one object"),
    # was: internal error (ValueError: Exceeds the limit (4300 digits) for integer string conversion)
    (_big_integer_in_manifest, "manifest.json is not valid JSON: a number too large: 5000 digits, at most 4300 "
                               "at line 3 column 23"),
    (_big_integer_in_a_decision, "decisions.jsonl line 1: not valid JSON (a number too large: 5000 digits, "
                                 "at most 4300)"),
    # was: internal error (RecursionError)
    (_deep_decision_line, "decisions.jsonl line 4: not valid JSON (nested too deeply)"),
    # was: read as a recording made before the planner was kept, then "divergence" (exit 1)
    (_planner_a_list, "manifest meta.planner must be an object"),
    # was: internal error (cv2.error: pixels <= CV_IO_MAX_IMAGE_PIXELS)
    (_damage_frame, "000001.png cannot be decoded as PNG (OpenCV: pixels <= CV_IO_MAX_IMAGE_PIXELS)"),
    # was: libpng's own "libpng error: Read Error" line on the process' stderr first
    (_cut_short_frame, "000001.png is cut short: its PNG has no end (5000 bytes)"),
    # was: "decisions.jsonl holds 14 decisions, the manifest says 14"
    (_counts_as_strings, "'counts.decisions' must be a whole number, not '14'"),
])
def test_replay_refuses_the_damage_in_one_clear_line(tmp_path, capfd, damage, message):
    d = tmp_path / "rec"
    shutil.copytree(SHIPPED, d)
    damage(d)
    before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    code, out, err = run_cli("replay", d, capsys=capfd)  # (the process' own stderr: a library's lines too)
    assert code == 2 and message in err and "internal error" not in err, err
    assert len(err.strip().splitlines()) == 1
    assert {p: p.read_bytes() for p in d.rglob("*") if p.is_file()} == before  # reading never changes it


def _as_a_user_bound_by_file_modes():
    """argv prefix under which mode 000 means unreadable: none for a user, setpriv without the DAC override for
    root (who reads anything); None when neither works here."""
    import os

    if os.geteuid() != 0:
        return []
    return ["setpriv", "--bounding-set", "-dac_override,-dac_read_search", "--"] if shutil.which("setpriv") else None


@pytest.mark.parametrize("denied, message", [
    ("frames/000001.png", "recording frame {d}/frames/000001.png cannot be read: Permission denied"),  # was: 'cannot
    # be decoded as PNG'
    ("frames", "recording {d}: frames/ cannot be read: Permission denied"),  # was: '[Errno 13] ...' without context
])
def test_replay_names_an_unreadable_frame_or_frames_folder(tmp_path, denied, message):
    import os
    import subprocess
    import sys

    prefix = _as_a_user_bound_by_file_modes()
    if prefix is None:
        pytest.skip("running as root without setpriv: file modes do not bind")
    d = tmp_path / "rec"
    shutil.copytree(SHIPPED, d)
    os.chmod(d / denied, 0)
    try:
        p = subprocess.run([*prefix, sys.executable, "-m", "cell", "replay", str(d)], capture_output=True, text=True,
                           cwd=Path(__file__).resolve().parent.parent, timeout=120)
    finally:
        os.chmod(d / denied, 0o755)
    assert p.returncode == 2 and p.stderr.strip() == f"cell: error: {message.format(d=d)}", p.stderr
