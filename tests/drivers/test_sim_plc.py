"""SimPlc (the PLC twin, a real Modbus TCP client) against PlcLink (a real server), on the
simulated clock.

Everything timed runs on one :class:`~cell.sim.clock.VirtualClock` per test: the SimPlc's
scan task, the controller's side of the handshake (``ControllerStandIn``, a clock task that
uses nothing but PlcLink's public accessors, as the cell loop will) and the test thread
itself, which keeps the clock's time for the whole test (the ``clock`` fixture attaches it).
PlcLink stamps PLC writes with the same clock. A Modbus request blocks its participant until
the answer, so no simulated time passes while it is in flight: every time below is exact in
simulated seconds, whatever the load of the host.
"""
from __future__ import annotations

import math
import struct
import threading

import pytest

from cell.sim.clock import VirtualClock
from cell.sim.plc import RESULTS, SimPlc, SimPlcError
from drivers.plc.register_map import PLC_MAP, REGISTERS, PlcMapError, RegisterMap
from drivers.plc.server import PlcLink, PlcWrite
from tests.drivers.test_sim_plc_client import FakeServer, answer, good

SCAN_S = 0.002
T0 = 1000.0            # clock time at the start of a test: no stamp can be mistaken for a default 0
EPS = 1e-9             # float noise of summed scan periods, s
RESULT = {"initial_error_um": 1234, "final_error_um": 17, "moves": 3, "cycle_time_ms": 2500}
CYCLE_TASK = "sim-plc-cycle"
SIM_THREADS = ("sim-clock", CYCLE_TASK)

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")


@pytest.fixture(autouse=True)
def no_leaked_sim_threads():
    """Besides the PLC threads (conftest): the clock's own thread and the tasks of this file."""
    before = set(threading.enumerate())
    yield
    leaked = [t.name for t in threading.enumerate() if t not in before and t.name in SIM_THREADS]
    assert not leaked, f"threads left running: {leaked}"


def bits(image: dict[str, int]) -> dict[str, bool]:
    return PLC_MAP.bits("status_word", image["status_word"])


class ControllerStandIn:
    """The controller's half of the handshake, through PlcLink only, as a clock task
    (``controller-stand-in``) that looks at the PLC's writes every ``PERIOD_S`` clock seconds.

    Known recipes are accepted into recipe_ack; an execute rising edge latches part_id and
    finishes at once with ``RESULT`` (or error + ``fault_code`` if set), unless ``hold`` is
    true, in which case the cycle stays busy until an abort edge or ``hold`` is cleared.
    Every PLC write it took is kept in ``seen`` (with PlcLink's clock stamp).
    """

    NAME = "controller-stand-in"
    PERIOD_S = 0.002

    def __init__(self, link: PlcLink, clock: VirtualClock, recipes=(1, 2, 5)):
        self.link, self.clock, self.recipes = link, clock, set(recipes)
        self.fault_code = 0
        self.hold = False
        self.seen: list[PlcWrite] = []
        self.cycles = 0
        self.error: BaseException | None = None
        self._busy_part: int | None = None
        self._quit = clock.event()
        self._task = None

    def start(self) -> None:
        self._task = self.clock.spawn(self._run, self.NAME)

    def stop(self) -> None:
        """Stop the task (it ends at its next tick) and re-raise what made it fail, if anything."""
        self._quit.set()
        assert self._task.join(timeout=10 * self.PERIOD_S), "controller stand-in did not end"
        if self.error is not None:
            raise AssertionError("controller stand-in failed") from self.error

    def edges(self, bit: str) -> list[float]:
        """Clock times of the PLC's rising edges of command bit ``bit``."""
        return [e.t for e in self.seen if e.name == "command_word"
                and PLC_MAP.bits("command_word", e.value & ~e.previous)[bit]]

    def _status(self, **flags: bool) -> int:
        return PLC_MAP.with_bits("status_word", self.link.read("status_word"), flags)

    def _run(self) -> None:
        try:
            self.link.write("status_word", self._status(ready=True, auto=True, homed=True,
                                                         plc_link_ok=True))
            while True:
                for ev in self.link.drain_writes():
                    self.seen.append(ev)
                    self._handle(ev)
                if self._busy_part is not None and not self.hold:
                    self._finish()
                if self._quit.wait(self.PERIOD_S):
                    return
        except BaseException as exc:   # noqa: BLE001 -- reported by stop()
            self.error = exc

    def _handle(self, ev: PlcWrite) -> None:
        link = self.link
        if ev.name == "recipe_select":
            if ev.value in self.recipes:
                link.write_many({"recipe_ack": ev.value, "recipe_status": 0})
            else:
                link.write("recipe_status", 1)
        elif ev.name == "command_word":
            rising = PLC_MAP.bits("command_word", ev.value & ~ev.previous)
            if rising["execute"]:
                self._busy_part = link.read("part_id")
                link.write("status_word", self._status(busy=True, ready=False, done=False,
                                                       error=False, aborted=False))
                if not self.hold:
                    self._finish()
            if rising["abort"] and self._busy_part is not None:
                self._busy_part = None
                link.write("status_word", self._status(busy=False, aborted=True, ready=True))
            if rising["acknowledge"]:
                link.write("status_word", self._status(done=False, aborted=False))
            if rising["reset"]:
                link.write_many({"fault_code": 0, "status_word": self._status(error=False)})

    def _finish(self) -> None:
        self.cycles += 1
        part, self._busy_part = self._busy_part, None
        if self.fault_code:   # results first, status last, in one atomic update
            self.link.write_many({"fault_code": self.fault_code, "part_id_echo": part,
                                  "status_word": self._status(busy=False, error=True, ready=True)})
        else:
            self.link.write_many({**RESULT, "part_id_echo": part, "cycle_count": self.cycles,
                                  "status_word": self._status(busy=False, done=True, ready=True)})


