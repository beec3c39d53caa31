"""The arm's safety limits pinned at their boundaries: exactly at a limit is sent, just past it is
refused (`LimitError`) with no frame from the host on the bus and no drive moving.

Mutation testing found these unpinned (the other tests use values far past a limit). Each bound
is tested alone (every other limit met) and in both directions, on the real drivers against
the simulated drives on python-can's virtual bus, in simulated time:

- the J1/J2 maximum step of one move (`drivers.limits.command_violations`), positive and negative;
- the workspace box: x min, x max, y min, y max, each exactly on the bound (the reach annulus is
  no check of its own: a tool placed by forward kinematics cannot leave it);
- J3's travel [0, 200] mm and the 1e-9 mm tolerance of `cell.kinematics.limit_violations`;
- the gripper width in `open()` and `grip()` (`drivers.limits.gripper_violations`);
- the clamp of the profile velocity 0x6081 to the cell file's `max_velocity` (`Arm.move_joints`);
- the pre-open `min(opening + 2 x clearance, stroke)` of `cell.runtime.motion.pick_commands`;
- the carry-off pre-check of `CellLoop._recover_pick` (a pick cut short with the part held).

Several "just past" values round to the limit's own count (200.0005 mm -> 200000 counts): the
drives' software limits 0x607D would take them, so the host's check is the only one that refuses.
"""

from __future__ import annotations

import dataclasses
import math

import pytest
from drivers_fixtures import *  # noqa: F403 - bus fixtures
from drivers_fixtures import needs_sim

from cell.kinematics import Joints, forward, inverse
from drivers.errors import LimitError
from drivers.limits import as_sent

pytestmark = needs_sim

LIMIT_TOL = 1e-9  # the product's tolerance on joint limits and max_step (deg or mm)
WITHIN_TOL = 0.5 * LIMIT_TOL  # past the limit, but inside the tolerance: allowed
PAST_TOL = 2 * LIMIT_TOL  # just past the tolerance: refused
HALF_COUNT = 0.0005  # rounds to the limit's count (1000 counts per unit): the drives would take it
PAST_BOX_MM = 1e-6  # the workspace box has no tolerance
FIELDS = {"j1": "j1_deg", "j2": "j2_deg", "j3": "j3_mm", "j4": "j4_deg"}


# ------------------------------------------------------------------ shared helpers
@pytest.fixture
def arm(sim_drives, open_test_bus, sim_clock, cell_cfg):
    """drivers_fixtures' connected arm, with 1 s for an SDO answer (wall time): this file connects
    about 60 times, and the fixture's 0.2 s ran out at connect with three runs on the 2 cores."""
    from drivers import Arm

    a = Arm(open_test_bus(), cell_cfg, clock=sim_clock, sdo_timeout_s=1.0)
    a.connect()
    yield a
    a.disconnect()


@pytest.fixture
def spy(open_test_bus):
    """A third participant on the bus: hears every frame the host sends."""
    return open_test_bus()


def _drain(bus) -> list:
    frames = []
    while (m := bus.recv(timeout=0)) is not None:
        frames.append(m)
    return frames


def _is_host_command(cob_id: int) -> bool:
    """NMT, SYNC, RPDO1-4 and SDO requests: the frames a master sends to the drives."""
    return cob_id in (0x000, 0x080) or 0x200 <= cob_id < 0x580 or 0x600 <= cob_id < 0x680


def _drive_snapshot(drives) -> dict:
    """Every drive's target position 0x607A (counts) and actual position."""
    return {name: (d.node.sdo[0x607A].raw, d.position()) for name, d in drives.drives.items()}


def refused_before_any_frame(spy, drives, command, error=LimitError) -> str:
    """Run `command`, which must raise `error` with nothing sent and no drive moved; its message."""
    _drain(spy)
    before = _drive_snapshot(drives)
    with pytest.raises(error) as refused:
        command()
    assert [hex(m.arbitration_id) for m in _drain(spy) if _is_host_command(m.arbitration_id)] == []
    assert _drive_snapshot(drives) == before
    return str(refused.value)


def with_joint(j: Joints, joint: str, value: float) -> Joints:
    return dataclasses.replace(j, **{FIELDS[joint]: value})


