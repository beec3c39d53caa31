"""CiA 402 option codes of the simulated drives (0x605A quick stop, 0x605B shutdown, 0x605C
disable operation, 0x605D halt, 0x605E fault reaction): how a drive stops when it leaves
OPERATION ENABLED during a move. A canopen master writes the option code by SDO, sends a move and
then the command, and follows position actual (0x6064) and the statusword by SDO on the
simulated clock: the ramp's deceleration (0x6084 or 0x6085), the state during the ramp and at
standstill; "disable drive function" gives up the axis at once (it coasts, undriven)."""

from __future__ import annotations

import canopen
import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from drivers import codec, sim
from drivers.simdrive import COAST_DECEL_FACTOR, QUICK_STOP_OPTIONS

pytestmark = needs_sim

SW_TARGET_REACHED = 1 << 10
CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE, CW_QUICK_STOP, CW_DISABLE_VOLTAGE = 0x06, 0x07, 0x0F, 0x02, 0x00
CW_HALT = 0x100
VALUE_RANGE_EXCEEDED = 0x06090030
COAST = "coast"  # the axis is no longer driven: it runs out on friction alone


@pytest.fixture
def j1(open_test_bus, sim_clock, cell_cfg):
    """The simulated drives in simulated time and a canopen master node for j1."""
    with sim.serve(open_test_bus(), cell_cfg, clock=sim_clock) as drives:
        network = canopen.Network(open_test_bus())
        network.connect()
        try:
            info = next(n for n in drives.nodes if n["name"] == "j1")
            node = canopen.BaseNode402(info["node_id"], info["eds"])
            network.add_node(node)
            yield drives, node
        finally:
            network.disconnect()


def _state(node) -> str:
    return codec.state_name(node.sdo[0x6041].raw)


def _enable_pp(node, sim_clock) -> None:
    node.nmt.state = "OPERATIONAL"
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE):
        node.sdo[0x6040].raw = cw
    node.sdo[0x6060].raw = codec.PP_MODE
    sim_clock.sleep(0.01)
    assert _state(node) == "OPERATION_ENABLED"


def _cruising(node, sim_clock) -> tuple[int, float]:
    """A 100-degree move of j1 sent with the handshake, at its profile velocity after 0.4 s
    (0.25 s to accelerate): the position then and the velocity (counts, counts/s)."""
    start = node.sdo[0x6064].raw
    node.sdo[0x607A].raw = start + 100_000
    node.sdo[0x6040].raw = CW_ENABLE | codec.CW_NEW_SET_POINT
    node.sdo[0x6040].raw = CW_ENABLE
    sim_clock.sleep(0.4)
    assert _state(node) == "OPERATION_ENABLED" and not node.sdo[0x6041].raw & SW_TARGET_REACHED
    return node.sdo[0x6064].raw, float(node.sdo[0x6081].raw)


def _follow(node, sim_clock, duration_s: float) -> list[tuple[float, int, int]]:
    """(seconds since now, position actual, statusword) every 10 ms for `duration_s`."""
    t0, samples = sim_clock.now(), []
    while sim_clock.now() - t0 < duration_s - 1e-9:
        sim_clock.sleep(0.01)
        samples.append((sim_clock.now() - t0, node.sdo[0x6064].raw, node.sdo[0x6041].raw))
    return samples


def _decel(node, cell_cfg, ramp) -> float:
    if ramp == COAST:
        return COAST_DECEL_FACTOR * cell_cfg.scara.max_acceleration["j1"] * cell_cfg.can.nodes["j1"].counts_per_unit
    return float(node.sdo[ramp].raw)


