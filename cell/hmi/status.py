"""What the HMI shows of the running cell, read-only: the cycle log and the PLC registers.

:func:`log_status` reads the cycle log read-only (it works beside a running controller, which
holds the writer's lock): how many cycles, the last ones, the cycle in flight, the last
audit rows. :func:`plc_status` reads the whole register map once over Modbus TCP as a
read-only client (the link serves reads to every allowed client and refuses any write from
a client that does not own it; this one never writes): the controller's state, fault code,
status bits, active recipe and its status, cycle count. :func:`trend_png` draws the
accuracy trend ``cellctl report`` writes.
"""
from __future__ import annotations

import tempfile
import threading
from pathlib import Path

from cell.errors import CellError

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

    from cell.statemachine import State
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
               cycle_count=image["cycle_count"], controller_heartbeat=image["controller_heartbeat"])
    return out


def trend_png(path: Path, recipes_dir: Path | None = None) -> bytes | None:
    """The accuracy-trend PNG of ``cellctl report`` for the log at ``path`` (tolerances
    also from the files of ``recipes_dir``); None without cycles or a readable log."""
    from cell.cyclelog import CycleLog
    from cell.trend import write_png
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
