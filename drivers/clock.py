"""Time for the drives: one clock shared by the master and the simulated drives.

Two clocks with one interface:

- `RealClock`: wall time. Periodic jobs (heartbeats, the simulated drives' motion) run in a
  background thread; `sleep` sleeps. This is what the real cell and `cell hw` use.
- `SimClock`: simulated time that only moves when someone calls `sleep(dt)` (the master does,
  while it waits for a move). `sleep` steps time from one due job to the next, runs the jobs
  in the caller's thread, then *settles* the bus: it waits until every registered receiver
  has handled every frame already sent (`BusPump.settle`). So a whole move in simulation
  takes milliseconds of wall time, frames are seen at the simulated time they were sent,
  and the run is deterministic. Replies that need no time to pass (SDO answers, the
  set-point acknowledge) still come from the drives' receive thread at once, as on a bus.

Times are seconds as floats (`now()`), starting at 0 for a SimClock.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable


class Job:
    """A periodic callback registered with `Clock.every`; `cancel()` stops it."""

    def __init__(self, clock: Clock, period_s: float, fn: Callable[[], None], name: str):
        self.clock, self.period_s, self.fn, self.name = clock, period_s, fn, name
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class Clock:
    """Interface: `now()`, `sleep(dt)`, `every(period_s, fn)`, `add_settler(fn)`, `close()`."""

    def now(self) -> float:
        raise NotImplementedError

    def sleep(self, dt_s: float) -> None:
        raise NotImplementedError

    def every(self, period_s: float, fn: Callable[[], None], name: str = "") -> Job:
        raise NotImplementedError

    def add_settler(self, fn: Callable[[], None]) -> None:
        """Register a function that returns once a receiver has handled all frames sent so far."""

    def remove_settler(self, fn: Callable[[], None]) -> None:
        """Undo `add_settler`."""

    def close(self) -> None:
        """Stop background work (if any)."""

    @property
    def simulated(self) -> bool:
        return False


class SimClock(Clock):
    """Simulated time; see the module docstring. Not thread-safe for `sleep`: one thread drives it."""

    def __init__(self, start_s: float = 0.0):
        self._now = float(start_s)
        self._heap: list[tuple[float, int, Job]] = []
        self._seq = itertools.count()
        self._settlers: list[Callable[[], None]] = []
        self._lock = threading.Lock()

    @property
    def simulated(self) -> bool:
        return True

    def now(self) -> float:
        return self._now

    def every(self, period_s: float, fn: Callable[[], None], name: str = "") -> Job:
        if not period_s > 0:
            raise ValueError(f"period must be positive, got {period_s}")
        job = Job(self, period_s, fn, name)
        with self._lock:
            heapq.heappush(self._heap, (self._now + period_s, next(self._seq), job))
        return job

    def add_settler(self, fn) -> None:
        with self._lock:
            self._settlers.append(fn)

    def remove_settler(self, fn) -> None:
        with self._lock:
            if fn in self._settlers:
                self._settlers.remove(fn)

    def settle(self) -> None:
        """Let every receiver catch up with the frames sent so far (twice: answers to answers)."""
        for _ in range(2):
            for fn in list(self._settlers):
                fn()

    def sleep(self, dt_s: float) -> None:
        if dt_s < 0:
            raise ValueError(f"cannot sleep a negative time ({dt_s} s)")
        if dt_s != dt_s:
            raise ValueError("cannot sleep nan s (simulated time would run forever)")
        end = self._now + dt_s
        self.settle()
        while True:
            with self._lock:
                while self._heap and self._heap[0][2].cancelled:
                    heapq.heappop(self._heap)
                if not self._heap or self._heap[0][0] > end + 1e-12:
                    break
                due, _, job = heapq.heappop(self._heap)
                self._now = max(self._now, due)
                heapq.heappush(self._heap, (due + job.period_s, next(self._seq), job))
            job.fn()
            self.settle()
        self._now = end

    def advance_to(self, t_s: float) -> None:
        self.sleep(max(0.0, t_s - self._now))


class RealClock(Clock):
    """Wall time (monotonic, seconds since the clock was made); jobs run in one thread."""

    def __init__(self, resolution_s: float = 0.002):
        self._t0 = time.monotonic()
        self._resolution_s = resolution_s
        self._jobs: list[list] = []  # [next_due, job]
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def now(self) -> float:
        return time.monotonic() - self._t0

    def sleep(self, dt_s: float) -> None:
        if dt_s != dt_s:
            raise ValueError("cannot sleep nan s")
        if dt_s > 0:
            time.sleep(dt_s)

    def every(self, period_s: float, fn: Callable[[], None], name: str = "") -> Job:
        if not period_s > 0:
            raise ValueError(f"period must be positive, got {period_s}")
        job = Job(self, period_s, fn, name)
        with self._lock:
            self._jobs.append([self.now() + period_s, job])
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="drivers-clock", daemon=True)
                self._thread.start()
        return job

    def _run(self) -> None:
        import logging

        log = logging.getLogger(__name__)
        stop = self._stop  # this thread's own stop signal (close() makes a fresh one)
        while not stop.is_set():
            now = self.now()
            with self._lock:
                self._jobs = [e for e in self._jobs if not e[1].cancelled]
                due = [e for e in self._jobs if e[0] <= now]
                for e in due:
                    # keep the phase; skip missed periods rather than bursting
                    e[0] = max(e[0] + e[1].period_s, now)
                next_due = min((e[0] for e in self._jobs), default=now + 0.05)
            for _, job in due:
                try:
                    job.fn()
                except Exception:  # a failing job must not stop the others (heartbeats!)
                    log.exception("clock job %s failed", job.name)
            stop.wait(max(self._resolution_s, min(next_due - self.now(), 0.05)))

    def close(self) -> None:
        """Stop the job thread and forget the jobs; the clock can be used again afterwards."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        with self._lock:
            self._thread = None
            self._jobs.clear()
            self._stop = threading.Event()
