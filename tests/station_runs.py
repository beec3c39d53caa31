"""`cell run --station` on a thread, driven over its HTTP API as the page drives it (tests' helpers)."""

from __future__ import annotations

import json
import re
import threading
import time
import urllib.request
from importlib import resources
from pathlib import Path

from cell.runtime.session import RunConfig, run_session

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))
T = 60.0
TOKEN = "station-test-token"


def default_parts(tmp_path, keep: list[str]) -> Path:
    """The default assembly cut down to `keep` (in that order), as an assembly file."""
    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] in keep]
    d["sequence"] = list(keep)
    d.pop("cell", None)
    path = tmp_path / f"{'-'.join(keep)}.json"
    path.write_text(json.dumps(d))
    return path


def post(url, path, body=None) -> dict:
    req = urllib.request.Request(url + path, data=json.dumps(body or {}).encode(), method="POST")
    req.add_header("Content-Type", "application/json")
    req.add_header("X-Cell-Token", TOKEN)
    with urllib.request.urlopen(req, timeout=T) as r:
        return json.loads(r.read())


def state(url) -> dict:
    with urllib.request.urlopen(url + "/api/state", timeout=T) as r:
        return json.loads(r.read())


def wait(url, pred, what) -> dict:
    """The state once `pred(state)` holds (T at most)."""
    deadline = time.monotonic() + T
    while time.monotonic() < deadline:
        s = state(url)
        if pred(s):
            return s
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}: {s['control']['state']}")


def station_run(assembly, **config):
    """run_session(RunConfig(station=True, ...)) on a thread: (the thread, the station's URL, [its summary or
    error]) once the station is up."""
    lines, ended = [], []
    cfg = RunConfig(assembly=assembly, **{"seed": 1, **config}, station=True, station_port=0, station_token=TOKEN,
                    progress=lines.append)

    def work():
        try:
            ended.append(run_session(cfg))
        except BaseException as e:  # noqa: BLE001 - the test asserts on it
            ended.append(e)

    t = threading.Thread(target=work, daemon=True)
    t.start()
    deadline = time.monotonic() + T
    while not any("operator station:" in s for s in lines):
        assert time.monotonic() < deadline and t.is_alive(), (lines, ended)
        time.sleep(0.05)
    url = re.search(r"(http://127\.0\.0\.1:\d+)", next(s for s in lines if "operator station:" in s)).group(1)
    return t, url, ended
