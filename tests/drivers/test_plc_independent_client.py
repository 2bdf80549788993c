"""Clients nobody here wrote must work against PlcLink: pyModbusTCP always, and mbpoll
(Debian's ``mbpoll``; without it its tests skip, and fail under ``CI=true``: tests/tools.py).

Both count addresses their own way (pyModbusTCP: 0-based protocol addresses; mbpoll:
1-based references unless ``-0``), which checks the map's documented address base too.
"""
from __future__ import annotations

import subprocess

import pytest
from pyModbusTCP.client import ModbusClient

from drivers.plc.register_map import PLC_MAP
from tests.tools import require_tool

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")


@pytest.fixture
def client(link):
    c = ModbusClient(host="127.0.0.1", port=link.port, unit_id=1, timeout=5.0, auto_open=True)
    yield c
    c.close()


def test_pymodbustcp_reads_the_map(link, client):
    link.write_many({"part_id_echo": 0xCAFE0001, "recipe_ack": 12, "state_code": 4})
    link.set_bits("status_word", ready=True, auto=True)
    regs = client.read_holding_registers(0, PLC_MAP.size)
    assert regs is not None, client.last_error_as_txt
    values = PLC_MAP.decode_image(regs)
    assert values == link.snapshot()
    assert values["map_version"] == PLC_MAP.version and values["part_id_echo"] == 0xCAFE0001
    assert client.read_discrete_inputs(16 * 10, 5) == [True, False, False, False, True]


def test_pymodbustcp_writes_a_command_and_a_part_id(link, client):
    assert client.write_single_register(1, 1)                          # heartbeat: owner
    assert client.write_multiple_registers(24, [0x0001, 0x86A0])       # part_id 100000
    assert client.write_single_register(11, 0b0001)                    # execute
    assert client.write_single_coil(16 * 11 + 3, True)                 # acknowledge
    assert link.read("part_id") == 100_000
    events = link.drain_writes()
    assert [(e.name, e.value) for e in events] == [("part_id", 100_000), ("command_word", 1),
                                                   ("command_word", 0b1001)]


@pytest.mark.parametrize("write, code", [
    (lambda c: c.write_single_register(0, 2), 2),            # RO
    (lambda c: c.write_single_register(20, 1000), 3),        # out of range
    (lambda c: c.write_multiple_registers(20, [1, 2]), 2),   # runs into RO recipe_ack
])
def test_pymodbustcp_sees_the_exception_codes(link, client, write, code):
    before = link.snapshot()
    assert not write(client)
    assert client.last_except == code
    assert link.snapshot() == before


def _mbpoll(port: int, *args: str) -> subprocess.CompletedProcess:
    mbpoll = require_tool("mbpoll", package="mbpoll")
    return subprocess.run([mbpoll, "-m", "tcp", "-p", str(port), "-1", "-o", "5", *args],
                          capture_output=True, text=True, timeout=30)


def test_mbpoll_reads_with_1_based_references(link):
    link.write("part_id_echo", 0x12345678)
    out = _mbpoll(link.port, "-r", "1", "-c", "3", "127.0.0.1")
    assert out.returncode == 0, out.stderr
    # reference 1 = address 0 = map_version
    assert f"[1]: \t{PLC_MAP.version}" in out.stdout
    ref = PLC_MAP["part_id_echo"].modicon - 40000
    out = _mbpoll(link.port, "-t", "4:int", "-B", "-r", str(ref), "127.0.0.1")
    assert out.returncode == 0, out.stderr
    assert f"[{ref}]: \t{0x12345678}" in out.stdout           # high word first = mbpoll -B


def test_mbpoll_writes_rw_and_is_refused_ro(link):
    # one writer: a write before any client owns the link is refused with exception 01
    select = str(PLC_MAP["recipe_select"].modicon - 40000)
    out = _mbpoll(link.port, "-r", select, "127.0.0.1", "7")
    assert out.returncode != 0 and "Illegal function" in out.stdout + out.stderr
    assert link.read("recipe_select") == 0
    # the heartbeat (RW) is the write that takes the link: mbpoll's is accepted
    out = _mbpoll(link.port, "-r", str(PLC_MAP["plc_heartbeat"].modicon - 40000), "127.0.0.1", "5")
    assert out.returncode == 0, out.stderr
    assert link.read("plc_heartbeat") == 5
    assert link.owner is not None and link.owner.startswith("127.0.0.1:")
    # RO: map_version is refused with exception 02 whoever asks
    out = _mbpoll(link.port, "-r", "1", "127.0.0.1", "7")
    assert out.returncode != 0 and "Illegal data address" in out.stdout + out.stderr
    assert link.read("map_version") == PLC_MAP.version
