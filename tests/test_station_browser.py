"""The station page in a real headless Chromium (selenium + Debian's chromium/chromedriver).

Clicks Step, Run, Pause, Approve, a two-click teach on the frame, Reject with a reason, the
approve-each toggle and the keyboard shortcut, and checks both what the backend saw (run
control, the example file) and what the page shows. Set STATION_SCREENSHOT=path.png to keep
a screenshot.
"""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from cell.examples import load_examples
from cell.runtime.control import AWAITING_APPROVAL, DONE, PAUSED, RunControl
from cell.station.demo import DemoCell, demo_parts, mm_to_px
from cell.station.server import StationServer

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
T = 10.0

pytestmark = pytest.mark.skipif(
    not (os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER)),
    reason="the browser test needs Debian's chromium and chromedriver (apt-get install chromium "
           "chromium-driver); they are not installed here",
)


@pytest.fixture
def browser(monkeypatch):
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    monkeypatch.setenv("SE_OFFLINE", "true")  # never let Selenium Manager fetch anything
    profile = tempfile.mkdtemp(prefix="station-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run",
                 "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--window-size=1400,1000"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(T)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


@pytest.fixture
def station(tmp_path):
    control = RunControl(require_approval=True)
    cell = DemoCell(control, tmp_path / "examples.jsonl", motion_s=0.0)
    with StationServer(cell, control, port=0) as server:
        cell.start()
        yield server, control, cell, tmp_path / "examples.jsonl"
        cell.close()


def click_frame_px(driver, u, v):
    """Click the overlay at image pixel (u, v): the page's own SVG transform gives the screen point."""
    from selenium.webdriver.common.action_chains import ActionChains

    svg, dx, dy = frame_offset(driver, u, v)
    ActionChains(driver).move_to_element_with_offset(svg, dx, dy).click().perform()


def frame_offset(d, u, v):
    """Offset from the overlay's centre of image pixel (u, v), for ActionChains."""
    svg = d.find_element("id", "overlay")
    dx, dy = d.execute_script(
        """const svg = arguments[0], p = svg.createSVGPoint();
           p.x = arguments[1]; p.y = arguments[2];
           const q = p.matrixTransform(svg.getScreenCTM()), r = svg.getBoundingClientRect();
           return [q.x - (r.left + r.width / 2), q.y - (r.top + r.height / 2)];""", svg, u, v)
    return svg, round(dx), round(dy)


def test_operator_runs_approves_teaches_and_rejects_in_a_real_browser(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, examples = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)

    def badge():
        return d.find_element(By.ID, "state").text.lower()

    d.get(server.url)
    wait.until(lambda _: badge() == "idle")
    assert "#token" not in d.current_url  # the token is taken from the URL and hidden
    wait.until(lambda _: d.execute_script("return document.getElementById('frame').naturalWidth") == cell.view.width_px)
    assert len(d.find_elements(By.CSS_SELECTOR, "#parts polygon")) == 4

    # Step: one checkpoint passes, then the loop holds
    d.find_element(By.ID, "btn-step").click()
    control.wait_for_state(PAUSED, timeout_s=T)
    wait.until(lambda _: badge() == "paused")
    # Run: the loop proposes a grasp on the cover and waits for approval
    d.find_element(By.ID, "btn-run").click()
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    wait.until(lambda _: badge() == "awaiting approval")
    wait.until(lambda _: "cover" in d.find_element(By.ID, "proposal-text").text)
    assert len(d.find_elements(By.CSS_SELECTOR, "#proposal .finger")) == 2
    shot = os.environ.get("STATION_SCREENSHOT")
    if shot:
        d.save_screenshot(str(Path(shot).with_suffix(".awaiting.png")))
    # Pause while awaiting, then Approve: the grasp is approved and the loop pauses after it
    d.find_element(By.ID, "btn-pause").click()
    wait.until(lambda _: any(e["event"] == "pause" for e in control.snapshot()["events"]))
    d.find_element(By.ID, "btn-approve").click()
    control.wait_for_state(PAUSED, timeout_s=T)
    wait.until(lambda _: badge() == "paused")
    events = control.snapshot(200)["events"]
    assert any(e["event"] == "approve" and e["data"]["by"] == "station" for e in events)

    # Teach: Teach, click the board, click two points on its opposite edges
    board = next(p for p in demo_parts() if p.id == "board")
    o = board.outline_mm
    c1, c2 = (o[0] + o[1]) / 2, (o[2] + o[3]) / 2
    d.find_element(By.ID, "btn-teach").click()
    wait.until(lambda _: "click the part" in d.find_element(By.ID, "teach-status").text)
    click_frame_px(d, *mm_to_px(board.polygon.centroid.coords[0]))
    wait.until(lambda _: "first contact" in d.find_element(By.ID, "teach-status").text)
    click_frame_px(d, *mm_to_px(c1))
    wait.until(lambda _: "second contact" in d.find_element(By.ID, "teach-status").text)
    click_frame_px(d, *mm_to_px(c2))
    wait.until(lambda _: examples.exists())
    wait.until(lambda _: "taught board" in d.find_element(By.ID, "toast").text)
    ex = load_examples(examples)
    assert len(ex) == 1 and ex[0].valid and ex[0].part.id == "board"
    assert ex[0].source["kind"] == "station-teach"
    assert abs(ex[0].contacts_mm - [c1, c2]).max() < 3.0  # two clicks in a scaled view, snapped to the edge
    wait.until(lambda _: d.find_element(By.ID, "examples").text.startswith("1 example in"))

    # Run on: the board's proposal is the taught grasp; approve it with the keyboard
    d.find_element(By.ID, "btn-run").click()
    wait.until(lambda _: (control.snapshot()["proposal"] or {}).get("target") == "board")
    wait.until(lambda _: "taught by the operator" in d.find_element(By.ID, "proposal-text").text)
    d.find_element(By.TAG_NAME, "body").send_keys("a")
    # the bracket: reject it with a reason -> an invalid example
    wait.until(lambda _: (control.snapshot()["proposal"] or {}).get("target") == "bracket")
    wait.until(lambda _: "bracket" in d.find_element(By.ID, "proposal-text").text)
    d.find_element(By.ID, "reason").send_keys("finger on the spring")
    d.find_element(By.ID, "btn-reject").click()
    wait.until(lambda _: len(load_examples(examples)) == 2)
    rejected = load_examples(examples)[1]
    assert not rejected.valid and rejected.source["note"] == "finger on the spring"
    wait.until(lambda _: "finger on the spring" in d.find_element(By.ID, "log").text)

    # turn approval off: the loop finishes the tray by itself
    wait.until(lambda _: control.state == AWAITING_APPROVAL)
    d.find_element(By.ID, "approve-each").click()
    wait.until(lambda _: not control.require_approval)
    d.find_element(By.ID, "btn-approve").click()
    control.wait_for_state(DONE, timeout_s=T)
    wait.until(lambda _: badge() == "done")
    assert cell.snapshot()["removed"] == ["cover", "board", "bracket", "cap"]
    wait.until(lambda _: len(d.find_elements(By.CSS_SELECTOR, "#parts polygon")) == 0)
    # the header says what the run removed, not the last part's move
    assert d.find_element(By.ID, "current").text == "removed 4 parts"
    shot = os.environ.get("STATION_SCREENSHOT")
    if shot:
        d.save_screenshot(str(Path(shot)))


def test_page_without_token_shows_the_token_field_and_commands_change_nothing(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    d.get(server.base_url)
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "idle")
    assert d.find_element(By.ID, "token-card").is_displayed()
    d.find_element(By.ID, "btn-run").click()
    wait.until(lambda _: "token" in d.find_element(By.ID, "toast").text)
    assert control.state == "idle"
    # a wrong token: the server answers 403, nothing happens
    d.find_element(By.ID, "token").send_keys("not-the-right-token")
    d.find_element(By.ID, "btn-token").click()
    d.find_element(By.ID, "btn-run").click()
    wait.until(lambda _: "valid token" in d.find_element(By.ID, "toast").text)
    assert control.state == "idle"
    # in the operator's words: what to do, not a header's name
    assert "open the link the cell printed" in d.find_element(By.ID, "toast").text
    assert "X-Cell-Token" not in d.find_element(By.ID, "toast").text


def test_the_reason_of_a_fault_and_of_a_stop_is_on_the_page(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    d.get(server.url)
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "idle")
    control.report_fault("j2", "following error 3.1 deg")
    wait.until(lambda _: d.find_element(By.ID, "fault").is_displayed())
    banner = d.find_element(By.ID, "fault").text
    assert "j2" in banner and "following error 3.1 deg" in banner
    assert d.find_element(By.ID, "btn-run").get_attribute("disabled") is not None
    d.find_element(By.ID, "btn-reset").click()
    wait.until(lambda _: not d.find_element(By.ID, "fault").is_displayed())
    assert control.state == "idle"
    control.stop("light curtain interrupted", by="safety")
    wait.until(lambda _: d.find_element(By.ID, "message").text == "light curtain interrupted")
    assert d.find_element(By.ID, "state").text.lower() == "stopped"


def run_to_the_first_proposal(d, server):
    """Open the page, press Run and wait for the grasp awaiting approval; the page's WebDriverWait."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    wait = WebDriverWait(d, T, poll_frequency=0.05)
    d.get(server.url)
    d.find_element(By.ID, "btn-run").click()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "awaiting approval")
    return wait


def test_when_the_cell_stops_answering_the_page_says_so_and_offers_no_commands(browser, station):
    """The run ended (`cell run --station` closes the station with it) or the cell is gone: the page
    must not go on showing a green RUNNING with live buttons."""
    from selenium.webdriver.common.by import By

    server, control, cell, _ = station
    d = browser
    wait = run_to_the_first_proposal(d, server)
    server.close()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "offline")
    assert "does not answer" in d.find_element(By.ID, "message").text
    for b in ("btn-run", "btn-pause", "btn-step", "btn-approve", "btn-reject", "btn-reset",
              "btn-teach", "approve-each"):
        assert not d.find_element(By.ID, b).is_enabled(), b
    # Stop always tries (a cell that cannot report its state may still take it); here nobody answers, and the
    # page says so
    d.find_element(By.ID, "btn-stop").click()
    wait.until(lambda _: "the cell does not answer" in d.find_element(By.ID, "toast").text)


def test_a_cell_that_hangs_with_the_connection_open_is_shown_offline_and_stop_says_no_answer(browser, station):
    """A station process stopped (SIGSTOP) or hung keeps its connections open: the page's requests waited for
    ever, and it went on showing a green "running", its Stop saying nothing. Now a state not answered within
    5 s is "offline", and a command not answered within 10 s says so."""
    import threading

    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, _ = station
    d = browser
    open_page(d, server, "idle")
    control.run()
    WebDriverWait(d, T, poll_frequency=0.05).until(
        lambda _: d.find_element(By.ID, "state").text.lower() != "idle")
    hung = threading.Event()
    state, command = server.state, server.command

    def hangs(fn):
        def wrapper(*a, **k):
            hung.wait(60)
            return fn(*a, **k)
        return wrapper

    server.state, server.command = hangs(state), hangs(command)
    try:
        WebDriverWait(d, 15, poll_frequency=0.1).until(
            lambda _: d.find_element(By.ID, "state").text.lower() == "offline")
        assert "does not answer (no answer within 5 s)" in d.find_element(By.ID, "message").text
        d.find_element(By.ID, "btn-stop").click()
        WebDriverWait(d, 20, poll_frequency=0.1).until(
            lambda _: "no answer within 10 s" in d.find_element(By.ID, "toast").text)
        assert "stop may not have been done" in d.find_element(By.ID, "toast").text
    finally:
        hung.set()
    WebDriverWait(d, T, poll_frequency=0.1).until(
        lambda _: d.find_element(By.ID, "state").text.lower() not in ("offline", ""))


def _a_proposal_then_no_state(d, station, monkeypatch):
    """Run to the first proposal, then make the cell's state fail (its snapshot raises) until the page is
    offline; the page's WebDriverWait."""
    from selenium.webdriver.common.by import By

    server, _, cell, _ = station
    wait = run_to_the_first_proposal(d, server)

    def broken():
        raise RuntimeError("camera buffer gone")

    monkeypatch.setattr(cell, "snapshot", broken)
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "offline")
    return wait