def assert_drives_at(drives, sent: Joints) -> None:
    """The drives were told `sent` (targets in whole counts) and reached it."""
    for joint, field in FIELDS.items():
        d = drives.drives[joint]
        assert d.node.sdo[0x607A].raw == round(getattr(sent, field) * d.counts_per_unit), joint
        assert d.position() == pytest.approx(getattr(sent, field), abs=1e-3), joint


# ------------------------------------------------------------------ J1/J2 maximum step (200 / 240 deg)
# (start, target): exactly max_step on one joint, the other joints' steps and the tool well inside, at the
# J3 top (no move of J3 below the safe height crosses the tray). A step this large sweeps the tool out of the
# default workspace on the way (J1: the tool turns 200 deg about the base; J2: the elbow flips through the
# stretched arm, 600 mm out), which the drivers refuse too: these tests widen the box past the arm's reach
MAX_STEP_MOVES = {
    "J1+200deg": (Joints(-100.0, 100.0, 200.0, 0.0), Joints(100.0, -100.0, 200.0, 0.0)),
    "J1-200deg": (Joints(100.0, -100.0, 200.0, 0.0), Joints(-100.0, 100.0, 200.0, 0.0)),
    "J2+240deg": (Joints(0.0, -120.0, 200.0, 0.0), Joints(0.0, 120.0, 200.0, 0.0)),
    "J2-240deg": (Joints(0.0, 120.0, 200.0, 0.0), Joints(0.0, -120.0, 200.0, 0.0)),
}


@pytest.fixture
def wide_cell(cell_cfg):
    """The default cell with a workspace box beyond the arm's reach (600 mm): only max_step limits a step."""
    from cell.cellconfig import Box2D

    return dataclasses.replace(cell_cfg, workspace=Box2D((-700.0, 700.0), (-700.0, 700.0)))


def _step_target(move: str, beyond_deg: float) -> tuple[str, Joints, Joints]:
    """The move's joint, start, and target moved `beyond_deg` further in the step's direction."""
    start, target = MAX_STEP_MOVES[move]
    joint = move[:2].lower()
    step = getattr(target, FIELDS[joint]) - getattr(start, FIELDS[joint])
    return joint, start, with_joint(target, joint, getattr(target, FIELDS[joint]) + math.copysign(beyond_deg, step))


class TestMaxStep:
    @pytest.fixture
    def cell_cfg(self, wide_cell):
        return wide_cell

    @pytest.mark.parametrize("beyond_deg", [0.0, WITHIN_TOL], ids=["exactly", "within-tolerance"])
    @pytest.mark.parametrize("move", MAX_STEP_MOVES)
    def test_a_step_of_max_step_or_within_its_tolerance_is_sent(self, arm, sim_drives, move, beyond_deg):
        joint, start, target = _step_target(move, beyond_deg)
        arm.move_joints(start)
        step_deg = abs(getattr(target, FIELDS[joint]) - getattr(start, FIELDS[joint]))
        assert step_deg - arm.cell.scara.max_step[joint] == pytest.approx(beyond_deg, abs=1e-12)
        sent = arm.move_joints(target)
        assert_drives_at(sim_drives, sent)
        assert getattr(sent, FIELDS[joint]) == round(getattr(target, FIELDS[joint]), 3)

    @pytest.mark.parametrize("beyond_deg", [PAST_TOL, HALF_COUNT], ids=["past-tolerance", "half-a-count"])
    @pytest.mark.parametrize("move", MAX_STEP_MOVES)
    def test_a_step_just_past_max_step_is_refused_before_any_frame(self, arm, sim_drives, spy, move, beyond_deg):
        joint, start, target = _step_target(move, beyond_deg)
        arm.move_joints(start)
        message = refused_before_any_frame(spy, sim_drives, lambda: arm.move_joints(target))
        max_step = arm.cell.scara.max_step[joint]
        assert message == (f"move refused, nothing sent: {joint.upper()} step {max_step + beyond_deg:.3f} deg "
                           f"larger than max_step {max_step:g} deg")


def test_a_max_step_move_that_sweeps_the_tool_out_of_the_default_workspace_is_refused(arm, sim_drives, spy):
    joint, start, target = _step_target("J2-240deg", 0.0)
    arm.move_joints(start)
    message = refused_before_any_frame(spy, sim_drives, lambda: arm.move_joints(target))
    assert message.startswith("move refused, nothing sent: the tool would leave the workspace on the way, at x = 5")


