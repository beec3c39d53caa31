"""Findings of the outside check (CONTRACT.md, "The simulated drives"): canopen as an
independent master probes what a real CiA 301/402 drive does, over the virtual bus."""

from __future__ import annotations

import canopen
import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from drivers import sim

pytestmark = needs_sim


@pytest.fixture
def master(open_test_bus):
    """A canopen master on the test's channel, disconnected at teardown."""
    networks = []

    def _master(drives, name):
        info = next(n for n in drives.nodes if n["name"] == name)
        network = canopen.Network(open_test_bus())
        network.connect()
        networks.append(network)
        node = canopen.BaseNode402(info["node_id"], info["eds"])
        network.add_node(node)
        return network, node

    yield _master
    for network in networks:
        network.disconnect()


@pytest.mark.parametrize(
    ("index", "subindex"),
    [(0x607D, 3), (0x1016, 2), (0x6041, 1), (0x6040, 1), (0x1017, 1)],
)
def test_a_subindex_the_object_does_not_have_is_refused(open_test_bus, sim_clock, master, index, subindex):
    """CiA 301: an SDO to a sub-index an object does not have aborts with 0x06090011
    (a VAR has only sub-index 0; an ARRAY only the entries it declares)."""
    with sim.serve(open_test_bus(), clock=sim_clock) as drives:
        _, node = master(drives, "j1")
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo.upload(index, subindex)
        assert e.value.code == 0x06090011
        size = 2 if index in (0x6040, 0x6041, 0x1017) else 4
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo.download(index, subindex, bytes(size))
        assert e.value.code == 0x06090011
        assert drives.drives["j1"].controlword == 0  # the write to 0x6040 sub 1 changed nothing
