"""`cell run` on the real cell: the drives on a CAN bus given by --interface/--channel, frames
from --camera. Here the "real" drives are the simulated ones served on a virtual channel by
another participant (as a real cell's drives would answer), in real time, and the camera is a
folder of frames rendered from the assembly."""

import json
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from calibration import load_calibration
from cell.scene import load_assembly
from cell.vision import SimCamera, SimCameraOptions
from cell.vision.sources import write_image
from drivers import open_bus, sim

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))
SHIPPED_FRAMES = Path(__file__).resolve().parents[1] / "recordings" / "shipped" / "frames"


@pytest.fixture
def washer_only(tmp_path):
    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] == "washer"]
    d["sequence"], d["name"] = ["washer"], "washer only"
    path = tmp_path / "washer.json"
    path.write_text(json.dumps(d))
    return path


@pytest.fixture
def served_drives(request):
    """The cell's drives answering on their own virtual channel, as the real ones would."""
    channel = f"real-cell-{request.node.name}"
    bus = open_bus("virtual", channel)
    handle = sim.serve(bus)
    yield channel, handle
    handle.__exit__(None, None, None)
    bus.shutdown()


def frames_folder(folder: Path, frames) -> Path:
    folder.mkdir()
    for i, f in enumerate(frames):
        write_image(folder / f"{i:03d}.png", f)
    return folder


def fast_cell(tmp_path) -> Path:
    """The drives run in real time: the arm and the jaws 3 x as fast (the default cell's pick: 5.5 s of 8.5)."""
    raw = json.loads((Path(str(resources.files("cell"))) / "data" / "default_cell.json").read_text())
    for j in raw["scara"]["max_velocity"]:
        raw["scara"]["max_velocity"][j] *= 3
        raw["scara"]["max_acceleration"][j] *= 9
    raw["gripper"]["speed_mm_s"] *= 3
    (tmp_path / "fast_cell.json").write_text(json.dumps(raw))
    return tmp_path / "fast_cell.json"


def jaws_close_on(drives, part) -> None:
    """The served gripper stops on the part (its width across the jaws, about its mean diameter)."""
    c = np.asarray(part.polygon.centroid.coords[0])
    drives.gripper_object_width_mm = 2 * float(np.linalg.norm(part.outline_mm - c, axis=1).mean())


def test_the_real_cell_removes_a_part_seen_by_its_camera(tmp_path, washer_only, served_drives, capsys):
    channel, drives = served_drives
    washer = load_assembly(washer_only).parts[0]
    cam = SimCamera(load_calibration(), SimCameraOptions(seed=2))
    camera = frames_folder(tmp_path / "camera", [cam.render([washer]), cam.render([])])  # before, after the pick
    jaws_close_on(drives, washer)
    fast_cell(tmp_path)
    code, out, err = run_cli("run", washer_only, "--cell", tmp_path / "fast_cell.json", "--interface", "virtual",
                             "--channel", channel, "--camera", camera, "--record", tmp_path / "rec", "--json",
                             capsys=capsys)
    summary = json.loads(out.splitlines()[-1])
    assert code == 0, err
    assert (summary["parts_total"], summary["parts_removed"]) == (1, 1)
    assert summary["real_cell"] == {"interface": "virtual", "channel": channel, "camera": str(camera)}
    assert "sim_events" not in summary  # no simulated world: what the camera shows is the truth
    # the drives moved: the gripper let the washer go at the drop-off, the arm went back home
    assert drives.drives["gripper"].object_width_mm is not None
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["meta"]["real_cell"]["channel"] == channel


def test_a_part_the_camera_finds_off_the_tray_is_not_picked(tmp_path, washer_only, served_drives, capsys):
    """On the real cell the assembly only says where to look: a washer the camera found 20 mm past the tray's
    edge (x 500) was gripped and carried off, "1 of 1 removed", where `cell hw pick` refuses such a target. The
    loop now stops and asks before anything goes near it; the recording replays to that stop."""
    channel, drives = served_drives
    d = json.loads(washer_only.read_text())
    washer = load_assembly(washer_only).parts[0]
    cx, cy = washer.polygon.centroid.coords[0]
    at_edge = washer.moved(480.0 - cx, 0.0, 0.0)  # where the assembly says: on the tray, near its edge
    d["parts"][0] = {**d["parts"][0], **at_edge.to_json()}
    washer_only.write_text(json.dumps(d))
    seen = at_edge.moved(40.0, 0.0, 0.0)  # where the camera finds it: centre at x 520
    cam = SimCamera(load_calibration(), SimCameraOptions(seed=2))
    camera = frames_folder(tmp_path / "camera", [cam.render([seen])] * 3)
    code, out, err = run_cli("run", washer_only, "--interface", "virtual", "--channel", channel, "--camera", camera,
                             "--record", tmp_path / "rec", "--json", capsys=capsys)
    summary = json.loads(out.splitlines()[-1])
    assert code == 1 and summary["status"] == "stopped" and summary["parts_removed"] == 0, err
    stopped = summary["stopped"]
    assert "washer lies at (519.9, -7.9) mm" in stopped and "outside the cell's tray (x 200 to 500" in stopped
    assert "put it back on the tray" in summary["stopped"]
    assert drives.drives["gripper"].object_width_mm is None  # nothing was gripped
    decisions = [json.loads(line) for line in (tmp_path / "rec" / "decisions.jsonl").read_text().splitlines()]
    assert [d["type"] for d in decisions if d["type"] in ("grasp", "commands", "stop")] == ["stop"]
    code, _, err = run_cli("replay", tmp_path / "rec", capsys=capsys)
    assert code == 0, err


