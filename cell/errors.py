"""One error family for the whole cell.

    CellError                 anything the cell refuses or cannot do (exit 1)
    +-- BadInput              a file, option or value given by the user is wrong (exit 2)
    +-- NoFeasibleGrasp       the planner found no grasp (exit 3)

The CLI turns these into a message on stderr and the exit code; never a traceback.
"""

from __future__ import annotations


class CellError(Exception):
    """Base of all errors the cell reports to its user."""

    exit_code = 1


class BadInput(CellError, ValueError):
    """Input that cannot be used: the message says which file/key and why."""

    exit_code = 2


class NoFeasibleGrasp(CellError):
    """The pipeline ran but no grasp survived; `reason` says at which stage."""

    exit_code = 3

    def __init__(self, reason: str, counts: dict | None = None, partial: dict | None = None,
                 at_any_step: bool = False):
        super().__init__(reason)
        self.reason = reason
        self.counts = counts or {}
        self.partial = partial or {}  # what the steps made before none was left (for --explain)
        self.at_any_step = at_any_step  # the planner's: no other step or grasp z would give one (too heavy)