def test_when_the_cell_cannot_report_its_state_the_page_says_so_and_comes_back(browser, station, monkeypatch):
    """A 500 from /api/state left the page showing the last state (a waiting grasp, Approve live) with
    no sign that anything was wrong."""
    from selenium.webdriver.common.by import By

    d = browser
    wait = _a_proposal_then_no_state(d, station, monkeypatch)
    message = d.find_element(By.ID, "message").text
    assert "cannot report its state (HTTP 500" in message and "camera buffer gone" in message, message
    assert not d.find_element(By.ID, "btn-approve").is_enabled()
    monkeypatch.undo()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "awaiting approval")
    assert d.find_element(By.ID, "btn-approve").is_enabled()


def test_a_cell_that_cannot_report_its_state_still_takes_stop_from_the_page(browser, station, monkeypatch):
    """The page greyed Stop out while the state failed, though the server would take it; and a Stop it took then
    got no answer (the state after it failed: a dropped connection, 'the cell does not answer')."""
    from selenium.webdriver.common.by import By

    d, control = browser, station[1]
    wait = _a_proposal_then_no_state(d, station, monkeypatch)
    d.find_element(By.ID, "btn-stop").click()
    wait.until(lambda _: "stop: done; the cell cannot report its state" in d.find_element(By.ID, "toast").text)
    assert control.state == "stopped"


@pytest.mark.parametrize("focus, key", [("btn-stop", " "), ("btn-stop", "\ue007"), (None, "s")],
                         ids=["space-on-stop", "enter-on-stop", "s"])
def test_space_and_enter_press_the_focused_button_and_s_stops(browser, station, focus, key):
    """Space on the focused Stop button sent step (the shortcut caught it) and the cell went on; no key stopped."""
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page_awaiting_approval(d, server, control)
    if focus:
        d.execute_script(f"document.getElementById('{focus}').focus()")
    keys(d, key)
    WebDriverWait(d, T).until(lambda _: control.state == "stopped")
    assert posts(d) == ["stop"]