# ------------------------------------------------------------------ workspace box x [-50, 560], y [-450, 450]
# bound: (coordinate, value on the bound, the other coordinate well inside, elbow sign, outward sign)
WORKSPACE_BOUNDS = {
    "x-min": ("x", -50.0, 300.0, +1, -1),
    "x-max": ("x", 560.0, 200.0, +1, +1),
    "y-min": ("y", -450.0, 300.0, +1, -1),
    "y-max": ("y", 450.0, 300.0, -1, +1),
}
# the pose asked for exactly on the bound, as the drives get it (each joint rounded to a whole count):
# inside x min, 1.7-1.9 um past the others
PAST_THE_BOUND_AS_SENT = {"x-min": False, "x-max": True, "y-min": True, "y-max": True}


def joints_with_tool_at(scara, coord: str, value_mm: float, other_mm: float, elbow: int,
                        z_mm: float = 200.0) -> Joints:
    """A pose (J3 = z_mm, that elbow) whose tool `coord` is `value_mm` to the last float: J1 bisected
    near the inverse kinematics' solution (its J2 and J4 kept)."""
    x, y = (value_mm, other_mm) if coord == "x" else (other_mm, value_mm)
    ik = min((q for q in inverse(x, y, z_mm, 0.0, scara) if q.j2_deg * elbow > 0), key=lambda q: abs(q.j4_deg))

    def off(j1):
        return getattr(forward(with_joint(ik, "j1", j1), scara), f"{coord}_mm") - value_mm

    lo, hi = ik.j1_deg - 0.01, ik.j1_deg + 0.01
    assert off(lo) * off(hi) < 0
    while (mid := 0.5 * (lo + hi)) not in (lo, hi) and off(mid) != 0.0:
        lo, hi = (mid, hi) if (off(mid) < 0) == (off(lo) < 0) else (lo, mid)
    return with_joint(ik, "j1", min((mid, lo, hi), key=lambda j1: abs(off(j1))))


def tool_xy(j: Joints, scara) -> tuple[float, float]:
    tool = forward(j, scara)
    return tool.x_mm, tool.y_mm


@pytest.mark.parametrize("bound", WORKSPACE_BOUNDS)
def test_a_tool_exactly_on_a_workspace_bound_is_sent_unless_its_counts_land_past_it(arm, sim_drives, spy, bound):
    coord, value, other, elbow, outward = WORKSPACE_BOUNDS[bound]
    target = joints_with_tool_at(arm.cell.scara, coord, value, other, elbow)
    x, y = tool_xy(target, arm.cell.scara)
    assert (x, y)[coord == "y"] == value  # exactly on the bound, not a float inside it
    assert (x, y)[coord == "x"] == pytest.approx(other)
    sent_x, sent_y = tool_xy(as_sent(arm.cell, target), arm.cell.scara)
    past_um = outward * ((sent_x, sent_y)[coord == "y"] - value) * 1e3
    assert (past_um > 0) == PAST_THE_BOUND_AS_SENT[bound] and past_um < 5
    if not PAST_THE_BOUND_AS_SENT[bound]:
        assert_drives_at(sim_drives, arm.move_joints(target))
        return
    # (the box was checked on the joints asked for only, and the drives were sent a pose past it)
    message = refused_before_any_frame(spy, sim_drives, lambda: arm.move_joints(target))
    assert message == (f"move refused, nothing sent: tool at {_shown(coord, sent_x, sent_y)} mm outside the "
                       "workspace x in [-50, 560], y in [-450, 450] (as sent: each joint rounded to a whole "
                       "drive count)")


def _shown(coord: str, x: float, y: float) -> str:
    """The tool as the refusal shows it: the coordinate past the bound to the nanometre (to 0.1 mm it
    would read as the bound itself), the other to 0.1 mm."""
    x_text, y_text = (f"{v:.6f}".rstrip("0") if c == coord else f"{v:.1f}" for c, v in (("x", x), ("y", y)))
    return f"x = {x_text}, y = {y_text}"


