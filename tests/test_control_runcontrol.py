"""RunControl with a real loop thread: every blocking call is released by the operator side."""

import json
import threading
import time

import pytest

from cell.runtime.control import (
    AWAITING_APPROVAL,
    DONE,
    FAULT,
    IDLE,
    PAUSED,
    RUNNING,
    STOPPED,
    Faulted,
    InvalidCommand,
    RunControl,
    Stopped,
)

T = 5.0  # generous timeout: tests never wait this long unless something is broken


class Loop(threading.Thread):
    """A simple cell loop: n picks of (checkpoint, approval, checkpoint); records what it passed."""

    def __init__(self, rc: RunControl, n: int = 3, labels=("plan", "move")):
        super().__init__(daemon=True)
        self.rc, self.n, self.labels = rc, n, labels
        self.passed: list[str] = []
        self.decisions = []
        self.ended: str | None = None

    def run(self):
        try:
            for i in range(self.n):
                self.rc.checkpoint(self.labels[0], step=i, part=f"p{i}")
                self.passed.append(f"{self.labels[0]}{i}")
                d = self.rc.request_approval({"target": f"p{i}", "contacts": [[0, 0], [1, 1]]})
                self.decisions.append(d)
                self.rc.checkpoint(self.labels[1], step=i)
                self.passed.append(f"{self.labels[1]}{i}")
            self.rc.done({"parts_removed": self.n})
            self.ended = "done"
        except Stopped:
            self.ended = "stopped"
        except Faulted:
            self.ended = "faulted"


def wait_until(pred, timeout_s=T):
    t0 = time.monotonic()
    while not pred():
        assert time.monotonic() - t0 < timeout_s, "condition not reached"
        time.sleep(0.005)


def test_idle_holds_the_loop_until_run_and_runs_to_done():
    rc = RunControl()
    loop = Loop(rc)
    loop.start()
    wait_until(lambda: rc.snapshot()["checkpoint"] == "plan")
    time.sleep(0.05)
    assert loop.passed == [] and rc.state == IDLE
    rc.run()
    assert rc.wait_for_state(DONE, timeout_s=T) == DONE
    loop.join(T)
    assert loop.ended == "done" and len(loop.passed) == 6
    assert all(d.approved and d.by == "auto" for d in loop.decisions)
    snap = rc.snapshot()
    assert snap["summary"] == {"parts_removed": 3}
    json.dumps(snap)  # the page receives it as JSON


def test_step_passes_exactly_one_checkpoint_then_pauses():
    rc = RunControl()
    loop = Loop(rc)
    loop.start()
    wait_until(lambda: rc.snapshot()["checkpoint"] == "plan")
    rc.step()
    rc.wait_for_state(PAUSED, timeout_s=T)
    assert loop.passed == ["plan0"]
    snap = rc.snapshot()
    assert snap["checkpoint"] == "move" and "after one step" in snap["message"]
    rc.step()
    rc.wait_for_state(PAUSED, timeout_s=T)
    wait_until(lambda: rc.snapshot()["checkpoint"] == "plan" and rc.state == PAUSED)
    assert loop.passed == ["plan0", "move0"]
    rc.run()
    rc.wait_for_state(DONE, timeout_s=T)
    loop.join(T)
    assert len(loop.passed) == 6


def test_pause_holds_at_the_next_checkpoint():
    rc = RunControl()
    gate = threading.Event()
    passed = []

    def loop():
        rc.checkpoint("a")
        passed.append("a")
        gate.wait(T)  # the loop is busy (a motion) when the operator pauses
        rc.checkpoint("b")
        passed.append("b")

    t = threading.Thread(target=loop, daemon=True)
    rc.run()
    t.start()
    wait_until(lambda: passed == ["a"])
    assert rc.pause() == PAUSED
    gate.set()
    wait_until(lambda: rc.snapshot()["checkpoint"] == "b")
    time.sleep(0.05)
    assert passed == ["a"]
    rc.run()
    t.join(T)
    assert passed == ["a", "b"]


def test_approval_blocks_until_the_operator_decides_and_rejection_carries_the_reason():
    rc = RunControl(require_approval=True)
    loop = Loop(rc, n=2)
    loop.start()
    rc.run()
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    snap = rc.snapshot()
    assert snap["proposal"]["target"] == "p0" and loop.passed == ["plan0"]
    time.sleep(0.05)
    assert loop.decisions == []  # still blocked
    rc.reject("  finger on the connector ")
    wait_until(lambda: len(loop.decisions) == 1)
    assert not loop.decisions[0].approved
    assert loop.decisions[0].reason == "finger on the connector" and loop.decisions[0].by == "operator"
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    assert rc.snapshot()["proposal"]["target"] == "p1"
    rc.approve()
    rc.wait_for_state(DONE, timeout_s=T)
    loop.join(T)
    assert [d.approved for d in loop.decisions] == [False, True]
    events = [e["event"] for e in rc.snapshot(200)["events"]]
    assert events.count("proposal") == 2 and "reject" in events and "approve" in events
    rejected = next(e for e in rc.snapshot(200)["events"] if e["event"] == "reject")
    assert "finger on the connector" in rejected["message"]


