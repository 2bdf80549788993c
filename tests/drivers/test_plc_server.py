"""PlcLink: controller accessors, PLC write events, and every refused PLC write.

Contract tests: the ``link`` fixture is parametrised over every backend in
``drivers.plc.BACKENDS``; each runs a real server on a loopback port and real clients.
"""
from __future__ import annotations

import threading

import pytest
from pydantic import ValidationError
from pymodbus.client import ModbusTcpClient

from cell.clock import ManualClock
from cell.errors import CellError, ConfigError
from drivers.plc import BACKENDS, PlcConfig, open_link
from drivers.plc.register_map import PLC_MAP, Access, PlcMapError, Register, RegisterMap, RegType
from drivers.plc.server import PlcLink, PlcLinkError

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")


@pytest.fixture(params=sorted(BACKENDS))
def link(request):
    link = open_link(request.param, clock=ManualClock(100.0))
    link.start()
    yield link
    link.stop()


@pytest.fixture
def plc(link):
    client = ModbusTcpClient("127.0.0.1", port=link.port, timeout=2, retries=0)
    assert client.connect()
    yield client
    client.close()


def _exc_code(rr) -> int:
    assert rr.isError(), rr
    return rr.exception_code


# ---------------------------------------------------------------- reads
def test_plc_reads_the_whole_map_in_one_request(link, plc):
    rr = plc.read_holding_registers(0, count=PLC_MAP.size)
    assert not rr.isError()
    values = PLC_MAP.decode_image(rr.registers)
    assert values == link.snapshot()
    assert values["map_version"] == PLC_MAP.version
    assert rr.registers[5] == 0   # reserved reads 0


@pytest.mark.parametrize("address, count", [(PLC_MAP.size, 1), (PLC_MAP.size - 2, 4), (1000, 1)])
def test_read_beyond_the_map_is_illegal_data_address(plc, address, count):
    assert _exc_code(plc.read_holding_registers(address, count=count)) == 2


def test_controller_writes_are_what_the_plc_reads_u32_high_word_first(link, plc):
    link.write_many({"part_id_echo": 0x12345678, "recipe_ack": 7, "state_code": 3})
    rr = plc.read_holding_registers(26, count=2)
    assert rr.registers == [0x1234, 0x5678]
    assert link.read("part_id_echo") == 0x12345678
    assert plc.read_holding_registers(21, count=1).registers == [7]


def test_status_bits_are_discrete_inputs_and_coils_at_16r_plus_n(link, plc):
    link.set_bits("status_word", ready=True, done=True, plc_link_ok=True)
    assert link.read_bits("status_word")["done"] and link.read("status_word") == 0b1_0000_0101
    bits = plc.read_discrete_inputs(16 * 10, count=9).bits[:9]
    assert bits == [True, False, True, False, False, False, False, False, True]
    assert plc.read_coils(16 * 10, count=3).bits[:3] == [True, False, True]


# ---------------------------------------------------------------- PLC writes -> events
def test_plc_writes_land_in_the_image_and_as_events(link, plc):
    assert not plc.write_register(1, 1).isError()      # the heartbeat makes this client the owner
    assert not plc.write_register(20, 42).isError()
    assert not plc.write_registers(24, [0x0001, 0x0002]).isError()
    assert not plc.write_register(11, 0b0001).isError()
    assert link.read("recipe_select") == 42 and link.read("part_id") == 0x10002
    events = link.drain_writes()
    assert [(e.name, e.value, e.previous, e.t) for e in events] == [
        ("recipe_select", 42, 0, 100.0), ("part_id", 0x10002, 0, 100.0), ("command_word", 1, 0, 100.0)]
    assert link.drain_writes() == [] and link.next_write(timeout=0.0) is None


def test_a_value_written_again_is_an_event_and_leaves_the_image_and_heartbeat_time(link, plc):
    """Only registers whose value changed are written into the image, but every register a
    PLC writes is an event (the same value again included), and the heartbeat's change time
    moves only when its value does."""
    clock = link._clock
    assert not plc.write_register(1, 7).isError()
    assert link.last_heartbeat_change == 100.0
    clock.advance(0.5)
    assert not plc.write_register(1, 7).isError()                   # the same heartbeat
    assert link.last_heartbeat_change == 100.0
    for _ in range(2):
        assert not plc.write_registers(24, [0x0001, 0x0002]).isError()
    assert link.read("part_id") == 0x10002 and link.read("plc_heartbeat") == 7
    assert [(e.name, e.value, e.previous) for e in link.drain_writes()] == [
        ("part_id", 0x10002, 0), ("part_id", 0x10002, 0x10002)]
    rr = plc.write_registers(24, [0, 9, 5])                         # part_id_echo is read-only
    assert rr.isError() and rr.exception_code == 2 and link.read("part_id") == 0x10002