@pytest.fixture
def clock():
    """One simulated clock per test; the test thread keeps its time for the whole test
    (fixtures that depend on this one are set up and torn down inside)."""
    clock = VirtualClock(T0)
    try:
        with clock.attach("test"):
            yield clock
    finally:
        clock.close()


@pytest.fixture
def link(clock):
    link = PlcLink(clock=clock)
    link.start()
    yield link
    link.stop()


@pytest.fixture
def controller(link, clock):
    c = ControllerStandIn(link, clock)
    c.start()
    yield c
    c.stop()


@pytest.fixture
def sim(link, controller, clock):
    sim = SimPlc("127.0.0.1", link.port, scan_s=SCAN_S, clock=clock)
    sim.start()
    sim.wait_scans(1)            # the first scan runs at once: the test starts right after a scan
    assert clock.now() == T0
    yield sim
    sim.stop()


def test_run_cycle_follows_the_handshake_and_returns_results(sim, link, controller, clock):
    r = sim.run_cycle(recipe=5, part_id=0xDEAD_BEEF)
    assert {k: r[k] for k in RESULT} == RESULT
    assert (r["part_id_echo"], r["recipe_ack"], r["recipe_status"]) == (0xDEAD_BEEF, 5, 0)
    assert (r["done"], r["error"], r["aborted"], r["fault_code"], r["cycle_count"]) == (1, 0, 0, 0, 1)
    assert set(RESULTS) <= set(r)
    # the PLC's writes, stamped with the clock time of the scan that made them: recipe and
    # part id together in the first scan after the call, execute only once recipe_ack was back
    data = [(e.t, e.name, e.value) for e in controller.seen if e.name != "command_word"]
    assert data == [(pytest.approx(T0 + SCAN_S, abs=EPS), "recipe_select", 5),
                    (pytest.approx(T0 + SCAN_S, abs=EPS), "part_id", 0xDEAD_BEEF)]
    [t_execute] = controller.edges("execute")
    assert t_execute >= T0 + 2 * SCAN_S - EPS
    # acknowledged, execute dropped: ready for the next part
    sim.wait_scans(2)
    assert not any(link.read_bits("command_word").values())
    assert not sim.status()["done"] and sim.status()["ready"]
    r2 = sim.run_cycle(recipe=5, part_id=2)
    assert (r2["part_id_echo"], r2["cycle_count"]) == (2, 2)
    assert sim.write_errors == [] and link.rejected_writes == 0 and sim.link_errors == 0


def test_error_cycle_returns_the_fault_code(sim, controller):
    controller.fault_code = 42
    r = sim.run_cycle(recipe=1, part_id=9)
    assert (r["done"], r["error"], r["fault_code"], r["part_id_echo"]) == (0, 1, 42, 9)
    assert bits(sim.inputs())["error"]   # acknowledge does not clear it
    sim.wait_scans(5)
    assert bits(sim.inputs())["error"]   # nor does time
    sim.reset()
    assert not bits(sim.inputs())["error"] and sim.inputs()["fault_code"] == 0
    assert len(controller.edges("reset")) == 1


