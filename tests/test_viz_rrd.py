"""cell.viz writes a real .rrd; read it back with rerun's own reader and check what is in it."""

from collections import defaultdict

import numpy as np
import pytest

from cell.cellconfig import default_cell
from cell.kinematics import Joints, elbow_points
from cell.viz import INVALID_RGB, VALID_RGB, Viz


def _read_rrd(path):
    """entity path -> list of record-batch dicts (non-static chunks), via rerun.chunk.RrdReader."""
    from rerun.chunk import RrdReader

    out = defaultdict(list)
    for chunk in RrdReader(path).stream():
        out[str(chunk.entity_path)].append((chunk.is_static, chunk.to_record_batch().to_pydict()))
    return out


def _column(batches, name):
    vals = []
    for static, d in batches:
        if not static and name in d:
            vals.extend(d[name])
    return vals


def test_a_session_is_saved_with_the_pipeline_entity_paths_and_values(tmp_path):
    cell = default_cell()
    path = tmp_path / "session.rrd"
    rng = np.random.default_rng(0)
    with Viz("test-cell", save_path=path) as viz:
        for i in range(3):
            viz.frame(i, rng.integers(0, 256, size=(120, 160, 3), dtype=np.uint8))
            viz.contours([np.array([[10, 10], [100, 10], [100, 80], [10, 80]])])
            viz.parts([np.array([[300, 0], [350, 0], [350, 40], [300, 40]])], [12.0], labels=["cover"])
            viz.candidates(rng.uniform(300, 350, size=(6, 2)), [True, False, True, True, False, False])
            viz.pairs(np.array([[[300, 5], [350, 5]], [[300, 20], [350, 20]]]))
            viz.grasp([[300, 20], [350, 20]],
                      [np.array([[290, 14], [300, 14], [300, 26], [290, 26]]),
                       np.array([[350, 14], [360, 14], [360, 26], [350, 26]])],
                      np.array([[280, 0], [370, 0], [370, 40], [280, 40]]), grasp_z_mm=6.0, label="cover")
            j = Joints(10.0 + i, 20.0, 50.0 - i, -5.0)
            viz.arm(elbow_points(j, cell.scara), j)
            viz.gripper_width(60.0 - 10 * i)
            viz.can(tx=12, rx=14 + i)
            viz.event(f"pick {i}")
    assert path.stat().st_size > 20_000  # three frames and everything else: not an empty file

    data = _read_rrd(path)
    expected = {"/camera/frame", "/vision/contours", "/vision/parts", "/grasp/candidates", "/grasp/pairs",
                "/grasp/selected/contacts", "/grasp/selected/fingers", "/grasp/selected/palm", "/arm/links",
                "/arm/joints/j1", "/arm/joints/j2", "/arm/joints/j3", "/arm/joints/j4", "/gripper/width",
                "/can/tx", "/can/rx", "/log/events"}
    assert expected <= set(data)
    assert _column(data["/arm/joints/j1"], "frame") == [0, 1, 2]
    assert _column(data["/arm/joints/j1"], "Scalars:scalars") == [[10.0], [11.0], [12.0]]
    assert _column(data["/arm/joints/j3"], "Scalars:scalars") == [[50.0], [49.0], [48.0]]
    assert _column(data["/gripper/width"], "Scalars:scalars") == [[60.0], [50.0], [40.0]]
    assert len(_column(data["/camera/frame"], "frame")) == 3
    # candidates coloured by verdict: 3 valid (green) and 3 refused (red) per frame
    colors = _column(data["/grasp/candidates"], "Points3D:colors")[0]
    packed = [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in colors]
    assert packed.count(VALID_RGB) == 3 and packed.count(INVALID_RGB) == 3
    # the fingers are drawn at the grasp z, the palm 40 mm above it
    palm = _column(data["/grasp/selected/palm"], "LineStrips3D:strips")[0][0]
    assert {p[2] for p in palm} == {46.0}


def test_bad_shapes_are_refused(tmp_path):
    viz = Viz("test-cell", save_path=tmp_path / "x.rrd")
    with pytest.raises(ValueError, match="valid_mask"):
        viz.candidates(np.zeros((4, 2)), [True])
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        viz.contours([np.zeros((4, 5))])
    with pytest.raises(ValueError, match="uint8"):
        viz.frame(0, np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="space"):
        viz.candidates(np.zeros((1, 2)), [True], space="inch")
    viz.close()


def test_a_viewer_that_never_takes_the_stream_does_not_hold_the_run(tmp_path, capsys, monkeypatch):
    # `cell run --rerun` on a machine without a display: the viewer's port never answers. The
    # flush gives up after FLUSH_TIMEOUT_S, once, and the .rrd file is still complete. Checked by the flushes
    # that reached rerun, not by wall time: rerun's own 5 s waits (replacing a sink, disconnecting) took 10.5 s
    # of the 15 s bound, and a slow machine went over it (3 of 5 runs at nice 5 on a busy core: 17-25 s).
    import socket

    import rerun as rr

    import cell.viz as viz_module

    monkeypatch.setattr(viz_module, "FLUSH_TIMEOUT_S", 0.5)
    with socket.socket() as s:  # a local port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    path = tmp_path / "s.rrd"
    viz = Viz("test-cell", save_path=path)
    viz.rec.set_sinks(rr.FileSink(str(path)), rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    waits, real_flush = [], viz.rec.flush

    def flush(*, timeout_sec):
        waits.append(timeout_sec)
        real_flush(timeout_sec=timeout_sec)  # the real one: it raises when the viewer never takes it

    viz.rec.flush = flush
    for i in range(3):
        viz.frame(i, np.zeros((40, 60, 3), np.uint8))
        viz.event(f"frame {i}")
        viz.flush()
    viz.close()
    assert waits == [0.5]  # the first flush waited FLUSH_TIMEOUT_S; the later ones and close did not wait again
    warned = [line for line in capsys.readouterr().err.splitlines() if line.startswith("cell: warning")]
    assert len(warned) == 1 and "rerun viewer did not take the recording" in warned[0]
    assert len(_column(_read_rrd(path)["/log/events"], "TextLog:text")) == 3


def test_no_viewer_to_spawn_is_a_clear_error(tmp_path, monkeypatch):
    import sys

    from cell.errors import BadInput

    monkeypatch.setattr(sys, "executable", str(tmp_path / "no-venv" / "python"))
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("DISPLAY", ":99")  # (a display: else that is what is missing first)
    with pytest.raises(BadInput, match="no rerun viewer found"):
        Viz("test-cell", spawn=True)


def test_rerun_without_a_display_is_refused_before_the_run_makes_anything(tmp_path, capsys, monkeypatch):
    """Was: exit 0, the viewer started, failed and filled stderr with its errors (winit, gRPC) while the run
    went on."""
    from conftest import run_cli

    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    code, out, err = run_cli("run", "--rerun", "--record", tmp_path / "rec", capsys=capsys)
    assert code == 2 and err.count("\n") == 1 and "--rerun: no display here" in err and "--save FILE.rrd" in err
    assert not (tmp_path / "rec").exists() and out == ""