def test_a_decision_for_the_grasp_the_operator_saw_never_lands_on_the_next_one():
    """approve/reject carry the proposal shown; under the decision's own lock, a stale one is refused
    (409 at the station) and the grasp waiting now stays undecided."""
    rc = RunControl(require_approval=True)
    loop = Loop(rc, n=2)
    loop.start()
    rc.run()
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    first = json.loads(json.dumps(rc.snapshot()["proposal"]))  # as the page has it
    rc.reject("too close to the rim", shown=first)
    wait_until(lambda: len(loop.decisions) == 1)
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    assert rc.snapshot()["proposal"]["target"] == "p1"
    for decide in (lambda: rc.approve(shown=first), lambda: rc.reject("again", shown=first)):
        with pytest.raises(InvalidCommand, match="no longer the one waiting.*p1"):
            decide()
    time.sleep(0.05)
    assert len(loop.decisions) == 1 and rc.state == AWAITING_APPROVAL
    rc.approve(shown=json.loads(json.dumps(rc.snapshot()["proposal"])))
    rc.wait_for_state(DONE, timeout_s=T)
    loop.join(T)
    assert [d.approved for d in loop.decisions] == [False, True]


def test_a_repeat_of_a_decision_on_the_same_grasp_changes_nothing_and_is_no_error():
    """A double tap on Approve: the second approve came after the first had decided (refused: 'no grasp
    is waiting' or 'no longer the one waiting', an error on the page for a tap that did what was meant)
    or before the loop took the first (a second approve logged). Proposals are numbered; a decision
    names the one it is for."""
    rc = RunControl(require_approval=True)
    loop = Loop(rc, n=2)
    loop.start()
    rc.run()
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    no = rc.snapshot()["proposal_no"]
    rc.approve(shown_no=no)
    assert rc.approve(shown_no=no) in (AWAITING_APPROVAL, RUNNING)  # before the loop took the first, or after
    wait_until(lambda: rc.snapshot()["proposal_no"] == no + 1)  # the next grasp waits
    assert rc.approve(shown_no=no) == AWAITING_APPROVAL  # a late second tap: nothing decided
    with pytest.raises(InvalidCommand, match="already approved"):
        rc.reject("changed my mind", shown_no=no)
    with pytest.raises(InvalidCommand, match="no longer the one waiting"):
        rc.approve(shown_no=no + 7)
    assert len(loop.decisions) == 1 and rc.snapshot()["proposal"]["target"] == "p1"
    assert [e["event"] for e in rc.snapshot(200)["events"]].count("approve") == 1
    rc.reject("rim", shown_no=no + 1)
    assert rc.reject("rim again", shown_no=no + 1) in (AWAITING_APPROVAL, RUNNING, DONE)
    rc.wait_for_state(DONE, timeout_s=T)
    loop.join(T)
    assert [d.approved for d in loop.decisions] == [True, False] and loop.decisions[1].reason == "rim"
    assert rc.snapshot()["proposal_no"] is None  # none waits


def test_no_approval_required_returns_at_once():
    rc = RunControl(require_approval=False)
    rc.run()
    d = rc.request_approval({"target": "x"})
    assert d.approved and d.by == "auto" and rc.state == RUNNING


def test_stop_raises_in_the_loop_whether_it_waits_at_a_checkpoint_or_for_approval():
    rc = RunControl(require_approval=True)
    loop = Loop(rc)
    loop.start()
    rc.run()
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    rc.stop("tray moved")
    loop.join(T)
    assert loop.ended == "stopped" and rc.state == STOPPED
    assert rc.snapshot()["message"] == "tray moved" and rc.snapshot()["proposal"] is None
    with pytest.raises(InvalidCommand, match="Reset"):
        rc.run()
    assert rc.reset() == IDLE

    rc2 = RunControl()
    loop2 = Loop(rc2)
    loop2.start()  # waiting at the first checkpoint while idle
    wait_until(lambda: rc2.snapshot()["checkpoint"] == "plan")
    rc2.stop()
    loop2.join(T)
    assert loop2.ended == "stopped" and not rc2.stop_requested


