"""Bring-up half of :class:`~drivers.stations.driver.JointStations`: canopen's remote nodes
with SDO answers awaited on the injected clock, waiting for boot-up, configuring every
station by SDO (heartbeats, gear, limits, PDO mapping) and the CiA 402 enable sequence.
Split from ``driver.py`` to keep modules small; the methods use the driver's state
(``_stations``, ``_heard``, ``_changed``, ``cfg``, ``clock``).
"""
from __future__ import annotations

import math
from fractions import Fraction
from typing import Callable

import canopen
from canopen.sdo.client import SdoClient

from cell.clock import Clock
from cell.errors import CellError
from drivers.stations import cia402
from drivers.stations.cia402 import State


class StationStartupError(CellError, RuntimeError):
    """Start-up or re-enable failed (no boot-up, SDO refused, drive would not enable)."""


class _ClockSdoClient(SdoClient):
    """canopen's SDO client, waiting for answers on the injected clock.

    canopen waits with ``queue.Queue.get(timeout=...)`` and replaces the queue to drop a
    stale answer; here the queue is the clock's and "replacing" it clears it."""

    def __init__(self, rx_cobid: int, tx_cobid: int, od, clock: Clock):
        self._clock_responses = clock.queue()
        super().__init__(rx_cobid, tx_cobid, od)

    @property
    def responses(self):
        return self._clock_responses

    @responses.setter
    def responses(self, _fresh) -> None:
        self._clock_responses.clear()


class _ClockRemoteNode(canopen.RemoteNode):
    """canopen's remote node whose SDO channels wait on the injected clock."""

    def __init__(self, node_id: int, od, clock: Clock):
        self._clock = clock              # before RemoteNode.__init__ calls add_sdo
        super().__init__(node_id, od)

    def add_sdo(self, rx_cobid, tx_cobid):
        client = _ClockSdoClient(rx_cobid, tx_cobid, self.object_dictionary, self._clock)
        self.sdo_channels.append(client)
        if self.has_network():
            self.network.subscribe(client.tx_cobid, client.on_response)
        return client


def _tries(cfg, exc: Exception) -> str:
    """", after N requests of T s each" for an unanswered SDO, else nothing."""
    if isinstance(exc, canopen.SdoCommunicationError) and "No SDO response" in str(exc):
        return f" after {cfg.sdo_attempts} request(s) of {cfg.sdo_timeout_s} s each"
    return ""


def _remote_node(node_id: int, od_path: str, clock: Clock) -> canopen.RemoteNode:
    return _ClockRemoteNode(node_id, canopen.import_od(od_path, node_id), clock)