def _assert_ramp(samples, p0: int, v: float, d: float, during: set[str], after: str) -> None:
    """Along the ramp p0 + v t - d t^2 / 2 until v / d, then standing at p0 + v^2 / 2d; the
    state is one of `during` while it moves and `after` once it stands."""
    t_stop = v / d
    for t, pos, sw in samples:
        tr = min(t, t_stop)
        assert pos == pytest.approx(p0 + v * tr - d * tr * tr / 2, abs=3), f"at {t:.2f} s"
        if t < t_stop - 0.011:
            assert codec.state_name(sw) in during, f"at {t:.2f} s: {codec.state_name(sw)}"
        elif t > t_stop + 0.011:
            assert codec.state_name(sw) == after, f"at {t:.2f} s: {codec.state_name(sw)}"
    assert samples[-1][0] > t_stop + 0.1 and samples[-1][1] == round(p0 + v * v / (2 * d))


def test_the_option_codes_are_in_the_dictionary_with_their_defaults(j1):
    _, node = j1
    assert [node.sdo[i].raw for i in (0x6007, 0x605A, 0x605B, 0x605C, 0x605D, 0x605E)] == [1, 6, 0, 1, 1, 2]
    int16 = canopen.objectdictionary.INTEGER16
    assert [node.object_dictionary[i].data_type for i in (0x6007, *range(0x605A, 0x605F))] == [int16] * 6


@pytest.mark.parametrize(
    ("index", "value", "command", "ramp", "during", "after"),
    [
        # 0x605C disable operation (transition 5): 1 = slow-down ramp, then SWITCHED ON (default)
        (0x605C, 1, CW_SWITCH_ON, 0x6084, {"OPERATION_ENABLED"}, "SWITCHED_ON"),
        (0x605C, 0, CW_SWITCH_ON, COAST, {"SWITCHED_ON"}, "SWITCHED_ON"),
        # 0x605B shutdown (transition 8): 0 = disable drive function, the axis coasts (default)
        (0x605B, 0, CW_SHUTDOWN, COAST, {"READY_TO_SWITCH_ON"}, "READY_TO_SWITCH_ON"),
        (0x605B, 1, CW_SHUTDOWN, 0x6084, {"OPERATION_ENABLED"}, "READY_TO_SWITCH_ON"),
        # 0x605A quick stop (transition 11): 6 = quick stop ramp, stay in QUICK STOP ACTIVE (default)
        (0x605A, 6, CW_QUICK_STOP, 0x6085, {"QUICK_STOP_ACTIVE"}, "QUICK_STOP_ACTIVE"),
        (0x605A, 5, CW_QUICK_STOP, 0x6084, {"QUICK_STOP_ACTIVE"}, "QUICK_STOP_ACTIVE"),
        (0x605A, 2, CW_QUICK_STOP, 0x6085, {"QUICK_STOP_ACTIVE"}, "SWITCH_ON_DISABLED"),
        (0x605A, 1, CW_QUICK_STOP, 0x6084, {"QUICK_STOP_ACTIVE"}, "SWITCH_ON_DISABLED"),
        (0x605A, 0, CW_QUICK_STOP, COAST, {"SWITCH_ON_DISABLED"}, "SWITCH_ON_DISABLED"),
        # disable voltage (transition 9) has no option code: the drive function goes off at once
        (None, None, CW_DISABLE_VOLTAGE, COAST, {"SWITCH_ON_DISABLED"}, "SWITCH_ON_DISABLED"),
        # 0x605D halt (controlword bit 8): stays in OPERATION ENABLED (1 = slow-down ramp, default)
        (0x605D, 1, CW_ENABLE | CW_HALT, 0x6084, {"OPERATION_ENABLED"}, "OPERATION_ENABLED"),
        (0x605D, 2, CW_ENABLE | CW_HALT, 0x6085, {"OPERATION_ENABLED"}, "OPERATION_ENABLED"),
    ],
    ids=lambda p: f"0x{p:04X}" if isinstance(p, int) and p > 8 else None,
)
def test_leaving_operation_enabled_during_a_move(j1, sim_clock, cell_cfg, index, value, command, ramp, during, after):
    _, node = j1
    if index is not None:
        node.sdo[index].raw = value
        assert node.sdo[index].raw == value
    _enable_pp(node, sim_clock)
    p0, v = _cruising(node, sim_clock)
    node.sdo[0x6040].raw = command
    first = _state(node)
    assert first in during  # at once: QUICK STOP ACTIVE, or the target state when it coasts
    samples = _follow(node, sim_clock, 0.8)
    d = _decel(node, cell_cfg, ramp)
    _assert_ramp(samples, p0, v, d, during, after)
    if command & CW_HALT:
        assert samples[-1][2] & SW_TARGET_REACHED  # halted: bit 10 reports standstill
    if ramp == COAST:  # undriven, it runs out further than on either ramp
        assert d < min(node.sdo[0x6084].raw, node.sdo[0x6085].raw)


