"""The register map: one table, explicit address base, 32-bit pairs, generated documents."""
from __future__ import annotations

import argparse
import csv
import io

import pytest

from cell.commands import registers as registers_cmd
from drivers.plc.register_map import (
    MAP_VERSION, PLC_MAP, REGISTERS, Access, Bit, IllegalDataAddress, IllegalDataValue,
    PlcMapError, RecipeStatus, Register, RegisterMap, RegType,
)

# The registers the PLC programmer relies on: name -> (type, access)
REQUIRED = {
    "map_version": ("u16", "RO"), "plc_heartbeat": ("u16", "RW"),
    "controller_heartbeat": ("u16", "RO"), "status_word": ("bitfield", "RO"),
    "command_word": ("bitfield", "RW"), "state_code": ("u16", "RO"),
    "recipe_select": ("u16", "RW"), "recipe_ack": ("u16", "RO"), "recipe_status": ("u16", "RO"),
    "part_id": ("u32", "RW"), "part_id_echo": ("u32", "RO"), "fault_code": ("u16", "RO"),
    "initial_error_um": ("u32", "RO"), "final_error_um": ("u32", "RO"), "moves": ("u32", "RO"),
    "cycle_time_ms": ("u32", "RO"), "cycle_count": ("u32", "RO"),
    "calibration_select": ("u16", "RW"), "calibration_version": ("u16", "RO"),
    "calibration_residual_um": ("u32", "RO"), "calibration_residual_udeg": ("u32", "RO"),
    "plant_backlog": ("u32", "RO"),
}
STATUS_BITS = ["ready", "busy", "done", "error", "auto", "homed", "recalibration_due",
               "aborted", "plc_link_ok", "execute_refused"]
COMMAND_BITS = ["execute", "reset", "abort", "acknowledge", "calibrate"]


def test_map_has_the_required_registers_with_type_and_access():
    got = {r.name: (r.type.value, r.access.value) for r in PLC_MAP}
    assert got == REQUIRED
    assert [b.name for b in PLC_MAP["status_word"].bits] == STATUS_BITS
    assert [b.name for b in PLC_MAP["command_word"].bits] == COMMAND_BITS
    assert PLC_MAP["recipe_select"].range_text() == "0..999"


def test_no_two_registers_share_an_address_and_all_fit_the_map():
    used: dict[int, str] = {}
    for r in REGISTERS:
        for a in range(r.address, r.address + r.words):
            assert a not in used, f"{r.name} overlaps {used.get(a)} at {a}"
            assert 0 <= a < PLC_MAP.size
            used[a] = r.name
    assert len(used) == sum(r.words for r in REGISTERS)


def test_address_base_is_zero_based_protocol_with_modicon_alongside():
    assert PLC_MAP["map_version"].address == 0 and PLC_MAP["map_version"].modicon == 40001
    assert PLC_MAP["plc_heartbeat"].address == 1 and PLC_MAP["plc_heartbeat"].modicon == 40002
    md = PLC_MAP.to_markdown()
    assert "| 0 | 40001 | `map_version` |" in md
    assert "| 24-25 | 40025-40026 | `part_id` |" in md
    assert "40001 + address" in md


def test_u32_takes_two_words_high_word_first():
    for r in PLC_MAP:
        if r.type is RegType.U32:
            assert r.words == 2
            assert PLC_MAP.at(r.address) == (r, 0) and PLC_MAP.at(r.address + 1) == (r, 1)
    assert PLC_MAP.to_words("part_id", 0x12345678) == [0x1234, 0x5678]
    assert PLC_MAP.from_words("part_id", [0x1234, 0x5678]) == 0x12345678
    assert PLC_MAP.to_words("cycle_count", 2**32 - 1) == [0xFFFF, 0xFFFF]


def test_spare_addresses_are_left_between_blocks():
    reserved = PLC_MAP.reserved()
    assert (3, 3) in reserved and (6, 9) in reserved and (14, 19) in reserved and (28, 39) in reserved
    assert reserved[-1][1] == PLC_MAP.size - 1   # room at the end too
    assert PLC_MAP.at(7) is None
    assert PLC_MAP.version == MAP_VERSION


def test_markdown_lists_every_register_and_bit():
    md = PLC_MAP.to_markdown()
    for r in PLC_MAP:
        assert f"`{r.name}`" in md
        for b in r.bits:
            assert f"| {b.index} | {16 * r.address + b.index} | `{b.name}` |" in md
    assert "Execute" in md and "Busy" in md and "Done" in md   # the PLCopen handshake is documented