class BringUpMixin:
    """Methods of :class:`JointStations` that bring the stations up (see the module doc)."""

    def _await(self, ready: Callable[[], bool], timeout_s: float) -> bool:
        """Wait on the clock until ``ready()`` (checked at every TPDO, heartbeat and fault)."""
        deadline = self.clock.now() + timeout_s
        while True:
            self._changed.clear()
            if ready():
                return True
            left = deadline - self.clock.now()
            if left <= 0:
                return False
            self._changed.wait(left)

    def _wait_boot(self) -> None:
        def missing():
            return [s for s in self._stations if self._heard.get(s.cfg.node_id) is None]
        if not self._await(lambda: not missing(), self.cfg.boot_timeout_s):
            raise StationStartupError(
                "no heartbeat within %.1f s from %s" % (self.cfg.boot_timeout_s, ", ".join(
                    f"{s.joint} (node {s.cfg.node_id})" for s in missing())))

    def _configure_all(self) -> None:
        c = self.cfg
        self._expect_operational = False
        for s in self._stations:
            node, sc = s.node, s.cfg
            try:
                node.nmt.state = "PRE-OPERATIONAL"
                sdo = node.sdo
                sdo[0x1017].raw = c.heartbeat_ms
                sdo[0x1016][1].raw = (c.controller_node_id << 16) | c.consumer_timeout_ms
                gear = Fraction(sc.gear_ratio).limit_denominator(1000)
                sdo[0x608F][1].raw, sdo[0x608F][2].raw = sc.encoder_increments, 1
                sdo[0x6091][1].raw, sdo[0x6091][2].raw = gear.numerator, gear.denominator
                lo, hi = sc.joint_limits
                sdo[0x607D][1].raw = math.ceil(lo * s.cpu)
                sdo[0x607D][2].raw = math.floor(hi * s.cpu)
                sdo[0x607F].raw = min(round(sc.max_velocity * s.cpu), 2 ** 32 - 1)
                sdo[0x6085].raw = min(round(sc.quick_stop_decel * s.cpu), 2 ** 32 - 1)
                sdo[0x605A].raw = 6   # quick stop: ramp, then hold in Quick stop active
                sdo[0x6060].raw = 1   # profile position (set-point streaming)
                self._map_pdos(s)
                node.nmt.state = "OPERATIONAL"
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
                raise StationStartupError(f"configuring {s.joint} (node {sc.node_id}) by SDO failed{_tries(c, exc)}: "
                                          f"{exc}") from exc
        # Operational only counts once each station's heartbeat says so (frames in flight
        # may still carry the old state).
        for s in self._stations:
            self._heard[s.cfg.node_id] = None
        if not self._await(lambda: all(self._heard.get(s.cfg.node_id) == 0x05 for s in self._stations),
                           3 * c.heartbeat_ms / 1000.0 + 0.1):
            bad = [f"{s.joint} (NMT state {self._heard.get(s.cfg.node_id)})" for s in self._stations
                   if self._heard.get(s.cfg.node_id) != 0x05]
            raise StationStartupError(f"stations not NMT Operational after start: {', '.join(bad)}")

    def _map_pdos(self, s) -> None:
        n = s.cfg.node_id
        node = s.node
        node.rpdo.read(from_od=True)
        layout = {1: ((0x607A, 0x6081), 255), 2: ((0x6040,), 255), 3: ((0x607A, 0x6081), 1)}
        for k, (objs, trans) in layout.items():
            m = node.rpdo[k]
            m.clear()
            for index in objs:
                m.add_variable(index)
            m.cob_id, m.trans_type, m.enabled = 0x100 + 0x100 * k + n, trans, True
        node.rpdo.save()
        t = node.tpdo[1]
        t.clear()
        t.add_variable(0x6064)
        t.add_variable(0x6041)
        t.cob_id, t.trans_type, t.event_timer, t.enabled = 0x180 + n, 255, self.cfg.tpdo_event_ms, True
        t.inhibit_time, t.sync_start_value = 0, 0
        t.save()

    def _read_state(self, s) -> State:
        return cia402.decode_statusword(int(s.node.sdo[0x6041].raw))

    def _enable_all(self) -> None:
        for s in self._stations:
            try:
                state = self._read_state(s)
                deadline = self.clock.now() + 1.0
                while state is State.FAULT_REACTION_ACTIVE and self.clock.now() < deadline:
                    self.clock.sleep(0.005)   # the reaction ends by itself (axis stopping)
                    state = self._read_state(s)
                for cmd in cia402.path_to(state, State.OPERATION_ENABLED):
                    s.node.sdo[0x6040].raw = cmd.word
                    state = self._read_state(s)
                if state is not State.OPERATION_ENABLED:
                    raise StationStartupError(f"{s.joint} (node {s.cfg.node_id}) stayed in "
                                              f"{state.label!r} after the enable sequence")
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError, cia402.IllegalTransition) as exc:
                raise StationStartupError(f"enabling {s.joint} (node {s.cfg.node_id}) failed{_tries(self.cfg, exc)}: "
                                          f"{exc}") from exc
            s.target = None
        # return only once the TPDOs say so too, so drive_states()/actual_positions() are fresh
        if not self._await(lambda: all(s.statusword & 0x6F == 0x27 for s in self._stations),
                           3 * self.cfg.tpdo_event_ms / 1000.0 + 0.2):
            raise StationStartupError("no TPDO reporting Operation enabled from " + ", ".join(
                s.joint for s in self._stations if s.statusword & 0x6F != 0x27))
