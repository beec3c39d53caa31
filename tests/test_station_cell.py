"""The operator station in front of the real cell loop (simulated world, camera and CANopen
drives): run, approve, reject (an invalid example), teach (a valid example) over HTTP with the
token, and the same in a real headless browser."""

import contextlib
import json
import shutil
import threading
import time
import urllib.error
import urllib.request
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from test_station_browser import CHROMEDRIVER, CHROMIUM, browser  # noqa: F401 - the browser fixture

from cell.cellconfig import default_cell
from cell.examples import default_examples_path, load_examples
from cell.runtime.backend import LoopBackend
from cell.runtime.control import AWAITING_APPROVAL, DONE, RunControl, Stopped
from cell.runtime.loop import CellLoop, LoopOptions
from cell.runtime.session import SimCameraSource, home_joints
from cell.runtime.simworld import SimWorld
from cell.scene import parse_assembly
from cell.station.server import StationServer

DEFAULT = Path(str(resources.files("cell") / "data" / "assemblies" / "default.json"))
T = 30.0


@pytest.fixture
def live(tmp_path):
    from calibration import load_calibration
    from drivers import simulated_cell

    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] in ("nut", "washer")]
    d["sequence"] = ["washer", "nut"]
    assembly = parse_assembly(d)
    cell, cal = default_cell(), load_calibration()
    examples = tmp_path / "examples.jsonl"
    shutil.copyfile(default_examples_path(), examples)
    control = RunControl(require_approval=True)
    with simulated_cell(cell) as (arm, drives):
        world = SimWorld(list(assembly.parts), cell, drives)
        loop = CellLoop(cell=cell, calibration=cal, assembly=assembly, camera=SimCameraSource(world, cal, 0),
                        arm=arm, control=control, examples_path=examples,
                        options=LoopOptions(interactive=True))
        arm.move_joints(home_joints(cell))
        with StationServer(LoopBackend(loop), control, port=0) as server:
            def work():
                with contextlib.suppress(Stopped):
                    loop.run()

            t = threading.Thread(target=work, daemon=True)
            t.start()
            yield server, control, loop, examples, world
            control.stop("test over")
            t.join(10)
        world.close()


def call(server, path, body=None, token=True):
    req = urllib.request.Request(server.base_url + path, method="POST" if body is not None else "GET",
                                 data=None if body is None else json.dumps(body).encode())
    req.add_header("Content-Type", "application/json")
    if token:
        req.add_header("X-Cell-Token", server.token)
    try:
        with urllib.request.urlopen(req, timeout=T) as r:
            raw = r.read()
            return r.status, (json.loads(raw) if r.headers.get_content_type() == "application/json" else raw)
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


def across(part, cal):
    """Two points on the part's outline across its centre (image px at its top)."""
    c = np.asarray(part.polygon.centroid.coords[0])
    b = part.polygon.exterior
    far = max((np.asarray(p) for p in b.coords), key=lambda p: np.linalg.norm(p - c))
    opposite = np.asarray(b.interpolate(b.project(type(part.polygon.centroid)(*(2 * c - far)))).coords[0])
    return cal.mm_to_px(np.array([far, opposite]), part.z_top_mm)


