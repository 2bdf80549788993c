"""The controller publishes a scan's outputs so that a PLC read between its writes never
sees ``done`` (or ``fault``) beside values that are not yet its own.

Probe: ``done`` was set first and the results written after, each under its own hold of
the link's lock, so a PLC read in between saw ``done`` with the previous part's results
(the register map promises the results are valid before ``done`` is set)."""
from cell.clock import ManualClock
from cell.controller import CellController
from drivers.plc.server import PlcLink


class Watched(PlcLink):
    """The real link; takes the image a PLC read would see after every controller write."""

    def __init__(self):
        super().__init__(clock=ManualClock(0.0))
        self.seen: list[dict] = []

    def write_many(self, values):
        super().write_many(values)
        self.seen.append(self.snapshot())

    def set_bits(self, name, **flags):
        out = super().set_bits(name, **flags)
        self.seen.append(self.snapshot())
        return out


def publish(link, status, registers):
    controller = object.__new__(CellController)        # only _write and its link are used
    controller.plc = link
    controller._write(status, registers)


def test_done_rises_only_after_the_results_are_in():
    link = Watched()
    publish(link, {"busy": True, "done": False}, {"part_id_echo": 6, "final_error_um": 0, "moves": 0})
    publish(link, {"busy": False, "done": True}, {"part_id_echo": 7, "final_error_um": 31, "moves": 2})
    for image in link.seen:
        bits = link.map.bits("status_word", image["status_word"])
        if bits["done"]:
            assert (image["part_id_echo"], image["final_error_um"], image["moves"]) == (7, 31, 2)
    assert link.map.bits("status_word", link.seen[-1]["status_word"])["done"]


def test_done_falls_before_the_next_parts_values_replace_the_results():
    link = Watched()
    publish(link, {"busy": False, "done": True}, {"part_id_echo": 7, "final_error_um": 31, "moves": 2})
    link.seen.clear()
    publish(link, {"busy": True, "done": False}, {"part_id_echo": 8, "final_error_um": 0, "moves": 0})
    for image in link.seen:
        if link.map.bits("status_word", image["status_word"])["done"]:
            assert image["part_id_echo"] == 7
