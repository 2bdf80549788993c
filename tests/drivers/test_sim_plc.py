"""SimPlc (the PLC twin, a real Modbus TCP client) against PlcLink (a real server).

The controller side of the handshake is played here by ``ControllerStandIn``, a thread that
uses nothing but PlcLink's public accessors, as the cell loop will.
"""
from __future__ import annotations

import threading

import pytest

from cell.clock import ManualClock
from drivers.plc.register_map import PLC_MAP, REGISTERS, PlcMapError, RegisterMap
from drivers.plc.server import PlcLink
from cell.sim.plc import RESULTS, SimPlc, SimPlcError

SCAN_S = 0.002
RESULT = {"initial_error_um": 1234, "final_error_um": 17, "moves": 3, "cycle_time_ms": 2500}

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")


class ControllerStandIn(threading.Thread):
    """The controller's half of the handshake, through PlcLink only.

    Known recipes are accepted into recipe_ack; an execute rising edge latches part_id and
    finishes at once with ``RESULT`` (or error + ``fault_code`` if set), unless ``hold`` is
    set, in which case the cycle stays busy until an abort edge or ``hold`` is cleared.
    """

    def __init__(self, link: PlcLink, recipes=(1, 2, 5)):
        super().__init__(name="controller-stand-in")
        self.link, self.recipes = link, set(recipes)
        self.fault_code = 0
        self.hold = threading.Event()
        self._quit = threading.Event()
        self._busy_part: int | None = None
        self.cycles = 0

    def stop(self) -> None:
        self._quit.set()
        self.join()

    def _status(self, **flags: bool) -> int:
        return PLC_MAP.with_bits("status_word", self.link.read("status_word"), flags)

    def run(self) -> None:
        link = self.link
        link.write("status_word", self._status(ready=True, auto=True, homed=True, plc_link_ok=True))
        while not self._quit.is_set():
            ev = link.next_write(timeout=0.01)
            if self._busy_part is not None and not self.hold.is_set():
                self._finish()
            if ev is None:
                continue
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
                    if not self.hold.is_set():
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
    return ManualClock(0.0)


@pytest.fixture
def link(clock):
    link = PlcLink(clock=clock)
    link.start()
    yield link
    link.stop()


@pytest.fixture
def controller(link):
    c = ControllerStandIn(link)
    c.start()
    yield c
    c.stop()


@pytest.fixture
def sim(link, controller):
    sim = SimPlc("127.0.0.1", link.port, scan_s=SCAN_S)
    sim.start()
    yield sim
    sim.stop()


def test_run_cycle_follows_the_handshake_and_returns_results(sim, link, controller):
    r = sim.run_cycle(recipe=5, part_id=0xDEAD_BEEF)
    assert {k: r[k] for k in RESULT} == RESULT
    assert (r["part_id_echo"], r["recipe_ack"], r["recipe_status"]) == (0xDEAD_BEEF, 5, 0)
    assert (r["done"], r["error"], r["aborted"], r["fault_code"], r["cycle_count"]) == (1, 0, 0, 0, 1)
    assert set(RESULTS) <= set(r)
    # acknowledged, execute dropped: ready for the next part
    sim.wait_scans(2)
    assert not any(link.read_bits("command_word").values())
    assert not sim.status()["done"] and sim.status()["ready"]
    r2 = sim.run_cycle(recipe=5, part_id=2)
    assert (r2["part_id_echo"], r2["cycle_count"]) == (2, 2)
    assert sim.write_errors == []


def test_error_cycle_returns_the_fault_code(sim, controller):
    controller.fault_code = 42
    r = sim.run_cycle(recipe=1, part_id=9)
    assert (r["done"], r["error"], r["fault_code"], r["part_id_echo"]) == (0, 1, 42, 9)
    assert PLC_MAP.bits("status_word", sim.inputs()["status_word"])["error"]   # ack does not clear it
    sim.reset()
    assert not PLC_MAP.bits("status_word", sim.inputs()["status_word"])["error"]


def test_abort_while_busy_ends_the_cycle_as_aborted(sim, controller):
    controller.hold.set()
    out: dict = {}
    t = threading.Thread(target=lambda: out.update(sim.run_cycle(recipe=2, part_id=5)))
    t.start()
    sim.wait_until(lambda i: PLC_MAP.bits("status_word", i["status_word"])["busy"], 5, "busy")
    sim.set_command(abort=True)
    t.join(timeout=10)
    sim.set_command(abort=False)
    assert (out["aborted"], out["done"], out["error"]) == (1, 0, 0)