@pytest.mark.parametrize("bound", WORKSPACE_BOUNDS)
def test_a_tool_just_past_a_workspace_bound_is_refused_before_any_frame(arm, sim_drives, spy, bound):
    coord, value, other, elbow, outward = WORKSPACE_BOUNDS[bound]
    target = joints_with_tool_at(arm.cell.scara, coord, value + outward * PAST_BOX_MM, other, elbow)
    x, y = tool_xy(target, arm.cell.scara)
    assert 0 < outward * ((x, y)[coord == "y"] - value) < 2 * PAST_BOX_MM
    message = refused_before_any_frame(spy, sim_drives, lambda: arm.move_joints(target))
    # the only reason given: this bound (joints, steps and the other coordinate are fine)
    assert message == (f"move refused, nothing sent: tool at {_shown(coord, x, y)} mm outside "
                       "the workspace x in [-50, 560], y in [-450, 450]")


# ------------------------------------------------------------------ J3 travel [0, 200] mm and its tolerance
J3_TARGETS_SENT = {
    "top-exactly-200": 200.0,
    "top-within-tolerance": 200.0 + WITHIN_TOL,
    "bottom-exactly-0": 0.0,
    "bottom-within-tolerance": -WITHIN_TOL,
}
J3_TARGETS_REFUSED = {
    "top-past-tolerance": 200.0 + PAST_TOL,
    "top-half-a-count-200.0005": 200.0 + HALF_COUNT,
    "bottom-past-tolerance": -PAST_TOL,
    "bottom-half-a-count": -HALF_COUNT,
}
MID_J3 = Joints(0.0, 90.0, 100.0, 0.0)  # tool at (325, 275) mm: well inside the box


@pytest.mark.parametrize("j3_mm", J3_TARGETS_SENT.values(), ids=J3_TARGETS_SENT)
def test_j3_at_its_limit_or_within_the_tolerance_is_sent(arm, sim_drives, j3_mm):
    arm.move_joints(MID_J3)
    sent = arm.move_joints(with_joint(MID_J3, "j3", j3_mm))
    assert sent.j3_mm == round(j3_mm)  # the limit's own count
    assert_drives_at(sim_drives, sent)


@pytest.mark.parametrize("j3_mm", J3_TARGETS_REFUSED.values(), ids=J3_TARGETS_REFUSED)
def test_j3_just_past_its_tolerance_is_refused_before_any_frame(arm, sim_drives, spy, j3_mm):
    arm.move_joints(MID_J3)
    message = refused_before_any_frame(spy, sim_drives, lambda: arm.move_joints(with_joint(MID_J3, "j3", j3_mm)))
    assert message == f"move refused, nothing sent: J3 = {j3_mm:.3f} mm outside [0, 200]"


# ------------------------------------------------------------------ gripper width [0, 80] mm
GRIPPER_WIDTHS_SENT = {"closed-0": 0.0, "stroke-80": 80.0}
GRIPPER_WIDTHS_REFUSED = {
    "below-0-by-1e-9": -1e-9,
    "below-0-by-half-a-count": -HALF_COUNT,
    "above-80-by-1e-9": 80.0 + 1e-9,
    "above-80-by-half-a-count": 80.0 + HALF_COUNT,
}


@pytest.mark.parametrize("width_mm", GRIPPER_WIDTHS_SENT.values(), ids=GRIPPER_WIDTHS_SENT)
def test_gripper_opens_to_either_end_of_its_stroke(arm, sim_drives, width_mm):
    arm.gripper.open(40.0)
    assert arm.gripper.open(width_mm) == pytest.approx(width_mm, abs=1e-3)
    assert sim_drives.drives["gripper"].node.sdo[0x607A].raw == round(width_mm * 1000)


@pytest.mark.parametrize("width_mm", GRIPPER_WIDTHS_SENT.values(), ids=GRIPPER_WIDTHS_SENT)
def test_gripper_grips_a_part_as_wide_as_either_end_of_its_stroke(arm, sim_drives, width_mm):
    sim_drives.gripper_object_width_mm = width_mm
    result = arm.gripper.grip(width_mm)
    assert result.expected_width_mm == width_mm and result.width_mm == pytest.approx(width_mm, abs=1e-3)
    assert sim_drives.drives["gripper"].node.sdo[0x607A].raw == 0  # grip closes fully under the force limit