@pytest.mark.parametrize("after_the_pick, outcome", [
    ("dark", "camera: no readable frame after 3 tries: the frame is dark"),
    ("moved 80 mm", "cell: washer did not leave the tray"),
])
def test_a_part_is_removed_only_when_a_frame_shows_the_tray_without_it(tmp_path, washer_only, served_drives, capsys,
                                                                      after_the_pick, outcome):
    """After the pick the next frame must show the part gone. A black frame (lights off, the lens covered) showed
    no part, and a washer lying 80 mm from where it was picked (fallen back) was looked for only 60 mm about:
    both counted as removed, 1 of 1, exit 0."""
    channel, drives = served_drives
    washer = load_assembly(washer_only).parts[0]
    cam = SimCamera(load_calibration(), SimCameraOptions(seed=2))
    after = (np.zeros_like(cam.render([])) if after_the_pick == "dark" else cam.render([washer.moved(0.0, 80.0, 0.0)]))
    camera = frames_folder(tmp_path / "camera", [cam.render([washer])] + [after] * 3)
    jaws_close_on(drives, washer)
    code, out, err = run_cli("run", washer_only, "--cell", fast_cell(tmp_path), "--interface", "virtual",
                             "--channel", channel, "--camera", camera, "--record", tmp_path / "rec", "--json",
                             capsys=capsys)
    summary = json.loads(out.splitlines()[-1])
    assert code == 1 and summary["status"] == "stopped" and summary["parts_removed"] == 0, err
    assert summary["stopped"].startswith(outcome), summary["stopped"]
    code, _, err = run_cli("replay", tmp_path / "rec", capsys=capsys)
    assert code == 0, err


def test_a_fault_on_the_way_home_is_a_recorded_stop(tmp_path, washer_only, served_drives, capsys):
    """A real arm may stand anywhere; the first move takes it home. A drive fault on that way stops the run
    as one during it does, with the stop in the recording (it was an error past the loop, no stop decision)."""
    channel, drives = served_drives
    drives.drives["j3"].position_counts *= 0.5  # the fingers low on the tray: home lifts J3 first
    drives.inject_fault("emcy", "j3", after_s=0.05)
    cam = SimCamera(load_calibration(), SimCameraOptions(seed=2))
    camera = frames_folder(tmp_path / "camera", [cam.render([load_assembly(washer_only).parts[0]])])
    code, out, err = run_cli("run", washer_only, "--interface", "virtual", "--channel", channel, "--camera", camera,
                             "--record", tmp_path / "rec", "--json", capsys=capsys)
    summary = json.loads(out.splitlines()[-1])
    assert code == 1 and summary["status"] == "stopped" and "EMCY 0x2310" in summary["stopped"], err
    decisions = [json.loads(line) for line in (tmp_path / "rec" / "decisions.jsonl").read_text().splitlines()]
    assert [(d["type"], d["source"]) for d in decisions] == [("stop", "j3")] and "EMCY 0x2310" in decisions[0]["reason"]


def test_jaws_that_are_not_open_at_the_start_refuse_the_run_before_anything_moves(tmp_path, washer_only,
                                                                                 served_drives, capsys):
    """A real gripper may still hold a part (a run cut short): the first pre-open, high over the tray, would
    drop it. The run does not start."""
    channel, drives = served_drives
    drives.drives["gripper"].position_counts = 20.0 * 1000  # the jaws at 20 mm
    before = {n: d.position_counts for n, d in drives.drives.items()}
    cam = SimCamera(load_calibration(), SimCameraOptions(seed=2))
    camera = frames_folder(tmp_path / "camera", [cam.render([load_assembly(washer_only).parts[0]])])
    code, out, err = run_cli("run", washer_only, "--interface", "virtual", "--channel", channel, "--camera", camera,
                             "--yes", capsys=capsys)
    assert code != 0 and "the jaws stand at 20.0 mm, not open (80 mm)" in err and "Traceback" not in err
    assert {n: d.position_counts for n, d in drives.drives.items()} == pytest.approx(before)


