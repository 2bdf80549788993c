"""``cellctl report``: the process engineer's accuracy trend, and ``cellctl export``.

``report`` prints, per block of consecutive cycles, the initial and final error (mean, p95,
max), moves and faults, and writes a PNG of the trend against the recipe's tolerance and
the recalibration threshold (:mod:`cell.cyclelog.trend`).
``export`` writes the logged cycles as a measurement campaign for ``cellctl diagnose``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from cell import paths
from cell.commands import file_in_the_way, open_log_readonly, plot_file, preset_name
from cell.errors import ConfigError

DEFAULT_DB = paths.DEFAULT_DB   #: in the project folder, whatever the shell's (cell.paths)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="accuracy trend of the logged cycles (table + PNG plot)")
    p.add_argument("--db", default=str(paths.project(DEFAULT_DB)), help=f"cycle log (default: the project's {DEFAULT_DB})")
    p.add_argument("--block", type=int, default=10, help="cycles per table row (default 10)")
    p.add_argument("--recipe", help="only this recipe")
    p.add_argument("--png", default=str(paths.project("var/accuracy.png")), help="plot file, or folder for accuracy.png (default: the project's var/accuracy.png; '' for none)")
    p.add_argument("--config", help="cell config whose scheduler section gives the recalibration "
                                    "threshold and window (default: the built-in defaults the "
                                    "simulated cell runs with)")
    p.add_argument("--recipes", default=None,
                   help="recipe folder, for versions the log does not hold (default: the project's recipes/)")
    p.set_defaults(func=run_report)
    e = sub.add_parser("export", help="export logged cycles to the measurement exchange format")
    e.add_argument("out", help="campaign directory to write")
    e.add_argument("--db", default=str(paths.project(DEFAULT_DB)), help=f"cycle log (default: the project's {DEFAULT_DB})")
    e.add_argument("--robot", type=preset_name, default="seed000", metavar="PRESET",
                   help="robot preset of the nominal model (default seed000)")
    e.add_argument("--force", action="store_true",
                   help="write into a folder that holds other files (they are kept, never deleted)")
    e.set_defaults(func=run_export)


def run_report(args: argparse.Namespace) -> int:
    """Every input is checked (block, config, recipes, PNG file, log) and the plot written
    before the first line is printed: a bad input never follows a printed table."""
    import numpy as np

    from cell.cyclelog import CycleStatus
    if args.block < 1:
        raise ConfigError(f"--block {args.block} must be ≥ 1")
    sched = _scheduler(args.config)
    recipes = _recipes_dir(args.recipes)
    png = plot_file(args.png, "accuracy.png")
    log = open_log_readonly(args.db)
    cycles = [c for c in log.cycles() if not args.recipe or c.recipe == args.recipe]
    if not cycles:
        print("no cycles logged" + (f" for recipe {args.recipe}" if args.recipe else ""))
        return 0
    if png is not None:
        _plot(args.db, cycles, png, recipes, sched)
    print(f"{len(cycles)} cycles in {args.db}" + (f", recipe {args.recipe}" if args.recipe else ""))
    print("| cycles | first part | initial mean mm | final mean mm | final p95 mm | final max mm "
          "| mean moves | faults |")
    print("|---|---|---|---|---|---|---|---|")
    for i in range(0, len(cycles), args.block):
        blk = cycles[i:i + args.block]
        done = [c for c in blk if c.status == CycleStatus.DONE and c.final_error_mm is not None]
        faults = sum(c.status != CycleStatus.DONE for c in blk)
        if done:
            ini = np.array([c.initial_error_mm for c in done])
            fin = np.array([c.final_error_mm for c in done])
            mv = np.mean([c.moves for c in done])
            stats = (f"{ini.mean():.4f} | {fin.mean():.4f} | {np.percentile(fin, 95):.4f} | "
                     f"{fin.max():.4f} | {mv:.2f}")
        else:
            stats = "– | – | – | – | –"
        print(f"| {blk[0].id}–{blk[-1].id} | {blk[0].part_id} | {stats} | {faults} |")
    if png is not None:
        print(f"plot written to {png}")
    return 0


def _scheduler(config: str | None):
    """The ``scheduler`` section of ``--config`` (None: the built-in defaults); ConfigError
    naming file, line and field when the config is missing or bad."""
    if not config:
        return None
    from cell.config import CellConfig
    return CellConfig.load(config).scheduler


def _recipes_dir(given: str | None) -> Path:
    """``--recipes``: the folder given (ConfigError unless it is one), else the project's."""
    if given is None:
        return paths.project(paths.DEFAULT_RECIPES)
    if not Path(given).is_dir():
        raise ConfigError(f"--recipes {given}: no such folder")
    return Path(given)


def _plot(db: str, cycles, path: Path, recipes: Path, sched) -> None:
    """The trend PNG (:func:`cell.cyclelog.trend.write_png`): tolerance of each cycle's recipe
    version, the drift watch's recalibration threshold from ``sched`` (None: the defaults)."""
    from cell.cyclelog.trend import write_png
    try:
        write_png(Path(db), cycles, path, recipes, sched.drift_threshold_mm if sched else None,
                  sched.drift_window if sched else None)
    except OSError as exc:
        raise ConfigError(f"--png {path}: cannot write the plot: {exc.strerror or exc}") from None


def run_export(args: argparse.Namespace) -> int:
    from cell.cyclelog import CycleStatus
    from cell.cyclelog.export import cycles_to_campaign
    from cell.kinematics import Scara
    from cell.measurements import write_campaign
    robot = Scara.preset(args.robot)
    blocker = file_in_the_way(Path(args.out))
    if blocker is not None:
        raise ConfigError(f"{args.out}: {blocker} is not a folder; nothing written")
    cycles = open_log_readonly(args.db).cycles(status=CycleStatus.DONE)
    try:
        campaign = cycles_to_campaign(cycles, robot.g.l1_mm, robot.g.l2_mm, command_unit_deg=robot.g.unit[0],
                                      joint_limits_deg=[list(map(float, robot.g.limits[k])) for k in (0, 1)])
    except ValueError as exc:
        raise ConfigError(f"{args.db}: {exc}") from None
    try:
        write_campaign(campaign, args.out, force=args.force)
    except OSError as exc:
        raise ConfigError(f"{args.out}: cannot write the campaign: {exc.strerror or exc}") from None
    print(f"{len(campaign.points['sample'])} measured moves written to {args.out}")
    return 0
