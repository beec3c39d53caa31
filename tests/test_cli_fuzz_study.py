"""`cell study` with an example count that would never end: exit 2 before any work, nothing written."""

import pytest
from conftest import run_cli


@pytest.mark.parametrize("n", ["99999999999", "10001", "19"])
def test_study_example_counts_out_of_range_are_refused(tmp_path, capsys, n):
    code, out, err = run_cli("study", "--budget", "tiny", "--examples", n, "--out", tmp_path / "st", capsys=capsys)
    assert code == 2 and f"--examples must be 20..10000, got {n}" in err and out == "", err
    assert not (tmp_path / "st").exists()