@pytest.mark.parametrize("size", [(1366, 768), (1920, 1080)])
def test_the_whole_frame_and_the_approve_button_fit_the_window(browser, station, size):
    """A station PC's common screen sizes: the frame (with the grasp drawn on it) is seen whole
    without scrolling, next to Stop and Approve."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, _ = station
    d = browser
    d.set_window_size(*size)
    d.get(server.url)
    d.find_element(By.ID, "btn-run").click()
    WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "state").text.lower() == "awaiting approval")
    view, approve, inner_h, inner_w = d.execute_script(
        """const r = (id) => document.getElementById(id).getBoundingClientRect().toJSON();
           return [r('view'), r('btn-approve'), innerHeight, innerWidth];""")
    assert view["bottom"] <= inner_h and approve["bottom"] <= inner_h, (view, approve, inner_h)
    assert view["width"] > 0.4 * inner_w  # and still large
    assert d.execute_script("return document.documentElement.scrollWidth") <= inner_w


def test_a_run_that_ended_before_the_station_closed_says_how_it_ended(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    d.get(server.url)
    control.stop("end of shift")
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "stopped")
    server.close()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "offline")
    assert "the run is stopped and the cell closed the station" in d.find_element(By.ID, "message").text


# ---------------------------------------------------------------- what an operator trips over
RECORD_POSTS = """window.__posts = []; window.__bodies = [];
const orig = window.fetch;
window.fetch = (u, o) => {
  if (o && o.method === 'POST') { window.__posts.push(String(u)); window.__bodies.push(JSON.parse(o.body)); }
  return orig(u, o);
};"""


def posts(d):
    return [u.rsplit("/", 1)[-1] for u in d.execute_script("return window.__posts")]


def viewport(d, width, height):
    """The page's own size, exactly (a window's size includes the browser's frame)."""
    d.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                      {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})


def open_page(d, server, state):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    d.get(server.url)
    WebDriverWait(d, T, poll_frequency=0.05).until(
        lambda _: d.find_element(By.ID, "state").text.lower() == state)
    d.execute_script(RECORD_POSTS)


def open_page_awaiting_approval(d, server, control):
    """Run the demo cell until its first grasp waits for approval, and open the page on it."""
    control.run()
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    open_page(d, server, "awaiting approval")


def keys(d, *k):
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(d).send_keys(*k).perform()


def test_browser_shortcuts_with_ctrl_do_not_approve_reject_or_pause(browser, station):
    """Ctrl+A (select all), Ctrl+R (reload), Ctrl+P (print) are the browser's: Ctrl+A approved the
    grasp waiting on the page."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    server, control, _, _ = station
    d = browser
    open_page_awaiting_approval(d, server, control)
    for k in "aprt":
        ActionChains(d).key_down(Keys.CONTROL).send_keys(k).key_up(Keys.CONTROL).perform()
        ActionChains(d).key_down(Keys.ALT).send_keys(k).key_up(Keys.ALT).perform()
    assert posts(d) == []
    assert control.state == AWAITING_APPROVAL
    assert not any(e["event"] in ("approve", "reject", "pause") for e in control.snapshot(200)["events"])


def test_r_with_an_empty_reason_focuses_the_field_without_typing_an_r_into_it(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page_awaiting_approval(d, server, control)
    keys(d, "r")
    reason = d.find_element(By.ID, "reason")
    assert d.switch_to.active_element == reason
    assert reason.get_attribute("value") == ""  # was "r": the key's own character landed in the field
    keys(d, "tilted, a spring")  # typing the reason: letters that are shortcuts elsewhere do nothing
    assert reason.get_attribute("value") == "tilted, a spring"
    assert posts(d) == []
    keys(d, "\ue007")  # Enter rejects with that reason
    WebDriverWait(d, T).until(lambda _: any(e["event"] == "reject" for e in control.snapshot(200)["events"]))
    assert [e["message"] for e in control.snapshot(200)["events"] if e["event"] == "reject"] == [
        "grasp rejected: tilted, a spring"]


def test_a_shortcut_whose_button_is_disabled_sends_nothing_and_says_why(browser, station):
    """'a' with no grasp waiting used to post approve (a 409 and a red toast); a key held down sent a
    step per auto-repeat."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page(d, server, "idle")
    keys(d, "a")
    WebDriverWait(d, T).until(lambda _: "Approve is not available now" in d.find_element(By.ID, "toast").text)
    assert posts(d) == []
    # a held space: the first keydown steps, its auto-repeats do not
    d.execute_script("""for (const repeat of [false, true, true, true])
        document.body.dispatchEvent(new KeyboardEvent('keydown', {key: ' ', repeat, bubbles: true}));""")
    assert posts(d) == ["step"]


def test_space_on_the_focused_approve_each_checkbox_toggles_it_and_does_not_step(browser, station):
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page(d, server, "idle")
    d.execute_script("document.getElementById('approve-each').focus()")
    keys(d, " ")
    WebDriverWait(d, T).until(lambda _: not control.require_approval)
    assert posts(d) == ["approval"]



def test_a_slow_tap_on_a_part_while_teaching_selects_it(browser, station):
    """The page redrew every outline at every poll (300 ms): a part pressed across a redraw (a slow
    tap on a touchscreen) got no click, and teaching stayed at 'click the part'."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page(d, server, "idle")
    cap = next(p for p in demo_parts() if p.id == "cap")
    d.find_element(By.ID, "btn-teach").click()
    svg, dx, dy = frame_offset(d, *mm_to_px(cap.polygon.centroid.coords[0]))
    ActionChains(d).move_to_element_with_offset(svg, dx, dy).click_and_hold().perform()
    d.execute_script("render(last)")  # a poll's answer arrives while the finger is down
    ActionChains(d).release().perform()
    status = d.find_element(By.ID, "teach-status")
    WebDriverWait(d, T).until(lambda _: "Teach cap: click the first contact" in status.text)
    # the prompt is under the frame too, where the clicks go, in place of the keys
    assert d.find_element(By.ID, "teach-hint").text == status.text + " · Esc cancels"
    assert not d.find_element(By.ID, "keys").is_displayed()
    assert d.find_element(By.CSS_SELECTOR, "#parts polygon.selected").get_attribute("data-part") == "cap"
    # a tap beside every part says so, and teaching waits for the part
    d.find_element(By.ID, "btn-teach").click()  # off
    d.find_element(By.ID, "btn-teach").click()  # on again
    ActionChains(d).move_to_element_with_offset(svg, *frame_offset(d, 5, 5)[1:]).click().perform()
    WebDriverWait(d, T).until(lambda _: "no part there" in d.find_element(By.ID, "teach-status").text)
    # Esc cancels wherever the focus is, as the hint says: typed into the reason field it did nothing
    from selenium.webdriver.common.keys import Keys

    d.find_element(By.ID, "reason").send_keys(Keys.ESCAPE)
    WebDriverWait(d, T).until(lambda _: not d.find_element(By.ID, "teach-hint").is_displayed())
    assert d.find_element(By.ID, "keys").is_displayed()


def test_a_reason_typed_for_one_grasp_is_not_kept_for_the_next(browser, station):
    """The operator typed a reason, then approved after all: the text stayed, and 'r' on the next
    grasp rejected it at once with the first grasp's reason."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page_awaiting_approval(d, server, control)
    d.find_element(By.ID, "reason").send_keys("finger on the spring")
    d.find_element(By.ID, "btn-approve").click()
    WebDriverWait(d, T).until(lambda _: "board" in d.find_element(By.ID, "proposal-text").text)
    assert d.find_element(By.ID, "reason").get_attribute("value") == ""
    d.execute_script("document.activeElement.blur()")
    keys(d, "r")  # asks for a reason, rejects nothing
    assert d.switch_to.active_element == d.find_element(By.ID, "reason")
    assert posts(d) == ["approve"] and control.state == AWAITING_APPROVAL