def test_abort_while_busy_ends_the_cycle_as_aborted(sim, controller, clock):
    controller.hold = True
    out: dict = {}

    def cycle() -> None:
        try:
            out.update(sim.run_cycle(recipe=2, part_id=5))
        except BaseException as exc:   # noqa: BLE001 -- asserted below
            out["raised"] = exc

    task = clock.spawn(cycle, CYCLE_TASK)
    try:
        sim.wait_until(lambda i: bits(i)["busy"], 5, "busy")
        t_busy = clock.now()
        sim.wait_scans(10)
        assert bits(sim.inputs())["busy"] and not task.finished   # held: stays busy
        sim.set_command(abort=True)
        t_abort = clock.now()
        assert task.join(timeout=20 * SCAN_S), "run_cycle did not return after the abort"
    finally:
        controller.hold = False          # lets a cycle still running end, whatever failed
        task.join(timeout=5)
    sim.set_command(abort=False)
    assert "raised" not in out, out.get("raised")
    assert (out["aborted"], out["done"], out["error"]) == (1, 0, 0)
    assert controller.cycles == 0
    assert t_busy < t_abort
    # the abort bit went out with the very next scan
    assert controller.edges("abort") == [pytest.approx(t_abort + SCAN_S, abs=EPS)]


def test_plc_writes_are_register_map_writes_seen_by_the_controller(link, clock):
    # no controller here: only look at what arrives at the server
    with SimPlc("127.0.0.1", link.port, scan_s=SCAN_S, clock=clock) as sim:
        assert link.last_heartbeat_change is None       # start() only reads
        sim.select_recipe(3)
        sim.set_part_id(70_000)
        sim.set_command(execute=True)
        sim.wait_scans(2)
        assert clock.now() == pytest.approx(T0 + SCAN_S, abs=EPS)   # scans at T0 and T0 + scan
        events = link.drain_writes()
        # the first scan (at T0, no time passed in its requests) wrote them, data before command
        assert [(e.t, e.name, e.value, e.previous) for e in events] == [
            (T0, "recipe_select", 3, 0), (T0, "part_id", 70_000, 0), (T0, "command_word", 1, 0)]
        assert link.read("plc_heartbeat") == 2                       # one increment per scan
        assert link.last_heartbeat_change == clock.now()             # stamped by the last scan
        sim.wait_scans(3)
        assert link.drain_writes() == []                             # unchanged outputs: no writes
        assert link.read("plc_heartbeat") == 5


def test_on_the_simulated_clock_a_scan_is_a_clock_callback_not_a_thread(link, clock):
    # a scan run by whichever thread runs the agenda costs no thread switch of its own
    sim = SimPlc("127.0.0.1", link.port, scan_s=SCAN_S, clock=clock)
    sim.start()
    try:
        sim.wait_scans(3)
        assert "sim-plc-scan" not in {t.name for t in threading.enumerate()}
        assert link.read("plc_heartbeat") == 3
    finally:
        sim.stop()
    clock.sleep(5 * SCAN_S)                   # stopped: no scan comes any more
    assert sim.scans == 3 and link.read("plc_heartbeat") == 3


def test_scans_run_every_scan_s_of_clock_time(link, clock):
    scan_s = 0.025                   # not a multiple of anything else running here
    with SimPlc("127.0.0.1", link.port, scan_s=scan_s, clock=clock) as sim:
        sim.wait_scans(1)                                            # the first scan, at once
        assert clock.now() == T0 and sim.scans == 1
        stamps = []
        for _ in range(5):
            sim.wait_scans(1)
            stamps.append(link.last_heartbeat_change)
            assert stamps[-1] == clock.now()
        assert stamps == pytest.approx([T0 + k * scan_s for k in range(1, 6)], abs=EPS)
        t = clock.now()
        sim.wait_scans(4)
        assert clock.now() - t == pytest.approx(4 * scan_s, abs=EPS)
        assert sim.scans == 10 and link.read("plc_heartbeat") == 10
        # the time-out of a wait is in clock seconds too
        t = clock.now()
        with pytest.raises(SimPlcError, match=r"10 scans did not complete within 0\.09 s"):
            sim.wait_scans(10, timeout_s=0.09)
        assert clock.now() - t == pytest.approx(0.09, abs=EPS)
        assert sim.scans == 13                     # 0.09 s = 3.6 scans


