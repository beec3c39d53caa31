"""Bringing the arm's nodes into service: what the host sets up in each (SDO), NMT start, and enabling every
drive where it stands. `connect` does it for every node; `reset_faults` again for a node that lost its setup
(rebooted), before it enables them all.
"""

from __future__ import annotations

import logging
import math

from cell.cellconfig import HEARTBEAT_DEADLINE_FACTOR, QUICK_STOP_DECEL_FACTOR, grip_force_units
from drivers import codec
from drivers.arm_supervision import HOST_NODE_ID, STANDSTILL_MARGIN_S
from drivers.axis import Axis
from drivers.eds import GRIP_FORCE_INDEX
from drivers.errors import DriveFault, FaultLatched
from drivers.gripper import GRIPPER_ACCEL_FACTOR

log = logging.getLogger("drivers.arm")  # the arm's one logger (tests and users filter on it)

TPDO_EVENT_TIMER_MS = 50  # status at least every 50 ms when nothing changes (the watch sees a stuck drive)
# mm or deg: a drive at rest this far past a joint limit (a home at the limit, settled a few counts past it) is
# enabled holding the limit; further out it is not enabled
SETTLED_PAST_LIMIT = 0.5
SETUPS_MAX = 3  # set-ups of a node that boots again before NMT start (`Setup._set_up_after_boot`)