def test_coil_write_sets_a_command_bit_with_previous_value(link, plc):
    assert not plc.write_register(1, 1).isError()      # owner
    assert not plc.write_coil(16 * 11 + 3, True).isError()      # acknowledge
    assert not plc.write_coil(16 * 11 + 0, True).isError()      # execute
    e1, e2 = link.next_write(timeout=5), link.next_write(timeout=5)
    assert (e1.name, e1.value, e1.previous) == ("command_word", 0b1000, 0)
    assert (e2.value, e2.previous) == (0b1001, 0b1000)
    assert link.read_bits("command_word") == {"execute": True, "reset": False, "abort": False,
                                              "acknowledge": True, "calibrate": False}


def test_read_write_multiple_fc23(link, plc):
    assert not plc.write_register(1, 1).isError()      # owner
    rr = plc.readwrite_registers(read_address=20, read_count=2, write_address=20, values=[9])
    assert rr.registers == [9, 0]
    assert link.read("recipe_select") == 9


def test_heartbeat_is_quiet_but_timed_only_when_it_changes(link, plc):
    clock = link._clock   # the ManualClock the fixture injected
    assert link.last_heartbeat_change is None
    plc.write_register(1, 5)
    assert link.last_heartbeat_change == 100.0
    clock.advance(2.0)
    plc.write_register(1, 5)                     # same value: no change
    assert link.last_heartbeat_change == 100.0
    plc.write_register(1, 6)
    assert link.last_heartbeat_change == 102.0
    assert link.drain_writes() == []             # heartbeat is not queued by default
    assert link.read("plc_heartbeat") == 6


# ---------------------------------------------------------------- refused PLC writes
BAD_WRITES = [
    # (label, request(client), exception code)
    ("RO map_version FC6", lambda c: c.write_register(0, 2), 2),
    ("RO status_word FC6", lambda c: c.write_register(10, 1), 2),
    ("RO recipe_ack FC16", lambda c: c.write_registers(21, [1]), 2),
    ("RO cycle_count FC16", lambda c: c.write_registers(48, [0, 1]), 2),
    ("reserved address", lambda c: c.write_register(5, 0), 2),
    ("beyond the map", lambda c: c.write_register(PLC_MAP.size, 0), 2),
    ("half of part_id (high)", lambda c: c.write_register(24, 1), 2),
    ("half of part_id (low)", lambda c: c.write_register(25, 1), 2),
    ("RW then RO in one FC16", lambda c: c.write_registers(20, [5, 7]), 2),
    ("part_id then RO echo", lambda c: c.write_registers(24, [1, 2, 3]), 2),
    ("recipe_select 1000", lambda c: c.write_register(20, 1000), 3),
    ("recipe_select 65535 FC16", lambda c: c.write_registers(20, [65535]), 3),
    ("undefined command bit", lambda c: c.write_register(11, 0x0020), 3),
    ("status bit coil (RO)", lambda c: c.write_coil(16 * 10, True), 2),
    ("coil of a u16 register", lambda c: c.write_coil(16 * 20, True), 2),
    ("coils incl. undefined bit", lambda c: c.write_coils(16 * 11, [True, False, False, False, False, True]), 3),
    ("calibration_select out of range", lambda c: c.write_register(60, 5), 3),
    ("FC23 write RO", lambda c: c.readwrite_registers(read_address=0, read_count=1, write_address=21,
                                                      values=[1]), 2),
]


@pytest.mark.parametrize("label, request_, code", BAD_WRITES, ids=[b[0] for b in BAD_WRITES])
def test_refused_plc_write_answers_the_code_and_changes_nothing(link, plc, label, request_, code):
    link.write_many({"recipe_select": 3, "part_id": 77, "command_word": 0b0100})
    before, image_before = link.snapshot(), plc.read_holding_registers(0, count=PLC_MAP.size).registers
    rejected = link.rejected_writes
    assert _exc_code(request_(plc)) == code, label
    assert link.snapshot() == before
    assert plc.read_holding_registers(0, count=PLC_MAP.size).registers == image_before
    assert link.drain_writes() == []
    assert link.rejected_writes == rejected + 1     # every refusal is decided (and counted) by the map