@pytest.mark.parametrize(
    ("value", "ramp", "during"),
    [
        (2, 0x6085, {"FAULT_REACTION_ACTIVE"}),  # slow down on the quick stop ramp (default)
        (1, 0x6084, {"FAULT_REACTION_ACTIVE"}),  # slow down on the slow-down ramp
        (0, COAST, {"FAULT"}),  # disable drive function, the motor is free to rotate
    ],
)
def test_fault_reaction_during_a_move(j1, sim_clock, cell_cfg, value, ramp, during):
    drives, node = j1
    node.sdo[0x605E].raw = value
    _enable_pp(node, sim_clock)
    p0, v = _cruising(node, sim_clock)
    drives.inject_fault("emcy", "j1", code=0x2310)  # over-current: the drive faults at once
    assert _state(node) in during
    samples = _follow(node, sim_clock, 0.8)
    _assert_ramp(samples, p0, v, _decel(node, cell_cfg, ramp), during, "FAULT")
    assert node.sdo[0x603F].raw == 0x2310


def test_a_ramped_shutdown_takes_no_set_point_and_yields_to_a_quick_stop(j1, sim_clock, cell_cfg):
    """While a shutdown (0x605B = 1) ramps down, the drive still reports OPERATION ENABLED but
    takes no set-point; a quick stop then replaces the slow-down ramp by the quick stop ramp
    (and 0x605A = 6 keeps it in QUICK STOP ACTIVE, not READY TO SWITCH ON)."""
    _, node = j1
    node.sdo[0x605B].raw = 1
    _enable_pp(node, sim_clock)
    _cruising(node, sim_clock)
    node.sdo[0x6040].raw = CW_SHUTDOWN
    sim_clock.sleep(0.05)
    assert _state(node) == "OPERATION_ENABLED"
    node.sdo[0x607A].raw = 0
    node.sdo[0x6040].raw = CW_ENABLE | codec.CW_NEW_SET_POINT
    assert not node.sdo[0x6041].raw & codec.SW_SET_POINT_ACK  # not taken
    node.sdo[0x6040].raw = CW_QUICK_STOP
    p0 = node.sdo[0x6064].raw
    v = 180_000 - node.sdo[0x6084].raw * 0.05  # 50 ms into the slow-down ramp
    samples = _follow(node, sim_clock, 0.5)
    _assert_ramp(samples, p0, v, float(node.sdo[0x6085].raw), {"QUICK_STOP_ACTIVE"}, "QUICK_STOP_ACTIVE")


def test_a_quick_stop_that_ends_in_switch_on_disabled_cannot_be_re_enabled_during_its_ramp(j1, sim_clock):
    """Transition 16 (enable operation in QUICK STOP ACTIVE) exists only for 0x605A 5-8."""
    _, node = j1
    node.sdo[0x605A].raw = 2
    _enable_pp(node, sim_clock)
    _cruising(node, sim_clock)
    node.sdo[0x6040].raw = CW_QUICK_STOP
    node.sdo[0x6040].raw = CW_ENABLE
    assert _state(node) == "QUICK_STOP_ACTIVE"
    sim_clock.sleep(0.3)
    assert _state(node) == "SWITCH_ON_DISABLED"


