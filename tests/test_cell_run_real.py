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


def test_the_real_cell_removes_a_part_seen_by_its_camera(tmp_path, washer_only, served_drives, capsys):
    channel, drives = served_drives
    washer = load_assembly(washer_only).parts[0]
    cam = SimCamera(load_calibration(), SimCameraOptions(seed=2))
    camera = frames_folder(tmp_path / "camera", [cam.render([washer]), cam.render([])])  # before, after the pick
    c = np.asarray(washer.polygon.centroid.coords[0])
    drives.gripper_object_width_mm = 2 * float(np.linalg.norm(washer.outline_mm - c, axis=1).mean())
    code, out, err = run_cli("run", washer_only, "--interface", "virtual", "--channel", channel, "--camera", camera,
                             "--record", tmp_path / "rec", "--json", capsys=capsys)
    summary = json.loads(out.splitlines()[-1])
    assert code == 0, err
    assert (summary["parts_total"], summary["parts_removed"]) == (1, 1)
    assert summary["real_cell"] == {"interface": "virtual", "channel": channel, "camera": str(camera)}
    assert "sim_events" not in summary  # no simulated world: what the camera shows is the truth
    # the drives moved: the gripper let the washer go at the drop-off, the arm went back home
    assert drives.drives["gripper"].object_width_mm is not None
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["meta"]["real_cell"]["channel"] == channel


def test_a_camera_of_another_resolution_stops_the_run(tmp_path, washer_only, served_drives, capsys):
    channel, _ = served_drives
    camera = frames_folder(tmp_path / "camera", [np.full((480, 640, 3), 90, np.uint8)] * 3)  # every retry
    code, out, err = run_cli("run", washer_only, "--interface", "virtual", "--channel", channel, "--camera", camera,
                             "--json", capsys=capsys)
    summary = json.loads(out.splitlines()[-1])
    assert code == 1 and summary["parts_removed"] == 0
    assert "640 x 480 px" in summary["stopped"] and "calibration" in summary["stopped"]


@pytest.mark.parametrize("argv, message", [
    (["--interface", "virtual"], "needs both --interface"),
    (["--camera", "0"], "needs both --interface"),
    (["--channel", "can0"], "for the real cell"),
    (["--interface", "virtual", "--camera", "0", "--sim-miss", "nut"], "not of the real cell"),
    (["--interface", "virtual", "--channel", "nobody-here", "--camera", "no/such/folder"], "cannot be opened"),
    (["--interface", "socketcan", "--channel", "vcan9", "--camera", "0"], "without confirmation"),
])
def test_bad_real_cell_options_are_bad_input(argv, message, capsys):
    code, out, err = run_cli("run", *argv, capsys=capsys)
    assert code == 2 and message in err and "Traceback" not in err
