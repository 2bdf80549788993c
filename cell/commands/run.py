"""``cellctl run --sim`` (the main job) and ``cellctl serve``.

``run --sim --cycles N`` starts the whole cell on this machine — Modbus server on loopback,
simulated stations on the virtual CAN bus, simulated camera, the plant — plus a simulated
PLC, a real Modbus TCP client running a PLC scan loop, which indexes the part conveyor,
selects the recipe, raises execute, waits for done and reads the results, N times.

``serve --sim`` runs the same cell without the simulated PLC so any Modbus client (a real
PLC, ``mbpoll``) can drive it; ``serve --config deploy/cell.yaml`` runs it on hardware.
"""
from __future__ import annotations

import argparse
import json
import signal
import threading
import time

from cell.config import CellConfig, SimSection
from cell.errors import ConfigError

DEFAULT_SIM_DB = "var/cell.sqlite"      #: where cellctl report/export/diagnose look by default


def register(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("run", help="run the simulated cell with a simulated PLC for N parts")
    r.add_argument("--sim", action="store_true", required=True, help="simulated devices (required)")
    r.add_argument("--cycles", type=int, default=10, help="parts to run (default 10)")
    r.add_argument("--recipe", default="bracket-a", help="recipe name (default bracket-a)")
    r.add_argument("--config", help="cell config (default: built-in simulated cell)")
    r.add_argument("--db", help=f"cycle log (default {DEFAULT_SIM_DB})")
    r.add_argument("--first-part", type=int, default=1, help="first part id (default 1)")
    r.add_argument("--json", action="store_true", help="print the cycles as JSON")
    r.set_defaults(func=run_sim)
    s = sub.add_parser("serve", help="run the controller (simulated devices with --sim)")
    s.add_argument("--sim", action="store_true", help="simulated devices, PLC link on loopback")
    s.add_argument("--config", help="cell config (required without --sim)")
    s.add_argument("--port", type=int, help="Modbus TCP port (default: config; 5020 with --sim)")
    s.add_argument("--seconds", type=float, help="stop after this many seconds (default: run until signalled)")
    s.set_defaults(func=serve)


def load_config(path: str | None, sim: bool, db: str | None = None) -> CellConfig:
    if path:
        cfg = CellConfig.load(path)
    elif sim:
        cfg = CellConfig(sim=SimSection())
    else:
        raise ConfigError("serve: --config is required without --sim")
    update = {}
    if sim and cfg.sim is None:
        update["sim"] = SimSection()
    if sim and not path:
        update["plc"] = cfg.plc.model_copy(update={"host": "127.0.0.1"})
        update["log"] = cfg.log.model_copy(update={"path": DEFAULT_SIM_DB})
    if db:
        update["log"] = cfg.log.model_copy(update={"path": db})
    return cfg.model_copy(update=update) if update else cfg


def run_sim(args: argparse.Namespace) -> int:
    from cell.app import Cell
    from drivers.plc.sim_plc import SimPlc
    if args.cycles < 1:
        raise ConfigError(f"--cycles {args.cycles} must be ≥ 1")
    cfg = load_config(args.config, True, args.db)
    cell = Cell(cfg, sim=True, plc_port=0)
    port = cell.start()
    rows = []
    try:
        active = cell.recipes.active.get(args.recipe)
        if active is None:
            raise ConfigError(f"recipe {args.recipe!r} is not active (known: {sorted(cell.recipes.active)})")
        plc = SimPlc("127.0.0.1", port)
        plc.start()
        try:
            for part_id in range(args.first_part, args.first_part + args.cycles):
                cell.sim.feeder.present(part_id, active.recipe)
                t0 = time.monotonic()
                res = plc.run_cycle(active.recipe.number, part_id, timeout_s=30.0)
                fault = res.get("fault_code") or None
                rows.append({"part_id": part_id, "recipe": active.recipe.name,
                             "initial_error_mm": res["initial_error_um"] / 1000.0,
                             "final_error_mm": res["final_error_um"] / 1000.0,
                             "moves": res["moves"], "cycle_time_s": res["cycle_time_ms"] / 1000.0,
                             "plc_round_trip_s": round(time.monotonic() - t0, 3),
                             "fault": fault if not res["done"] else None})
                if not res["done"]:
                    break
        finally:
            plc.stop()
    finally:
        cell.stop()
    if args.json:
        print(json.dumps({"cycles": rows}, indent=2))
    else:
        print(f"{'part':>5} {'recipe':<10} {'initial mm':>10} {'final mm':>9} {'moves':>5} "
              f"{'cycle s':>8}  fault")
        for r in rows:
            print(f"{r['part_id']:>5} {r['recipe']:<10} {r['initial_error_mm']:>10.3f} "
                  f"{r['final_error_mm']:>9.3f} {r['moves']:>5} {r['cycle_time_s']:>8.3f}  "
                  f"{r['fault'] or '-'}")
        done = [r for r in rows if r["fault"] is None]
        if done:
            fin = [r["final_error_mm"] for r in done]
            print(f"{len(done)}/{len(rows)} cycles done; final error mean {sum(fin) / len(fin):.3f} mm, "
                  f"max {max(fin):.3f} mm; log {cfg.log.path}")
    return 0 if all(r["fault"] is None for r in rows) and len(rows) == args.cycles else 1


def serve(args: argparse.Namespace) -> int:
    from cell import log
    from cell.app import Cell
    cfg = load_config(args.config, args.sim)
    if args.config:                            # a service logs as its config says
        log.configure(cfg.log.format, cfg.log.level)
    port = args.port if args.port is not None else (5020 if args.sim and not args.config else None)
    cell = Cell(cfg, sim=args.sim, plc_port=port)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    actual = cell.start()
    print(f"cell {cfg.name} serving Modbus TCP on {cfg.plc.host}:{actual}"
          f"{' (simulated devices)' if args.sim else ''}; Ctrl-C to stop", flush=True)
    if args.sim:
        _auto_feed(cell, stop)
    stop.wait(args.seconds)
    cell.stop()
    return 0


def _auto_feed(cell, stop: threading.Event) -> None:
    """``serve --sim``: the conveyor presents a new part of the selected recipe after every
    logged cycle (the PLC program that indexes a real conveyor is not simulated here)."""
    def feed():
        part_id, seen = 1, -1
        while not stop.is_set():
            n = cell.cyclelog.count()
            c = cell.controller
            active = cell.recipes.by_number(c._recipe_number) if c else None
            if active is not None and (n != seen or cell.sim.feeder.part is None):
                cell.sim.feeder.present(part_id, active.recipe)
                part_id, seen = part_id + 1, n
            stop.wait(0.05)
    threading.Thread(target=feed, name="sim-feeder", daemon=True).start()