@pytest.mark.parametrize("width_mm", GRIPPER_WIDTHS_REFUSED.values(), ids=GRIPPER_WIDTHS_REFUSED)
def test_gripper_open_outside_its_stroke_is_refused_before_any_frame(arm, sim_drives, spy, width_mm):
    arm.gripper.open(40.0)
    message = refused_before_any_frame(spy, sim_drives, lambda: arm.gripper.open(width_mm))
    assert message == f"gripper command refused, nothing sent: gripper width {width_mm} mm outside [0, 80]"


@pytest.mark.parametrize("width_mm", GRIPPER_WIDTHS_REFUSED.values(), ids=GRIPPER_WIDTHS_REFUSED)
def test_gripper_grip_outside_its_stroke_is_refused_before_any_frame(arm, sim_drives, spy, width_mm):
    arm.gripper.open(40.0)
    message = refused_before_any_frame(spy, sim_drives, lambda: arm.gripper.grip(width_mm, force_n=50.0))
    assert message == f"grip refused, nothing sent: gripper width {width_mm} mm outside [0, 80]"
    assert sim_drives.drives["gripper"].grip_force_n == arm.cell.gripper.grip_force_n  # the new force not sent


# ------------------------------------------------------------------ profile velocity 0x6081 clamp
# unit/s, with 1 count per unit: the mean speed of a 1-count move is above it, and the limit is not a
# whole count (rounding to the nearest would send 11 counts/s, 0.4 past it)
SLOW_MAX_VELOCITY = 10.6
SLOW_MAX_COUNTS = 10


def _sdo_writes_6081(frames, node_id: int) -> list[int]:
    """The values of the expedited SDO downloads to 0x6081 sub 0 of that node."""
    return [int.from_bytes(m.data[4:8], "little") for m in frames
            if m.arbitration_id == 0x600 + node_id and m.data[0] & 0xE0 == 0x20 and m.data[1:4] == b"\x81\x60\x00"]


@pytest.mark.parametrize("joint", FIELDS)
class TestProfileVelocityClamp:
    """One joint with a coarse encoder (1 count per unit) and max_velocity 10.6 unit/s: a move of
    0.6 unit is one count, whose mean speed (14 counts/s over its 0.074 s) exceeds the maximum."""

    @pytest.fixture
    def cell_cfg(self, joint):
        from cell.cellconfig import default_cell

        c = default_cell()
        s = dataclasses.replace(c.scara, max_velocity={**c.scara.max_velocity, joint: SLOW_MAX_VELOCITY})
        nodes = {**c.can.nodes, joint: dataclasses.replace(c.can.nodes[joint], counts_per_unit=1.0)}
        return dataclasses.replace(c, scara=s, can=dataclasses.replace(c.can, nodes=nodes))

    @staticmethod
    def move_and_hear_0x6081(arm, spy, joint, by, lead=None):
        """Move `joint` by `by` (with `lead`, another axis, by +60 deg: a 0.5 s move that `joint`
        follows slowly); the 0x6081 values sent to `joint`'s drive during the move."""
        t = with_joint(arm.joints(), joint, getattr(arm.joints(), FIELDS[joint]) + by)
        if lead is not None:
            t = with_joint(t, lead, getattr(t, FIELDS[lead]) + 60.0)
        _drain(spy)
        arm.move_joints(t)
        return _sdo_writes_6081(_drain(spy), arm.cell.can.nodes[joint].node_id)

    def test_connect_sets_the_maximum_rounded_down(self, arm, sim_drives, joint):
        assert sim_drives.drives[joint].node.sdo[0x6081].raw == SLOW_MAX_COUNTS

    def test_below_the_maximum_the_velocity_is_sent_unclamped(self, arm, sim_drives, spy, joint):
        sent = self.move_and_hear_0x6081(arm, spy, joint, -1.0, lead="j2" if joint != "j2" else "j4")
        assert len(sent) == 1 and 1 <= sent[0] < SLOW_MAX_VELOCITY  # about 2.4 counts/s
        assert sim_drives.drives[joint].node.sdo[0x6081].raw == sent[0]

    def test_above_the_maximum_the_velocity_is_clamped_to_it(self, arm, sim_drives, spy, joint):
        self.move_and_hear_0x6081(arm, spy, joint, -1.0, lead="j2" if joint != "j2" else "j4")  # 0x6081 lowered
        start = getattr(arm.joints(), FIELDS[joint])
        sent = self.move_and_hear_0x6081(arm, spy, joint, -0.6)
        assert sent == [SLOW_MAX_COUNTS]  # sent over CAN, rounded down to stay within the limit ...
        assert sim_drives.drives[joint].node.sdo[0x6081].raw == SLOW_MAX_COUNTS  # ... and stored
        assert sim_drives.drives[joint].position() == start - 1.0  # the one-count move ran

    def test_a_move_at_the_maximum_right_after_connect_sends_no_0x6081(self, arm, sim_drives, spy, joint):
        """connect() set 0x6081 to the maximum and the arm remembers it: no SDO write mid-sequence to set it again."""
        start = getattr(arm.joints(), FIELDS[joint])
        assert self.move_and_hear_0x6081(arm, spy, joint, -0.6) == []
        assert sim_drives.drives[joint].position() == start - 1.0

    def test_a_move_of_one_count_goes_at_least_at_its_mean_speed(self, arm, spy, joint):
        """0.6 unit is one whole count: the profile for 0.6 unit over the lead's duration (about 1.2 counts/s)
        would be rounded to 1 count/s, and the count take about twice the move's duration."""
        lead = "j2" if joint != "j2" else "j4"
        start = arm.joints()
        target = with_joint(with_joint(start, joint, getattr(start, FIELDS[joint]) - 0.6), lead,
                            getattr(start, FIELDS[lead]) + 60.0)
        duration_s = arm.move_time_s(start, target)
        assert 1 / duration_s < SLOW_MAX_VELOCITY
        assert self.move_and_hear_0x6081(arm, spy, joint, -0.6, lead=lead) == [math.ceil(1 / duration_s)]


