"""A receive thread for one python-can bus that can tell when it has caught up.

python-can's `Notifier` does the same job; this one adds `settle()`, which the simulated
clock calls after every step so that frames are handled at the simulated time they were
sent (see `drivers.clock`). For python-can's `virtual` interface settling is exact (the
bus's queue counts frames put and handled); for other interfaces it waits until the bus
has been quiet for a short moment.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import can

log = logging.getLogger(__name__)


class BusPump:
    """Receive frames from `bus` in a thread and hand each to every listener.

    Parameters
    ----------
    bus : can.BusABC
        The bus to read; the pump never closes it (its creator does).
    listeners : list of callables taking a `can.Message`, or `can.Listener`s
    """

    def __init__(self, bus: can.BusABC, listeners=(), name: str = "bus-pump"):
        self.bus = bus
        self._listeners: list[Callable[[can.Message], None]] = []
        for listener in listeners:
            self.add_listener(listener)
        self._queue = getattr(bus, "queue", None)  # python-can VirtualBus's receive queue
        self._stop = threading.Event()
        self._last_rx = time.monotonic()
        self.errors: list[BaseException] = []
        self._said: set = set()  # (listener, error type) already logged
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def add_listener(self, listener) -> None:
        fn = listener.on_message_received if isinstance(listener, can.Listener) else listener
        self._listeners.append(fn)

    def remove_listener(self, listener) -> None:
        fn = listener.on_message_received if isinstance(listener, can.Listener) else listener
        if fn in self._listeners:
            self._listeners.remove(fn)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.02)
            except can.CanError as e:  # bus gone or broken: stop quietly, remember why
                if not self._stop.is_set():
                    self.errors.append(e)
                    log.error("receive failed on %s: %s", self._thread.name, e)
                break
            except Exception as e:  # noqa: BLE001 - e.g. ValueError from a shut-down bus
                if not self._stop.is_set():
                    self.errors.append(e)
                break
            if msg is None:
                continue
            self._last_rx = time.monotonic()
            try:
                for fn in list(self._listeners):
                    try:
                        fn(msg)
                    except Exception as e:  # one listener's bug must not starve the others
                        self._listener_failed(fn, e)
            finally:
                if self._queue is not None:
                    self._queue.task_done()

    def _listener_failed(self, fn, e: Exception) -> None:
        """Say why a listener failed, once for each listener and kind of error (a full disk failed every frame:
        "listener failed on can-recorder" over and over, without the reason); the traceback at debug level."""
        self.errors.append(e)
        key = (getattr(fn, "__qualname__", repr(fn)), type(e))
        if key in self._said:
            return
        self._said.add(key)
        log.error("listener %s failed on %s: %s: %s (said once; later failures are counted in errors)",
                  key[0], self._thread.name, type(e).__name__, e)
        log.debug("listener %s failed", key[0], exc_info=e)

    def settle(self, timeout_s: float = 2.0) -> bool:
        """Return once every frame already on its way to this bus has been handled."""
        if self._stop.is_set() or threading.current_thread() is self._thread:
            return True
        if self._queue is not None:
            q = self._queue
            deadline = time.monotonic() + timeout_s
            with q.all_tasks_done:
                while q.unfinished_tasks:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return False
                    q.all_tasks_done.wait(left)
            return True
        # other interfaces: wait for a short quiet period
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if time.monotonic() - self._last_rx > 0.002:
                return True
            time.sleep(0.0005)
        return False

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