@pytest.mark.parametrize("size", [(1280, 800), (1920, 1080)])
def test_with_the_fault_banner_the_frame_and_its_hint_still_fit_the_window(browser, station, size):
    """The frame's height was the window's less a fixed 100 px: the fault banner (and a header that
    wraps to two lines) pushed the bottom of the tray and the hint line out of the window."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    d.set_window_size(*size)
    control.report_fault("j2", "following error 3.1 deg on the way down to the bracket, drive 2 disabled")
    open_page(d, server, "fault")
    WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "fault").is_displayed())
    view, hint, inner_h, inner_w = d.execute_script(
        """const r = (id) => document.getElementById(id).getBoundingClientRect().toJSON();
           return [r('view'), r('hint'), innerHeight, innerWidth];""")
    assert hint["bottom"] <= inner_h and view["bottom"] <= hint["top"], (view, hint, inner_h)
    assert view["width"] > 0.4 * inner_w


def test_on_a_portrait_tablet_the_frame_spans_the_width_above_the_buttons(browser, station):
    """800 x 1280: the frame was squeezed into the left half (372 px wide) beside the panel, and the
    lower half of the screen was empty."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    d.set_window_size(800, 1280)
    open_page_awaiting_approval(d, server, control)
    WebDriverWait(d, T).until(lambda _: "cover" in d.find_element(By.ID, "proposal-text").text)
    view, run, approve, inner_h, inner_w, scroll_w = d.execute_script(
        """const r = (id) => document.getElementById(id).getBoundingClientRect().toJSON();
           return [r('view'), r('btn-run'), r('btn-approve'), innerHeight, innerWidth,
                   document.documentElement.scrollWidth];""")
    assert view["width"] > 0.9 * inner_w, view
    assert view["bottom"] < run["top"] and approve["bottom"] <= inner_h, (view, approve, inner_h)
    assert scroll_w <= inner_w


def test_a_disabled_command_button_does_not_wear_its_colour(browser, station):
    """Disabled buttons were their colour at 35 % opacity: a dark green Run or dark red Stop read as
    live on a touchscreen in daylight."""
    server, control, _, _ = station
    d = browser
    open_page(d, server, "idle")  # Run, Step, Stop, Teach enabled; Pause, Approve, Reject, Reset not
    bg = d.execute_script("""const o = {};
        for (const b of document.querySelectorAll('.panel button.big'))
            o[b.id] = [b.disabled, getComputedStyle(b).backgroundColor, getComputedStyle(b).opacity];
        return o;""")
    disabled = {k: v[1] for k, v in bg.items() if v[0]}
    enabled = {k: v[1] for k, v in bg.items() if not v[0]}
    assert set(disabled) == {"btn-pause", "btn-approve", "btn-reject", "btn-reset"}, bg
    assert len(set(disabled.values())) == 1  # one grey for every disabled command
    assert not set(disabled.values()) & set(enabled.values()), bg
    assert all(v[2] == "1" for v in bg.values())  # the label stays readable


def test_after_a_refused_token_the_token_field_is_on_screen_and_focused(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    d.set_window_size(1280, 800)
    control.run()
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    d.get(server.base_url)
    d.execute_script("sessionStorage.setItem('cell-token', 'the-token-of-yesterday')")
    d.refresh()  # the tab kept an old token (the station was restarted with a new one)
    WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "state").text.lower() == "awaiting approval")
    assert not d.find_element(By.ID, "token-card").is_displayed()
    d.find_element(By.ID, "btn-approve").click()
    WebDriverWait(d, T).until(lambda _: "valid token" in d.find_element(By.ID, "toast").text)
    field = d.find_element(By.ID, "token")
    top, bottom, inner_h = d.execute_script(
        "const r = arguments[0].getBoundingClientRect(); return [r.top, r.bottom, innerHeight]", field)
    assert 0 <= top and bottom <= inner_h, (top, bottom, inner_h)
    assert d.switch_to.active_element == field
    assert control.state == AWAITING_APPROVAL


def test_stop_is_offered_in_a_fault_and_abandons_the_sequence(browser, station):
    """Stop was disabled in a fault, though the cell takes it: Reset was the only way on, and a reset
    mid-pick moves the arm (it carries the part off)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    control.report_fault("j1", "drive 1 fault 0x7121 (motor blocked)")
    open_page(d, server, "fault")
    assert d.find_element(By.ID, "btn-stop").is_enabled()
    assert not d.find_element(By.ID, "btn-step").is_enabled() and not d.find_element(By.ID, "btn-run").is_enabled()
    d.find_element(By.ID, "btn-stop").click()
    WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "state").text.lower() == "stopped")
    assert control.state == "stopped" and posts(d) == ["stop"]


def test_the_approve_each_box_always_shows_the_cells_setting(browser, station):
    """The box was never redrawn while it had the focus (it keeps it after a tap): a toggle that did
    not reach the cell left it showing the tap ('approve each grasp' on while the cell ran without
    asking), and a change made elsewhere (the cell's terminal, another tab) did not show."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T)
    control.set_require_approval(False)
    open_page(d, server, "idle")
    box = d.find_element(By.ID, "approve-each")
    assert not box.is_selected()
    # the toggle does not reach the cell (the connection drops at that moment)
    d.execute_script("""const orig = window.fetch;
        window.fetch = (u, o) => String(u).endsWith('/api/approval') ? Promise.reject(new TypeError('network'))
                                                                       : orig(u, o);""")
    box.click()
    wait.until(lambda _: "does not answer" in d.find_element(By.ID, "toast").text)
    assert d.switch_to.active_element == box and not control.require_approval
    wait.until(lambda _: not box.is_selected())
    # changed elsewhere while the box has the focus
    control.set_require_approval(True, by="terminal")
    wait.until(lambda _: box.is_selected())
    assert d.switch_to.active_element == box


HOLD_STATE_POLLS = """window.__hold = true; window.__held = [];
const orig = window.fetch;
window.fetch = (u, o) => {
  if (window.__hold && String(u).includes('/api/state')) {
    const answer = orig(u, o);   // asked now, answered when the test releases it
    return new Promise((res) => window.__held.push(() => answer.then(res)));
  }
  return orig(u, o);
};"""


def test_a_state_polled_before_a_command_does_not_undo_what_the_command_showed(browser, station):
    """A poll asked before Stop and answered after it flipped the page back to 'awaiting approval'
    with Approve enabled, until the next poll."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.02)
    open_page_awaiting_approval(d, server, control)
    d.execute_script(HOLD_STATE_POLLS)
    wait.until(lambda _: d.execute_script("return window.__held.length") == 1)  # asked while awaiting
    d.find_element(By.ID, "btn-stop").click()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "stopped")  # the command's answer
    d.execute_script("window.__held.shift()()")  # the stale answer arrives
    wait.until(lambda _: d.execute_script("return window.__held.length") == 1)  # ... was handled: next poll
    assert d.find_element(By.ID, "state").text.lower() == "stopped"
    assert not d.find_element(By.ID, "btn-approve").is_enabled()
    assert control.state == "stopped"


def test_after_the_station_restarts_the_page_shows_the_new_frame(browser, station, tmp_path):
    """The page kept the frame's number across the restart: the new station's frame 0 was never
    loaded, and the old tray's picture stood under the new tray's outlines."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    open_page(d, server, "idle")
    wait.until(lambda _: d.execute_script("return document.getElementById('frame').complete "
                                          "&& document.getElementById('frame').naturalWidth") == cell.view.width_px)
    d.execute_script("window.__loads = 0; document.getElementById('frame').addEventListener('load', "
                     "() => window.__loads++)")
    port = server.port
    server.close()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "offline")
    assert "stale" in d.find_element(By.ID, "view").get_attribute("class")  # the old picture is greyed
    control2 = RunControl()
    cell2 = DemoCell(control2, tmp_path / "examples2.jsonl", parts=demo_parts()[:2], motion_s=0.0)
    assert cell2.snapshot()["frame"]["index"] == cell.snapshot()["frame"]["index"] == 0
    served, frame_png = [], cell2.frame_png
    cell2.frame_png = lambda: served.append(1) or frame_png()
    with StationServer(cell2, control2, port=port):
        wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "idle")
        wait.until(lambda _: len(d.find_elements(By.CSS_SELECTOR, "#parts polygon")) == 2)
        wait.until(lambda _: d.execute_script("return window.__loads") >= 1)
        assert "stale" not in d.find_element(By.ID, "view").get_attribute("class")
        # the picture is the new station's: asked of it (the same address "?i=0" was answered from the
        # browser's memory with the old tray's picture)
        assert served


