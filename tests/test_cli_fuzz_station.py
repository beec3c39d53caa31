"""`cell station` with times and paths it accepted or crashed on: exit 2 and one line, before serving."""

import pytest
from conftest import run_cli


@pytest.mark.parametrize("extra, message", [
    (["--motion-s", "nan"], "--motion-s must be 0..600 s"),  # was: served; the pick thread's sleep raised
    (["--motion-s", "1e300"], "--motion-s must be 0..600 s"),
    (["--for-s", "nan"], "--for-s nan: give a finite number"),  # was: served 0 s, exit 0
    (["--for-s", "-1"], "--for-s -1: give a finite number"),
    (["--for-s", "inf"], "--for-s inf: give a finite number"),
    (["--examples", "f/e.jsonl"], "--examples f/e.jsonl: f is a file, not a folder"),  # was: served, failed
    # at the first taught grasp
])
def test_station_refuses_bad_values_before_serving(tmp_path, monkeypatch, capsys, extra, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "f").write_text("x")
    code, out, err = run_cli("station", "--port", "0", "--for-s", "0", *extra, capsys=capsys)
    assert code == 2 and message in err and out == "", err
    assert [p.name for p in tmp_path.iterdir()] == ["f"] and (tmp_path / "f").read_text() == "x"


def test_station_serves_for_longer_than_a_sleep_can_be(tmp_path, monkeypatch, capsys):
    """--for-s 1e300 was 'internal error: OverflowError'; it sleeps as long as the platform can."""
    import time

    monkeypatch.chdir(tmp_path)
    slept, real_sleep = [], time.sleep

    def sleep(s):
        if s < 1e6:  # the demo cell's own short sleeps
            return real_sleep(s)
        slept.append(s)
        raise KeyboardInterrupt  # the operator's Ctrl-C, at once

    monkeypatch.setattr(time, "sleep", sleep)
    code, out, err = run_cli("station", "--port", "0", "--for-s", "1e300", capsys=capsys)
    assert code == 0 and "station closed" in out, err
    assert 1e9 < slept[0] < 1e300


def test_run_with_the_station_refuses_a_short_token_and_a_busy_port_before_the_recording(tmp_path, capsys):
    """Both were refused (exit 2) only once the recording was made: DIR stayed behind as a recording of
    nothing, which the next run refused as taken and replay as holding no frames."""
    import socket

    rec = tmp_path / "rec"
    code, out, err = run_cli("run", "--station", "--port", "0", "--token", "abc", "--record", rec, capsys=capsys)
    assert code == 2 and "at least 8 characters" in err and not rec.exists(), err
    with socket.socket() as busy:
        busy.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, out, err = run_cli("run", "--station", "--port", port, "--record", rec, capsys=capsys)
    assert code == 2 and f"cannot serve the station on 127.0.0.1:{port}" in err and not rec.exists(), err


def test_the_approve_option_has_one_name_on_both_commands(capsys):
    """`cell run --station` took --approve and `cell station` --approve-each (docs/station.md): the other name
    was 'unrecognized arguments'. Each now takes both."""
    code, out, err = run_cli("run", "--approve-each", capsys=capsys)
    assert code == 2 and "--approve needs --station" in err, err
    code, out, err = run_cli("station", "--approve", "--port", "0", "--for-s", "0", capsys=capsys)
    assert code == 0 and "station closed" in out, err


@pytest.mark.parametrize("token", ["abc&defgh", "abc%zzdefg", "\u20acuro-token-1", "with space1", "a+b=c/d=e"])
def test_a_token_the_page_cannot_carry_is_refused(tmp_path, capsys, token):
    """The token goes in the printed link's query and in an HTTP header: 'abc&defgh' gave the page "abc" (403,
    "was the cell restarted?"), '%zz' stopped the page's script, a non-ASCII one could not be sent at all."""
    code, out, err = run_cli("station", "--port", "0", "--token", token, "--examples", tmp_path / "ex.jsonl",
                             capsys=capsys)
    assert code == 2 and "letters, digits and - . _ ~ only" in err, err
    assert not (tmp_path / "ex.jsonl").exists()
