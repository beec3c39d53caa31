"""The arm's commands: coordinated profile-position moves of the four axes, checked by
`drivers.limits` before any frame, started together under halt, and waited for while the host looks at
every drive each poll.
"""

from __future__ import annotations

import contextlib
import math
import time

from cell.kinematics import Joints
from drivers import codec
from drivers.axis import Axis
from drivers.errors import DriveFault, DriverError, LimitError, MoveTimeout, NodeSilent, NotConnected, SdoError
from drivers.limits import JOINT_FIELDS, command_violations
from drivers.profile import coordinated_move_s, coordinated_path, velocity_for_duration

POSITION_TOLERANCE_COUNTS = 2


def at_counts(status, counts: int) -> bool:
    """The drive's reported position is `counts`, within the arrival tolerance (POSITION_TOLERANCE_COUNTS)."""
    return abs(status.position_counts - counts) <= POSITION_TOLERANCE_COUNTS


# wall time an axis gets to show it started at the halt's release (its answer takes ms; meanwhile the axes
# released before it run)
START_CONFIRM_S = 0.2


class Moves:
    """The arm's moves.

    A part of `drivers.arm.Arm`, whose `__init__` sets the state these methods use.
    """

    def _begin_command(self) -> None:
        """Every command: connected, the previous move finished, no fault latched, every drive the host
        enabled still in OPERATION ENABLED."""
        self._require_connected()
        if self._pending[0]:
            self.wait_idle()
        self._check_faults(during_move=False)
        # every status after this that is not OPERATION ENABLED is the drive's side's doing (`_left_operation`):
        # taken before the look below, so that none slips in between it and the move's first frame
        self._move_seqs = {name: ax.status_seq for name, ax in self.axes.items()}
        for ax in self.axes.values():
            err = self._left_operation(ax, "while idle")
            if err is not None:
                self._latch(err)
                raise err  # nothing sent: the axes still enabled stand

    def _stop_on(self, err: DriverError) -> None:
        """A fault the host found itself (not at a look at the drives): latched, every axis stopped, raised."""
        self._latch(err)
        self._stop_all()
        raise err

    def _require_connected(self) -> None:
        if not self._connected:
            raise NotConnected("the arm is not connected: call connect() first")

    def joints(self) -> Joints:
        """The actual joint values (from the drives' last TPDOs)."""
        self._require_connected()
        vals = []
        for joint, _, _ in JOINT_FIELDS:
            p = self.axes[joint].position
            if p is None:
                raise NotConnected(f"{joint}: no position received yet")
            vals.append(p)
        return Joints(*vals)

    def move_time_s(self, start: Joints, target: Joints) -> float:
        """Duration of the coordinated move (every axis arrives with the slowest), from the
        trapezoidal profiles under the cell file's speed and acceleration limits."""
        return coordinated_move_s(self.cell.scara, start, target)

    def path(self, start: Joints, target: Joints, step_deg: float = 2.0) -> list[Joints]:
        """Where the axes are during the coordinated move from `start` to `target` (the end
        included): sampled in time so that J1 and J2 turn at most about step_deg between samples.
        Each axis follows its own trapezoid to arrive with the slowest, so the joints do not move in
        proportion (the long axis ramps, the short one nearly cruises)."""
        return coordinated_path(self.cell.scara, start, target, step_deg)

    def move_joints(self, target: Joints, *, wait: bool = True) -> Joints:
        """Move all four axes to `target` in one coordinated profile-position move.

        Refuses (`LimitError`, nothing sent) anything outside the joint limits, the workspace
        box or the maximum step; refuses (`FaultLatched`) while a fault is latched. Returns
        the command actually sent (the targets rounded to whole counts). With `wait`, returns
        when every axis reports target reached; a fault during the move, or an axis leaving
        OPERATION ENABLED (`DriveDisabled`), quick-stops all axes and raises the node's error,
        within a poll (the way check's can.stop_lag_ms). Without `wait` the host answers such a
        fault only when it next waits (`wait_idle()`) or commands: meanwhile the other axes run on.
        """
        self._begin_command()
        current = self.joints()
        problems = command_violations(self.cell, target, current)
        if problems:
            raise LimitError("move refused, nothing sent: " + "; ".join(problems))
        s = self.cell.scara
        duration_s = self.move_time_s(current, target)
        targets: dict[str, int] = {}
        for joint, field, _ in JOINT_FIELDS:
            ax = self.axes[joint]
            counts = ax.to_counts(getattr(target, field))
            distance = getattr(target, field) - getattr(current, field)
            if counts == ax.status.position_counts:
                continue
            targets[joint] = counts
            v = velocity_for_duration(distance, duration_s, s.max_acceleration[joint]) if duration_s > 0 else 0.0
            # at least the mean speed, so that a move of a few counts does not crawl at 1 count/s
            mean_counts_s = abs(counts - ax.status.position_counts) / duration_s if duration_s > 0 else 1.0
            v_counts = max(1, round(v * ax.counts_per_unit), math.ceil(mean_counts_s))
            v_counts = min(v_counts, codec.rate_counts_within(s.max_velocity[joint], ax.counts_per_unit))
            if self._velocity_counts.get(joint) != v_counts:
                self._guarded(ax.sdo_write, 0x6081, 0, v_counts)
                self._velocity_counts[joint] = v_counts
        sent = Joints(
            *(self.axes[j].from_counts(targets.get(j, self.axes[j].status.position_counts)) for j, _, _ in JOINT_FIELDS)
        )
        self._run_moves(targets, wait=wait, timeout_s=1.5 * duration_s + 1.0)
        return sent

    def _guarded(self, fn, *args):
        """Run an SDO/handshake step; a failure latches the fault (and stops everything)."""
        try:
            return fn(*args)
        except DriverError as e:
            self._latch(e)
            self._stop_all()
            also = self._silent_besides(e.node) if getattr(e, "unanswered", False) else ""
            if also:
                raise SdoError(f"{e}; {also}", node=e.node, node_id=e.node_id) from e
            raise

    def _silent_besides(self, node: str | None) -> str:
        """After a node gave no SDO answer: the other nodes silent too, a heartbeat deadline on (a dead bus or
        power named only the first node asked, j1, and sent the operator to its wiring)."""
        self.clock.sleep(self.heartbeat_deadline_s)
        self._watch()
        with self._lock:
            silent = [name for name, err in self._faults.items() if name != node and isinstance(err, NodeSilent)]
        if not silent:
            return ""
        return (f"{', '.join(silent)} silent too (no heartbeat within {self.heartbeat_deadline_s:g} s): look at the "
                f"bus (cable, termination, the drives' power), not {node} alone")

    def _run_moves(self, targets: dict[str, int], *, wait: bool, timeout_s: float) -> None:
        self._move_no += 1
        # (none runs on, and none keeps a set-point that a later release would start)
        with self._stopped_if_interrupted("a move was interrupted while its axes took their set-points or started"):
            if self.cell.can.coordinated_start and len(targets) > 1:
                self._start_together(targets)
            else:
                for name, counts in targets.items():
                    # one stopped from its side during an earlier axis' handshake: its own would re-enable it
                    self._stop_on_faults(targets, "while the axes took their set-points")
                    self._guarded(self.axes[name].start_move, counts)
            self._pending = (targets, self.clock.now() + timeout_s)
        if wait:
            self.wait_idle()

    @contextlib.contextmanager
    def _stopped_if_interrupted(self, what: str):
        """Something other than the drives' own errors (which stop and latch where they are raised) ending a move:
        Ctrl-C, a bug. The stop is latched first (a second Ctrl-C during the stop leaves the commands refused all
        the same), then every axis quick-stopped, and the error goes on up."""
        try:
            yield
        except DriverError:
            raise
        except BaseException:
            self._latch(DriverError(f"{what}: every axis quick-stopped"), key="stop")
            self._stop_all()
            raise

    def _start_together(self, targets: dict[str, int]) -> None:
        """Every axis takes its set-point under halt, then all are released back to back: they start within
        the release frames' time on the bus, as the way check (drivers.limits) has them. One after another,
        each axis would start a handshake's round trips (ms on real drives) after the one before, off the
        checked path, and run on alone while a later drive did not acknowledge."""
        for name, counts in targets.items():
            # one stopped from its side since the command began: its handshake's enable operation would re-enable
            # it (transition 16) without taking the set-point
            self._stop_on_faults(targets, "while the axes took their set-points")
            self._guarded(self.axes[name].arm_move, counts)
        # an armed axis stopped from the drive's side meanwhile (its quick stop input, STO, another
        # master): the release (enable operation) would re-enable it behind that side's back (transition
        # 16), without its set-point, and the others would run alone
        self._stop_on_faults(targets, "while its set-point waited for the other axes")
        seqs = {name: self._guarded(self.axes[name].release) for name in targets}
        self._confirm_started(targets, seqs)

    def _stop_on_faults(self, targets, when: str) -> None:
        """A latched fault, or an axis of `targets` that left OPERATION ENABLED on its own `when`: stop every
        axis and raise it."""
        self._check_faults(during_move=True)
        for name in targets:
            err = self._left_operation(self.axes[name], when, self._move_seqs.get(name))
            if err is not None:
                self._stop_on(err)

    def _confirm_started(self, targets: dict[str, int], seqs: dict[str, int]) -> None:
        """Every released axis must show within START_CONFIRM_S (wall time) that it started, or all are
        stopped. Meanwhile the host looks at every drive each poll, as `wait_idle` does: an axis that faults or
        stops on its own (its quick stop input) as the move starts stops the others within can.stop_lag_ms."""
        deadline = time.monotonic() + START_CONFIRM_S
        waiting = dict(targets)
        while True:
            waiting = {n: c for n, c in waiting.items()
                       if not self.axes[n].has_started(seqs[n], c, POSITION_TOLERANCE_COUNTS)}
            self._watch(stops=True)
            self._stop_on_faults(targets, "as its move started")
            if not waiting:
                return
            name, counts = next(iter(waiting.items()))
            left = deadline - time.monotonic()
            try:  # a poll's wait, woken by this axis' status
                self.axes[name].confirm_started(seqs[name], counts, POSITION_TOLERANCE_COUNTS,
                                                max(0.0, min(self.poll_s, left)), told_s=START_CONFIRM_S)
            except NodeSilent:
                if left > self.poll_s:
                    continue  # not yet: look at every drive again
                self._guarded(self.axes[name].confirm_started, seqs[name], counts, POSITION_TOLERANCE_COUNTS,
                              0.0, START_CONFIRM_S)  # (latches the timeout and stops every axis)
            except DriverError as e:  # it faulted meanwhile
                self._latch(e)
                self._stop_all()
                raise

    def wait_idle(self) -> None:
        """Wait (on the shared clock) until the last move's axes report target reached. Anything else that
        ends the wait (Ctrl-C, an error in a look at the drives) quick-stops every axis and latches a stop
        before it goes on up."""
        targets, deadline = self._pending
        try:
            with self._stopped_if_interrupted("waiting for a move was interrupted"):
                while targets:
                    # every poll, not only at the watchdog's: an axis that stopped on its own (a fault, its quick
                    # stop input) is answered within a poll, as the way check's can.stop_lag_ms has it
                    self._watch(stops=True)
                    self._check_faults(during_move=True)
                    self._stop_if_stopped_short(targets)
                    if all(self._arrived(self.axes[n], c) for n, c in targets.items()):
                        return
                    if self.clock.now() > deadline:
                        late = [n for n, c in targets.items() if not self._arrived(self.axes[n], c)]
                        err = MoveTimeout(
                            f"{', '.join(late)}: target not reached in time",
                            node=late[0],
                            node_id=self.axes[late[0]].node_id,
                        )
                        self._stop_on(err)
                    self.clock.sleep(self.poll_s)
        finally:
            self._pending = ({}, 0.0)

    @staticmethod
    def _ended(st) -> bool:
        """The drive says its move ended: target reached in OPERATION ENABLED, no set-point being taken (bit 10
        also reports the end of a quick stop ramp in QUICK STOP ACTIVE, CiA 402: no arrival)."""
        return st is not None and st.state == "OPERATION_ENABLED" and st.target_reached and not st.ack

    @classmethod
    def _arrived(cls, ax: Axis, counts: int) -> bool:
        """The move ended at the target (a count or two short of it is no arrival after a quick stop: `_ended`).
        The gripper's jaws stopped on a part (internal limit active) have arrived where the part is."""
        st = ax.status
        return cls._ended(st) and (at_counts(st, counts) or (ax.name == "gripper" and st.internal_limit))

    def _stop_if_stopped_short(self, targets: dict[str, int]) -> None:
        """An arm axis whose drive reports its move ended with internal limit active, away from the target: a
        limit switch, a torque or current limit, a target clipped to the drive's own limits. It was taken for
        arrival (the pick record said the axis stood where it was sent): every axis is stopped and the fault
        latched, naming where the axis stands."""
        for name, counts in targets.items():
            ax = self.axes[name]
            st = ax.status
            if name == "gripper" or not self._ended(st) or not st.internal_limit or self._arrived(ax, counts):
                continue
            err = DriveFault(f"{name} (node {ax.node_id}): stopped at {ax.position:g} {ax.unit}, short of "
                             f"{ax.from_counts(counts):g} {ax.unit}: the drive reports an internal limit (a limit "
                             "switch, a torque or current limit, or its own position limits)", node=name,
                             node_id=ax.node_id)
            self._stop_on(err)