def test_operator_runs_rejects_teaches_and_approves_over_http(live):
    server, control, loop, examples, world = live
    n0 = len(load_examples(examples))
    code, _ = call(server, "/api/run", {}, token=False)
    assert code == 403 and control.state == "idle"  # no token: nothing moves
    assert call(server, "/api/run", {})[0] == 200
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    code, state = call(server, "/api/state")
    cell = state["cell"]
    assert state["control"]["proposal"]["target"] == "washer"
    assert cell["proposal_px"]["target"] == "washer" and len(cell["proposal_px"]["contacts_px"]) == 2
    assert {p["id"] for p in cell["parts"]} == {"nut", "washer"} and cell["frame"]["index"] == 0
    code, png = call(server, "/api/frame.png")
    assert code == 200 and png[:4] == b"\x89PNG"

    # teach a grasp across the nut: a valid example with a configuration, saved at once, learned at the next plan
    p1, p2 = across(loop.state.seen["nut"], loop.cal)
    code, r = call(server, "/api/teach", {"part": "nut", "p1_px": p1.tolist(), "p2_px": p2.tolist()})
    assert code == 200, r
    taught = load_examples(examples)[-1]
    assert taught.valid and taught.source["kind"] == "station-teach" and taught.joints is not None
    assert taught.part.id == "nut" and r["result"]["n_examples"] == n0 + 1 and len(loop.examples) == n0
    code, r = call(server, "/api/teach", {"part": "washer", "p1_px": [5, 5], "p2_px": [9, 9]})
    assert code == 400 and "outline" in r["error"]

    # reject the proposal: an invalid example; the cell plans again and asks about another grasp
    first = np.array(call(server, "/api/state")[1]["control"]["proposal"]["contacts"])
    seq = control.snapshot()["seq"]
    assert call(server, "/api/reject", {"reason": "pads on the threads"})[0] == 200
    # the loop thread takes the decision, appends the example, plans again and asks again
    def asked_again():
        return control.state == "fault" or (
            control.state == AWAITING_APPROVAL and not load_examples(examples)[-1].valid)

    deadline = time.monotonic() + T
    while not asked_again():
        assert time.monotonic() < deadline, control.snapshot()
        seq = control.wait_change(seq, timeout_s=T)
    assert control.state == AWAITING_APPROVAL, control.snapshot()["fault"]
    rejected = load_examples(examples)[-1]
    assert not rejected.valid and rejected.source["note"] == "pads on the threads"
    assert rejected.part.id == "washer" and len(loop.examples) == n0 + 2  # the reject, then the taught one
    assert [e.id for e in loop.examples[-2:]] == [rejected.id, taught.id]
    second = np.array(control.snapshot()["proposal"]["contacts"])
    assert min(np.abs(second - first).max(), np.abs(second[::-1] - first).max()) > 6.0

    # approve both picks: the world is empty at the end. The loop takes a decision when it next runs, so the
    # state stays awaiting until then: each approval names its proposal, and the next one is awaited by number
    # (approving again at once was a no-op repeat of the same decision, and a loaded machine ran out of tries)
    for _ in range(10):
        shown = control.snapshot()["proposal_no"]
        assert call(server, "/api/approve", {"proposal_no": shown})[0] == 200
        seq, deadline = control.snapshot()["seq"], time.monotonic() + T
        while not (control.state == DONE or control.snapshot()["proposal_no"] not in (shown, None)):
            assert time.monotonic() < deadline, control.snapshot()["state"]
            seq = control.wait_change(seq, timeout_s=T)
        if control.state == DONE:
            break
    assert control.state == DONE
    assert world.removed == ["washer", "nut"]
    assert call(server, "/api/state")[1]["cell"]["removed"] == ["washer", "nut"]


@pytest.mark.skipif(not (Path(CHROMIUM).exists() and Path(CHROMEDRIVER).exists()),
                    reason="the browser test needs Debian's chromium and chromium-driver (apt-get install)")
def test_the_page_shows_the_cell_and_approves_in_a_browser(live, browser):  # noqa: F811 - the fixture
    from selenium.webdriver.support.ui import WebDriverWait

    driver = browser

    server, control, loop, examples, world = live
    driver.get(server.url)
    WebDriverWait(driver, T).until(lambda d: d.find_element("id", "btn-run").is_enabled())
    driver.find_element("id", "btn-run").click()
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    WebDriverWait(driver, T).until(lambda d: "awaiting" in d.find_element("id", "state").text.lower())
    WebDriverWait(driver, T).until(lambda d: d.execute_script(
        "return document.querySelectorAll('#overlay .part').length") == 2)
    driver.find_element("id", "btn-approve").click()
    WebDriverWait(driver, T).until(lambda _: "washer" in world.removed)