def test_teach_is_not_offered_when_no_part_is_on_the_frame(browser, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    control = RunControl()
    cell = DemoCell(control, tmp_path / "examples.jsonl", parts=[], motion_s=0.0)
    with StationServer(cell, control, port=0) as server:
        d = browser
        d.get(server.url)
        WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "state").text.lower() == "idle")
        assert not d.find_element(By.ID, "btn-teach").is_enabled()


def test_the_page_does_not_scroll_and_the_header_keeps_its_badge_on_one_line(browser, station):
    """1280 x 800 with a grasp waiting: the log ran 100 px below the window, so the page scrolled
    (and with it the frame and the buttons); on a portrait tablet the badge broke into
    'AWAITING / APPROVAL' and the title into two lines."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    viewport(d, 1280, 800)  # the station PC's screen, the browser full screen
    open_page_awaiting_approval(d, server, control)
    WebDriverWait(d, T).until(lambda _: "cover" in d.find_element(By.ID, "proposal-text").text)
    for n in range(40):
        control.log("note", f"a long line of the log, number {n}, to fill the card")
    WebDriverWait(d, T).until(lambda _: "number 39" in d.find_element(By.ID, "log").text)
    scroll_h, inner_h = d.execute_script("return [document.documentElement.scrollHeight, innerHeight]")
    assert scroll_h <= inner_h, (scroll_h, inner_h)
    viewport(d, 800, 1280)
    WebDriverWait(d, T).until(lambda _: d.execute_script("return innerWidth") == 800)
    badge, title = d.execute_script("""const r = (q) => document.querySelector(q).getBoundingClientRect().height;
        return [r('#state'), r('h1')];""")
    assert badge < 40 and title < 32, (badge, title)  # one line each (15 px and 20 px type)


def test_a_toast_does_not_catch_taps_meant_for_what_it_covers(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page(d, server, "idle")
    keys(d, "a")  # "Approve is not available now": a toast for 5 s
    toast = d.find_element(By.ID, "toast")
    WebDriverWait(d, T).until(lambda _: toast.is_displayed())
    hit = d.execute_script("""const r = arguments[0].getBoundingClientRect();
        return document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);""", toast)
    assert hit != toast


def test_reject_with_an_empty_reason_asks_for_one_first(browser, station):
    """Reject rejected at once with 'rejected by the operator' while 'r' asked for a reason: the
    button now asks too; a second Reject rejects without one."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page_awaiting_approval(d, server, control)
    reason = d.find_element(By.ID, "reason")
    d.find_element(By.ID, "btn-reject").click()
    assert posts(d) == [] and control.state == AWAITING_APPROVAL
    assert d.switch_to.active_element == reason and "why?" in reason.get_attribute("placeholder")
    d.find_element(By.ID, "btn-reject").click()  # no reason after all
    WebDriverWait(d, T).until(lambda _: any(e["event"] == "reject" for e in control.snapshot(200)["events"]))
    assert posts(d) == ["reject"]
    assert "why?" not in reason.get_attribute("placeholder")


def test_teach_starts_over_when_a_new_frame_comes_in_between_the_clicks(browser):
    """A part chosen and a contact clicked on one frame, the second contact on the next one: the
    example mixed two frames (the loop had moved on, the part was measured anew)."""
    import numpy as np
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    from cell.station.live import LiveView

    taught = []
    view = LiveView(teach_fn=lambda part, p1, p2: taught.append((part, p1, p2)) or
                    {"example_id": "ex-1", "n_examples": 1})
    square = [[200, 150], [300, 150], [300, 250], [200, 250]]
    view.show_frame(0, np.zeros((400, 500, 3), np.uint8))
    view.show_parts([{"id": "plate", "outline_px": square}])
    control = RunControl()
    with StationServer(view, control, port=0) as server:
        d = browser
        wait = WebDriverWait(d, T, poll_frequency=0.05)
        d.get(server.url)
        wait.until(lambda _: len(d.find_elements(By.CSS_SELECTOR, "#parts polygon")) == 1)
        status = d.find_element(By.ID, "teach-status")

        def click(u, v):
            svg, dx, dy = frame_offset(d, u, v)
            ActionChains(d).move_to_element_with_offset(svg, dx, dy).click().perform()

        d.find_element(By.ID, "btn-teach").click()
        click(250, 200)
        click(200, 200)  # the first contact, on frame 0
        wait.until(lambda _: "second contact" in status.text)
        moved = [[u + 40, v] for u, v in square]
        view.show_frame(1, np.zeros((400, 500, 3), np.uint8))
        view.show_parts([{"id": "plate", "outline_px": moved}])
        wait.until(lambda _: "new frame" in status.text)
        click(290, 200)
        click(240, 200)
        click(340, 200)
        wait.until(lambda _: taught)
        assert len(taught) == 1 and taught[0][0] == "plate", taught
        # both contacts on frame 1's plate (a click lands within a screen px of the aimed point)
        assert np.abs(np.array(taught[0][1:]) - [[240, 200], [340, 200]]).max() <= 1.5, taught