def test_at_standstill_the_transitions_are_immediate(j1, sim_clock):
    """No move running: a ramped shutdown or disable operation has nothing to slow down."""
    _, node = j1
    node.sdo[0x605B].raw = 1
    _enable_pp(node, sim_clock)
    node.sdo[0x6040].raw = CW_SWITCH_ON
    assert _state(node) == "SWITCHED_ON"
    node.sdo[0x6040].raw = CW_ENABLE
    node.sdo[0x6040].raw = CW_SHUTDOWN
    assert _state(node) == "READY_TO_SWITCH_ON"


@pytest.mark.parametrize(
    ("index", "values"),
    [
        (0x605A, [3, 4, 7, 8, 9, -1]),  # current / voltage limit stops: not supported; out of range
        (0x605B, [2, -1]),
        (0x605C, [2, -1]),
        (0x605D, [0, 3, 4]),
        (0x605E, [3, 4, -1]),
    ],
)
def test_an_unsupported_option_code_is_refused(j1, index, values):
    """CiA 301: a value the drive does not support aborts with 0x06090030 (value range of
    parameter exceeded); the object keeps its value."""
    _, node = j1
    before = node.sdo[index].raw
    for value in values:
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo[index].raw = value
        assert e.value.code == VALUE_RANGE_EXCEEDED
        assert node.sdo[index].raw == before


@pytest.mark.parametrize("between_ticks_s", [0.0, 0.004, 0.009])
def test_a_stop_between_two_ticks_ramps_from_where_the_axis_is(j1, sim_clock, between_ticks_s):
    """The drive steps every 10 ms; a quick stop that arrives between two steps ramps from where the
    axis is then. It ramped from the last step's position: 9 ms late at 180000 counts/s, 1620 counts
    short."""
    _, node = j1
    _enable_pp(node, sim_clock)
    p_tick, v = _cruising(node, sim_clock)  # 0.4 s: on a step
    sim_clock.sleep(between_ticks_s)
    p0 = p_tick + v * between_ticks_s  # cruising: where the axis is when the quick stop comes
    node.sdo[0x6040].raw = CW_QUICK_STOP
    d = float(node.sdo[0x6085].raw)
    sim_clock.sleep(v / d + 0.2)
    assert node.sdo[0x6064].raw == pytest.approx(p0 + v * v / (2 * d), abs=2)


@pytest.mark.parametrize("value", [6, 5])
def test_quick_stop_active_reports_target_reached_once_the_ramp_has_ended(j1, sim_clock, cell_cfg, value):
    """CiA 402 statusword bit 10: with 0x605A = 5-8 it is set when the quick stop is over and the axis
    stands (in QUICK STOP ACTIVE), clear while the axis still ramps down."""
    _, node = j1
    node.sdo[0x605A].raw = value
    _enable_pp(node, sim_clock)
    p0, v = _cruising(node, sim_clock)
    node.sdo[0x6040].raw = CW_QUICK_STOP
    assert not node.sdo[0x6041].raw & SW_TARGET_REACHED
    d = _decel(node, cell_cfg, QUICK_STOP_OPTIONS[value][0])
    samples = _follow(node, sim_clock, 0.5)
    _assert_ramp(samples, p0, v, d, {"QUICK_STOP_ACTIVE"}, "QUICK_STOP_ACTIVE")
    t_stop = v / d
    assert all(not sw & SW_TARGET_REACHED for t, _, sw in samples if t < t_stop - 0.011)
    assert all(sw & SW_TARGET_REACHED for t, _, sw in samples if t > t_stop + 0.011)


def test_a_quick_stop_at_standstill_reports_target_reached_at_once(j1, sim_clock):
    _, node = j1
    _enable_pp(node, sim_clock)
    node.sdo[0x6040].raw = CW_QUICK_STOP
    sw = node.sdo[0x6041].raw
    assert codec.state_name(sw) == "QUICK_STOP_ACTIVE" and sw & SW_TARGET_REACHED