class TestAccelerationRoundedDown:
    """The acceleration and deceleration 0x6083 / 0x6084 are rounded down like the velocity: 0.6 count/s^2
    over a whole count (default cell, 1000 counts per unit) is not sent as the next count."""

    @pytest.fixture
    def cell_cfg(self):
        from cell.cellconfig import default_cell

        c = default_cell()
        s = dataclasses.replace(c.scara, max_acceleration={j: a + 0.0006 for j, a in c.scara.max_acceleration.items()})
        g = dataclasses.replace(c.gripper, speed_mm_s=c.gripper.speed_mm_s + 0.00006)  # its acceleration: 10 x
        return dataclasses.replace(c, scara=s, gripper=g)

    def test_connect_sets_the_acceleration_and_deceleration_rounded_down(self, arm, sim_drives, cell_cfg):
        wanted = {**{j: math.floor(a * 1000) for j, a in cell_cfg.scara.max_acceleration.items()},
                  "gripper": 10 * 60_000}
        assert {j: a % 1000 for j, a in wanted.items()} == dict.fromkeys(wanted, 0)  # x.6 counts/s^2 -> x
        for name, counts in wanted.items():
            sdo = sim_drives.drives[name].node.sdo
            assert (name, sdo[0x6083].raw, sdo[0x6084].raw) == (name, counts, counts)
        assert sim_drives.drives["gripper"].node.sdo[0x6081].raw == 60_000


# ------------------------------------------------------------------ pre-open: min(opening + 2 x 5 mm, 80 mm)
@pytest.mark.parametrize(
    ("opening_mm", "pre_open_mm"),
    [(0.0, 10.0), (69.999, 79.999), (70.0, 80.0), (70.001, 80.0), (75.0, 80.0), (80.0, 80.0)],
)
def test_the_jaws_pre_open_by_the_clearance_but_never_past_the_stroke(cell_cfg, opening_mm, pre_open_mm):
    from cell.runtime.motion import pick_commands

    grasp = Joints(0.0, 90.0, 10.0, 0.0)
    commands = {c.label: c for c in pick_commands(grasp, opening_mm, cell_cfg)}
    assert commands["pre-open"].action == "open"
    assert commands["pre-open"].width_mm == pytest.approx(pre_open_mm, abs=1e-12)


