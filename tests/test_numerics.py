"""The same numbers on every machine: OpenBLAS picks its kernels by the CPU, and a recording made with one
kernel set diverged in replay under another (a registration's start half a turn round). The cell pins one
kernel set and one thread before numpy loads (cell/numerics.py), works out a region's axis without LAPACK,
keeps in the manifest what computed the numbers, and names a difference when a replay diverges."""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli
from hypothesis import given
from hypothesis import strategies as st
from shapely import affinity
from shapely.geometry import Polygon

from cell.numerics import BLAS_CORETYPE_X86, numeric_platform, platform_difference
from cell.runtime.matching import _axis_deg

SHIPPED = Path(__file__).resolve().parent.parent / "recordings" / "shipped"
X86 = platform.machine().lower() in ("x86_64", "amd64")


def _blas_in_a_fresh_process(first: str = "cell", **env) -> list:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("OPENBLAS")}
    out = subprocess.run([sys.executable, "-c", f"import {first}, threadpoolctl, numpy; print(__import__('json').dumps("
                          "[(i['architecture'], i['num_threads']) for i in threadpoolctl.threadpool_info() "
                          "if i['user_api'] == 'blas']))"], env={**clean, **env}, capture_output=True, text=True,
                         check=True, timeout=120)
    return json.loads(out.stdout)


@pytest.mark.skipif(not X86, reason="the kernel set is pinned on x86-64 only")
def test_importing_the_cell_pins_one_blas_kernel_set_and_one_thread_unless_the_user_set_them():
    assert _blas_in_a_fresh_process() == [[BLAS_CORETYPE_X86, 1]]
    assert _blas_in_a_fresh_process(OPENBLAS_CORETYPE="Sandybridge", OPENBLAS_NUM_THREADS="2") == [["Sandybridge", 2]]


@pytest.mark.skipif(not X86, reason="the kernel set is pinned on x86-64 only")
@pytest.mark.parametrize("first", ["calibration", "drivers", "calibration.intrinsics"])
def test_importing_any_top_level_package_first_pins_them_too(first):
    """`python -m calibration.default`, or a script importing the calibration first, loaded numpy with the CPU's
    own kernels (Zen here) and as many threads as cores."""
    blas = _blas_in_a_fresh_process(first)  # (scipy's own OpenBLAS too, where the package loads scipy)
    assert blas and all(b == [BLAS_CORETYPE_X86, 1] for b in blas), blas


@given(st.floats(-179.0, 179.0), st.floats(2.0, 10.0), st.floats(-50, 50), st.floats(-50, 50))
def test_a_regions_axis_is_the_principal_axis_folded_into_a_half_turn(turn_deg, aspect, dx, dy):
    """The closed form agrees with the eigenvector of the hull's scatter (mod 180) and always lies in (-90, 90]:
    LAPACK's eigenvector came out with either sign, as the CPU's kernels had it."""
    poly = affinity.translate(affinity.rotate(Polygon([(0, 0), (10 * aspect, 0), (10 * aspect, 10), (3, 12)]),
                                              turn_deg), dx, dy)
    got = _axis_deg(poly)
    xy = np.asarray(poly.convex_hull.exterior.coords)[:-1]
    xy = xy - xy.mean(axis=0)
    w, v = np.linalg.eigh(xy.T @ xy)
    major = v[:, int(np.argmax(w))]
    want = math.degrees(math.atan2(major[1], major[0]))
    assert -90.0 < got <= 90.0
    assert min(abs((got - want) % 180.0), 180.0 - abs((got - want) % 180.0)) < 1e-6
    assert _axis_deg(affinity.rotate(poly, 180.0, origin="centroid")) == pytest.approx(got, abs=1e-6) or abs(
        got) == pytest.approx(90.0, abs=1e-6)


def test_a_recording_keeps_what_computed_its_numbers(tmp_path, capsys):
    code, _, err = run_cli("run", "--record", tmp_path / "rec", capsys=capsys)
    assert code == 0, err
    numeric = json.loads((tmp_path / "rec" / "manifest.json").read_text())["software"]["numeric"]
    assert numeric == numeric_platform()
    assert numeric["numpy"] == np.__version__ and numeric["blas"]
    if X86:
        assert {b["architecture"] for b in numeric["blas"]} == {BLAS_CORETYPE_X86}


def _shipped_diverging_at_its_first_grasp(tmp_path, numeric) -> Path:
    """A copy of recordings/shipped whose manifest says `numeric` (None: nothing) and whose first grasp's
    opening is 3 mm off: its replay diverges there."""
    d = tmp_path / "rec"
    shutil.copytree(SHIPPED, d)
    m = json.loads((d / "manifest.json").read_text())
    m["software"].pop("numeric", None)
    if numeric is not None:
        m["software"]["numeric"] = numeric
    (d / "manifest.json").write_text(json.dumps(m))
    lines = (d / "decisions.jsonl").read_text().splitlines()
    g = json.loads(lines[1])
    g["opening_mm"] += 3.0
    lines[1] = json.dumps(g)
    (d / "decisions.jsonl").write_text("\n".join(lines) + "\n")
    return d


def test_a_divergence_names_the_numeric_platform_the_recording_was_made_on(tmp_path, capsys):
    here = numeric_platform()
    d = _shipped_diverging_at_its_first_grasp(tmp_path, {
        **here, "numpy": "1.26.4", "blas": [{**b, "architecture": "Haswell", "threads": 4} for b in here["blas"]]})
    code, out, err = run_cli("replay", d, capsys=capsys)
    assert code == 1 and "decision #1 (grasp, nut): opening_mm" in err
    assert "recorded with other numeric libraries or kernels: numpy 1.26.4 -> " in err
    assert "openblas Haswell x4" in err
    code, out, err = run_cli("replay", d, "--json", capsys=capsys)
    assert code == 1 and "numpy 1.26.4" in json.loads(out)["platform_difference"]


def test_a_divergence_of_a_recording_made_before_the_pin_says_how_to_replay_it_as_made(tmp_path, capsys):
    d = _shipped_diverging_at_its_first_grasp(tmp_path, None)
    code, out, err = run_cli("replay", d, capsys=capsys)
    assert code == 1 and "made before the cell pinned its BLAS kernels" in err
    assert "OPENBLAS_CORETYPE= OPENBLAS_NUM_THREADS= cell replay" in err


def test_a_recording_made_before_the_platform_was_kept_names_no_difference():
    assert platform_difference(None, numeric_platform()) is None
    assert platform_difference(numeric_platform(), numeric_platform()) is None
