"""Run control: the thread-safe state machine between the operator (station page, CLI) and the
cell loop thread.

    states: idle -> running <-> paused
                    running -> awaiting_approval -> running (approve / reject)
            any -> stopped (stop)     any -> fault (report_fault)     running -> done (done)
            fault | stopped | done -> idle (reset)

The operator side calls `run`, `pause`, `step`, `approve`, `reject`, `stop`, `reset` and
`set_require_approval`; a command that makes no sense in the current state raises
`InvalidCommand` (the station answers 409) and changes nothing. The loop side calls
`checkpoint(label)` between the steps of a pick (it blocks while idle, paused or in fault,
returns once per `step()`, and raises `Stopped` after `stop()`), `request_approval(proposal)`
before a grasp is executed, `report_fault`, `log` and `done`. Every wait sleeps on one
condition variable (no polling) and takes an optional timeout.

`snapshot()` is a JSON-able dict for the page: the state, why it is in that state, the
current step and part, the pending proposal and a bounded log of events with reasons.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from datetime import UTC, datetime

from cell.errors import CellError

IDLE, RUNNING, PAUSED, AWAITING_APPROVAL = "idle", "running", "paused", "awaiting_approval"
STOPPED, FAULT, DONE = "stopped", "fault", "done"
STATES = (IDLE, RUNNING, PAUSED, AWAITING_APPROVAL, STOPPED, FAULT, DONE)
# States in which the loop is not allowed past a checkpoint.
_HOLD = (IDLE, PAUSED, FAULT, DONE)
EVENT_LOG_SIZE = 200


class InvalidCommand(CellError):
    """An operator command that the current state does not allow (nothing was changed)."""


class Interrupted(Exception):  # noqa: N818 - raised in the loop thread, not an error of the loop
    """Base of the exceptions that end a blocking call of the loop side."""


class Stopped(Interrupted):
    """The operator pressed stop: the loop abandons the current sequence."""


class Faulted(Interrupted):
    """A fault was reported while the loop waited for approval: the proposal is withdrawn."""


@dataclass(frozen=True)
class Decision:
    """The answer to a proposal. `by` is "operator" or "auto" (approval not required); only an
    operator's rejection is a judgement on the grasp (the loop turns it into an invalid example)."""

    approved: bool
    reason: str
    by: str

    def as_dict(self) -> dict:
        return {"approved": self.approved, "reason": self.reason, "by": self.by}


def _now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


