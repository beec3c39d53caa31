import cell  # noqa: F401, I001 - first, before anything loads numpy: the BLAS kernels the CLI pins (cell/numerics.py)
import sys
import time
from pathlib import Path

import pytest
from hypothesis import settings

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
EXTERNAL = SHARED / "external"
# tests on the shared photographs (../shared/external next to the checkout) skip, saying so, without them
needs_photos = pytest.mark.skipif(not EXTERNAL.is_dir(), reason=f"{EXTERNAL} (the shared photographs) is not there")

# no per-example wall-time deadline (hypothesis's 200 ms): speed is the benchmarks' business, and a
# loaded CI core must not fail a property that holds
settings.register_profile("cell", deadline=None)
settings.load_profile("cell")


@pytest.fixture
def cell_cfg():
    from cell.cellconfig import default_cell

    return default_cell()


@pytest.fixture(scope="module", autouse=True)
def no_driver_threads_outlive_the_module(request):
    """A test module's buses, receive threads and wall-time clocks end with it: a RealClock's thread
    left by tests/test_station_cell.py made every drivers test run after it in the process fail at
    teardown, and only the alphabetical order hid it. This names the module that leaked."""
    yield
    from drivers_fixtures import _driver_threads

    deadline = time.monotonic() + 2.0
    while _driver_threads() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not _driver_threads(), f"{request.module.__name__} left threads running: {_driver_threads()}"


def run_cli(*argv, capsys=None):
    """Run the CLI in-process; returns (exit code, stdout, stderr) when given capsys."""
    from cell.cli import main

    code = main([str(a) for a in argv])
    if capsys is not None:
        out = capsys.readouterr()
        return code, out.out, out.err
    return code


sys.path.insert(0, str(ROOT))
