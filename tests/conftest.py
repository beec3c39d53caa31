import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
EXTERNAL = SHARED / "external"


@pytest.fixture
def cell_cfg():
    from cell.cellconfig import default_cell

    return default_cell()


def run_cli(*argv, capsys=None):
    """Run the CLI in-process; returns (exit code, stdout, stderr) when given capsys."""
    from cell.cli import main

    code = main([str(a) for a in argv])
    if capsys is not None:
        out = capsys.readouterr()
        return code, out.out, out.err
    return code


sys.path.insert(0, str(ROOT))