def test_approve_and_reject_send_the_grasp_the_page_shows(browser, station):
    """So the cell refuses a tap that would decide a grasp the operator has not seen (409)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    control.run()
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    shown, shown_no = control.snapshot(0)["proposal"], control.snapshot(0)["proposal_no"]
    open_page(d, server, "awaiting approval")
    d.find_element(By.ID, "reason").send_keys("rim")
    d.find_element(By.ID, "btn-reject").click()
    WebDriverWait(d, T).until(lambda _: d.execute_script("return window.__bodies.length") == 1)
    assert d.execute_script("return window.__bodies") == [{"reason": "rim", "proposal": shown,
                                                           "proposal_no": shown_no}]
    # the page a poll behind: its Approve names the rejected grasp, the cell refuses it
    d.execute_script(HOLD_STATE_POLLS)  # no poll answered from here on
    WebDriverWait(d, T).until(lambda _: d.execute_script("return window.__held.length") == 1)
    WebDriverWait(d, T).until(lambda _: control.snapshot(0)["proposal"] not in (None, shown))
    # (as a page that did not decide it itself: this one keeps Approve off for the grasp it rejected)
    d.execute_script("last.control.state = 'awaiting_approval'; last.control.proposal = arguments[0];"
                     "last.control.proposal_no = arguments[1]; decidedNo = null; render(last)", shown, shown_no)
    d.find_element(By.ID, "btn-approve").click()
    WebDriverWait(d, T).until(lambda _: "that grasp was already rejected" in d.find_element(By.ID, "toast").text)
    assert not any(e["event"] == "approve" for e in control.snapshot(200)["events"])


def test_zoom_magnifies_the_parts_and_teach_clicks_stay_in_image_px(browser):
    """The real cell's parts fill a small middle of its 1280 x 1024 frame: at 1280 x 800 a part of
    40 px was 26 px on the screen, less than a fingertip, for two contact clicks on its edge."""
    import numpy as np
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    from cell.station.live import LiveView

    taught = []
    view = LiveView(teach_fn=lambda part, p1, p2: taught.append((part, p1, p2)) or
                    {"example_id": "ex-1", "n_examples": 1})
    frame = np.zeros((1024, 1280, 3), np.uint8)
    frame[500:531, 600:641] = (0, 255, 0)  # the part, as the camera sees it
    view.show_frame(0, frame)
    view.show_parts([{"id": "clip", "outline_px": [[600, 500], [641, 500], [641, 531], [600, 531]]},
                     {"id": "nut", "outline_px": [[700, 560], [720, 560], [720, 580], [700, 580]]}])
    with StationServer(view, RunControl(), port=0) as server:
        d = browser
        viewport(d, 1280, 800)
        wait = WebDriverWait(d, T, poll_frequency=0.05)
        d.get(server.url)
        wait.until(lambda _: len(d.find_elements(By.CSS_SELECTOR, "#parts polygon")) == 2)
        wait.until(lambda _: d.execute_script("return document.getElementById('frame').naturalWidth") == 1280)

        def clip_width():
            return d.find_element(By.CSS_SELECTOR, "#parts polygon[data-part=clip]").rect["width"]

        whole = clip_width()
        d.find_element(By.ID, "btn-zoom").click()
        wait.until(lambda _: clip_width() > 3 * whole)
        # the picture is cropped and scaled as the overlay: image px (620, 515) is one screen point
        img_pt, svg_pt = d.execute_script(
            """const img = document.getElementById('frame').getBoundingClientRect();
               const svg = document.getElementById('overlay'), p = svg.createSVGPoint();
               p.x = 620; p.y = 515; const q = p.matrixTransform(svg.getScreenCTM());
               return [[img.left + 620 * img.width / 1280, img.top + 515 * img.height / 1024], [q.x, q.y]];""")
        assert abs(img_pt[0] - svg_pt[0]) < 1 and abs(img_pt[1] - svg_pt[1]) < 1, (img_pt, svg_pt)
        # teach with the parts magnified
        d.find_element(By.ID, "btn-teach").click()
        for u, v in ((620, 515), (600, 515), (641, 515)):
            svg, dx, dy = frame_offset(d, u, v)
            ActionChains(d).move_to_element_with_offset(svg, dx, dy).click().perform()
        wait.until(lambda _: taught)
        assert taught[0][0] == "clip"
        assert np.abs(np.array(taught[0][1:]) - [[600, 515], [641, 515]]).max() <= 0.5, taught
        keys(d, "z")  # and back to the whole frame
        wait.until(lambda _: abs(clip_width() - whole) < 1)


def test_before_the_first_frame_the_view_shows_no_broken_picture(browser):
    """`cell run --station` before Run: the empty <img> drew a broken-image icon and its alt text over
    'no frame yet'."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    from cell.station.live import LiveView

    with StationServer(LiveView(), RunControl(), port=0) as server:
        d = browser
        d.get(server.url)
        WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "state").text.lower() == "idle")
        assert d.find_element(By.ID, "noframe").is_displayed()
        assert not d.find_element(By.ID, "frame").is_displayed()


def test_the_fault_banner_asks_for_reset_only_while_the_cell_can_take_one(browser, station):
    """A fault, then Stop, then the station closed (`cell run --station` ends with the run): the banner
    still said 'fix it, then Reset' over an offline page whose Reset is disabled."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    banner = lambda: d.find_element(By.ID, "fault").text  # noqa: E731
    control.report_fault("cell", "nut did not leave the tray", asking=True)
    open_page(d, server, "fault")
    wait.until(lambda _: "fix it, then Reset" in banner())
    assert banner().startswith("STOPPED TO ASK — cell needs you: nut did not leave the tray"), banner()
    d.find_element(By.ID, "btn-stop").click()
    wait.until(lambda _: "the sequence is stopped" in banner())
    server.close()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "offline")
    assert banner().startswith("The last stop, cell needed you: nut did not leave the tray"), banner()
    assert "Reset" not in banner()
    assert not d.find_element(By.ID, "btn-reset").is_enabled()


def test_the_log_shows_the_station_pcs_clock(browser, station):
    """The log showed the events' UTC time: an hour or more off the operator's watch (and the
    cell's terminal) anywhere but in UTC."""
    from datetime import datetime, timedelta

    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    d.execute_cdp_cmd("Emulation.setTimezoneOverride", {"timezoneId": "Asia/Tokyo"})  # UTC+9, no DST
    control.log("note", "the clock check")
    open_page(d, server, "idle")
    e = next(e for e in control.snapshot(200)["events"] if e["event"] == "note")
    tokyo = (datetime.fromisoformat(e["t"].replace("Z", "+00:00")) + timedelta(hours=9)).strftime("%H:%M:%S")
    line = WebDriverWait(d, T).until(
        lambda _: next((li.text for li in d.find_elements(By.CSS_SELECTOR, "#log li") if "clock check" in li.text),
                       None))
    assert line.startswith(tokyo + " note"), (line, e["t"])


def test_enter_in_the_token_field_uses_the_token(browser, station):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    d.get(server.base_url)
    WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "token-card").is_displayed())
    d.find_element(By.ID, "token").send_keys(server.token + "\ue007")
    WebDriverWait(d, T).until(lambda _: not d.find_element(By.ID, "token-card").is_displayed())
    d.find_element(By.ID, "btn-step").click()
    control.wait_for_state(PAUSED, timeout_s=T)