def test_the_plc_page_holds_the_whole_map_as_the_command_prints_it():
    """docs/plc.md shows the map's heading (with its version), reserved ranges, bit tables and
    handshake exactly as ``cellctl registers --format md`` prints them, not only its tables:
    a new register must not leave a stale version or reserved range on the page."""
    from pathlib import Path
    page = (Path(__file__).resolve().parents[2] / "docs" / "plc.md").read_text(encoding="utf-8")
    assert PLC_MAP.to_markdown().strip() in page, \
        "docs/plc.md differs from `cellctl registers --format md`: paste its output over the section"


def test_csv_has_one_row_per_register_and_bit():
    rows = list(csv.DictReader(io.StringIO(PLC_MAP.to_csv())))
    names = [row["name"] for row in rows]
    assert names[:3] == ["map_version", "plc_heartbeat", "controller_heartbeat"]
    for r in PLC_MAP:
        assert r.name in names
        for b in r.bits:
            assert f"{r.name}.{b.name}" in names
    assert len(rows) == len(PLC_MAP) + sum(len(r.bits) for r in PLC_MAP)
    part = next(row for row in rows if row["name"] == "part_id")
    assert (part["address"], part["modicon"], part["words"], part["access"]) == ("24", "40025-40026", "2", "RW")


@pytest.mark.parametrize("regs, size, message", [
    ([Register(0, "a", RegType.U32, Access.RO), Register(1, "b", RegType.U16, Access.RO)], 4,
     "b overlaps a at address 1"),
    ([Register(0, "a", RegType.U16, Access.RO), Register(1, "a", RegType.U16, Access.RO)], 4,
     "name 'a' used twice"),
    ([Register(3, "a", RegType.U32, Access.RO)], 4, "outside 0..3"),
    ([Register(0, "a", RegType.BITFIELD, Access.RW)], 4, "bits are given iff type is bitfield"),
    ([Register(0, "a", RegType.BITFIELD, Access.RW, bits=(Bit(16, "x", ""),))], 4, "0..15"),
])
def test_bad_map_is_refused_with_the_reason(regs, size, message):
    with pytest.raises(PlcMapError, match=message):
        RegisterMap(regs, size=size, version=1)


def test_value_checks_name_register_and_range():
    with pytest.raises(PlcMapError, match="no register named 'nope'"):
        PLC_MAP.check("nope", 1)
    with pytest.raises(PlcMapError, match=r"recipe_select: value 1000 outside 0\.\.999"):
        PLC_MAP.check("recipe_select", 1000)
    with pytest.raises(PlcMapError, match="not an integer"):
        PLC_MAP.check("recipe_select", True)
    with pytest.raises(PlcMapError, match="command_word: value 32 outside mask 0x001F"):
        PLC_MAP.to_words("command_word", 32)
    with pytest.raises(PlcMapError, match="part_id: value -1"):
        PLC_MAP.to_words("part_id", -1)
    with pytest.raises(PlcMapError, match="no bit named 'go'"):
        PLC_MAP.with_bits("command_word", 0, {"go": True})
    with pytest.raises(PlcMapError, match="not a bit field"):
        PLC_MAP.bits("recipe_select", 0)


def test_bits_round_trip():
    v = PLC_MAP.with_bits("status_word", 0, {"ready": True, "plc_link_ok": True})
    assert v == 0x0101
    assert PLC_MAP.bits("status_word", v)["plc_link_ok"] and not PLC_MAP.bits("status_word", v)["busy"]
    assert PLC_MAP.with_bits("status_word", v, {"ready": False}) == 0x0100


def test_masks_and_recipe_statuses_are_the_maps():
    # the PLC's contract (docs: command_word bits 0..4, recipe_status 0..3), and the
    # controller takes its constants from the map, not from numbers of its own
    from cell.controller import core
    assert PLC_MAP.mask("command_word", "execute") == 1 and PLC_MAP.mask("command_word") == 0
    assert PLC_MAP.mask("command_word", "reset", "acknowledge") == 0b1010
    assert (core.EXECUTE, core.RESET, core.ABORT, core.ACK, core.CALIBRATE) == (1, 2, 4, 8, 16)
    with pytest.raises(PlcMapError, match="command_word: no bit named 'start'"):
        PLC_MAP.mask("command_word", "start")
    meaning = PLC_MAP["recipe_status"].meaning
    for status, words in ((RecipeStatus.OK, "0 ok"), (RecipeStatus.UNKNOWN, "1 unknown recipe"),
                          (RecipeStatus.REJECTED, "2 last edit rejected"),
                          (RecipeStatus.BUSY, "3 change refused while busy")):
        assert words in meaning, status
    assert PLC_MAP["recipe_status"].hi == max(RecipeStatus) == RecipeStatus.BUSY == 3


