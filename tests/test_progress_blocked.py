"""A terminal that stops reading (Ctrl-S, a pipe nobody reads) must not hold up the cell: the run's progress
lines were printed under the run control's lock, so the page's state went unanswered and its Stop waited,
sending no quick stop, until the terminal read again. Now a thread of its own prints them."""

from __future__ import annotations

import re
import threading
import time

from station_runs import DEFAULT, TOKEN, post, state

from cell.runtime.control import RunControl
from cell.runtime.session import ProgressPrinter, RunConfig, run_session


def test_a_blocked_printer_holds_up_neither_the_run_control_nor_its_stop():
    release, blocked = threading.Event(), threading.Event()

    def stuck(line):
        blocked.set()
        release.wait(30)

    control = RunControl()
    say = ProgressPrinter(stuck)
    control.add_listener(lambda e: say(f"[{e['event']}] {e.get('message', '')}"))
    try:
        control.run(by="test")
        assert blocked.wait(10)
        t0 = time.monotonic()
        control.pause(by="test")
        assert control.stop("test", by="test") == "stopped"
        assert time.monotonic() - t0 < 1.0
    finally:
        release.set()
        say.close()


def test_the_stations_stop_is_answered_and_ends_the_run_while_the_terminal_is_blocked():
    lines, ended = [], []
    hold, release = threading.Event(), threading.Event()

    def terminal(line):
        lines.append(line)
        if hold.is_set():
            release.wait(60)  # a terminal paused with Ctrl-S

    cfg = RunConfig(assembly=DEFAULT, seed=1, station=True, station_port=0, station_token=TOKEN, progress=terminal)
    t = threading.Thread(target=lambda: ended.append(run_session(cfg)), daemon=True)
    t.start()
    try:
        deadline = time.monotonic() + 60
        while not any("operator station:" in s for s in lines):
            assert time.monotonic() < deadline and t.is_alive()
            time.sleep(0.05)
        url = re.search(r"(http://127\.0\.0\.1:\d+)", next(s for s in lines if "operator station:" in s)).group(1)
        hold.set()
        post(url, "/api/run")
        time.sleep(1.0)  # the run goes on; its lines queue up behind the blocked terminal
        t0 = time.monotonic()
        assert state(url)["control"]["state"] == "running"
        answer = post(url, "/api/stop", {"reason": "blocked terminal"})
        assert answer["result"] == "stopped" and time.monotonic() - t0 < 5.0
    finally:
        release.set()
        t.join(60)
    assert not t.is_alive() and ended and ended[0]["status"] == "stopped", ended
    assert any("stopped" in s for s in lines)  # the lines held back come out once the terminal reads again