class RunControl:
    """The run-control state machine. All public methods are safe to call from any thread."""

    def __init__(self, *, require_approval: bool = False, event_log_size: int = EVENT_LOG_SIZE):
        self._cond = threading.Condition()
        self._state = IDLE
        self._message = "idle: press Run to start"
        self._require_approval = bool(require_approval)
        self._step_mode = False  # pause again at the next checkpoint after this one
        self._step_budget = 0  # checkpoints that may still pass in step mode
        self._stop_pending = False  # a stop the loop has not yet seen (consumed by raising Stopped)
        self._pause_after_decision = False
        self._proposal: dict | None = None
        self._proposal_no = 0  # numbers the proposals: a decision names the one it is for
        self._decided: tuple[int, bool] | None = None  # (proposal_no, approved) of the last decision
        self._decision: Decision | None = None
        self._withdrawn: Interrupted | None = None
        self._checkpoint: str | None = None
        self._current: dict = {"step": None, "part": None}
        self._fault: dict | None = None
        self._summary: dict | None = None
        self._ended: str | None = None  # the loop is gone (its process ends): nothing can be run or reset
        self._seq = 0  # bumped on every change; the page can tell when to redraw
        self._events: deque[dict] = deque(maxlen=event_log_size)
        self._event_no = 0
        self._listeners: list = []
        with self._cond:
            each = "on" if self._require_approval else "off"
            self._log_locked("init", f"run control ready (approve each grasp: {each})")

    # ------------------------------------------------------------------ helpers (lock held)
    def _log_locked(self, event: str, message: str = "", **data) -> None:
        self._event_no += 1
        e = {"n": self._event_no, "t": _now_iso(), "event": event, "state": self._state}
        if message:
            e["message"] = message
        if data:
            e["data"] = data
        self._events.append(e)
        self._seq += 1
        self._cond.notify_all()
        for fn in self._listeners:
            fn(e)

    def add_listener(self, fn) -> None:
        """Call fn(event_dict) for every event from now on (with the lock held: keep it short,
        e.g. print a progress line)."""
        with self._cond:
            self._listeners.append(fn)

    def _set_locked(self, state: str, message: str, event: str, **data) -> None:
        self._state = state
        self._message = message
        self._log_locked(event, message, **data)

    def _refuse(self, command: str, why: str):
        raise InvalidCommand(f"cannot {command} while {self._state}: {why}")

    def _refuse_if_ended_locked(self, command: str) -> None:
        if self._ended is not None:
            raise InvalidCommand(f"cannot {command}: {self._ended}")

    def require_a_loop(self, command: str) -> None:
        """Refuse `command` (InvalidCommand) once the loop has ended: e.g. a teach no plan would learn."""
        with self._cond:
            self._refuse_if_ended_locked(command)

    def end(self, why: str = "the run has ended: start cell run again") -> None:
        """The loop has returned for good (the station still answers a moment to show how it ended):
        Run, Step and Reset are refused from now on, not taken by a control with no loop behind it."""
        with self._cond:
            self._ended = why
            self._log_locked("ended", why)

    def _refuse_unseen_locked(self, shown: dict | None, shown_no: int | None) -> None:
        """A decision for the proposal the operator saw must not land on another one that came since
        (a page a poll behind)."""
        unseen = ((shown is not None and shown != self._proposal)
                  or (shown_no is not None and shown_no != self._proposal_no))
        if unseen and self._proposal is not None:
            raise InvalidCommand(f"the grasp on the page is no longer the one waiting (now a grasp on "
                                 f"{self._proposal.get('target')}): look at it, then decide")

    def _repeats_decision_locked(self, approved: bool, shown_no: int | None) -> bool:
        """True for a repeat of the decision already taken on the proposal named (`shown_no`, else the
        one waiting): the second tap of a double tap did what the first did and is no error. The
        other decision on it is refused: the first one stands (the loop may have acted on it)."""
        no = self._proposal_no if shown_no is None and self._proposal is not None else shown_no
        if no is None or self._decided is None or self._decided[0] != no:
            return False
        if self._decided[1] != approved:
            raise InvalidCommand(f"that grasp was already {'approved' if self._decided[1] else 'rejected'}")
        return True

    def _decide_locked(self, decision: Decision) -> None:
        self._decision = decision
        self._decided = (self._proposal_no, decision.approved)

    def _wait_locked(self, predicate, timeout_s: float | None, what: str) -> None:
        """Sleep on the condition until predicate() is true; TimeoutError after timeout_s."""
        if not self._cond.wait_for(predicate, timeout=timeout_s):
            raise TimeoutError(f"{what}: still {self._state} after {timeout_s} s")

    # ------------------------------------------------------------------ operator side
    @property
    def state(self) -> str:
        with self._cond:
            return self._state

    @property
    def require_approval(self) -> bool:
        with self._cond:
            return self._require_approval

    @property
    def stop_requested(self) -> bool:
        """True between stop() and the loop noticing it: long motions may check it."""
        with self._cond:
            return self._stop_pending

    def run(self, by: str = "operator") -> str:
        """Run continuously (from idle or paused; ends step mode)."""
        with self._cond:
            self._refuse_if_ended_locked("run")
            if self._state in (STOPPED, FAULT, DONE):
                self._refuse("run", "press Reset first")
            self._step_mode = False
            self._step_budget = 0
            self._pause_after_decision = False
            if self._state == AWAITING_APPROVAL:
                self._log_locked("run", "will run on after the decision", by=by)
            elif self._state != RUNNING:
                self._set_locked(RUNNING, "running", "run", by=by)
            return self._state

    def pause(self, by: str = "operator") -> str:
        """Hold the loop at its next checkpoint (a motion under way is finished first)."""
        with self._cond:
            if self._state in (STOPPED, FAULT, DONE):
                self._refuse("pause", "nothing is running")
            if self._state == RUNNING:
                self._step_mode = False
                self._step_budget = 0
                self._set_locked(PAUSED, "paused by the operator", "pause", by=by)
            elif self._state == AWAITING_APPROVAL:
                self._pause_after_decision = True
                self._log_locked("pause", "will pause after the decision", by=by)
            return self._state

    def step(self, by: str = "operator") -> str:
        """Let the loop pass one checkpoint, then pause at the next one."""
        with self._cond:
            self._refuse_if_ended_locked("step")
            if self._state in (STOPPED, FAULT, DONE):
                self._refuse("step", "press Reset first")
            self._step_mode = True
            if self._state == AWAITING_APPROVAL:
                self._step_budget = 0  # the decision itself is the step
                self._log_locked("step", "will pause at the next checkpoint after the decision", by=by)
            else:
                self._step_budget = 1
                where = f" from {self._checkpoint}" if self._checkpoint else ""
                self._set_locked(RUNNING, f"stepping{where}", "step", by=by)
            return self._state

    def approve(self, by: str = "operator", shown: dict | None = None, shown_no: int | None = None) -> str:
        """Approve the pending grasp; with `shown` (the proposal the operator saw) or `shown_no` (its
        `proposal_no`) only if that one still waits, checked under the same lock as the decision.
        Approving a grasp already approved changes nothing (a double tap)."""
        with self._cond:
            if self._repeats_decision_locked(True, shown_no):
                return self._state
            if self._state != AWAITING_APPROVAL:
                self._refuse("approve", "no grasp is waiting for approval")
            self._refuse_unseen_locked(shown, shown_no)
            self._decide_locked(Decision(True, "approved by the operator", by))
            self._log_locked("approve", "grasp approved", by=by)
            return self._state

    def reject(self, reason: str = "", by: str = "operator", shown: dict | None = None,
               shown_no: int | None = None) -> str:
        """Reject the pending grasp; the reason is kept with the invalid example. `shown`, `shown_no`
        and a repeat as for approve (a repeat keeps the first reason)."""
        reason = (reason or "").strip() or "rejected by the operator"
        with self._cond:
            if self._repeats_decision_locked(False, shown_no):
                return self._state
            if self._state != AWAITING_APPROVAL:
                self._refuse("reject", "no grasp is waiting for approval")
            self._refuse_unseen_locked(shown, shown_no)
            self._decide_locked(Decision(False, reason, by))
            self._log_locked("reject", f"grasp rejected: {reason}", by=by)
            return self._state

    def stop(self, reason: str = "", by: str = "operator") -> str:
        """Abandon the sequence: the loop's next checkpoint (or pending approval) raises Stopped."""
        reason = (reason or "").strip() or "stopped by the operator"
        with self._cond:
            if self._state in (STOPPED, DONE):
                return self._state
            self._stop_pending = True
            self._step_mode = False
            self._step_budget = 0
            self._set_locked(STOPPED, reason, "stop", by=by)
            return self._state

    def reset(self, by: str = "operator") -> str:
        """Clear a fault (or a stop, or the end of a sequence) and go back to idle."""
        with self._cond:
            self._refuse_if_ended_locked("reset")
            if self._state == IDLE:
                return self._state
            if self._state not in (FAULT, STOPPED, DONE):
                self._refuse("reset", "only a fault, a stop or the end is reset; press Stop first")
            was = self._fault
            self._fault = None
            self._summary = None
            msg = "fault cleared" if was else "reset"
            self._set_locked(IDLE, f"idle ({msg}): press Run to start", "reset", by=by)
            return self._state

    def set_require_approval(self, required: bool, by: str = "operator") -> bool:
        with self._cond:
            self._require_approval = bool(required)
            self._log_locked("approval", f"approve each grasp: {'on' if required else 'off'}", by=by)
            return self._require_approval

    def wait_for_state(self, *states: str, timeout_s: float | None = None) -> str:
        """Block until the state is one of `states` (for the CLI and tests); returns it."""
        with self._cond:
            self._wait_locked(lambda: self._state in states, timeout_s, f"waiting for {'/'.join(states)}")
            return self._state

    def wait_change(self, seq: int, timeout_s: float | None = None) -> int:
        """Block until something changed after `seq` (long polling); returns the new seq."""
        with self._cond:
            self._cond.wait_for(lambda: self._seq != seq, timeout=timeout_s)
            return self._seq

    def snapshot(self, n_events: int = 50) -> dict:
        """The state as a JSON-able dict; `events` holds the last n_events, newest last."""
        with self._cond:
            return {
                "state": self._state,
                "message": self._message,
                "ended": self._ended,
                "seq": self._seq,
                "require_approval": self._require_approval,
                "step_mode": self._step_mode,
                "stop_requested": self._stop_pending,
                "checkpoint": self._checkpoint,
                "current": dict(self._current),
                "proposal": self._proposal,
                "proposal_no": self._proposal_no if self._proposal is not None else None,
                "fault": dict(self._fault) if self._fault else None,
                "summary": self._summary,
                "events": list(self._events)[-n_events:] if n_events > 0 else [],
            }

    # ------------------------------------------------------------------ loop side
    def _raise_if_stopped_locked(self) -> None:
        if self._stop_pending:
            self._stop_pending = False
            self._log_locked("stopped", "the loop abandoned the sequence")
            raise Stopped(self._message)

    def checkpoint(self, label: str, *, step: int | None = None, part: str | None = None,
                   timeout_s: float | None = None) -> None:
        """A point where the loop may be held. Blocks while idle, paused, in fault or done;
        in step mode lets one checkpoint pass and pauses at the next; raises Stopped after stop().
        """
        with self._cond:
            self._checkpoint = label
            if step is not None:
                self._current["step"] = step
            if part is not None:
                self._current["part"] = part
            self._seq += 1
            self._cond.notify_all()
            while True:
                self._raise_if_stopped_locked()
                if self._state == RUNNING:
                    if not self._step_mode:
                        return
                    if self._step_budget > 0:
                        self._step_budget -= 1
                        return
                    self._step_mode = False
                    self._set_locked(PAUSED, f"paused after one step, at {label}", "pause", by="step")
                self._wait_locked(lambda: self._stop_pending or self._state == RUNNING, timeout_s,
                                  f"checkpoint {label}")

    def request_approval(self, proposal: dict, *, timeout_s: float | None = None) -> Decision:
        """Ask the operator to approve `proposal` (JSON-able: target, contacts, joints ...).

        Returns at once with an automatic approval when approval is not required. Otherwise
        blocks until approve/reject; raises Stopped after stop(), Faulted if a fault is reported
        meanwhile, TimeoutError after timeout_s (the proposal is withdrawn in each case).
        """
        with self._cond:
            self._raise_if_stopped_locked()
            if not self._require_approval:
                self._log_locked("proposal", "grasp approved automatically (approval not required)",
                                 target=proposal.get("target"))
                return Decision(True, "approval not required", "auto")
            if self._state == FAULT:
                raise Faulted(self._message)
            # Paused since the last checkpoint: ask anyway, and hold again after the decision.
            self._pause_after_decision = self._state != RUNNING
            self._proposal = proposal
            self._proposal_no += 1
            self._decision = None
            self._withdrawn = None
            target = proposal.get("target")
            self._set_locked(AWAITING_APPROVAL, f"waiting for approval of the grasp on {target}",
                             "proposal", target=target)
            try:
                self._wait_locked(lambda: self._decision is not None or self._stop_pending
                                  or self._withdrawn is not None, timeout_s, "approval")
            except TimeoutError:
                self._proposal = None
                self._set_locked(PAUSED if self._pause_after_decision else RUNNING, "approval timed out",
                                 "withdrawn", reason="approval timed out")
                raise
            self._proposal = None
            if self._withdrawn is not None:
                w, self._withdrawn = self._withdrawn, None
                raise w
            self._raise_if_stopped_locked()
            decision, self._decision = self._decision, None
            if self._pause_after_decision:
                self._pause_after_decision = False
                self._set_locked(PAUSED, "paused by the operator", "pause", by="operator")
            else:
                self._set_locked(RUNNING, "stepping" if self._step_mode else "running", "decided",
                                 approved=decision.approved)
            return decision

    def report_fault(self, source: str, why: str, *, asking: bool = False) -> None:
        """Something failed (a drive in FAULT, a lost heartbeat, an exception in the loop), or, with
        `asking`, the loop cannot go on without the operator (no grasp, a part that stays on the tray):
        nothing failed, and the page and the log say so. Either way the loop holds at its next
        checkpoint until the operator resets and runs again."""
        with self._cond:
            self._fault = {"source": str(source), "why": str(why), "t": _now_iso(), "asking": asking}
            message = f"{source} needs the operator: {why}" if asking else f"fault in {source}: {why}"
            if self._state == AWAITING_APPROVAL:
                self._withdrawn = Faulted(message)
            self._step_mode = False
            self._step_budget = 0
            self._set_locked(FAULT, message, "ask" if asking else "fault", source=str(source), why=str(why))

    def log(self, event: str, message: str = "", **data) -> None:
        """Add an event to the log the page shows (data must be JSON-able)."""
        with self._cond:
            self._log_locked(event, message, **data)

    def done(self, summary: dict | None = None) -> None:
        """The sequence is finished; `summary` is shown on the page."""
        with self._cond:
            self._summary = dict(summary or {})
            self._step_mode = False
            self._set_locked(DONE, "done: the sequence is finished", "done", **self._summary)
