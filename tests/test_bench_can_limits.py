"""`cell bench can` sends its targets straight to J1 (not through `Arm.move_joints`' checks): they must stay within
J1's limits. A cell whose home is at J1's upper limit had the bench send 132.01 deg; the simulated drive refused
it (EMCY 0x8612, its software position limit) and the bench stopped on the fault."""

import dataclasses

from drivers_fixtures import needs_sim

from cell.cellconfig import default_cell
from drivers.bench import round_trips

pytestmark = needs_sim


def test_the_round_trips_stay_within_j1s_limits_from_a_home_at_the_limit():
    cell = default_cell()
    hi = cell.scara.j1_deg[1]
    at_limit = dataclasses.replace(cell, motion=dataclasses.replace(
        cell.motion, home_joints={**cell.motion.home_joints, "j1_deg": hi}))
    figures = round_trips(at_limit, n=3)  # a drive fault (the target past 0x607D) raised DriveFault
    assert figures["move_handshake"]["n"] == 3 and figures["set_point_ack"]["n"] == 3
