"""What the HMI shows of the running cell, read-only: the cycle log and the PLC registers.

:func:`log_status` reads the cycle log read-only (it works beside a running controller, which
holds the writer's lock): how many cycles, the last ones, the cycle in flight, the last
audit rows. :func:`plc_status` reads the whole register map once over Modbus TCP as a
read-only client (the link serves reads to every allowed client and refuses any write from
a client that does not own it; this one never writes): the controller's state, fault code,
status bits, active recipe and its status (in words, from the register map's own text),
cycle count. :func:`trend_png` draws the accuracy trend ``cellctl report`` writes;
:class:`TrendCache` draws it once per state of the log (:func:`trend_key`: the file's
identity, how many cycles, the last one's id, and the recipe files the tolerances come
from), however many pages ask at once.
"""
from __future__ import annotations

import os
import re
import tempfile
import threading
from pathlib import Path

from cell.errors import CellError
from cell.hmi.work import SingleFlight, WorkPool

_plot_lock = threading.Lock()        # matplotlib's pyplot is not thread-safe


def _cycle_row(c) -> dict:
    return {"id": c.id, "part_id": c.part_id, "recipe": c.recipe, "recipe_hash": c.recipe_hash,
            "status": c.status, "finished_at": c.finished_at, "initial_error_mm": c.initial_error_mm,
            "final_error_mm": c.final_error_mm, "verify_error_mm": c.verify_error_mm, "moves": c.moves,
            "cycle_time_s": c.cycle_time_s, "fault_code": c.fault_code, "fault_text": c.fault_text}


def log_status(path: Path, last: int = 15, audit: int = 8) -> dict:
    """The log's summary: ``{"log", "ok", "error", "cycles_total", "in_flight", "cycles",
    "audit"}``; ``ok`` False (with ``error``) when there is no log or it cannot be read."""
    from cell.cyclelog import CycleLog
    out = {"log": str(path), "ok": False, "error": None, "cycles_total": 0, "in_flight": None,
           "cycles": [], "audit": []}
    if not Path(path).is_file():
        out["error"] = "no cycle log yet (the cell has not run)"
        return out
    try:
        log = CycleLog(path, readonly=True)
        try:
            out["cycles_total"] = log.count()
            out["in_flight"] = log.open_cycle()
            out["cycles"] = [_cycle_row(c) for c in reversed(log.cycles(limit=last))]
            rows = log.audit_rows(last=audit)
            out["audit"] = [{k: r[k] for k in ("id", "at", "who", "action", "target", "hash", "result")}
                            for r in reversed(rows)]
        finally:
            log.close()
    except (CellError, Exception) as exc:   # noqa: BLE001 -- a page shows why, never a 500
        out["error"] = f"cannot read the cycle log: {exc}"
        return out
    out["ok"] = True
    return out


def plc_status(host: str, port: int, timeout_s: float = 1.0) -> dict:
    """One FC3 read of the whole register map: ``{"reachable", "error", "state", ...}``."""
    from pymodbus.client import ModbusTcpClient
    from pymodbus.exceptions import ModbusException

    from cell.cycle.statemachine import State
    from drivers.plc.register_map import PLC_MAP
    out: dict = {"address": f"{host}:{port}", "reachable": False, "error": None}
    client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)
    try:
        if not client.connect():
            out["error"] = "no answer (is the controller running?)"
            return out
        rr = client.read_holding_registers(0, count=PLC_MAP.size, device_id=1)
        if rr.isError():
            out["error"] = f"read refused: {rr}"
            return out
        image = PLC_MAP.decode_image(rr.registers)
    except (ModbusException, OSError) as exc:
        out["error"] = f"read failed: {exc}"
        return out
    finally:
        client.close()
    try:
        state = State(image["state_code"]).name.lower()
    except ValueError:
        state = f"code {image['state_code']}"
    out.update(reachable=True, state=state, fault_code=image["fault_code"],
               status=PLC_MAP.bits("status_word", image["status_word"]),
               recipe_ack=image["recipe_ack"], recipe_status=image["recipe_status"],
               recipe_line=recipe_line(image["recipe_ack"], image["recipe_status"]),
               cycle_count=image["cycle_count"], controller_heartbeat=image["controller_heartbeat"],
               plant_backlog=image["plant_backlog"])
    return out