def test_stop_on_the_page_quick_stops_a_pick_under_way(tmp_path):
    """Stop during a pick stops the arm now (the real cell's drives run in wall time), not after
    the whole pick; the run ends stopped, not in a fault."""
    from calibration import load_calibration
    from drivers import simulated_cell
    from drivers.clock import RealClock

    d = json.loads(DEFAULT.read_text())
    d["parts"] = [p for p in d["parts"] if p["id"] == "washer"]
    d["sequence"] = ["washer"]
    assembly = parse_assembly(d)
    cell, cal = default_cell(), load_calibration()
    examples = tmp_path / "examples.jsonl"
    shutil.copyfile(default_examples_path(), examples)
    control = RunControl(require_approval=True)
    ended = []
    clock = RealClock()  # ours to close, as `cell hw` does: its thread outlived the test and failed later drivers tests
    with contextlib.ExitStack() as stack:
        stack.callback(clock.close)
        arm, drives = stack.enter_context(simulated_cell(cell, clock=clock))
        world = SimWorld(list(assembly.parts), cell, drives)
        loop = CellLoop(cell=cell, calibration=cal, assembly=assembly, camera=SimCameraSource(world, cal, 0),
                        arm=arm, control=control, examples_path=examples, options=LoopOptions(interactive=True))
        with StationServer(LoopBackend(loop), control, port=0) as server:
            def work():
                try:
                    loop.run()
                except Stopped:
                    ended.append("stopped")

            t = threading.Thread(target=work, daemon=True)
            t.start()
            assert call(server, "/api/run", {})[0] == 200
            control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
            assert call(server, "/api/approve", {})[0] == 200
            deadline = time.monotonic() + T
            while control.snapshot()["checkpoint"] != "pick":
                assert time.monotonic() < deadline
                time.sleep(0.01)
            time.sleep(0.3)  # the arm is on its way to the part (a pick takes seconds)
            t_stop = time.monotonic()
            assert call(server, "/api/stop", {"reason": "hand in the cell"})[0] == 200
            t.join(3)
            assert not t.is_alive() and ended == ["stopped"]
            assert time.monotonic() - t_stop < 2.0
            before = arm.joints()
            time.sleep(0.3)
            assert arm.joints() == before  # standing still
            assert world.removed == []
            assert control.state == "stopped", control.snapshot()["message"]
        world.close()


@pytest.mark.skipif(not (Path(CHROMIUM).exists() and Path(CHROMEDRIVER).exists()),
                    reason="the browser test needs Debian's chromium and chromium-driver (apt-get install)")
def test_labels_and_contacts_are_readable_on_the_cells_full_size_frame(live, browser):  # noqa: F811
    """The cell's camera frame (1280 x 1024) is drawn at about half size: the part names and the
    proposed contacts must stay a readable size on the screen, not shrink with the image."""
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, loop, examples, world = live
    d = browser
    d.set_window_size(1366, 768)
    d.get(server.url)
    WebDriverWait(d, T).until(lambda x: x.find_element("id", "btn-run").is_enabled())
    d.find_element("id", "btn-run").click()
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    WebDriverWait(d, T).until(
        lambda x: x.execute_script("return document.querySelectorAll('#proposal .contact').length") == 2)
    label_h, contact_w = d.execute_script(
        """const r = (sel) => document.querySelector(sel).getBoundingClientRect();
           return [r('#parts .part-label').height, r('#proposal .contact').width];""")
    assert label_h >= 11 and contact_w >= 7, (label_h, contact_w)


def test_the_frame_the_station_shows_changes_with_the_parts_seen_on_it(live):
    """The station's frame index named the newest frame from the moment it was read, while its parts were still
    the last frame's for the whole segmentation: a teach naming that frame was checked against the frame but
    applied to the last frame's parts. Now index, frame and parts change together once the parts are known."""
    server, control, loop, _, _ = live
    backend, perceive, at_entry = LoopBackend(loop), loop._perceive, []

    def watched(frame, index):
        snap = backend.snapshot()
        at_entry.append((index, snap["frame"]["index"], loop.state.frame is frame))
        out = perceive(frame, index)
        assert (loop.state.frame_index, loop.state.frame is frame) == (index, True)
        return out

    loop._perceive = watched
    control.run(by="test")
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    control.approve(by="test")
    deadline = time.monotonic() + T
    while len(at_entry) < 2 and time.monotonic() < deadline:  # the washer picked, the next frame perceived
        time.sleep(0.05)
    assert len(at_entry) >= 2
    for index, shown, same_frame in at_entry:  # while a frame is segmented the station shows the one before
        assert shown != index and not same_frame, at_entry


def test_the_station_lists_removed_and_skipped_parts_apart(live):
    """The snapshot's `removed` held every report's part, skipped ones too."""
    from cell.runtime.loop import PartReport

    _, _, loop, _, _ = live
    loop.reports.append(PartReport("nut", "skipped", reason="no feasible grasp"))
    snap = LoopBackend(loop).snapshot()
    assert (snap["removed"], snap["skipped"], snap["carried"]) == ([], ["nut"], [])
