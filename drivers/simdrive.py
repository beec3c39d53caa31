"""One simulated CiA 402 drive (and the gripper) on a canopen `Network`: the drive logic
behind `drivers.sim.serve`.

A `canopen.LocalNode` provides the SDO server and the object dictionary (from the shipped
EDS); `SimDrive` adds, one module each: the objects it computes, checks and restores
(`drivers.sim_objects`), NMT with boot-up, EMCY and the host heartbeat watch (`drivers.sim_nmt`),
RPDOs and TPDO1 on change, on its event timer and on SYNC (`drivers.sim_pdo`), the 402 state
machine with faults (`drivers.sim_state_machine`), profile position with the set-point handshake,
the software position limits and trapezoidal motion on the shared clock (`drivers.sim_motion`),
and fault injection (`drivers.sim_fault_injection`). Here: its state, the time step and the gripper.
"""

from __future__ import annotations

import threading

import canopen

from drivers import codec
from drivers.clock import Clock
from drivers.eds import GRIP_FORCE_INDEX, object_dictionary
from drivers.sim_fault_injection import FAULT_KINDS, FaultInjection
from drivers.sim_motion import COAST_DECEL_FACTOR, Motion, ProfilePosition
from drivers.sim_nmt import NMT_INIT, NMT_OPERATIONAL, NetworkManagement, next_phase
from drivers.sim_objects import ObjectDictionary, power_on_values
from drivers.sim_pdo import TPDO_EVENT_MS, Pdos
from drivers.sim_state_machine import OPTION_CODES, QUICK_STOP_OPTIONS, StateMachine

# the drive, and the names other modules import from here (defined in the modules above since the split)
__all__ = ["HOST_WATCH_STARVED_SHARE", "TICK_MS", "SimDrive", "SimGripper",
           "COAST_DECEL_FACTOR", "FAULT_KINDS", "NMT_OPERATIONAL", "OPTION_CODES", "QUICK_STOP_OPTIONS",
           "TPDO_EVENT_MS", "power_on_values"]

TICK_MS = 10  # the drives' tick (drivers.sim.TICK_S): no heartbeat or event timer shorter than that
HOST_WATCH_STARVED_SHARE = 0.5  # a step this much of the host deadline after the last one: we were held up