def test_heartbeat_pause_and_resume(sim, link, clock):
    hb = link.read("plc_heartbeat")
    assert link.last_heartbeat_change == T0                          # the fixture's scan
    sim.wait_scans(3)
    assert clock.now() == pytest.approx(T0 + 3 * SCAN_S, abs=EPS)
    assert link.read("plc_heartbeat") == hb + 3
    assert link.last_heartbeat_change == clock.now()
    # no scan is in flight while the test runs: the very next scan no longer writes it
    sim.pause_heartbeat()
    t_pause, frozen = clock.now(), link.read("plc_heartbeat")
    sim.wait_scans(1)
    assert link.read("plc_heartbeat") == frozen and link.last_heartbeat_change == t_pause
    t, scans = clock.now(), sim.scans
    clock.sleep(5.0)                                                 # 5 simulated seconds
    assert clock.now() == pytest.approx(t + 5.0, abs=EPS)
    assert abs(sim.scans - scans - 5.0 / SCAN_S) <= 1                # still scanning all along
    assert link.read("plc_heartbeat") == frozen and sim.inputs()["plc_heartbeat"] == frozen
    assert link.last_heartbeat_change == t_pause
    sim.resume_heartbeat()
    t_resume = clock.now()
    sim.wait_scans(1)
    assert link.read("plc_heartbeat") == (frozen + 1) & 0xFFFF
    assert link.last_heartbeat_change == clock.now()
    assert t_resume <= clock.now() <= t_resume + SCAN_S + EPS


def test_refused_write_is_reported_and_changes_nothing(sim, link, clock):
    t = clock.now()
    with pytest.raises(SimPlcError, match=r"refused recipe_select = 1000 \(Modbus exception 03\)"):
        sim.run_cycle(recipe=1000, part_id=1, timeout_s=5)
    assert clock.now() - t <= SCAN_S + EPS          # reported by the scan that was refused
    assert sim.write_errors == [("recipe_select", 1000, 3)] and link.rejected_writes == 1
    assert link.read("recipe_select") == 0 and link.read("command_word") == 0
    sim.wait_scans(3)
    assert link.rejected_writes == 1                # a refused value is not retried


def test_unknown_recipe_is_reported_with_recipe_status_then_a_good_one_works(sim, link, clock,
                                                                             controller):
    t = clock.now()
    with pytest.raises(SimPlcError, match="recipe 7 not active: recipe_status 1"):
        sim.run_cycle(recipe=7, part_id=1)
    assert clock.now() - t <= 3 * SCAN_S + EPS      # at the read-back, not after the time-out
    assert link.read("recipe_status") == 1 and link.read("command_word") == 0
    # the stale status 1 must not be mistaken for a refusal of the next recipe
    assert sim.run_cycle(recipe=2, part_id=3)["recipe_ack"] == 2
    with pytest.raises(SimPlcError, match="recipe 8 not active: recipe_status 1"):
        sim.run_cycle(recipe=8, part_id=1)
    t = clock.now()
    with pytest.raises(SimPlcError, match="waiting for recipe_ack and part_id read-back.*; recipe_status 1"):
        sim.run_cycle(recipe=9, part_id=1, timeout_s=0.1)   # same code again: only a timeout tells
    assert clock.now() - t == pytest.approx(0.1, abs=EPS)     # the first step's time-out, exactly
    assert controller.cycles == 1 and len(controller.edges("execute")) == 1


def test_not_ready_means_no_execute(link, clock):
    with SimPlc("127.0.0.1", link.port, scan_s=SCAN_S, clock=clock) as sim:
        link.write_many({"recipe_ack": 0, "recipe_status": 0})
        t = clock.now()
        with pytest.raises(SimPlcError, match="waiting for ready"):
            sim.run_cycle(recipe=0, part_id=1, timeout_s=0.1)
        assert abs(clock.now() - t - 0.1) <= SCAN_S + EPS      # 0.1 s, ± the read-back scan
        sim.wait_scans(2)
        # not even a pulse of execute went out: the part id, and execute low (the first scan's
        # start-up write, after the data as always)
        assert [(e.name, e.value) for e in link.drain_writes()] == [("part_id", 1), ("command_word", 0)]
        assert link.read("command_word") == 0


