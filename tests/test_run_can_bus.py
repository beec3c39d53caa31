"""The CAN bus in a run's summary: the error frames a shift heard, and the one that stopped it
(`drivers.errorframes` decides which stop; here, that a run reports them)."""

import io
import json
from importlib import resources
from pathlib import Path

import pytest

from cell.commands.run import _print_summary
from cell.recording import RecordingReader
from cell.runtime.session import RunConfig, run_session

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))


@pytest.fixture(scope="module")
def nut_only(tmp_path_factory):
    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] == "nut"]
    d["sequence"], d["name"] = ["nut"], "nut only"
    p = tmp_path_factory.mktemp("asm") / "nut.json"
    p.write_text(json.dumps(d))
    return p


def test_sporadic_error_frames_are_counted_in_the_summary_and_the_run_completes(nut_only, tmp_path):
    s = run_session(RunConfig(assembly=nut_only, seed=3, record=tmp_path / "r",
                              drive_fault=(None, "error_frames", {"count": 3, "error_class": "bus_error"})))
    assert s["status"] == "complete" and s["parts_removed"] == 1
    bus = s["can_bus"]
    # (a frame names every class it carries: SocketCAN's bus error comes with its protocol violation and counters)
    assert bus["error_frames"] == 3 and bus["by_class"]["bus-error"] == 3 and bus["fault"] is None
    assert RecordingReader(tmp_path / "r").manifest["summary"]["can_bus"] == bus  # kept with the recording
    text = io.StringIO()
    _print_summary(s, text)  # what `cell run` prints without --json
    assert "CAN bus: 3 error frame(s) (3 bus-error" in text.getvalue()


def test_a_bus_off_stops_the_run_and_the_summary_names_it(nut_only):
    s = run_session(RunConfig(assembly=nut_only, seed=3,
                              drive_fault=(None, "error_frames", {"count": 1, "error_class": "bus_off"})))
    assert s["status"] == "stopped" and s["parts_removed"] == 0
    assert s["can_bus"]["error_frames"] == 1 and s["can_bus"]["by_class"]["bus-off"] == 1
    assert "bus-off" in s["can_bus"]["fault"]
    assert "bus-off" in s["stopped"]