def test_multi_write_with_one_bad_value_changes_none():
    # two adjacent RW registers (the cell map has none), second value out of range
    regs = [Register(0, "map_version", RegType.U16, Access.RO),
            Register(1, "a", RegType.U16, Access.RW, hi=10),
            Register(2, "b", RegType.U16, Access.RW, hi=10)]
    with PlcLink(RegisterMap(regs, size=4, version=1)) as link:
        port = link.start()
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        try:
            assert client.connect()
            assert _exc_code(client.write_registers(1, [5, 11])) == 3
            assert (link.read("a"), link.read("b")) == (0, 0)
            assert link.drain_writes() == []
            assert not client.write_registers(1, [5, 10]).isError()
            assert (link.read("a"), link.read("b")) == (5, 10)
        finally:
            client.close()


# ---------------------------------------------------------------- controller-side bad input
def test_controller_bad_input_is_named_and_changes_nothing(link):
    link.write("recipe_ack", 5)
    before = link.snapshot()
    with pytest.raises(PlcMapError, match="no register named 'recpie_ack'"):
        link.write("recpie_ack", 1)
    with pytest.raises(PlcMapError, match="recipe_ack: value 1000 outside 0..999"):
        link.write("recipe_ack", 1000)
    with pytest.raises(PlcMapError, match="fault_code: value 70000"):
        link.write_many({"recipe_ack": 6, "fault_code": 70000})    # first value fine: still nothing
    with pytest.raises(PlcMapError, match="no bit named 'bussy'"):
        link.set_bits("status_word", ready=True, bussy=True)
    with pytest.raises(PlcMapError, match="no register named 'x'"):
        link.read("x")
    assert link.snapshot() == before
    assert isinstance(PlcMapError("x"), CellError)


def test_controller_may_write_ro_registers_and_u32_is_atomic_for_readers(link, plc):
    stop = threading.Event()

    def writer():   # hi word == lo word always; a torn read would break that
        k = 0
        while not stop.is_set():
            k = (k + 1) & 0xFFFF
            link.write("initial_error_um", k * 0x10001)

    t = threading.Thread(target=writer)
    t.start()
    try:
        for _ in range(200):
            hi, lo = plc.read_holding_registers(40, count=2).registers
            assert hi == lo
    finally:
        stop.set()
        t.join()


def test_event_queue_is_bounded_and_counts_drops():
    with PlcLink(max_events=3, clock=ManualClock(0.0)) as link:   # owner never times out here
        client = ModbusTcpClient("127.0.0.1", port=link.start(), timeout=2, retries=0)
        try:
            client.write_register(1, 1)                                  # heartbeat: owner
            for v in range(5):
                client.write_register(20, v)
        finally:
            client.close()
        assert [e.value for e in link.drain_writes()] == [2, 3, 4]
        assert link.dropped_writes == 2


# ---------------------------------------------------------------- lifecycle and config
def test_lifecycle_errors_and_no_leaked_thread(link):
    with pytest.raises(PlcLinkError, match="already running on port"):
        link.start()
    other = PlcLink()
    with pytest.raises(PlcLinkError, match=f"cannot listen on 127.0.0.1:{link.port}"):
        other.start(port=link.port)
    assert other.port is None
    link.stop()
    link.stop()   # idempotent
    assert link.port is None
    assert not [t for t in threading.enumerate() if t.name == "plc-modbus-server"]


def test_unknown_quiet_register_is_refused():
    with pytest.raises(PlcMapError, match="no register named 'heartbeat'"):
        PlcLink(quiet=("heartbeat",))


def test_backend_registry_and_config_validation():
    with pytest.raises(ConfigError, match="plc.backend: unknown backend 'profinet'"):
        open_link("profinet")
    assert PlcConfig().port == 502
    with pytest.raises(ValidationError, match="prot"):
        PlcConfig(prot=502)
    with pytest.raises(ValidationError, match="port"):
        PlcConfig(port=70000)