def test_a_refused_teach_keeps_the_part_for_another_pair_of_contacts(browser, station):
    """Teach refused (a contact clicked off the edge): the page dropped everything, and the operator
    had to press Teach and pick the part again."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, examples = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    open_page(d, server, "idle")
    board = next(p for p in demo_parts() if p.id == "board")
    o = board.outline_mm
    centre = board.polygon.centroid.coords[0]
    status = d.find_element(By.ID, "teach-status")

    def click_mm(xy):
        svg, dx, dy = frame_offset(d, *mm_to_px(xy))
        ActionChains(d).move_to_element_with_offset(svg, dx, dy).click().perform()

    d.find_element(By.ID, "btn-teach").click()
    click_mm(centre)
    click_mm(centre)  # the middle of the board: 22 mm from its edge, refused
    wait.until(lambda _: "second contact" in status.text)
    click_mm(centre)
    wait.until(lambda _: "from the outline of board" in d.find_element(By.ID, "toast").text)
    wait.until(lambda _: "Teach board: click the first contact" in status.text)
    click_mm((o[0] + o[1]) / 2)
    click_mm((o[2] + o[3]) / 2)
    wait.until(lambda _: examples.exists())
    ex = load_examples(examples)
    assert len(ex) == 1 and ex[0].part.id == "board" and ex[0].valid


def test_teach_clicks_land_on_the_part_across_a_turn_of_the_tablet(browser, station):
    """A guard: the part and the first contact clicked in portrait (800 x 1280), the second after
    the tablet turned to landscape (1280 x 800, the frame re-laid out): both are image px."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, examples = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    viewport(d, 800, 1280)
    open_page(d, server, "idle")
    board = next(p for p in demo_parts() if p.id == "board")
    o = board.outline_mm
    c1, c2 = (o[0] + o[1]) / 2, (o[2] + o[3]) / 2

    def click_mm(xy):
        svg, dx, dy = frame_offset(d, *mm_to_px(xy))
        ActionChains(d).move_to_element_with_offset(svg, dx, dy).click().perform()

    d.find_element(By.ID, "btn-teach").click()
    click_mm(board.polygon.centroid.coords[0])
    click_mm(c1)
    wait.until(lambda _: "second contact" in d.find_element(By.ID, "teach-status").text)
    portrait_w = d.find_element(By.ID, "view").rect["width"]
    viewport(d, 1280, 800)
    wait.until(lambda _: abs(d.find_element(By.ID, "view").rect["width"] - portrait_w) > 50)
    click_mm(c2)
    wait.until(lambda _: examples.exists())
    ex = load_examples(examples)
    assert abs(ex[0].contacts_mm - [c1, c2]).max() < 3.0


def test_a_pause_pressed_while_a_grasp_waits_shows(browser, station):
    """Pause while a grasp waits takes effect after the decision: the page showed no sign of it (the
    badge still 'awaiting approval', Pause still live), and operators pressed it again."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    open_page_awaiting_approval(d, server, control)
    d.find_element(By.ID, "btn-pause").click()
    wait.until(lambda _: "then pause" in d.find_element(By.ID, "message").text)
    assert not d.find_element(By.ID, "btn-pause").is_enabled()
    d.find_element(By.ID, "btn-run").click()  # taken back: runs on after the decision
    wait.until(lambda _: "then" not in d.find_element(By.ID, "message").text)
    assert not d.find_element(By.ID, "btn-run").is_enabled() and d.find_element(By.ID, "btn-pause").is_enabled()
    d.find_element(By.ID, "btn-pause").click()
    wait.until(lambda _: "then pause" in d.find_element(By.ID, "message").text)
    d.find_element(By.ID, "btn-approve").click()
    control.wait_for_state(PAUSED, timeout_s=T)
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "paused")
    d.find_element(By.ID, "btn-run").click()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "awaiting approval")
    assert "then" not in d.find_element(By.ID, "message").text  # the next grasp: nothing pending
    assert d.find_element(By.ID, "btn-pause").is_enabled()


def test_every_control_is_a_fingertip_high(browser, station):
    """Touch targets of 44 px at least: "approve each grasp" was a 28 px row, "Use token" 38 px, the
    reason and token fields 40 px."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    viewport(d, 1280, 800)
    d.get(server.base_url)  # no token: the token card shows too
    WebDriverWait(d, T).until(lambda _: d.find_element(By.ID, "token-card").is_displayed())
    sizes = d.execute_script("""const out = {};
        for (const e of document.querySelectorAll('button, label.toggle, input[type=text], input[type=password]')) {
            const r = e.getBoundingClientRect();
            if (r.width && r.height) out[e.id || e.className || e.tagName] = r.height;
        }
        return out;""")
    assert len(sizes) == 13, sizes  # 10 buttons, the toggle, the reason and token fields
    small = {k: v for k, v in sizes.items() if v < 44}
    assert not small, small


def test_the_tab_title_names_the_state(browser, station):
    """A station page in a background tab said 'Cell station' whatever happened: a grasp waiting or a
    fault did not show in the tab."""
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page(d, server, "idle")
    assert d.title == "idle · Cell station"
    control.report_fault("j3", "brake not released")
    WebDriverWait(d, T).until(lambda _: d.title == "fault · Cell station")
    server.close()
    WebDriverWait(d, T).until(lambda _: d.title == "offline · Cell station")


def test_on_a_wide_screen_the_buttons_sit_next_to_the_frame(browser, station):
    """1920 x 1080: the frame's column took the width the frame could not use, and a gap of 328 px
    opened between the frame and the buttons."""
    server, control, _, _ = station
    d = browser
    viewport(d, 1920, 1080)
    open_page(d, server, "idle")
    view, panel = d.execute_script("""const r = (q) => document.querySelector(q).getBoundingClientRect().toJSON();
        return [r('#view'), r('.panel')];""")
    assert 0 < panel["left"] - view["right"] <= 20, (view, panel)
    assert panel["width"] >= 380


def test_approval_turned_off_while_a_grasp_waits_says_that_one_still_waits(browser, station):
    """Switching 'approve each grasp' off does not decide the grasp already waiting: the page said
    nothing, and the operator waited for the cell to go on."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    open_page_awaiting_approval(d, server, control)
    d.find_element(By.ID, "approve-each").click()
    WebDriverWait(d, T).until(lambda _: "still needs Approve or Reject" in d.find_element(By.ID, "toast").text)
    assert not control.require_approval and control.state == AWAITING_APPROVAL


def test_on_a_touchscreen_the_last_tapped_button_does_not_stay_lit(browser, station):
    """:hover sticks to the button last tapped on a touchscreen: Pause stayed brightened after the tap,
    as if still on. The highlight is for pointers that hover (a mouse) only."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    server, control, _, _ = station
    d = browser
    open_page(d, server, "idle")
    if d.execute_script("return matchMedia('(hover: hover)').matches"):
        pytest.skip("this browser reports a hovering pointer; the test needs a touch-like one (hover: none)")
    run = d.find_element(By.ID, "btn-run")
    ActionChains(d).move_to_element(run).perform()
    assert d.execute_script("return arguments[0].matches(':hover')", run)
    assert d.execute_script("return getComputedStyle(arguments[0]).filter", run) == "none"


def test_while_the_cell_does_not_answer_the_page_asks_once_a_second(browser, station):
    """Offline, the page asked every 300 ms: three refused connections a second, each an error
    line in the browser's console. The test reads the delays the page asks for, not a clock."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    open_page(d, server, "idle")
    d.execute_script("""window.__delays = []; const st = window.setTimeout;
        window.setTimeout = (fn, ms, ...a) => {
            if (fn === poll) window.__delays.push(ms);
            return st(fn, ms, ...a);
        };""")
    wait.until(lambda _: len(d.execute_script("return window.__delays")) >= 1)
    online = d.execute_script("return window.__delays.slice()")
    server.close()
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "offline")
    wait.until(lambda _: len(d.execute_script("return window.__delays")) >= len(online) + 2)
    # (one poll may still have been answered between the two reads above: skip it)
    offline = d.execute_script("return window.__delays.slice(arguments[0])", len(online) + 1)
    assert set(online) == {300} and offline and set(offline) == {1000}, (online, offline)


def test_teach_names_the_frame_it_was_clicked_on(browser, station):
    """The cell applied a teach to whatever frame it held by then; the page now says which frame the
    clicks were on, and the cell refuses a teach for a frame that is no longer current."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, cell, examples = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    open_page(d, server, "idle")
    board = next(p for p in demo_parts() if p.id == "board")
    o = board.outline_mm
    shown = cell.snapshot()["frame"]["index"]
    d.find_element(By.ID, "btn-teach").click()
    click_frame_px(d, *mm_to_px(board.polygon.centroid.coords[0]))
    click_frame_px(d, *mm_to_px((o[0] + o[1]) / 2))
    wait.until(lambda _: "second contact" in d.find_element(By.ID, "teach-status").text)
    d.execute_script(HOLD_STATE_POLLS)  # the page stays a frame behind ...
    wait.until(lambda _: d.execute_script("return window.__held.length") == 1)
    cell._render()  # ... while the camera's next frame comes in
    click_frame_px(d, *mm_to_px((o[2] + o[3]) / 2))
    wait.until(lambda _: "no longer the current one" in d.find_element(By.ID, "toast").text)
    assert d.execute_script("return window.__bodies")[-1]["frame"] == shown
    assert not examples.exists()