def test_timeout_without_controller_drops_execute(link, clock):
    with SimPlc("127.0.0.1", link.port, scan_s=SCAN_S, clock=clock) as sim:
        link.write_many({"recipe_ack": 0, "recipe_status": 0,
                         "status_word": PLC_MAP.with_bits("status_word", 0, {"ready": True})})
        t = clock.now()
        with pytest.raises(SimPlcError, match="waiting for done, error or aborted"):
            sim.run_cycle(recipe=0, part_id=1, timeout_s=0.1)
        t_raised = clock.now()
        assert abs(t_raised - t - 0.1) <= 2 * SCAN_S + EPS     # 0.1 s after the read-back
        sim.wait_scans(1)                                      # the next scan drops execute
        assert link.read("command_word") == 0
        execute = [(e.t, e.value) for e in link.drain_writes() if e.name == "command_word"][1:]
        assert [v for _, v in execute] == [1, 0]                # after the start-up execute low
        (t_up, _), (t_down, _) = execute
        assert abs(t_down - t_up - 0.1) <= SCAN_S + EPS         # held for the time-out, ± a scan
        assert t_raised <= t_down + EPS and t_down <= t_raised + SCAN_S + EPS


def test_start_refuses_a_map_version_mismatch(link, clock):
    other = RegisterMap(REGISTERS, size=PLC_MAP.size, version=PLC_MAP.version + 1)
    sim = SimPlc("127.0.0.1", link.port, register_map=other, clock=clock)
    with pytest.raises(SimPlcError, match=f"server map_version {PLC_MAP.version}, PLC program expects"):
        sim.start()
    sim.stop()
    assert link.drain_writes() == [] and link.last_heartbeat_change is None   # no scan ran
    assert clock.now() == T0


def test_start_refuses_when_nobody_listens(clock):
    dead = PlcLink(clock=clock)
    port = dead.start()
    dead.stop()
    sim = SimPlc("127.0.0.1", port, timeout_s=0.5, clock=clock)
    with pytest.raises(SimPlcError, match=f"cannot connect to 127.0.0.1:{port}"):
        sim.start()
    sim.stop()


@pytest.mark.parametrize("scan_s, shown", [(0, "0"), (-0.5, "-0.5"), (math.nan, "nan")])
def test_bad_arguments_are_refused_and_name_the_value(scan_s, shown):
    with pytest.raises(SimPlcError, match=f"scan_s = {shown} must be > 0"):
        SimPlc("127.0.0.1", 1, scan_s=scan_s)
    sim = SimPlc("127.0.0.1", 1)
    with pytest.raises(PlcMapError, match="no bit named 'go'"):
        sim.set_command(go=True)


def test_a_bad_answer_is_a_link_error_and_the_next_request_reconnects(clock):
    """A server answering one scan's FC23 with a stale transaction id: that scan is a link
    error, the connection is dropped, and the scan's writes (all outputs, as after any link
    error) go out on a new connection."""
    stale = [True]

    def reply(request: bytes) -> list:
        if request[7] not in (3, 23):
            return good(request)
        n = struct.unpack_from(">H", request, 10)[0]
        pdu = struct.pack(f">BB{n}H", request[7], 2 * n, PLC_MAP.version, *[0] * (n - 1))
        if request[7] == 23 and stale:
            stale.clear()
            return [answer(request, pdu, tid=0)]
        return [answer(request, pdu)]

    fake = FakeServer(reply)
    sim = SimPlc("127.0.0.1", fake.port, scan_s=SCAN_S, clock=clock)
    try:
        sim.start()
        sim.wait_scans(2)
    finally:
        sim.stop()
        fake.close()
    assert sim.link_errors == 1 and fake.connections == 2
    fcs = [r[7] for r in fake.requests]
    assert fcs[:6] == [3, 23, 6, 16, 6, 6]   # start, the stale scan, then every output again


@pytest.mark.parametrize("names", [("done", "error", "aborted"), ("done", "aborted"), ("ready",), ("error",)])
def test_status_predicates_read_the_named_bits_as_the_bit_table_does(names):
    """The handshake's waits test status_word with one mask: the same answer as the map's
    named bits, for every word (a mask off by a bit would wait for the wrong state)."""
    plc = SimPlc("127.0.0.1", 1, clock=VirtualClock())   # never started: no connection
    pred = plc._any_status(*names)
    for word in range(1 << 16):
        named = PLC_MAP.bits("status_word", word)
        assert pred({"status_word": word}) is any(named[k] for k in names), (names, hex(word))