@pytest.mark.parametrize("address, words, exc, message", [
    (0, [2], IllegalDataAddress, "map_version at 0: register is read-only"),
    (7, [0], IllegalDataAddress, "address 7 .40008.: no register there"),
    (4, [0, 1], IllegalDataAddress, "plant_backlog at 4: register is read-only"),
    (24, [1], IllegalDataAddress, "part_id at 24: a 32-bit register must be written whole"),
    (25, [1], IllegalDataAddress, "part_id at 25"),
    (20, [5, 7], IllegalDataAddress, "recipe_ack at 21: register is read-only"),
    (20, [1000], IllegalDataValue, "recipe_select: value 1000 outside 0..999"),
    (11, [0x20], IllegalDataValue, "command_word: value 32"),
    (60, [5], IllegalDataValue, "calibration_select: value 5 outside 0..4"),
    (60, [1, 7], IllegalDataAddress, "calibration_version at 61: register is read-only"),
    (62, [0, 1], IllegalDataAddress, "calibration_residual_um at 62: register is read-only"),
])
def test_plc_write_decoding_refuses_with_the_modbus_code(address, words, exc, message):
    with pytest.raises(exc, match=message) as info:
        PLC_MAP.decode_plc_write(address, words)
    assert info.value.modbus_code == (2 if exc is IllegalDataAddress else 3)


def test_plc_write_decoding_checks_every_value_of_a_write_it_has_planned():
    """Which registers a write covers is worked out once per (address, count); the values of
    each write are still decoded and checked."""
    assert PLC_MAP.decode_plc_write(20, [5]) == {"recipe_select": 5}
    with pytest.raises(IllegalDataValue, match="recipe_select: value 1000"):
        PLC_MAP.decode_plc_write(20, [1000])
    assert PLC_MAP.decode_plc_write(20, [999]) == {"recipe_select": 999}
    assert PLC_MAP.decode_plc_write(24, [0, 7]) == {"part_id": 7}
    assert PLC_MAP.decode_plc_write(24, [1, 0]) == {"part_id": 0x10000}
    for _ in range(2):
        with pytest.raises(IllegalDataAddress, match="part_id at 25"):
            PLC_MAP.decode_plc_write(25, [1])


def test_plc_write_decoding_accepts_whole_writes():
    assert PLC_MAP.decode_plc_write(24, [0x0001, 0x0002]) == {"part_id": 0x00010002}
    assert PLC_MAP.decode_plc_write(20, [999]) == {"recipe_select": 999}
    current = {"status_word": 0, "command_word": 0b0010}
    assert PLC_MAP.decode_plc_bit_write(176, [True], current) == {"command_word": 0b0011}
    with pytest.raises(IllegalDataAddress, match="coil 160"):
        PLC_MAP.decode_plc_bit_write(160, [True], current)          # status_word is RO
    with pytest.raises(IllegalDataValue, match="undefined bit"):
        PLC_MAP.decode_plc_bit_write(176, [True] * 6, current)      # bit 5 undefined


def _cli(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="cellctl")
    registers_cmd.register(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(argv)


@pytest.mark.parametrize("fmt", ["md", "csv"])
def test_cellctl_registers_prints_every_register(fmt, capsys):
    args = _cli(["registers", "--format", fmt])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    expected = PLC_MAP.to_markdown() if fmt == "md" else PLC_MAP.to_csv()
    assert out.rstrip("\n") == expected.rstrip("\n")
    for r in PLC_MAP:
        assert r.name in out


def test_cellctl_registers_defaults_to_markdown(capsys):
    args = _cli(["registers"])
    args.func(args)
    assert capsys.readouterr().out.startswith("### PLC register map")


def test_cellctl_registers_refuses_an_unknown_format(capsys):
    with pytest.raises(SystemExit) as info:
        _cli(["registers", "--format", "xml"])
    assert info.value.code == 2
    assert "invalid choice: 'xml'" in capsys.readouterr().err


def test_an_image_view_decodes_each_register_as_the_whole_decode_does():
    image = [(7 * a + 3) & 0xFFFF for a in range(PLC_MAP.size)]
    view = PLC_MAP.view(image)
    assert dict(view) == PLC_MAP.decode_image(image)
    part = PLC_MAP["part_id"]
    assert view["part_id"] == (image[part.address] << 16) | image[part.address + 1]   # u32, high word first
    with pytest.raises(KeyError):
        view["no_such_register"]
    with pytest.raises(PlcMapError, match="image has 69 words, map needs 70"):
        PLC_MAP.view(image[:-1])