def test_a_part_wider_than_the_stroke_minus_the_clearance_is_picked_with_the_jaws_fully_open(arm, sim_drives):
    from cell.runtime.motion import pick_commands
    from drivers.execute import run_commands

    grasp = min(inverse(380.0, -60.0, 10.0, 30.0, arm.cell.scara), key=lambda q: abs(q.j2_deg - 90.0))
    sim_drives.gripper_object_width_mm = 75.0
    records = {r["label"]: r for r in run_commands(arm, pick_commands(grasp, 75.0, arm.cell))}
    assert records["pre-open"]["width_mm"] == 80.0
    assert records["grip"]["holding"] and records["grip"]["width_mm"] == pytest.approx(75.0)


# ------------------------------------------------------------------ carry-off pre-check after a cut-short pick
class TestCarryOffPreCheck:
    """The loop's pick was cut short with the nut in the jaws (`_pick` at stage 'gripped', as
    `_one_part` leaves it); recovery carries it off unless a carry-off move is outside the limits.
    Every drop-off configuration of (300, 450) mm puts the tool exactly on y max."""

    @pytest.fixture
    def cell_cfg(self, dropoff_y_mm):
        from cell.cellconfig import default_cell

        c = default_cell()
        return dataclasses.replace(c, motion=dataclasses.replace(c.motion, dropoff_mm=(300.0, dropoff_y_mm, 120.0)))

    @pytest.fixture
    def loop_holding_a_part(self, arm, sim_drives, cell_cfg):
        from importlib import resources
        from pathlib import Path

        from calibration import load_calibration
        from cell.cellconfig import default_cell
        from cell.examples import default_examples_path
        from cell.runtime.control import RunControl
        from cell.runtime.loop import CellLoop, PartReport
        from cell.runtime.motion import dropoff_joints, pick_commands
        from cell.runtime.ways import routed
        from cell.scene import Scene, load_assembly
        from drivers.execute import run_commands

        assembly = load_assembly(Path(str(resources.files("cell") / "data" / "assemblies" / "default.json")))
        control = RunControl()
        control.run(by="test")
        loop = CellLoop(cell=cell_cfg, calibration=load_calibration(), assembly=assembly, camera=None, arm=arm,
                        control=control, examples_path=default_examples_path())
        part = assembly.sequence[0]
        grasp = loop.planner.plan(Scene(tuple(loop._on_tray()), part)).grasp
        sim_drives.gripper_object_width_mm = grasp.opening_mm
        safe_z = loop._safe_z_mm(part, grasp.grasp_z_mm)
        # (by way of the default drop-off: past the edge, none of this cell's can be sent)
        to_grip = routed(pick_commands(grasp.joints, grasp.opening_mm, cell_cfg, safe_z_mm=safe_z,
                                       drop=dropoff_joints(default_cell(), grasp.joints))[:4], arm.joints(), cell_cfg)
        assert to_grip[-1].label == "grip" and run_commands(arm, to_grip)[-1]["holding"]
        loop._pick = {"part": part, "grasp": grasp, "report": PartReport(part, "removed"), "attempt": 0,
                      "stage": "gripped"}
        return loop, part

    @pytest.mark.parametrize("dropoff_y_mm", [450.0])
    def test_a_carry_off_to_the_workspace_edge_goes_ahead(self, arm, sim_drives, loop_holding_a_part):
        loop, part = loop_holding_a_part
        assert loop._recover_pick() is True
        assert loop._pick is None and loop._taken_by_hand is None
        assert [r.part for r in loop.reports] == [part]
        assert sim_drives.positions()["gripper"] == pytest.approx(80.0)  # let go at the drop-off
        assert tool_xy(arm.joints(), arm.cell.scara) == pytest.approx((300.0, 450.0), abs=0.01)

    @pytest.mark.parametrize("dropoff_y_mm", [450.001])
    def test_a_carry_off_past_the_workspace_edge_is_refused_before_any_frame(
            self, sim_drives, spy, loop_holding_a_part):
        from cell.errors import CellError

        loop, part = loop_holding_a_part
        pick = loop._pick
        message = refused_before_any_frame(spy, sim_drives, loop._recover_pick, CellError)
        # refused before the lift: no drop-off configuration can be sent
        why = ("the drop-off (300.0, 450.001, 120.0) cannot be sent to the arm: tool at x = 300.0, y = 450.001 mm "
               "outside the workspace x in [-50, 560], y in [-450, 450]")
        assert message == (f"{part} is still in the jaws and cannot be carried off ({why}): "
                           "take it out by hand, then reset")
        assert loop._taken_by_hand is pick and loop._pick is None
