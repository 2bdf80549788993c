"""The controller publishes a scan's outputs so that a PLC read between its writes never
sees ``done`` (or ``fault``) beside values that are not yet its own.

Probe: ``done`` was set first and the results written after, each under its own hold of
the link's lock, so a PLC read in between saw ``done`` with the previous part's results
(the register map promises the results are valid before ``done`` is set)."""
from cell.clock import ManualClock
from cell.controller import OutputWriter
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


def test_done_rises_only_after_the_results_are_in():
    link = Watched()
    publish = OutputWriter(link).write
    publish( {"busy": True, "done": False}, {"part_id_echo": 6, "final_error_um": 0, "moves": 0})
    publish({"busy": False, "done": True}, {"part_id_echo": 7, "final_error_um": 31, "moves": 2})
    for image in link.seen:
        bits = link.map.bits("status_word", image["status_word"])
        if bits["done"]:
            assert (image["part_id_echo"], image["final_error_um"], image["moves"]) == (7, 31, 2)
    assert link.map.bits("status_word", link.seen[-1]["status_word"])["done"]


def test_done_falls_before_the_next_parts_values_replace_the_results():
    link = Watched()
    publish = OutputWriter(link).write
    publish({"busy": False, "done": True}, {"part_id_echo": 7, "final_error_um": 31, "moves": 2})
    link.seen.clear()
    publish({"busy": True, "done": False}, {"part_id_echo": 8, "final_error_um": 0, "moves": 0})
    for image in link.seen:
        if link.map.bits("status_word", image["status_word"])["done"]:
            assert image["part_id_echo"] == 7


def test_only_what_changed_is_written_and_the_order_holds():
    link = Watched()
    writer = OutputWriter(link)
    writer.write({"busy": True, "done": False}, {"part_id_echo": 6, "moves": 0})
    n = len(link.seen)
    writer.write({"busy": True, "done": False}, {"part_id_echo": 6, "moves": 0})
    assert len(link.seen) == n                          # nothing changed: the link is not touched
    writer.write({"busy": False, "done": True}, {"part_id_echo": 6, "moves": 2})
    assert len(link.seen) == n + 3                      # busy down, moves, done up
    assert link.snapshot()["moves"] == 2
    bits = link.map.bits("status_word", link.seen[n]["status_word"])
    assert not bits["busy"] and not bits["done"]         # the falling bit went first
