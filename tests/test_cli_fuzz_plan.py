"""`cell plan --figures`: a figure that fails part way leaves no half-written PNG in the folder."""

import errno
import json

from conftest import run_cli


def test_a_figure_that_fails_while_written_leaves_no_half_file(tmp_path, monkeypatch, capsys):
    from matplotlib.figure import Figure

    plate = {"id": "plate", "outline": [[300, -30], [370, -30], [370, 30], [300, 30]], "z_top": 5}
    asm = tmp_path / "asm.json"
    asm.write_text(json.dumps({"units": "mm", "parts": [plate], "sequence": ["plate"]}))
    real = Figure.savefig

    def savefig_then_disk_full(self, fname, *args, **kwargs):  # half the PNG reaches the disk, then ENOSPC
        real(self, fname, *args, **kwargs)
        data = open(fname, "rb").read()
        open(fname, "wb").write(data[: len(data) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", savefig_then_disk_full)
    code, out, err = run_cli("plan", asm, "--figures", tmp_path / "figs", capsys=capsys)
    assert code == 2 and "cannot write step_00_plate.png: No space left on device" in err, err
    assert list((tmp_path / "figs").iterdir()) == []  # was: step_00_plate.png, half a PNG
