"""Fixtures for the driver tests: buses on python-can's virtual interface, the simulated
drives and a connected arm, in simulated time by default.

Run the contract suite against a real bus with environment variables (no simulated drives
are served then, and the tests that need the simulated world are skipped):
    DRIVERS_CAN_INTERFACE=socketcan DRIVERS_CAN_CHANNEL=can0 pytest tests/test_can_contract.py
"""

from __future__ import annotations

import itertools
import os
import threading
import time

import pytest

REAL_INTERFACE = os.environ.get("DRIVERS_CAN_INTERFACE")
REAL_CHANNEL = os.environ.get("DRIVERS_CAN_CHANNEL", "can0")
ON_REAL_BUS = REAL_INTERFACE not in (None, "", "virtual")
needs_sim = pytest.mark.skipif(ON_REAL_BUS, reason="needs the simulated drives (fault injection, parts)")

_channels = itertools.count()


@pytest.fixture
def channel():
    """A virtual channel of its own for each test (tests never hear each other)."""
    return f"drivers-test-{os.getpid()}-{next(_channels)}"


@pytest.fixture
def open_test_bus(channel):
    """Open buses on the test's channel; every one is shut down and checked at teardown."""
    from drivers import open_bus

    buses = []

    def _open(**kw):
        if ON_REAL_BUS:
            bus = open_bus(REAL_INTERFACE, REAL_CHANNEL, **kw)
        else:
            bus = open_bus("virtual", channel, **kw)
        buses.append(bus)
        return bus

    yield _open
    for bus in buses:
        bus.shutdown()
    # like python-can's own test suite: nothing may outlive a test (buses, receive threads, clocks)
    deadline = time.monotonic() + 2.0
    while _driver_threads() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not _driver_threads(), f"threads left running: {_driver_threads()}"


def _driver_threads():
    names = ("arm-rx", "sim-drives-rx", "drivers-clock", "can-recorder", "bench-tap", "test-tap")
    return [t.name for t in threading.enumerate() if t.name in names and t.is_alive()]


@pytest.fixture
def sim_clock():
    from drivers.clock import SimClock

    return SimClock()


@pytest.fixture
def sim_drives(open_test_bus, sim_clock, cell_cfg):
    """The simulated drives on their own bus (None when testing a real bus)."""
    if ON_REAL_BUS:
        yield None
        return
    from drivers import sim

    with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as handle:
        yield handle


@pytest.fixture
def arm(sim_drives, open_test_bus, sim_clock, cell_cfg):
    """A connected, enabled arm on the same channel as the simulated drives."""
    from drivers import Arm

    clock = None if ON_REAL_BUS else sim_clock
    # the SDO timeout is wall time: 50 ms ran out once at setup on a loaded 2-core machine, 0.2 s once in a CI-like
    # run beside a benchmark
    a = Arm(open_test_bus(), cell_cfg, clock=clock, sdo_timeout_s=1.0)
    a.connect()
    yield a
    a.disconnect()


def random_way(rng, scara):
    """Two random poses (`Joints`) within J1's and J2's limits at J3 150 mm, J4 0: a way for the way checks'
    tests (each draws J1, then J2, for the start, then for the target)."""
    from cell.kinematics import Joints

    a = Joints(rng.uniform(*scara.j1_deg), rng.uniform(*scara.j2_deg), 150.0, 0.0)
    return a, Joints(rng.uniform(*scara.j1_deg), rng.uniform(*scara.j2_deg), 150.0, 0.0)