@pytest.mark.parametrize("value", [2, 1])
def test_a_quick_stop_that_ends_in_switch_on_disabled_reports_no_target_reached_while_it_ramps(j1, sim_clock, value):
    """Bit 10 in QUICK STOP ACTIVE is for 0x605A 5-8; with 1 or 2 the drive ramps in QUICK STOP ACTIVE
    (bit 10 clear) and then leaves it."""
    _, node = j1
    node.sdo[0x605A].raw = value
    _enable_pp(node, sim_clock)
    _cruising(node, sim_clock)
    node.sdo[0x6040].raw = CW_QUICK_STOP
    samples = _follow(node, sim_clock, 0.5)
    ramping = [sw for _, _, sw in samples if codec.state_name(sw) == "QUICK_STOP_ACTIVE"]
    assert ramping and not any(sw & SW_TARGET_REACHED for sw in ramping)
    assert codec.state_name(samples[-1][2]) == "SWITCH_ON_DISABLED"


# --- enabling while the axis still ramps down or coasts ----------------------------------------
# A drive cannot stop a moving axis in zero time: enable operation (transition 4, or 16 out of QUICK STOP
# ACTIVE) while the axis still ramps or coasts leaves the drive in its state, reporting it; the command
# is held (the controlword is a level, CiA 402) and the transition is taken at standstill, unless another
# command has replaced it meanwhile.


@pytest.mark.parametrize("value", [6, 5])
def test_enable_operation_during_a_quick_stop_ramp_is_taken_at_standstill(j1, sim_clock, cell_cfg, value):
    _, node = j1
    node.sdo[0x605A].raw = value
    _enable_pp(node, sim_clock)
    p0, v = _cruising(node, sim_clock)
    node.sdo[0x6040].raw = CW_QUICK_STOP
    node.sdo[0x6040].raw = CW_ENABLE  # transition 16 asked for at once
    assert _state(node) == "QUICK_STOP_ACTIVE"
    node.sdo[0x607A].raw = p0 - 50_000
    node.sdo[0x6040].raw = CW_ENABLE | codec.CW_NEW_SET_POINT  # no set-point is taken meanwhile
    assert not node.sdo[0x6041].raw & codec.SW_SET_POINT_ACK
    d = _decel(node, cell_cfg, QUICK_STOP_OPTIONS[value][0])
    samples = _follow(node, sim_clock, 0.5)
    _assert_ramp(samples, p0, v, d, {"QUICK_STOP_ACTIVE"}, "OPERATION_ENABLED")
    assert samples[-1][2] & SW_TARGET_REACHED  # enabled where it stands: enabling never jumps
    node.sdo[0x6040].raw = CW_ENABLE
    node.sdo[0x6040].raw = CW_ENABLE | codec.CW_NEW_SET_POINT  # a set-point edge now moves it
    sim_clock.sleep(1.0)
    assert node.sdo[0x6064].raw == p0 - 50_000


@pytest.mark.parametrize(
    ("index", "value", "stop", "state"),
    [
        (0x605C, 0, [CW_SWITCH_ON], "SWITCHED_ON"),  # disable operation, coasting
        (0x605B, 0, [CW_SHUTDOWN, CW_SWITCH_ON], "SWITCHED_ON"),  # shutdown, coasting; switched on again
        (None, None, [CW_DISABLE_VOLTAGE, CW_SHUTDOWN, CW_SWITCH_ON], "SWITCHED_ON"),  # disable voltage
        (0x605A, 0, [CW_QUICK_STOP, CW_SHUTDOWN, CW_SWITCH_ON], "SWITCHED_ON"),  # quick stop, coasting
    ],
    ids=["605C=0", "605B=0", "disable-voltage", "605A=0"],
)
def test_enable_operation_while_the_axis_coasts_is_taken_at_standstill(j1, sim_clock, cell_cfg, index, value, stop,
                                                                       state):
    """Transition 4 while the undriven axis still runs out: SWITCHED ON until it stands, then enabled."""
    _, node = j1
    if index is not None:
        node.sdo[index].raw = value
    _enable_pp(node, sim_clock)
    p0, v = _cruising(node, sim_clock)
    for cw in stop:
        node.sdo[0x6040].raw = cw
    node.sdo[0x6040].raw = CW_ENABLE
    assert _state(node) == state
    samples = _follow(node, sim_clock, 1.2)
    _assert_ramp(samples, p0, v, _decel(node, cell_cfg, COAST), {state}, "OPERATION_ENABLED")


