"""How a session's recording ends when a write into it fails (a full disk, an I/O error), in one place.

In the order a run meets them (cell.runtime.session):

- a frame or decision the loop writes fails (RecordingFailed out of the loop): the run stops there (`stopped_by`).
  When a fault or a stop was already ending the run, the stop decision the disk did not take names that cause: it
  stays the run's (its message; the exit code follows), the recording's failure said beside it (`recording_failed`);
- failures that do not end the run where they happen: a decision the loop could not write while a fault or a stop
  was cutting a pick short (the fault goes on; the writer keeps the failure, `RecordingWriter.failed`), the CAN
  log's first failed write (the drives' logger thread: `can_log_failed`), the rerun file's (`Viz.failed`: found at
  a frame it stops the run as above; found at the close, after the loop ended, only `rrd_failed` says so).
  `settle`, as the run ends and before the close, puts each into the summary; a run that completed is stopped on
  it (exit 1), as on any failed write into the recording;
- `close`: the manifest closed with the summary; one a write failure cut short says status "failed" with the error
  (its end is not recorded: replay calls it incomplete, exit 2);
- `after_shutdown`: the CAN log failed only as the drives shut down, after the close: the manifest says so then.
"""

from __future__ import annotations

from cell.recording import RecordingFailed


class RecordingEnd:
    """The write failures of one session's recording (`recorder` None: not recorded; `say` prints a line)."""

    def __init__(self, recorder, say):
        self.recorder, self.say = recorder, say
        self.can_log: RecordingFailed | None = None  # the CAN log's first failed write
        self.summary: dict | None = None  # the run's, once `settle` has it

    def can_log_failed(self, e: RecordingFailed) -> None:
        """The drivers' `on_record_failed` (from the logger's thread, or as it stops)."""
        if self.can_log is None:
            self.can_log = e

    def stopped_by(self, e: RecordingFailed, loop, arm) -> dict:
        """The recording cannot go on: the arm stops as at the operator's stop (it stands between moves: the loop
        writes between them) and the run ends stopped, on the cause the unwritten stop names, else on the failure
        (naming the file). No stop decision is written (the disk is full): the recording's end is missing, as
        `cell replay` reads it."""
        cause = _unwritten_stop(e)
        why = cause or f"recording: {e.reason}"
        try:
            arm.stop()
        finally:
            loop.stopped_on(why)  # the part worked on says so too
        self.say(f"stopped: {why}")
        if cause is not None:
            self.say(f"the recording failed too, its stop is not written: {e.reason}")
        return {**loop.summary(), "stopped": why, "recording_failed": e.reason}

    def settle(self, summary: dict, viz=None) -> str:
        """The failures that did not end the run, into its `summary` (said once each); returns the run's status."""
        self.summary = summary
        if self.can_log is not None:
            _cut_short(summary, "can_log_failed", self.can_log, "the recording's CAN log is cut short", self.say)
        unwritten = None if self.recorder is None else self.recorder.failed
        if unwritten is not None and "recording_failed" not in summary:
            _cut_short(summary, "recording_failed", unwritten, "the recording is a decision short", self.say)
        rrd = None if viz is None else viz.failed  # (during the run it stopped the run: recording_failed too)
        if rrd is not None:
            _cut_short(summary, "rrd_failed", rrd, "the rerun recording is cut short", self.say)
        return summary["status"]

    def close(self, status: str, summary: dict) -> None:
        """Close the recording with the run's summary (`recorded_summary`). A manifest the disk cannot take is said
        (it keeps "recording", read back as incomplete), unless the run completed: then it is the run's error."""
        try:
            self.recorder.close("complete" if status == "complete" else "incomplete", recorded_summary(summary))
        except OSError as e:
            if status == "complete":
                raise
            reason = e.reason if isinstance(e, RecordingFailed) else str(e)
            summary["recording_not_closed"] = reason
            self.say(f"the recording could not be closed ({reason}): its manifest still says 'recording'")

    def after_shutdown(self, exc) -> bool:
        """As the drives have shut down (an ExitStack callback): a CAN log that failed after the recording was
        closed (its last frames, the drives' shutdown) makes the manifest say so, closed as failed. True
        (suppressed) for the CAN log's RecordingFailed once the run has its summary."""
        summary = self.summary
        if summary is None:
            return False
        if self.can_log is not None and "can_log_failed" not in summary:
            _cut_short(summary, "can_log_failed", self.can_log, "the recording's CAN log is cut short", self.say)
            if self.recorder is not None and "recording_not_closed" not in summary:
                try:
                    self.recorder.restate_end("incomplete", recorded_summary(summary))
                except RecordingFailed as failed:
                    summary["recording_not_closed"] = failed.reason
                    self.say(f"the recording's manifest could not say that its CAN log is cut short ({failed.reason})")
        return isinstance(exc, RecordingFailed) and exc is self.can_log


def recorded_summary(summary: dict) -> dict:
    """The summary as the manifest keeps it: one a write failure cut short (the recording's or its CAN log's) is
    "failed", with the error (its end is not recorded: replay calls it incomplete, exit 2). A rerun file cut short
    at the close alone is not: replay does not read it, and the decisions and CAN log are whole (`rrd_failed`)."""
    why = summary.get("recording_failed") or summary.get("can_log_failed")
    if why is None:
        return summary
    return {**summary, "status": "failed", "error": summary.get("error") or f"recording: {why}"}


def _cut_short(summary: dict, key: str, e: RecordingFailed, what: str, say) -> None:
    """A part of the recording stopped at a write the disk refused: the summary says so under `key` (said once); a
    run that completed is stopped on it."""
    if key not in summary:
        summary[key] = e.reason
        say(f"{what}: {e.reason}")
    if summary["status"] == "complete":
        summary.update(status="stopped", stopped=f"recording: {e.reason}")


def _unwritten_stop(e: RecordingFailed) -> str | None:
    """The cause a stop decision the disk did not take names ("j2: ...", "operator: ..."), as the run reports it:
    the run was already stopping on it when the recording failed."""
    d = e.decision
    if d is None or d.get("type") != "stop":
        return None
    return f"{d.get('source')}: {d.get('reason')}"
