"""Options that belong to another option, given without it: they were dropped without a word; now exit 2."""

import pytest
from conftest import run_cli


@pytest.mark.parametrize("argv, message", [
    (["calibrate", "intrinsics", "a.png", "--pattern", "9x6", "--square", "25", "--out", "o.json", "--marker", "10"],
     "--marker and --dictionary describe a ChArUco board: give --charuco too"),
    (["calibrate", "intrinsics", "a.png", "--pattern", "9x6", "--square", "25", "--out", "o.json",
      "--dictionary", "DICT_4X4_50"], "give --charuco too"),
    (["run", "--token", "0123456789abcdef"], "--token is the operator station's: give --station too"),
])
def test_an_option_without_the_one_it_belongs_to_is_refused(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(*argv, capsys=capsys)
    assert code == 2 and message in err and out == "", err
    assert list(tmp_path.iterdir()) == []