def test_an_enable_held_during_the_ramp_is_dropped_by_the_next_command(j1, sim_clock, cell_cfg):
    """The held command is the controlword's: a quick stop sent again (no transition in QUICK STOP
    ACTIVE) replaces it, and the drive stays in QUICK STOP ACTIVE at standstill."""
    _, node = j1
    _enable_pp(node, sim_clock)
    p0, v = _cruising(node, sim_clock)
    node.sdo[0x6040].raw = CW_QUICK_STOP
    node.sdo[0x6040].raw = CW_ENABLE
    node.sdo[0x6040].raw = CW_QUICK_STOP
    samples = _follow(node, sim_clock, 0.5)
    _assert_ramp(samples, p0, v, float(node.sdo[0x6085].raw), {"QUICK_STOP_ACTIVE"}, "QUICK_STOP_ACTIVE")


# --- drives of another make: factory values, refused values, missing objects -------------------
OBJECT_DOES_NOT_EXIST = 0x06020000


def test_a_drive_with_other_factory_values_keeps_them_across_a_reset_node(j1, sim_clock):
    drives, node = j1
    drives.configure_option_codes("j1", values={0x605A: 2, 0x605E: 1})
    assert (node.sdo[0x605A].raw, node.sdo[0x605E].raw) == (2, 1)
    node.sdo[0x605A].raw = 6
    node.nmt.send_command(0x81)  # Reset Node: the power-on (factory) values again
    sim_clock.sleep(0.05)
    assert (node.sdo[0x605A].raw, node.sdo[0x605E].raw) == (2, 1)


def test_a_drive_that_takes_fewer_values_refuses_the_others(j1):
    drives, node = j1
    drives.configure_option_codes("j1", values={0x605A: 2}, accepted={0x605A: {0, 2}})
    with pytest.raises(canopen.SdoAbortedError) as e:
        node.sdo[0x605A].raw = 6
    assert e.value.code == VALUE_RANGE_EXCEEDED and node.sdo[0x605A].raw == 2
    node.sdo[0x605A].raw = 0
    assert node.sdo[0x605A].raw == 0


def test_a_drive_without_the_objects_aborts_every_access_and_stops_as_it_is_built(j1, sim_clock):
    """0x605A and 0x605E are optional in CiA 402: a drive without them answers 0x06020000 (object does not
    exist) and stops its own way, here the quick stop ramp, then SWITCH ON DISABLED."""
    drives, node = j1
    drives.configure_option_codes("j1", values={0x605A: 2}, missing={0x605A, 0x605E})
    for index in (0x605A, 0x605E):
        with pytest.raises(canopen.SdoAbortedError) as e:
            _ = node.sdo[index].raw
        assert e.value.code == OBJECT_DOES_NOT_EXIST
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo[index].raw = 2
        assert e.value.code == OBJECT_DOES_NOT_EXIST
    assert node.sdo[0x605B].raw == 0  # the others are there
    _enable_pp(node, sim_clock)
    p0, v = _cruising(node, sim_clock)
    node.sdo[0x6040].raw = CW_QUICK_STOP
    samples = _follow(node, sim_clock, 0.5)
    _assert_ramp(samples, p0, v, float(node.sdo[0x6085].raw), {"QUICK_STOP_ACTIVE"}, "SWITCH_ON_DISABLED")


def test_only_modelled_option_code_values_can_be_configured(j1):
    drives, _ = j1
    for kw in ({"values": {0x605A: 7}}, {"accepted": {0x605E: {2, 3}}}, {"missing": {0x6060}},
               {"values": {0x6060: 1}}):
        with pytest.raises(ValueError, match="not an option code value"):
            drives.configure_option_codes("j1", **kw)
    with pytest.raises(ValueError, match="unknown node"):
        drives.configure_option_codes("j9", values={0x605A: 2})