class Setup:
    """The setup and enabling of the nodes.

    A part of `drivers.arm.Arm`, whose `__init__` sets the state these methods use.
    """

    def _start(self, axes: list[Axis]) -> None:
        """NMT start, then wait for each node's first status and a heartbeat saying OPERATIONAL: from then on a
        heartbeat saying anything else is a fault (`Axis.lost_setup`). A boot-up message before the start is
        ordinary (`_set_up_after_boot`); one after it is a reboot, latched as one by the enable or the watchdog."""
        for ax in axes:
            self._set_up_after_boot(ax)
            ax.nmt(codec.NMT_START)
        for ax in axes:
            if not ax.wait_started(self.clock, self.boot_timeout_s, self.poll_s):
                log.warning("%s after its NMT start", ax.lost_setup())
            ax.started = True

    def _set_up_after_boot(self, ax: Axis) -> None:
        """A boot-up message after the node's setup but before the host started it (its power came up while the
        host connected; a drive that boots twice) is no fault: the node is set up again. Latched as a reboot, it
        stayed so until a reset. A node still booting after SETUPS_MAX setups is started as it is and latched."""
        for _ in range(SETUPS_MAX):
            if ax.boot_count == ax.boots_at_setup:
                return
            log.warning("%s (node %d) booted again after its setup, before NMT start: set up again", ax.name,
                        ax.node_id)
            ax.forget_status()  # from before the boot-up
            self._configure(ax)
            self._send_host_heartbeat()  # its host watch starts at the first heartbeat it hears (CiA 301)

    def _configure(self, ax: Axis) -> None:
        """Everything the host sets up in a node (SDO), and the host's record of what it wrote there."""
        c = self.cell
        # a boot-up message from here on is a reboot: what follows would be lost (`Axis.lost_setup`)
        ax.boots_at_setup, ax.started = ax.boot_count, False
        device_type = ax.sdo_read(0x1000)
        if device_type & 0xFFFF != 402:
            raise DriveFault(
                f"{ax.name} (node {ax.node_id}) is not a CiA 402 drive (0x1000 = 0x{device_type:08X})",
                node=ax.name,
                node_id=ax.node_id,
            )
        if ax.sdo_read(0x6502) & codec.SUPPORTED_MODES_PP == 0:
            raise DriveFault(
                f"{ax.name} (node {ax.node_id}) does not support profile position mode",
                node=ax.name,
                node_id=ax.node_id,
            )
        ax.setup_pdos(TPDO_EVENT_TIMER_MS)
        for warning in ax.setup_option_codes():  # 0x6007 = 1, 0x605A = 6, 0x605E = 2
            log.warning("%s", warning)
        ax.sdo_write(0x1017, 0, c.can.heartbeat_ms)
        deadline_ms = round(HEARTBEAT_DEADLINE_FACTOR * c.can.host_heartbeat_ms)
        ax.host_watch_entry = codec.consumer_heartbeat_entry(HOST_NODE_ID, deadline_ms)
        ax.sdo_write(0x1016, 1, ax.host_watch_entry)
        if ax.name == "gripper":
            lo, hi = c.gripper.opening_mm
            velocity, accel = c.gripper.speed_mm_s, GRIPPER_ACCEL_FACTOR * c.gripper.speed_mm_s
            ax.sdo_write(GRIP_FORCE_INDEX, 0, grip_force_units(c.gripper.grip_force_n))
            self.gripper._force_n = c.gripper.grip_force_n
        else:
            lo, hi = c.scara.limits(ax.name)
            velocity, accel = c.scara.max_velocity[ax.name], c.scara.max_acceleration[ax.name]
        ax.sdo_write(0x607D, 1, ax.to_counts(lo))
        ax.sdo_write(0x607D, 2, ax.to_counts(hi))
        # rounded down: never past the cell file's limits (the cell file is refused where they are under a count)
        v = codec.rate_counts_within(velocity, ax.counts_per_unit)
        ax.sdo_write(0x6081, 0, v)
        self._velocity_counts[ax.name] = v
        a = codec.rate_counts_within(accel, ax.counts_per_unit)
        ax.sdo_write(0x6083, 0, a)
        ax.sdo_write(0x6084, 0, a)
        ax.sdo_write(0x6085, 0, max(1, round(QUICK_STOP_DECEL_FACTOR * accel * ax.counts_per_unit)))

    def _set_up_again(self, ax: Axis) -> None:
        """A node that lost its setup (`Axis.lost_setup`): all of it again, as connect does, then NMT start. Its
        power-on values need not be the cell's (its host-heartbeat watch was 0: J2 ran its move on when the host
        died); the host's record of what it wrote (profile velocity, grip force) is rewritten with it."""
        log.warning("%s: set up again (%s)", ax.name, ax.lost_setup() or "its host-heartbeat watch 0x1016 was not "
                    "the host's: a reboot whose boot-up message was lost")
        ax.forget_status()  # from before the reboot: the first after NMT start is the one to go by
        self._configure(ax)
        self._send_host_heartbeat()  # its host watch starts at the first heartbeat it hears (CiA 301)
        self._start([ax])

    def enable(self) -> None:
        """Enable every drive, holding where it stands: the `connect(enable=False)` session's second half, for a
        host that asks the operator before the motors hold torque. A drive in FAULT or standing outside its
        limits is not enabled; its fault is latched and raised here."""
        self._require_connected()
        self._enable_all()
        with self._lock:
            refused = next(iter(self._faults.values()), None)
        if refused is not None:
            raise refused

    def require_enableable(self) -> None:
        """Raise FaultLatched (nothing sent) naming every drive `enable()` would not enable: one in FAULT, one
        standing past its limits. A host that asks the operator first says so before the question, not after
        the yes with the other drives holding torque."""
        self._require_connected()
        refused = {ax.name: str(err) for ax in self.axes.values() if (err := self._enable_refusal(ax)) is not None}
        if refused:
            raise FaultLatched(refused)

    def _enable_all(self) -> None:
        """Enable every drive. A drive found in FAULT (say, after a host crash) is not reset
        here: its fault is latched with its error code, and only `reset_faults()` clears it."""
        for ax in self.axes.values():
            err = self._enable_refusal(ax)
            if err is not None:
                self._latch(err)
                continue
            ax.enable(STANDSTILL_MARGIN_S + self._slowest_quick_stop_s(), self.poll_s, self._enable_hold(ax)[0])

    def _enable_refusal(self, ax: Axis) -> DriveFault | None:
        """Why `ax` is not to be enabled (None: it may be): in FAULT, with its error code; or standing outside its
        limits (`_enable_hold`); or without the setup the host gave it (rebooted: `reset_faults` sets it up again).
        """
        lost = self._lost_setup_fault(ax)
        if lost is not None:
            return lost
        if ax.state == "FAULT":
            code = ax.sdo_read(0x603F)
            return DriveFault(f"{ax.name} (node {ax.node_id}): in FAULT, error code 0x{code:04X} "
                              f"{codec.emcy_text(code)}", node=ax.name, node_id=ax.node_id, emcy_code=code)
        _, outside = self._enable_hold(ax)
        if outside:  # enabling sends the axis' position as its target: not one outside its limits
            return DriveFault(f"{ax.name} (node {ax.node_id}): {outside}; not enabled: move it back inside by hand "
                              "(brake released), then reset", node=ax.name, node_id=ax.node_id)
        return None

    def _enable_hold(self, ax: Axis):
        """(the target a drive is enabled with, for its position in counts; why it is not enabled). Its position,
        within the joint's limits (the gripper: its opening's range); a drive at rest up to SETTLED_PAST_LIMIT past
        one (a few counts past a home at the limit) is enabled holding the limit. Further out it coasted there (safe
        torque off, a jam, power lost mid-move: J1 stopped at 146 deg of 132) and is not enabled: its position would
        be sent as its target."""
        gripper = ax.name == "gripper"
        # the gripper: its opening's range (jaws found at 85 mm of 80 were held at 85), and held at the end of it
        # however far out: the jaws moving by a few mm is no danger, and jaws pressed past 0 kept the arm off
        lo, hi = self.cell.gripper.opening_mm if gripper else self.cell.scara.limits(ax.name)
        if ax.status is None:
            ax.wait_status(lambda s: True, None, "first TPDO")
        cpu = ax.counts_per_unit
        value = ax.status.position_counts / cpu
        if gripper or lo - SETTLED_PAST_LIMIT <= value <= hi + SETTLED_PAST_LIMIT:
            lo_c, hi_c = math.ceil(lo * cpu), math.floor(hi * cpu)
            return (lambda counts: min(max(counts, lo_c), hi_c)), None
        return None, f"stands at {value:.3f} {ax.unit}, outside its limits [{lo:g}, {hi:g}]"