def test_plc_writes_are_register_map_writes_seen_by_the_controller(link, clock):
    # no controller here: only look at what arrives at the server
    with SimPlc("127.0.0.1", link.port, scan_s=SCAN_S) as sim:
        sim.select_recipe(3)
        sim.set_part_id(70_000)
        sim.set_command(execute=True)
        sim.wait_scans(2)
        events = link.drain_writes()
    assert [(e.name, e.value) for e in events] == [
        ("recipe_select", 3), ("part_id", 70_000), ("command_word", 1)]   # data before command
    assert link.read("plc_heartbeat") > 0 and link.last_heartbeat_change == 0.0


def test_heartbeat_pause_and_resume(sim, link, clock):
    sim.wait_scans(2)
    assert link.last_heartbeat_change == 0.0
    sim.pause_heartbeat()
    sim.wait_scans(2)                      # the scan running at pause() may still write once
    clock.advance(5.0)
    frozen = link.read("plc_heartbeat")
    sim.wait_scans(3)
    assert link.read("plc_heartbeat") == frozen and link.last_heartbeat_change == 0.0
    sim.resume_heartbeat()
    sim.wait_scans(2)
    assert link.read("plc_heartbeat") != frozen and link.last_heartbeat_change == 5.0


def test_refused_write_is_reported_and_changes_nothing(sim, link):
    with pytest.raises(SimPlcError, match=r"refused recipe_select = 1000 \(Modbus exception 03\)"):
        sim.run_cycle(recipe=1000, part_id=1, timeout_s=5)
    assert sim.write_errors == [("recipe_select", 1000, 3)]
    assert link.read("recipe_select") == 0 and link.read("command_word") == 0


def test_unknown_recipe_is_reported_with_recipe_status_then_a_good_one_works(sim, link):
    with pytest.raises(SimPlcError, match="recipe 7 not active: recipe_status 1"):
        sim.run_cycle(recipe=7, part_id=1)
    assert link.read("recipe_status") == 1 and link.read("command_word") == 0
    # the stale status 1 must not be mistaken for a refusal of the next recipe
    assert sim.run_cycle(recipe=2, part_id=3)["recipe_ack"] == 2
    with pytest.raises(SimPlcError, match="recipe 8 not active: recipe_status 1"):
        sim.run_cycle(recipe=8, part_id=1)
    with pytest.raises(SimPlcError, match="waiting for recipe_ack and part_id read-back.*; recipe_status 1"):
        sim.run_cycle(recipe=9, part_id=1, timeout_s=0.1)   # same code again: only a timeout tells


def test_not_ready_means_no_execute(link):
    with SimPlc("127.0.0.1", link.port, scan_s=SCAN_S) as sim:
        link.write_many({"recipe_ack": 0, "recipe_status": 0})
        with pytest.raises(SimPlcError, match="waiting for ready"):
            sim.run_cycle(recipe=0, part_id=1, timeout_s=0.1)
        assert link.read("command_word") == 0


def test_timeout_without_controller_drops_execute(link):
    with SimPlc("127.0.0.1", link.port, scan_s=SCAN_S) as sim:
        link.write_many({"recipe_ack": 0, "recipe_status": 0,
                         "status_word": PLC_MAP.with_bits("status_word", 0, {"ready": True})})
        with pytest.raises(SimPlcError, match="waiting for done, error or aborted"):
            sim.run_cycle(recipe=0, part_id=1, timeout_s=0.1)
        sim.wait_scans(2)
        assert link.read("command_word") == 0


def test_start_refuses_a_map_version_mismatch(link):
    other = RegisterMap(REGISTERS, size=PLC_MAP.size, version=PLC_MAP.version + 1)
    sim = SimPlc("127.0.0.1", link.port, register_map=other)
    with pytest.raises(SimPlcError, match=f"server map_version {PLC_MAP.version}, PLC program expects"):
        sim.start()
    sim.stop()


def test_start_refuses_when_nobody_listens():
    dead = PlcLink()
    port = dead.start()
    dead.stop()
    sim = SimPlc("127.0.0.1", port, timeout_s=0.5)
    with pytest.raises(SimPlcError, match=f"cannot connect to 127.0.0.1:{port}"):
        sim.start()
    sim.stop()


def test_bad_arguments_are_refused_and_name_the_value():
    with pytest.raises(SimPlcError, match="scan_s = 0 must be > 0"):
        SimPlc("127.0.0.1", 1, scan_s=0)
    sim = SimPlc("127.0.0.1", 1)
    with pytest.raises(PlcMapError, match="no bit named 'go'"):
        sim.set_command(go=True)