def test_a_camera_of_another_resolution_is_refused_before_anything_moves(tmp_path, washer_only, served_drives,
                                                                         capsys):
    channel, drives = served_drives
    before = {n: d.position_counts for n, d in drives.drives.items()}
    camera = frames_folder(tmp_path / "camera", [np.full((480, 640, 3), 90, np.uint8)])
    code, out, err = run_cli("run", washer_only, "--interface", "virtual", "--channel", channel, "--camera", camera,
                             "--record", tmp_path / "rec", capsys=capsys)
    assert code == 2 and "640 x 480 px" in err and "calibration" in err and "Traceback" not in err
    assert {n: d.position_counts for n, d in drives.drives.items()} == before
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    assert manifest["status"] == "incomplete" and "640 x 480 px" in manifest["summary"]["error"]


def test_the_operator_says_no_and_nothing_opens(monkeypatch, washer_only, capsys):
    import drivers
    from cell.vision import sources

    opened = []
    monkeypatch.setattr(drivers, "real_cell", lambda *a, **k: opened.append("bus"))
    monkeypatch.setattr(sources.VideoCamera, "connect", lambda self: opened.append("camera"))
    monkeypatch.setattr("sys.stdin.isatty", lambda: True, raising=False)
    monkeypatch.setattr("builtins.input", lambda *a: "no")
    code, out, err = run_cli("run", washer_only, "--interface", "socketcan", "--channel", "can7", "--camera", "0",
                             "--json", capsys=capsys)
    assert code != 0 and "nothing moved" in err and "REAL cell (socketcan:can7)" in err
    assert out == "" and opened == []  # the question went to stderr; no bus, no camera


@pytest.mark.parametrize("argv, message", [
    (["--interface", "virtual"], "needs both --interface"),
    (["--camera", "0"], "needs both --interface"),
    (["--channel", "can0"], "for the real cell"),
    (["--sim", "--interface", "socketcan", "--camera", "0"], "--sim is the simulated cell"),
    (["--interface", "virtual", "--camera", "0", "--sim-miss", "nut"], "not of the real cell"),
    (["--interface", "virtual", "--camera", "0", "--sim-drop", "nut"], "--sim-drop: options of the simulated world"),
    (["--interface", "virtual", "--camera", "0", "--seed", "3"], "--seed: options of the simulated world"),
    (["--interface", "virtual", "--channel", "nobody-here", "--camera", "no/such/folder"], "cannot be opened"),
    (["--interface", "socketcan", "--channel", "vcan9", "--camera", "0"], "without confirmation"),
    (["--interface", "socketcan", "--channel", "vcan9", "--camera", str(SHIPPED_FRAMES)], "live camera"),
    (["--interface", "socketcan", "--channel", "vcan9", "--camera", str(SHIPPED_FRAMES / "000000.png")],
     "live camera"),
])
def test_bad_real_cell_options_are_bad_input(argv, message, capsys):
    code, out, err = run_cli("run", *argv, capsys=capsys)
    assert code == 2 and message in err and "Traceback" not in err


def test_only_frames_that_cannot_show_the_tray_are_blank():
    """Dark, overexposed and flat frames are blank; the simulated camera's empty tray and every shared
    photograph are not (mean 79 - 147 DN, sd 35 - 95 at 1/8 size)."""
    from conftest import EXTERNAL

    from cell.vision.sources import blank_frame_reason, read_image

    empty = SimCamera(load_calibration(), SimCameraOptions(seed=2)).render([])
    assert blank_frame_reason(empty) is None
    assert "dark" in blank_frame_reason(np.zeros_like(empty))
    assert "dark" in blank_frame_reason((empty * 0.05).astype(np.uint8))
    assert "overexposed" in blank_frame_reason(np.full_like(empty, 255))
    assert "one flat colour" in blank_frame_reason(np.full_like(empty, 128))
    # a back-lit tray is white, empty or not: where the run's first frame was so too, no frame is overexposed
    white = np.full_like(empty, 255)
    assert blank_frame_reason(white, first_saturated=0.97) is None
    assert "dark" in blank_frame_reason(np.zeros_like(empty), first_saturated=0.97)
    photos = sorted(p for p in EXTERNAL.glob("*/*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    assert all(blank_frame_reason(read_image(p)) is None for p in photos), [
        p.name for p in photos if blank_frame_reason(read_image(p))]