HOLD_ANSWERS_OF = """window.__heldPosts = [];
const orig = window.fetch, path = arguments[0];
window.fetch = (u, o) => {
  if (o && o.method === 'POST' && String(u).endsWith(path)) {
    const answer = orig(u, o);   // sent now, its answer handed to the page when the test releases it
    return new Promise((res, rej) => window.__heldPosts.push(() => answer.then(res, rej)));
  }
  return orig(u, o);
};"""

RECORD_TOASTS_AND_SETTLED_POSTS = """window.__toasts = []; window.__settled = 0;
const toast0 = toast, post0 = post;
window.toast = (text, ok) => { window.__toasts.push([text, !!ok]); toast0(text, ok); };
window.post = async (...a) => { try { return await post0(...a); } finally { window.__settled++; } };"""


def test_a_double_click_on_approve_decides_once_and_shows_no_error(browser, station):
    """The second click of a double click reached the cell after the first had decided: its 409 ('no
    longer the one waiting') was shown as an error for a tap that did what the operator meant."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.02)
    open_page_awaiting_approval(d, server, control)
    d.execute_script(RECORD_TOASTS_AND_SETTLED_POSTS)
    d.execute_script(HOLD_STATE_POLLS)  # the page keeps showing the cover's grasp ...
    wait.until(lambda _: d.execute_script("return window.__held.length") == 1)
    d.execute_script(HOLD_ANSWERS_OF, "/api/approve")  # ... and the first click's answer is slow
    approve = d.find_element(By.ID, "btn-approve")
    approve.click()
    wait.until(lambda _: (control.snapshot(0)["proposal"] or {}).get("target") == "board")  # decided
    if approve.is_enabled():
        approve.click()  # the double click's second
    d.execute_script("window.__heldPosts.forEach((release) => release())")
    wait.until(lambda _: d.execute_script("return window.__settled") == posts(d).count("approve"))
    assert [t for t, ok in d.execute_script("return window.__toasts") if not ok] == []
    assert [e["event"] for e in control.snapshot(200)["events"]].count("approve") == 1
    assert control.snapshot(0)["proposal"]["target"] == "board"
    d.execute_script("window.__hold = false; window.__held.forEach((release) => release())")
    wait.until(lambda _: "board" in d.find_element(By.ID, "proposal-text").text)
    wait.until(lambda _: approve.is_enabled())  # the next grasp can be decided


def test_a_page_left_open_across_a_restart_says_so_and_a_stale_token_says_what_to_do(browser, station, tmp_path):
    """After a restart with a new token the page got 403s it did not explain; it now says the station
    restarted, shows the new session's state, and a command with the old token says to open the new link."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    open_page(d, server, "idle")
    port = server.port
    server.close()
    control2 = RunControl()
    cell2 = DemoCell(control2, tmp_path / "examples2.jsonl", parts=demo_parts()[:2], motion_s=0.0)
    with StationServer(cell2, control2, port=port) as restarted:  # a new random token
        wait.until(lambda _: "the station was restarted" in d.find_element(By.ID, "toast").text)
        wait.until(lambda _: len(d.find_elements(By.CSS_SELECTOR, "#parts polygon")) == 2)
        d.find_element(By.ID, "btn-run").click()
        wait.until(lambda _: "from before the station restarted" in d.find_element(By.ID, "toast").text)
        assert "open the new link" in d.find_element(By.ID, "toast").text
        assert d.find_element(By.ID, "token-card").is_displayed()
        assert control2.state == "idle" and restarted.token != server.token


def test_a_command_sent_to_a_restarted_station_with_the_same_token_is_refused(browser, tmp_path):
    """With a fixed --token, a command the page sent before it saw the restart went to the new session
    as if it were the one shown; the station now refuses it and the page says so and shows the new state."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.05)
    token = "fixed-token-0123456789"
    control = RunControl()
    cell = DemoCell(control, tmp_path / "examples.jsonl", motion_s=0.0)
    with StationServer(cell, control, port=0, token=token) as server:
        open_page(d, server, "idle")
        d.execute_script(RECORD_TOASTS_AND_SETTLED_POSTS)
        d.execute_script(HOLD_STATE_POLLS)  # the page does not see the restart before the tap
        wait.until(lambda _: d.execute_script("return window.__held.length") == 1)
        port = server.port
    control2 = RunControl()
    cell2 = DemoCell(control2, tmp_path / "examples2.jsonl", parts=demo_parts()[:2], motion_s=0.0)
    with StationServer(cell2, control2, port=port, token=token):
        d.find_element(By.ID, "btn-run").click()
        wait.until(lambda _: "the station was restarted" in d.find_element(By.ID, "toast").text)
        assert control2.state == "idle" and posts(d) == ["run"]
        # pressed again before the page drew the new state: refused too (the page took on the new session
        # from the refusal, and the second press went to the new station as if its state had been seen)
        d.find_element(By.ID, "btn-run").click()
        wait.until(lambda _: d.execute_script("return window.__settled") == 2)
        assert control2.state == "idle" and posts(d) == ["run", "run"]
        d.execute_script("window.__hold = false; window.__held.forEach((release) => release())")
        wait.until(lambda _: len(d.find_elements(By.CSS_SELECTOR, "#parts polygon")) == 2)
        d.find_element(By.ID, "btn-run").click()  # pressed again on the new state: taken
        control2.wait_for_state("running", timeout_s=T)


def test_the_state_shows_during_a_slow_command_and_its_late_answer_does_not_undo_it(browser, station):
    """While a command was on its way, the page dropped every state it polled: a slow answer froze the
    page on the state before the command (the grasp the loop proposed meanwhile did not show)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    server, control, _, _ = station
    d = browser
    wait = WebDriverWait(d, T, poll_frequency=0.02)
    open_page(d, server, "idle")
    d.execute_script(RECORD_TOASTS_AND_SETTLED_POSTS)
    d.execute_script(HOLD_ANSWERS_OF, "/api/run")  # Run is taken, its answer ("running") is slow
    d.find_element(By.ID, "btn-run").click()
    control.wait_for_state(AWAITING_APPROVAL, timeout_s=T)  # the loop went on and proposes a grasp
    wait.until(lambda _: d.find_element(By.ID, "state").text.lower() == "awaiting approval")
    assert "cover" in d.find_element(By.ID, "proposal-text").text
    d.execute_script("window.__heldPosts.forEach((release) => release())")  # the older answer arrives
    wait.until(lambda _: d.execute_script("return window.__settled") == 1)
    assert d.find_element(By.ID, "state").text.lower() == "awaiting approval"
    assert d.find_element(By.ID, "btn-approve").is_enabled()
