"""The station's frame PNG is encoded once per frame, and each seen part's outline projected once per frame,
however many tabs poll (each GET encoded the 1.84 MB PNG again: 45-880 ms beside the loop)."""

import json
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest

from cell.cellconfig import default_cell
from cell.examples import default_examples_path
from cell.runtime import backend as backend_module
from cell.runtime.backend import LoopBackend
from cell.runtime.control import RunControl
from cell.runtime.loop import CellLoop, LoopOptions
from cell.runtime.session import SimCameraSource
from cell.runtime.simworld import SimWorld
from cell.scene import parse_assembly

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))


@pytest.fixture
def loop():
    from calibration import load_calibration
    from drivers import simulated_cell

    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] in ("nut", "washer")]
    d["sequence"] = ["washer", "nut"]
    assembly = parse_assembly(d)
    cell, cal = default_cell(), load_calibration()
    with simulated_cell(cell) as (arm, drives):
        world = SimWorld(list(assembly.parts), cell, drives)
        yield CellLoop(cell=cell, calibration=cal, assembly=assembly, camera=SimCameraSource(world, cal, 0),
                       arm=arm, control=RunControl(), examples_path=default_examples_path(),
                       options=LoopOptions(interactive=True))


def _show(loop, index: int) -> None:
    """The loop's next frame and what it saw on it, as the loop sets them (`_perceive`)."""
    frame = loop.camera.read()
    loop.state.frame, loop.state.frame_index = frame, index
    loop.state.seen = {p.id: p.moved(0.1 * index, 0.0, 0.0) for p in loop.assembly.parts}


def test_each_frame_is_encoded_and_projected_once_for_every_poll(loop, monkeypatch):
    encoded, projected = [], []
    imencode, to_px = cv2.imencode, type(loop.cal).mm_to_px
    monkeypatch.setattr(backend_module.cv2, "imencode", lambda *a: encoded.append(1) or imencode(*a))
    monkeypatch.setattr(type(loop.cal), "mm_to_px", lambda *a: projected.append(1) or to_px(*a))
    backend = LoopBackend(loop)
    _show(loop, 0)
    first = [backend.frame_png() for _ in range(5)]
    snaps = [backend.snapshot() for _ in range(5)]
    assert len(encoded) == 1 and all(png == first[0] for png in first)
    assert cv2.imdecode(np.frombuffer(first[0], np.uint8), cv2.IMREAD_UNCHANGED).shape[:2] == (
        loop.cal.height_px, loop.cal.width_px)
    n_rings = sum(1 + len(p.holes_mm) for p in loop.state.seen.values())
    assert len(projected) == n_rings and all(s["parts"] == snaps[0]["parts"] for s in snaps)
    _show(loop, 1)  # a new frame, the parts at new poses: encoded and projected anew
    assert backend.frame_png() != first[0] and len(encoded) == 2
    moved = backend.snapshot()["parts"]
    assert len(projected) == 2 * n_rings and moved != snaps[0]["parts"]


def test_the_outline_cache_holds_only_the_parts_of_the_current_frame_however_many_frames(loop):
    """A shift at the station: parts leave and come back over many frames; the cache keeps what the current
    frame shows, no more (it kept every part ever seen, with its last pose)."""
    backend, parts = LoopBackend(loop), list(loop.assembly.parts)
    sizes = []
    for i in range(300):
        shown = parts[: i % (len(parts) + 1)]  # all, then fewer, none, all again ...
        loop.state.frame_index = i
        loop.state.seen = {p.id: p.moved(0.01 * i, 0.0, 0.0) for p in shown}
        snap = backend.snapshot()
        assert [q["id"] for q in snap["parts"]] == [p.id for p in shown]
        sizes.append(len(backend._outlines))
        assert backend._outlines.keys() == loop.state.seen.keys()
    assert max(sizes) == len(parts) and min(sizes) == 0
