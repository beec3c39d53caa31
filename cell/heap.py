"""Keep Python's full garbage collections short in long-running commands.

Importing numpy, scipy, scikit-learn, OpenCV and shapely leaves ~130 000 objects the collector
tracks; a full collection walks them all, 110-160 ms on the 2-core host, and one lands now and
then in the middle of a plan (a plan's 110 ms spike against a median of 8 ms, measured over the
benchmark scenes) or of a pick. Freezing what start-up made takes those objects out of every
later collection (`gc.freeze`); only what the work itself makes is walked.
"""

from __future__ import annotations

import gc


def freeze_startup() -> None:
    """Call once start-up is done (modules imported, trees fitted): collect the young garbage,
    then freeze everything else. Later calls freeze what was made since (cheap)."""
    gc.collect(1)
    gc.freeze()
