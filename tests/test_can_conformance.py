"""The simulated drives as a CiA 301 / CiA 402 master outside the project sees them: a canopen master on
python-can's virtual bus, the drives in simulated time. Each test is one deviation from the standards that
an outside check found (and that the drives no longer show)."""

from __future__ import annotations

from contextlib import contextmanager

import canopen
import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from drivers import codec, sim

pytestmark = needs_sim


@contextmanager
def _master(open_test_bus, drives, name):
    """canopen's BaseNode402 on node `name` of the served drives, from a master bus of its own."""
    network = canopen.Network(open_test_bus())
    network.connect()
    try:
        info = next(n for n in drives.nodes if n["name"] == name)
        node = canopen.BaseNode402(info["node_id"], info["eds"])
        network.add_node(node)
        yield network, node
    finally:
        network.disconnect()


def test_switch_on_and_enable_operation_from_ready_to_switch_on_reaches_operation_enabled(
        open_test_bus, sim_clock):
    """CiA 402: controlword 0x000F (switch on + enable operation) in READY TO SWITCH ON takes transitions 3
    and 4; the drive used to stop in SWITCHED ON until the same controlword came again. Enabling never
    jumps: the axis stands where it was, even with bit 4 set."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives, _master(open_test_bus, drives, "j1") as (_, node):
        j1 = drives.drives["j1"]
        start = j1.position_counts
        node.sdo[0x6060].raw = codec.PP_MODE
        node.sdo[0x607A].raw = round(start) + 10_000
        for cw, want in ((0x06, "READY_TO_SWITCH_ON"), (0x0F, "OPERATION_ENABLED"), (0x06, "READY_TO_SWITCH_ON"),
                         (0x1F, "OPERATION_ENABLED")):
            node.sdo[0x6040].raw = cw
            sim_clock.sleep(0.05)
            assert codec.state_name(node.sdo[0x6041].raw) == want, f"after 0x{cw:04X}"
        assert j1.position_counts == start  # 0x1F enabled the drive, took no set-point
