"""``cellctl run --sim`` (the main job) and ``cellctl serve``.

``run --sim --cycles N`` starts the whole cell on this machine — Modbus server on loopback,
simulated stations on the virtual CAN bus, simulated camera, the plant — plus a simulated
PLC, a real Modbus TCP client running a PLC scan loop, which indexes the part conveyor,
selects the recipe, raises execute, waits for done and reads the results, N times. It all
runs on one simulated clock, as fast as the host allows: the same seed gives the same
cycles, whatever the load. Only fields named ``wall_s`` depend on the host.

``serve --sim`` runs the same cell without the simulated PLC so any Modbus client (a real
PLC, ``mbpoll``) can drive it; its simulated clock keeps to wall time. ``serve --config
deploy/cell.yaml`` runs it on hardware.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

from typing import TYPE_CHECKING

from cell import paths, progress
from cell.errors import ConfigError
from cell.shutdown import StopRequest

if TYPE_CHECKING:
    from cell.config import CellConfig

DEFAULT_SIM_DB = paths.DEFAULT_DB     #: where cellctl report/export/diagnose look by default (in the project)
OPCUA_HELP = ("also serve the read-only OPC UA server for the MES there (port 0: any free one); "
              "overrides the config's opcua host and port. Without --sim only Basic256Sha256 "
              "SignAndEncrypt with trusted certificates (docs/opcua.md)")


def register(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("run", help="run the simulated cell with a simulated PLC for N parts")
    r.add_argument("--sim", action="store_true", required=True, help="simulated devices (required)")
    r.add_argument("--cycles", type=int, default=10, help="parts to run (default 10)")
    r.add_argument("--recipe", default="bracket-a", help="recipe name (default bracket-a)")
    r.add_argument("--config", help="cell config (default: built-in simulated cell)")
    r.add_argument("--seed", type=int, help="seed of the simulated cell (default: the config's, 0)")
    r.add_argument("--db", help=f"cycle log to append to (default: a fresh log at the config's path, "
                                f"{DEFAULT_SIM_DB} without --config; the previous one is kept as "
                                "<name>.prev-<UTC time>.sqlite, never overwritten)")
    r.add_argument("--allow-examples", action="store_true",
                   help="also activate recipes marked 'production: false' (shipped examples such as pin-b)")
    r.add_argument("--first-part", type=int, default=1, help="first part id (default 1)")
    r.add_argument("--json", action="store_true", help="print the cycles as JSON at the end")
    r.add_argument("--opcua", metavar="HOST:PORT", help=OPCUA_HELP)
    r.set_defaults(func=run_sim)
    s = sub.add_parser("serve", help="run the controller (simulated devices with --sim)")
    s.add_argument("--sim", action="store_true", help="simulated devices, PLC link on loopback")
    s.add_argument("--config", help="cell config (required without --sim)")
    s.add_argument("--port", type=int, help="Modbus TCP port (default: config; 5020 with --sim)")
    s.add_argument("--seconds", type=float, help="stop after this many seconds (default: run until signalled)")
    s.add_argument("--db", help="cycle log (default: the config's log.path; var/cell.sqlite with --sim); "
                                "one controller per log: a second one on the same file is refused")
    s.add_argument("--opcua", metavar="HOST:PORT", help=OPCUA_HELP)
    s.set_defaults(func=serve)


def load_config(path: str | None, sim: bool, db: str | None = None, seed: int | None = None,
                allow_examples: bool = False, opcua: str | None = None) -> CellConfig:
    from cell.config import CellConfig, SimSection
    from cell.opcua.config import OpcuaSection, parse_address
    if path:
        cfg = CellConfig.load(path)
    elif sim:
        cfg = CellConfig(sim=SimSection())
    else:
        raise ConfigError("serve: --config is required without --sim")
    update = {}
    if sim and cfg.sim is None:
        update["sim"] = SimSection()
    if seed is not None:
        update["sim"] = (update.get("sim") or cfg.sim).model_copy(update={"seed": seed})
    if allow_examples:
        update["recipes"] = cfg.recipes.model_copy(update={"allow_examples": True})
    if opcua:
        try:
            host, port = parse_address(opcua)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        update["opcua"] = (cfg.opcua or OpcuaSection()).model_copy(update={"host": host, "port": port})
    if sim and not path:
        update["plc"] = cfg.plc.model_copy(update={"host": "127.0.0.1"})
        update["log"] = cfg.log.model_copy(update={"path": DEFAULT_SIM_DB})
    # defaults against the project (a loaded config's own paths are absolute already) ...
    cfg = (cfg.model_copy(update=update) if update else cfg).with_paths()
    if db:                                # ... but what the user typed, against their shell
        cfg = cfg.model_copy(update={"log": cfg.log.model_copy(update={"path": db})})
    return cfg


def run_sim(args: argparse.Namespace) -> int:
    from cell.app import Cell
    from cell.sim.plc import SimPlc, SimPlcError
    if args.cycles < 1:
        raise ConfigError(f"--cycles {args.cycles} must be ≥ 1")
    cfg = load_config(args.config, True, args.db, args.seed, args.allow_examples, args.opcua)
    _refuse_example(cfg, args.recipe)
    wall0 = time.monotonic()
    # a simulated cell starts from power-on, log included (unless --db names one to append to)
    cell = Cell(cfg, devices="sim", plc_port=0, fresh_log=not args.db)
    if cell.cyclelog.previous is not None:
        print(f"previous log kept as {paths.shown(str(cell.cyclelog.previous))}", file=sys.stderr, flush=True)
    rows: list[dict] = []
    clock = cell.clock
    # this thread keeps the simulated time from power-on to the end: no simulated time may
    # pass while it does anything else, or the run would depend on how fast it does it
    with clock.attach("run"):
        port = cell.start()
        try:
            if cell.opcua is not None:
                print(f"OPC UA server on {cell.opcua.url} (read-only)", file=sys.stderr, flush=True)
            active = cell.recipes.active.get(args.recipe)
            if active is None:
                raise ConfigError(f"recipe {args.recipe!r} is not active (known: {sorted(cell.recipes.active)})")
            if not args.json:
                _print_header()
            plc = SimPlc("127.0.0.1", port, clock=clock)
            plc.start()
            # the table's lines are its progress; --json prints at the end: a bar on a terminal
            bar = progress.bar("run", total=args.cycles, unit="part") if args.json else None
            try:
                for part_id in range(args.first_part, args.first_part + args.cycles):
                    row = _one_part(cell, plc, active, part_id, SimPlcError)
                    rows.append(row)
                    if not args.json:
                        _print_row(row)
                    elif bar is not None:
                        bar.update(1)
                    if row["fault"] is not None:
                        break
            finally:
                if bar is not None:
                    bar.close()
                plc.stop()
            sim_s = clock.now()
        finally:
            cell.stop()
    wall_s = time.monotonic() - wall0
    if args.json:
        print(json.dumps({"cycles": rows, "sim_s": round(sim_s, 6), "wall_s": round(wall_s, 3)}, indent=2))
    else:
        done = [r for r in rows if r["fault"] is None]
        if done:
            fin = [r["final_error_mm"] for r in done]
            print(f"{len(done)}/{len(rows)} cycles done; final error mean {sum(fin) / len(fin):.3f} mm, "
                  f"max {max(fin):.3f} mm; {sim_s:.1f} s simulated in {wall_s:.1f} s; log {paths.shown(cfg.log.path)}")
        else:
            print(f"no cycle done; log {paths.shown(cfg.log.path)}")
    return 0 if all(r["fault"] is None for r in rows) and len(rows) == args.cycles else 1


def _refuse_example(cfg, name: str) -> None:
    """Refuse, before anything starts, to run an example recipe the config does not allow
    (the controller would not activate it; say why and how, not just "not active")."""
    from cell.recipes.validation import check_file
    from cell.recipes import example_refusal
    path = Path(cfg.recipes.directory) / f"{name}.yaml"
    if cfg.recipes.allow_examples or not path.is_file():
        return
    _, err, recipe, text = check_file(path)
    if recipe is not None and not recipe.production:
        raise ConfigError(example_refusal(recipe, text, str(path)))


def _one_part(cell, plc, active, part_id: int, plc_error) -> dict:
    """Present a part, let the simulated PLC run its cycle, read back what the PLC got."""
    clock = cell.clock
    cell.devices.feeder.present(part_id, active.recipe)
    t0, w0 = clock.now(), time.monotonic()
    row = {"part_id": part_id, "recipe": active.recipe.name}
    try:
        res = plc.run_cycle(active.recipe.number, part_id, timeout_s=30.0)
    except plc_error as exc:
        res, fault = None, f"PLC: {exc}"
    else:
        fault = None if res["done"] else (res.get("fault_code") or "aborted")
    rec = _logged_record(cell, part_id)
    if res is not None and res["done"]:          # what the PLC read: the registers of this cycle
        figures = (res["initial_error_um"] / 1000.0, res["final_error_um"] / 1000.0, res["moves"],
                   res["cycle_time_ms"] / 1000.0)
    elif rec is not None:                        # faulted or cut off: what the log holds for it
        figures = (rec.initial_error_mm, rec.verify_error_mm if rec.verify_error_mm is not None
                   else rec.final_error_mm, rec.moves, rec.cycle_time_s)
    else:                                        # nothing measured for this part
        figures = (None, None, None, None)
    row.update(zip(("initial_error_mm", "final_error_mm", "moves", "cycle_time_s"), figures))
    row.update(plc_round_trip_s=round(clock.now() - t0, 6),
               motion=_motion(rec.motion) if rec is not None else None,
               fault=fault, wall_s=round(time.monotonic() - w0, 3))
    return row


def _logged_record(cell, part_id: int):
    """This part's cycle as the controller logged it (never an earlier part's), or None."""
    out = cell.controller.last_outcome
    if out is not None and out.record is not None and out.record.part_id == part_id:
        return out.record
    return None


def _motion(m: dict) -> dict:
    return {"mode": m.get("mode"), "segments": m.get("segments"), "delays_ms": m.get("delays_ms")}


def _print_header() -> None:
    print(f"{'part':>5} {'recipe':<10} {'initial mm':>10} {'final mm':>9} {'moves':>5} "
          f"{'cycle s':>8} {'mode':<9} {'λ j1..j4 ms':<27} fault", flush=True)


def _print_row(r: dict) -> None:
    def f(v, fmt):
        return format(v, fmt) if v is not None else "-"
    m = r.get("motion") or {}
    lam = "/".join(f"{d:.3f}" for d in m.get("delays_ms") or []) or "-"
    print(f"{r['part_id']:>5} {r['recipe']:<10} {f(r['initial_error_mm'], '>10.3f')} "
          f"{f(r['final_error_mm'], '>9.3f')} {f(r['moves'], '>5')} {f(r['cycle_time_s'], '>8.3f')} "
          f"{m.get('mode') or '-':<9} {lam:<27} {r['fault'] or '-'}", flush=True)


def serve(args: argparse.Namespace) -> int:
    from cell import log
    from cell.app import Cell
    cfg = load_config(args.config, args.sim, args.db, opcua=args.opcua)
    if args.config:                            # a service logs as its config says
        log.configure(cfg.log.format, cfg.log.level)
    port = args.port if args.port is not None else (5020 if args.sim and not args.config else None)
    cell = Cell(cfg, devices="sim" if args.sim else "hardware", plc_port=port, pace=True)
    stop = threading.Event()                     # set by this thread only: ends the feeder
    request = StopRequest().install()            # a handler without locks (cell/shutdown.py)
    why = request.why                            # what ended the service, first cause wins
    actual = cell.start()
    tls_port = getattr(cell.plc, "tls_port", None)
    where = (f"Modbus TCP on {cfg.plc.host}:{actual}" if cfg.plc.plain_tcp else "") + \
        (" and " if cfg.plc.plain_tcp and tls_port else "") + \
        (f"Modbus/TCP Security on {cfg.plc.tls.host}:{tls_port}" if tls_port else "") + \
        (f", OPC UA on {cell.opcua.url}" if cell.opcua is not None else "")
    print(f"cell {cfg.name} serving {where}"
          f"{' (simulated devices, clock paced to wall time)' if args.sim else ''}; Ctrl-C to stop", flush=True)
    cycles0 = cell.controller.cycle_count
    try:
        if args.sim:
            cell.clock.spawn(_auto_feed, "sim-feeder", cell, stop)
        if not request.wait(args.seconds):
            why.append(f"--seconds {args.seconds:g} elapsed")
    except BaseException as exc:                 # an error, or a second Ctrl-C: still say what stopped
        why.append(f"error: {exc!r}" if not isinstance(exc, KeyboardInterrupt) else "interrupted")
        raise
    finally:
        stop.set()
        state = _final_state(cell, cycles0)      # before the stop: the state the PLC last saw
        print(f"cell {cfg.name} stopping ({why[0] if why else 'stopped'})", file=sys.stderr, flush=True)
        try:
            cell.stop()
        finally:
            print(f"cell {cfg.name} stopped: {why[0] if why else 'stopped'}; {state}; "
                  f"log {paths.shown(cfg.log.path)}", file=sys.stderr, flush=True)
    return 0


def _final_state(cell, cycles0: int) -> str:
    """The controller's state, fault and cycle count, in words, for the stop message."""
    c = cell.controller
    if c is None:
        return "controller not started"
    try:
        fault = f"fault {c.fault_code} ({c.fault_text})" if c.fault_code else "no fault"
        return f"final state {c.sm.state.name}, {fault}, {c.cycle_count - cycles0} cycle(s) this run"
    except Exception as exc:                     # noqa: BLE001 -- the message must still be printed
        return f"final state unknown ({exc!r})"


def _auto_feed(cell, stop: threading.Event) -> None:
    """``serve --sim``: the conveyor presents a new part of the selected recipe after every
    logged cycle (the PLC program that indexes a real conveyor is not simulated here)."""
    part_id, seen = 1, None
    while not stop.is_set():
        ended = cell.controller.last_outcome        # a new object for every cycle that ends
        active = cell.recipes.by_number(cell.controller.recipe_number)
        if active is not None and (ended is not seen or cell.devices.feeder.part is None):
            cell.devices.feeder.present(part_id, active.recipe)
            part_id, seen = part_id + 1, ended
        cell.clock.sleep(0.05)