class SimDrive(ObjectDictionary, NetworkManagement, Pdos, StateMachine, ProfilePosition, FaultInjection):
    """One simulated CiA 402 drive on a canopen `Network`. Thread-safe (one lock)."""

    def __init__(
        self,
        name: str,
        node_id: int,
        eds: str,
        network: canopen.Network,
        clock: Clock,
        *,
        counts_per_unit: float,
        limits: tuple[float, float],
        velocity: float,
        acceleration: float,
        position: float,
        heartbeat_ms: int,
        tpdo_event_ms: int = TPDO_EVENT_MS,
        tick_ms: int = TICK_MS,
        grip_force_n: float | None = None,  # a gripper's (`SimGripper`)
    ):
        self.name, self.node_id, self.eds, self.clock = name, node_id, eds, clock
        self.tick_ms = tick_ms  # how often step() runs: the shortest period the drive keeps
        self.counts_per_unit = counts_per_unit
        self.coast_decel_counts = COAST_DECEL_FACTOR * acceleration * counts_per_unit
        self._lock = threading.RLock()
        self.network = network
        self.node = canopen.LocalNode(node_id, object_dictionary(eds, node_id))
        network.add_node(self.node)
        # NMT and heartbeats are ours (clock-driven), not canopen's send_periodic thread
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        network.unsubscribe(0, self.node.nmt.on_command)
        network.subscribe(0, self._on_nmt)
        self.node._find_object = self._find_object  # canopen's LocalNode lets any sub-index through
        self._set_data = self.node.set_data
        self.node.set_data = self._set_data_no_rtr
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self._sdo_send = self.node.sdo.send_response
        self.node.sdo.send_response = self._send_sdo_response
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        # RPDOs by their communication object (the COB-IDs are writable, as on real drives)
        self._rpdo_handlers = {0x1400: self._on_rpdo1, 0x1401: self._on_rpdo2, 0x1402: self._on_rpdo3}
        self._rpdo_cobs: dict[int, int] = {}
        for comm in self._rpdo_handlers:
            self._subscribe_rpdo(comm, int(self._get(comm, 1)))
        self._sync_cob: int | None = None
        self._subscribe_sync(int(self._get(0x1005)))
        self._sync_count = 0
        # object dictionary values the cell file sets (as a commissioning tool would; the node's EDS,
        # `drivers.sim.node_eds_paths`, has them as its DefaultValues)
        c = counts_per_unit
        for (index, sub), value in power_on_values(counts_per_unit=c, limits=limits, velocity=velocity,
                                                   acceleration=acceleration, heartbeat_ms=heartbeat_ms,
                                                   tpdo_event_ms=tpdo_event_ms, grip_force_n=grip_force_n).items():
            self._store(index, sub, value)
        # the power-on values (CiA 301: what the NMT resets restore), as stored by commissioning
        self._power_on = {i: dict(subs) for i, subs in self.node.data_store.items()}
        # the option code values this drive takes by SDO, and the objects it lacks (`configure_option_codes`)
        self._accepted = {index: set(values) for index, values in OPTION_CODES.items()}
        self._missing: set[int] = set()
        # drive state
        self.nmt = NMT_INIT
        self.state = "NOT_READY_TO_SWITCH_ON"
        self.position_counts = float(codec.to_counts(position, c))
        self._store(0x607A, 0, round(self.position_counts))
        self.mode = 0
        self.controlword = 0
        self.ack = False
        self.target_reached = True
        self.following_error = False
        self.internal_limit = False
        self.error_code = 0
        self.motion: Motion | None = None
        self.pending: tuple[int, bool] | None = None  # buffered set-point (single set-point mode)
        self.halted: int | None = None  # the target a halt (controlword bit 8) interrupted
        # the state a transition that waits for its ramp enters at standstill (shutdown and disable
        # operation stay in OPERATION ENABLED until then; quick stop 1/2 in QUICK STOP ACTIVE;
        # the fault reaction in FAULT REACTION ACTIVE)
        self.after_ramp: str | None = None
        # enable operation (transition 4 or 16) received while the axis still ramped down or coasted:
        # held, and taken at standstill unless another command replaced it (the controlword is a level)
        self.enable_held = False
        self.emcy_log: list[int] = []
        # host heartbeat watch (0x1016)
        self._host_id = 0
        self._host_deadline_s = 0.0
        self._host_seen_s: float | None = None
        self._stepped_s: float | None = None  # when step() last ran
        # timers
        self._last_hb_s = -1e9
        self._last_tpdo_s = -1e9  # the event timer's phase
        self._tpdo_sent_s = -1e9  # when TPDO1 last went out (its inhibit time counts from there)
        self._last_tpdo: bytes | None = None
        # injected faults
        self.silent = False
        self.drop_sdo = 0  # number of SDO answers still to drop (-1: all)
        self.ignore_set_point = False  # alive (heartbeat, TPDO1) but deaf to the new set-point edge
        self._armed: list[dict] = []
        self._jammed_at: float | None = None  # actual position of a blocked axis (following error)

    def step(self, now: float) -> None:
        with self._lock:
            if self.silent:
                # a dead node also stops hearing the host: it stops driving (as a real drive would)
                if self.state == "OPERATION_ENABLED":
                    self._fault(0x8130)
                self._host_seen_s = None  # watching restarts with the next heartbeat heard
                self._advance(now)  # the mechanics go on (the fault reaction ramp), in silence
                return
            starved = (self._stepped_s is not None
                       and now - self._stepped_s > HOST_WATCH_STARVED_SHARE * self._host_deadline_s)
            self._stepped_s = now
            if self._host_id and self._host_seen_s is not None and self._host_deadline_s > 0:
                if starved:
                    # the simulation itself was held up (it shares the host's process and clock
                    # thread): the host's silence meanwhile cannot be told from ours, so it counts
                    # from now; a real drive keeps time on its own and needs no such rule
                    self._host_seen_s = max(self._host_seen_s, now)
                if now - self._host_seen_s > self._host_deadline_s and "FAULT" not in self.state:
                    driven = self.motion is not None and not self.motion.coasting
                    if self.state in ("OPERATION_ENABLED", "QUICK_STOP_ACTIVE") or driven:
                        self._abort_connection()
                    self._host_seen_s = None  # report once; re-armed by the next heartbeat
            self._advance(now)
            self._publish(now)
            hb_s = int(self._get(0x1017)) / 1000.0
            if hb_s > 0 and now - self._last_hb_s >= hb_s - 1e-9:
                self._last_hb_s = next_phase(self._last_hb_s, hb_s, now)
                self.network.send_message(codec.HEARTBEAT_BASE + self.node_id, codec.pack_heartbeat(self.nmt))

    def _advance(self, now: float) -> None:
        """One step of the mechanics, then what waits for standstill."""
        self._move(now)
        self._take_held_enable()

    def position(self) -> float:
        with self._lock:
            return codec.from_counts(self.position_counts, self.counts_per_unit)


class SimGripper(SimDrive):
    """A parallel gripper on the 402 profile: position = jaw opening. Closing onto a part of
    width `object_width_mm` stops there with the force limit reached (statusword bit 11)."""

    def __init__(self, *args, grip_force_n: float, **kw):
        super().__init__(*args, grip_force_n=grip_force_n, **kw)  # a power-on value: a reset keeps it
        self.object_width_mm: float | None = None
        # A simulated world may say instead what lies between the jaws when they start closing:
        # called once per closing move, returns the part's width or None.
        self.object_width_fn = None
        self._fn_motion, self._fn_width = None, None

    def _blocked(self, m: Motion) -> bool:
        w = self.object_width_mm
        if self.object_width_fn is not None and m.target_counts < m.start_counts:
            if m is not self._fn_motion:
                self._fn_motion, self._fn_width = m, self.object_width_fn()
            w = self._fn_width
        if w is None:
            return False
        w_counts = w * self.counts_per_unit
        closing = m.target_counts < m.start_counts
        if closing and m.start_counts >= w_counts > m.target_counts and self.position_counts <= w_counts:
            self.position_counts = w_counts
            self.motion = None
            self.pending = None
            if not self.controlword & codec.CW_NEW_SET_POINT:
                self.ack = False  # a buffered set-point is dropped: the buffer is free
            self.internal_limit = True
            self.target_reached = True
            return True
        return False

    @property
    def grip_force_n(self) -> float:
        return int(self._get(GRIP_FORCE_INDEX)) / 10.0