def test_fault_holds_the_loop_until_reset_and_run_and_withdraws_a_proposal():
    rc = RunControl(require_approval=True)
    loop = Loop(rc, n=1)
    loop.start()
    rc.run()
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    rc.report_fault("j2", "following error")
    loop.join(T)
    assert loop.ended == "faulted"
    snap = rc.snapshot()
    assert snap["state"] == FAULT and snap["fault"]["source"] == "j2"
    assert "following error" in snap["message"]
    for cmd in (rc.run, rc.step, rc.pause):
        with pytest.raises(InvalidCommand):
            cmd()
    with pytest.raises(InvalidCommand):
        rc.approve()
    assert rc.state == FAULT  # a refused command changes nothing

    passed = []

    def retry():
        rc.checkpoint("retry")
        passed.append("retry")

    t = threading.Thread(target=retry, daemon=True)
    t.start()
    wait_until(lambda: rc.snapshot()["checkpoint"] == "retry")
    rc.reset()
    time.sleep(0.05)
    assert passed == [] and rc.state == IDLE and rc.snapshot()["fault"] is None
    rc.run()
    t.join(T)
    assert passed == ["retry"]


def test_invalid_commands_are_refused_without_change():
    rc = RunControl()
    with pytest.raises(InvalidCommand, match="no grasp is waiting"):
        rc.approve()
    with pytest.raises(InvalidCommand):
        rc.reject("x")
    rc.run()
    with pytest.raises(InvalidCommand, match="Stop first"):
        rc.reset()
    assert rc.state == RUNNING
    assert rc.pause() == PAUSED and rc.pause() == PAUSED  # idempotent


def test_timeouts_raise_instead_of_blocking_forever():
    rc = RunControl(require_approval=True)
    t0 = time.monotonic()
    with pytest.raises(TimeoutError, match="checkpoint a"):
        rc.checkpoint("a", timeout_s=0.1)
    rc.run()
    with pytest.raises(TimeoutError, match="approval"):
        rc.request_approval({"target": "x"}, timeout_s=0.1)
    assert time.monotonic() - t0 < 2.0
    assert rc.state == RUNNING and rc.snapshot()["proposal"] is None


def test_pause_while_awaiting_approval_pauses_after_the_decision():
    rc = RunControl(require_approval=True)
    loop = Loop(rc, n=1)
    loop.start()
    rc.run()
    rc.wait_for_state(AWAITING_APPROVAL, timeout_s=T)
    rc.pause()
    assert rc.state == AWAITING_APPROVAL
    rc.approve()
    rc.wait_for_state(PAUSED, timeout_s=T)
    time.sleep(0.05)
    assert loop.passed == ["plan0"]
    rc.run()
    rc.wait_for_state(DONE, timeout_s=T)


def test_event_log_is_bounded_and_wait_change_wakes_on_change():
    rc = RunControl(event_log_size=10)
    for i in range(30):
        rc.log("tick", i=i)
    events = rc.snapshot(100)["events"]
    assert len(events) == 10 and events[-1]["data"] == {"i": 29}
    seq = rc.snapshot()["seq"]
    threading.Timer(0.05, rc.run).start()
    assert rc.wait_change(seq, timeout_s=T) != seq
    assert rc.state == RUNNING


def test_a_stop_to_ask_is_not_called_a_fault():
    """The loop stopping because it cannot decide (no grasp) held in the fault state but was told as
    "fault in planner": the operator looked for a broken drive."""
    rc = RunControl()
    rc.report_fault("planner", "no feasible grasp for nut", asking=True)
    snap = rc.snapshot()
    assert snap["state"] == FAULT and snap["fault"]["asking"] is True
    assert snap["message"] == "planner needs the operator: no feasible grasp for nut"
    assert snap["events"][-1]["event"] == "ask"
    rc.reset()
    rc.report_fault("j2", "following error")
    snap = rc.snapshot()
    assert snap["fault"]["asking"] is False and snap["message"] == "fault in j2: following error"
    assert snap["events"][-1]["event"] == "fault"


def test_after_the_loop_has_ended_run_step_and_reset_are_refused():
    """`cell run --station` answers 2 s more after the run ends: Reset there went to idle and Run to
    "running" with no loop behind it, and the page then lost the cell without saying why."""
    rc = RunControl()
    rc.run()
    rc.stop("enough")
    rc.end()
    for command in (rc.reset, rc.run, rc.step):
        with pytest.raises(InvalidCommand, match="the run has ended: start cell run again"):
            command()
    assert rc.state == STOPPED and rc.snapshot()["ended"] == "the run has ended: start cell run again"
    assert rc.stop() == STOPPED  # a second stop stays harmless
