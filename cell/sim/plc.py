"""SimPlc: the simulated PLC, a real Modbus TCP client running a PLC-style scan loop.

It is the twin of the real cell PLC: it speaks Modbus TCP to the controller's
:class:`~drivers.plc.server.PlcLink` over loopback, with a client of its own
(:mod:`cell.sim.modbus_client`, no code shared with the server), and knows the controller
only through the register map (names -> addresses), never through the server's internals.

Time: the scan is a task of the injected clock (the simulated clock in the simulated
cell), and every wait of :meth:`SimPlc.run_cycle` is in that clock's seconds. A Modbus
request blocks the scan until the answer is back, so on the simulated clock no time
passes while a request is in flight. The only wall-time limit is the socket's own
``timeout_s`` (a dead server, not a slow host).

Scan (every ``scan_s`` of the injected clock, default 10 ms): on a clock that runs timed
callbacks (``call_at``: the simulated clock) each scan is one such callback, run by whichever
thread runs the clock's agenda, as the simulated drives' timers are, so a scan costs no
thread switch of its own; on another clock (the wall clock) the scan is a task,
``sim-plc-scan``. Either way a scan happens at the same clock times, in the same order:

1. write ``plc_heartbeat`` + 1 and read the whole map in one FC23 (read/write multiple
   registers: the write happens first) -> input image; a plain FC3 read while the
   heartbeat is paused;
2. write the outputs that changed since the last scan, data before commands so a rising
   edge of ``execute`` always finds recipe and part id already written:
   ``recipe_select`` (FC6), ``part_id`` (FC16, both words), ``command_word`` (FC6).

API calls (``select_recipe``, ``set_part_id``, ``set_command``) only change the output image;
the next scan writes it, as a PLC program sets outputs that the I/O scan transfers.
Writes the controller refuses (Modbus exception) are kept in ``write_errors``.
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Mapping

from cell.clock import Clock, MonotonicClock
from cell.errors import CellError
from cell.log import get_logger
from cell.sim.modbus_client import ModbusClientError, ModbusLinkError, ModbusRefused, ModbusTcpClient
from drivers.plc.register_map import PLC_MAP, RegisterMap


def _log():
    # looked up per use: a logger bound at import would keep the set-up of import time
    return get_logger("plc.sim")


#: Output registers in the order a scan writes them (data before commands).
OUTPUTS = ("recipe_select", "part_id", "calibration_select", "command_word")   #: written in this order
#: recipe_status values with which the selected recipe is active: 0 ok, 2 a recipe edit was
#: rejected (the last good version stays active: the PLC may log it, the run goes on)
RUNNABLE_RECIPE_STATUS = (0, 2)
RESULTS = ("initial_error_um", "final_error_um", "moves", "cycle_time_ms", "cycle_count",
           "part_id_echo", "fault_code", "recipe_ack", "recipe_status")


class SimPlcError(CellError):
    """The simulated PLC could not do what was asked (no connection, timeout, refused write)."""


class SimPlc:
    """Simulated PLC connected to ``host:port``.

    ``scan_s``: scan period in seconds of ``clock`` (default 0.010); ``unit``: Modbus unit id;
    ``timeout_s``: per-request socket timeout, wall seconds. Raises :class:`SimPlcError` from
    :meth:`start` if the server cannot be reached or its ``map_version`` differs from the map.
    """

    def __init__(self, host: str, port: int, register_map: RegisterMap = PLC_MAP,
                 scan_s: float = 0.010, clock: Clock | None = None, unit: int = 1,
                 timeout_s: float = 10.0):
        if not scan_s > 0:
            raise SimPlcError(f"SimPlc: scan_s = {scan_s} must be > 0")
        self.map = register_map
        self.scan_s = scan_s
        self._clock = clock or MonotonicClock()
        self._client = ModbusTcpClient(host, port, unit=unit, timeout_s=timeout_s)
        self._cv = threading.RLock()             # guards the images (short holds only)
        self._waiters: list = []                 # (ready, event): set by the scan that makes ready() true
        self._inputs: Mapping[str, int] = {}
        self._outputs = {n: 0 for n in OUTPUTS}    # wanted values (replaced at start)
        self._written = dict(self._outputs)        # values last sent (or refused)
        self._heartbeat = 0
        self._hb_paused = False
        self._scans = 0
        self._stop = self._clock.event()
        self._thread = None
        self._timer = None                       # the next scan's clock callback (call_at clocks)
        self._next_t = 0.0
        self._tick_lock = threading.Lock()       # a stop from outside the clock waits for a scan
        self.write_errors: list[tuple[str, int, int]] = []   # (name, value, exception code)
        self.link_errors = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Connect, check ``map_version``, start the scan task."""
        if self._thread is not None or self._timer is not None:
            raise SimPlcError("SimPlc already started")
        try:
            self._client.connect()
        except ModbusLinkError as exc:
            raise SimPlcError(f"SimPlc: {exc}") from None     # names host:port and the cause
        image = self._exchange(None)
        if image is None or image["map_version"] != self.map.version:
            self._client.close()
            raise SimPlcError(f"SimPlc: server map_version "
                              f"{None if image is None else image['map_version']}, "
                              f"PLC program expects {self.map.version}")
        with self._cv:
            self._inputs = image
            self._heartbeat = image["plc_heartbeat"]
            # take over what the server holds; only the command word is written at the first
            # scan (as a PLC program initialises its outputs): the controller arms only once it
            # has seen execute written low
            self._outputs = {n: image[n] for n in OUTPUTS}
            self._written = {**self._outputs, "command_word": None}
        self._stop.clear()
        call_at = getattr(self._clock, "call_at", None)
        if call_at is not None:
            self._next_t = self._clock.now()
            self._timer = call_at(self._next_t, self._tick)
        else:
            self._thread = self._clock.spawn(self._run, "sim-plc-scan")

    def stop(self) -> None:
        """Stop scanning and close the connection. Idempotent."""
        if self._timer is not None:
            with self._tick_lock:                # (a scan runs only as a callback: not ours)
                self._timer.cancel()
                self._timer = None
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=10)
            self._thread = None
        self._client.close()

    def __enter__(self) -> SimPlc:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ outputs
    def select_recipe(self, recipe: int) -> None:
        """Ask for recipe ``recipe`` (written by the next scan; not range-checked here)."""
        self._set_output("recipe_select", recipe)

    def set_part_id(self, part_id: int) -> None:
        """Announce the next part's id (u32, written whole by the next scan)."""
        self._set_output("part_id", part_id)

    def set_command(self, **bits: bool) -> None:
        """Set/clear named bits of ``command_word``, e.g. ``set_command(execute=True)``."""
        with self._cv:
            self._outputs["command_word"] = self.map.with_bits(
                "command_word", self._outputs["command_word"], bits)

    def pause_heartbeat(self) -> None:
        """Stop incrementing ``plc_heartbeat`` (simulates a PLC in STOP / a dead link)."""
        with self._cv:
            self._hb_paused = True

    def resume_heartbeat(self) -> None:
        with self._cv:
            self._hb_paused = False

    def _set_output(self, name: str, value: int) -> None:
        self.map[name]
        with self._cv:
            self._outputs[name] = int(value)

    # ------------------------------------------------------------------ inputs
    @property
    def scans(self) -> int:
        """Scans completed (input image refreshed) since start."""
        with self._cv:
            return self._scans

    def inputs(self) -> dict[str, int]:
        """Input image of the last scan: every named register."""
        with self._cv:
            return dict(self._inputs)

    def status(self) -> dict[str, bool]:
        """Named bits of ``status_word`` from the last scan."""
        return self.map.bits("status_word", self.inputs()["status_word"])

    def _wait_for(self, ready: Callable[[], bool], timeout_s: float) -> bool:
        """Wait (clock seconds) until a scan makes ``ready()`` true; the scan itself checks it,
        so the waiter sleeps until then."""
        event = self._clock.event()
        with self._cv:
            if ready():
                return True
            entry = (ready, event)
            self._waiters.append(entry)
        try:
            event.wait(timeout_s)
        finally:
            with self._cv:
                if entry in self._waiters:
                    self._waiters.remove(entry)
        with self._cv:
            return ready()

    def wait_scans(self, n: int = 1, timeout_s: float = 5.0) -> None:
        """Block until ``n`` more scans completed; SimPlcError on timeout (clock seconds)."""
        with self._cv:
            target = self._scans + n
        if not self._wait_for(lambda: self._scans >= target, timeout_s):
            raise SimPlcError(f"SimPlc: {n} scans did not complete within {timeout_s} s")

    def wait_until(self, predicate: Callable[[dict[str, int]], bool], timeout_s: float,
                   what: str = "condition") -> dict[str, int]:
        """Block until ``predicate(inputs)`` holds after a scan; return that input image.

        Raises SimPlcError naming ``what`` and the last status on timeout (clock seconds).
        """
        if self._wait_for(lambda: predicate(self._inputs), timeout_s):
            return self.inputs()
        status = self.map.bits("status_word", self.inputs()["status_word"])
        raise SimPlcError(f"SimPlc: timed out after {timeout_s} s waiting for {what}; "
                          f"status {[k for k, v in status.items() if v]}")

    # ------------------------------------------------------------------ the handshake
    def run_cycle(self, recipe: int, part_id: int, timeout_s: float = 5.0) -> dict[str, int]:
        """One full cycle by the handshake in the register map's ``HANDSHAKE``.

        Selects ``recipe`` (waits for recipe_ack), writes ``part_id``, clears stale
        done/aborted with acknowledge, raises execute, waits for done/error/aborted,
        reads the results from that same scan, drops execute and acknowledges (an error
        stays set until :meth:`reset`). Returns the
        results (``RESULTS`` names) plus ``done``/``error``/``aborted`` (0/1). Raises
        SimPlcError if a write is refused, recipe_status is not 0, or a step times out
        (execute is dropped first). ``timeout_s`` applies to each step.
        """
        errors_before = len(self.write_errors)
        bits = lambda img: self.map.bits("status_word", img["status_word"])  # noqa: E731
        finished = self._any_status("done", "error", "aborted")

        status_before = self.inputs()["recipe_status"]

        def recipe_settled(i: dict[str, int]) -> bool:
            if self._refused_since(errors_before):
                return True
            if i["recipe_select"] != recipe or i["part_id"] != part_id:
                return False   # our writes are not read back yet
            if i["recipe_status"] in RUNNABLE_RECIPE_STATUS:
                return i["recipe_ack"] == recipe
            # a refusal is fresh only if it differs from before; a repeat of the same
            # code cannot be told from a stale one and ends in the timeout below
            return status_before == 0 or i["recipe_status"] != status_before

        self.select_recipe(recipe)
        self.set_part_id(part_id)
        try:
            img = self.wait_until(recipe_settled, timeout_s, "recipe_ack and part_id read-back")
        except SimPlcError as exc:
            raise SimPlcError(f"{exc}; recipe_status {self.inputs()['recipe_status']}") from None
        self._raise_refused(errors_before)
        if img["recipe_status"] not in RUNNABLE_RECIPE_STATUS:
            raise SimPlcError(f"SimPlc: recipe {recipe} not active: recipe_status "
                              f"{img['recipe_status']}")
        if finished(img):
            self._pulse_acknowledge(timeout_s)
        self.wait_until(self._any_status("ready"), timeout_s, "ready")   # PLCopen: execute only when ready
        self.set_command(execute=True)
        try:
            img = self.wait_until(finished, timeout_s, "done, error or aborted")
        finally:
            self.set_command(execute=False)
        result = {name: img[name] for name in RESULTS}
        result.update({k: int(bits(img)[k]) for k in ("done", "error", "aborted")})
        self._pulse_acknowledge(timeout_s)
        self._raise_refused(errors_before)
        return result

    def run_calibration(self, select: int, timeout_s: float = 600.0) -> dict[str, int]:
        """One robot calibration by the same handshake: writes ``calibration_select``
        (0 kinematics, N joint jN), waits for ready, raises ``calibrate``, waits for
        done/error/aborted, reads the calibration registers from that scan, drops
        ``calibrate`` and acknowledges. Returns ``calibration_version``,
        ``calibration_residual_um``/``_udeg``, ``fault_code`` and ``done``/``error``/``aborted``.
        Raises SimPlcError if a write is refused or a step times out (clock seconds)."""
        errors_before = len(self.write_errors)
        bits = lambda img: self.map.bits("status_word", img["status_word"])  # noqa: E731
        finished = self._any_status("done", "error", "aborted")
        self._set_output("calibration_select", select)
        self.wait_until(lambda i: i["calibration_select"] == select or self._refused_since(errors_before),
                        5.0, "calibration_select read-back")
        self._raise_refused(errors_before)
        if finished(self.inputs()):
            self._pulse_acknowledge(5.0)
        self.wait_until(self._any_status("ready"), 5.0, "ready")
        self.set_command(calibrate=True)
        try:
            img = self.wait_until(finished, timeout_s, "calibration done, error or aborted")
        finally:
            self.set_command(calibrate=False)
        result = {n: img[n] for n in ("calibration_version", "calibration_residual_um",
                                      "calibration_residual_udeg", "fault_code")}
        result.update({k: int(bits(img)[k]) for k in ("done", "error", "aborted")})
        if result["done"] or result["aborted"]:
            self._pulse_acknowledge(5.0)
        return result

    def _pulse_acknowledge(self, timeout_s: float) -> None:
        """Acknowledge clears done/aborted; an error (latched fault) needs :meth:`reset`."""
        self.set_command(acknowledge=True)
        try:
            pending = self._any_status("done", "aborted")
            self.wait_until(lambda i: not pending(i), timeout_s, "done/aborted cleared by acknowledge")
        finally:
            self.set_command(acknowledge=False)

    def reset(self, timeout_s: float = 5.0) -> None:
        """Pulse ``reset`` and wait until ``error`` clears (the controller clears it only when
        the fault's cause is gone). Raises SimPlcError on timeout."""
        self.set_command(reset=True)
        try:
            error = self._any_status("error")
            self.wait_until(lambda i: not error(i), timeout_s, "error cleared by reset")
        finally:
            self.set_command(reset=False)

    def _any_status(self, *names: str) -> Callable[[Mapping[str, int]], bool]:
        """A predicate on an input image: any of the named ``status_word`` bits is set (one
        mask, where decoding every bit of the word took most of a scan's own time)."""
        mask = self.map.mask("status_word", *names)
        return lambda img: img["status_word"] & mask != 0

    def _refused_since(self, n: int) -> bool:
        return len(self.write_errors) > n

    def _raise_refused(self, n: int) -> None:
        with self._cv:
            refused = self.write_errors[n:]
        if refused:
            name, value, code = refused[0]
            raise SimPlcError(f"SimPlc: controller refused {name} = {value} (Modbus exception "
                              f"{code:02d})")

    # ------------------------------------------------------------------ scan loop
    def _run(self) -> None:
        """The scan as a task (a clock without ``call_at``)."""
        next_t = self._clock.now()
        while not self._stop.is_set():
            self._scan()
            next_t = self._next(next_t)
            self._stop.wait(max(0.0, next_t - self._clock.now()))

    def _tick(self) -> None:
        """The scan as a clock callback; schedules the next one at the time the task's
        wait would end (``now + (next - now)``, to the last bit)."""
        with self._tick_lock:
            if self._timer is None:              # stopped meanwhile
                return
            self._scan()
            self._next_t = self._next(self._next_t)
            now = self._clock.now()
            self._timer = self._clock.call_at(now + max(0.0, self._next_t - now), self._tick)

    def _next(self, next_t: float) -> float:
        """The next scan's time after the one due at ``next_t``."""
        next_t += self.scan_s
        if next_t - self._clock.now() < -self.scan_s:  # overran: do not try to catch up
            next_t = self._clock.now()
        return next_t

    def _scan(self) -> None:
        with self._cv:
            hb = None if self._hb_paused else (self._heartbeat + 1) & 0xFFFF
        image = self._exchange(hb)
        with self._cv:
            if image is not None:
                self._inputs = image
                if hb is not None:
                    self._heartbeat = hb
            todo = [(n, self._outputs[n]) for n in OUTPUTS if self._outputs[n] != self._written[n]]
        for name, value in todo:
            code = self._write(name, value)
            if code < 0:
                continue  # link down: try again next scan
            with self._cv:
                self._written[name] = value   # refused values are not retried
                if code:
                    self.write_errors.append((name, value, code))
        with self._cv:
            if image is not None:
                self._scans += 1
            for entry in [w for w in self._waiters if w[0]()]:
                self._waiters.remove(entry)
                entry[1].set()

    def _exchange(self, heartbeat: int | None) -> Mapping[str, int] | None:
        """Read the whole map; with ``heartbeat``, write it first in the same FC23."""
        try:
            if heartbeat is None:
                words = self._client.read_holding_registers(0, self.map.size)
            else:
                words = self._client.read_write_registers(0, self.map.size,
                                                          self.map["plc_heartbeat"].address, [heartbeat])
        except ModbusClientError as exc:   # a refused read is a link error too
            self._link_error("read", exc)
            return None
        return self.map.view(words)        # the client checked that all words came

    def _write(self, name: str, value: int) -> int:
        """Write one register; 0 if accepted, the Modbus exception code if refused, -1 on I/O error."""
        reg = self.map[name]
        words = [(value >> 16) & 0xFFFF, value & 0xFFFF] if reg.words == 2 else [value & 0xFFFF]
        if value < 0 or value >> (16 * reg.words):
            words = [0xFFFF] * reg.words   # what a PLC's saturating conversion would send
        try:
            if reg.words == 1:
                self._client.write_register(reg.address, words[0])
            else:
                self._client.write_registers(reg.address, words)
        except ModbusRefused as exc:
            _log().info("sim_plc_write_refused", name=name, value=value, code=exc.code)
            return exc.code
        except ModbusLinkError as exc:
            self._link_error(f"write {name}", exc)
            return -1
        return 0

    def _link_error(self, what: str, exc: object) -> None:
        """Count and log; after a link error every output is written again once the link is
        back (the server may have restarted with a fresh register image), as a PLC does."""
        self.link_errors += 1
        with self._cv:
            self._written = {n: None for n in self._written}
        _log().warning("sim_plc_link_error", op=what, error=str(exc))