def recipe_status_words() -> dict[int, str]:
    """``recipe_status`` code → words, read from the register map's meaning of the register
    ("0 ok (...), 1 unknown recipe, ..."), the one place the codes are defined."""
    from drivers.plc.register_map import PLC_MAP
    pairs = re.findall(r"(\d+) ([a-z][^,(]*)", PLC_MAP["recipe_status"].meaning)
    return {int(n): w.strip().rstrip(".") for n, w in pairs}


def recipe_line(ack: int, status: int) -> str:
    """The PLC recipe registers in words: "no recipe selected" for recipe 0, else
    "recipe 3: ok" (the status in words; an unknown code as "status 7")."""
    if not ack:
        return "no recipe selected"
    return f"recipe {ack}: {recipe_status_words().get(status, f'status {status}')}"


def trend_png(path: Path, recipes_dir: Path | None = None) -> bytes | None:
    """The accuracy-trend PNG of ``cellctl report`` for the log at ``path`` (tolerances
    also from the files of ``recipes_dir``); None without cycles or a readable log."""
    from cell.cyclelog import CycleLog
    from cell.cyclelog.trend import write_png
    if not Path(path).is_file():
        return None
    try:
        log = CycleLog(path, readonly=True)
        try:
            cycles = log.cycles()
        finally:
            log.close()
    except CellError:
        return None
    if not cycles:
        return None
    with _plot_lock, tempfile.TemporaryDirectory(prefix="hmi-trend-") as d:
        png = Path(d) / "accuracy.png"
        write_png(Path(path), cycles, png, recipes_dir)   # the very plot `cellctl report` writes
        return png.read_bytes()


def trend_key(path: Path, recipes_dir: Path | None = None) -> tuple | None:
    """What the trend picture depends on: the log file's identity (device, inode), its
    number of cycles and last cycle id, and the recipe files (name, size, mtime) the
    tolerances come from. None when there is no cycle to draw (or no readable log)."""
    from cell.cyclelog import CycleLog
    try:
        st = os.stat(path)
        log = CycleLog(path, readonly=True)
        try:
            count = log.count()
            last = log.cycles(limit=1)
        finally:
            log.close()
    except (OSError, CellError):
        return None
    if not count or not last:
        return None
    recipes: tuple = ()
    if recipes_dir is not None:
        try:
            recipes = tuple(sorted((e.name, e.stat().st_size, e.stat().st_mtime_ns) for e in os.scandir(recipes_dir)
                                   if e.name.endswith(".yaml") and not e.name.startswith(".")))
        except OSError:
            pass
    return (st.st_dev, st.st_ino, count, last[-1].id, recipes)


class TrendCache:
    """The trend PNG of one log, drawn once per :func:`trend_key`: concurrent requests share
    one look at the key and one drawing (:class:`~cell.hmi.work.SingleFlight`); a request for
    the same state again gets the picture already drawn. ``renders`` counts drawings.

    :param keys: the pool the key is read in (the log); ``draw``: the pool that draws.
    """

    def __init__(self, log_path: Path, recipes_dir: Path | None, keys: WorkPool, draw: WorkPool):
        self.log_path, self.recipes_dir = Path(log_path), recipes_dir
        self.keys, self.draw = keys, draw
        self.renders = 0
        self._key: tuple | None = None
        self._png: bytes | None = None
        self._key_flight, self._draw_flight = SingleFlight(), SingleFlight()

    async def png(self) -> bytes | None:
        """The picture for the log as it is now; None without cycles.

        :raises cell.hmi.work.Busy: a pool is full (the request answers 503).
        """
        key = await self._key_flight(lambda: self.keys.run(trend_key, self.log_path, self.recipes_dir))
        if key is None:
            return None
        if key == self._key:
            return self._png
        return await self._draw_flight(lambda: self._render(key))

    async def _render(self, key: tuple) -> bytes | None:
        png = await self.draw.run(trend_png, self.log_path, self.recipes_dir)
        self.renders += 1
        self._key, self._png = key, png
        return png
