"""``cellctl diagnose``: where the sim-to-real gap lies, which effect causes it, how far it
shrinks on withheld rows (report format in ``cell/measurements.md``).

    cellctl diagnose CAMPAIGN [--json] [--html DIR]      (planar or chain campaign)
    cellctl diagnose var/cell.sqlite [--robot seed000] [--camera-center X,Y] [--json]
    cellctl diagnose validate [--trials 200] [--seed S] [--combos] [--points 300] [--json]
                              [--out-of-vocabulary SHARE] [--oov-kinds K1,K2]
                              [--layout realistic|uniform]
    cellctl diagnose validate --chain [--trials 100] [--seed S] [--points 60] [--json]
                              [--out-of-vocabulary SHARE] [--oov-kinds lens,reach_sag,...]
    cellctl diagnose validate --both [--trials N] [--seed S] [--out-of-vocabulary SHARE]

CAMPAIGN is a campaign directory in the exchange format, or the cell's own SQLite cycle
log (exported on the fly with :func:`cell.cyclelog.export.cycles_to_campaign`; the nominal link
lengths come from ``--robot``). ``validate`` (a special first positional; write
``./validate`` for a directory of that name) draws campaigns with a hidden effect from the
independent forward model (:mod:`cell.truth`), written as files by the truth's own writer
and read with the project's reader, and prints the verdicts (right, ambiguous with the
truth among the rivals, ambiguous with the truth missing, unexplained, wrong), the 95 %
interval coverage and the earlier scores as Markdown tables (:mod:`cell.diagnosis.validate`).
``--layout realistic`` (default) draws production-like campaigns (poses clustered at 3–12
stations, optional columns often missing, outliers); ``uniform`` the earlier spread-out
design. ``--out-of-vocabulary SHARE`` gives that share of the trials (0–1, default 0) an
effect from outside the vocabulary instead (``--oov-kinds``; default all), which should come
back unexplained or as none, never as a confident cause. ``--chain`` validates on chain
campaigns instead (:mod:`cell.diagnosis.chain.validate`: a UR5 measured by a tracker, drawn from
:mod:`cell.truth.chain`; ``--points`` is then the poses per campaign). ``--both`` runs the
planar and the chain validation (default 100 trials each) and prints one verdict table for
both before each kind's tables. Every campaign goes through the one diagnosis
(:func:`cell.diagnosis.answer.diagnose_campaign`).

Bad input exits with status 2 and a message naming file, line and column
(:class:`~cell.measurements.CampaignFormatError`, raised before anything is diagnosed).
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from cell import progress
from cell.commands import float_list, summary
from cell.errors import ConfigError
from cell.jsonsafe import json_safe

if TYPE_CHECKING:
    from cell.measurements import Campaign

SQLITE_MAGIC = b"SQLite format 3\x00"
VALIDATE = "validate"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="sim-to-real gap diagnosis of a campaign or the cycle log",
                       description=summary(__doc__))
    p.add_argument("campaign", metavar="CAMPAIGN",
                   help="campaign directory, SQLite cycle log, or 'validate'")
    p.add_argument("--json", action="store_true", help="print the report as JSON (cell-diagnosis/1)")
    p.add_argument("--html", metavar="DIR", help="write DIR/index.html with PNG plots")
    p.add_argument("--model", metavar="MODEL.yaml",
                   help="chain campaigns: nominal model to use instead of CAMPAIGN/model.yaml "
                        "(e.g. the one 'cellctl calibrate kinematics CAMPAIGN' wrote)")
    p.add_argument("--noise-mm", type=float, metavar="SIGMA",
                   help="expected σ per axis of one point measurement incl. repeatability, mm "
                        "(optional; sharpens the 'unexplained' test)")
    p.add_argument("--robot", default="seed000",
                   help="cycle log only: robot preset of the nominal model (default seed000)")
    p.add_argument("--camera-center", type=float_list(2), metavar="X,Y",
                   help="cycle log only: camera centre on the work plane, mm")
    v = p.add_argument_group("validate")
    v.add_argument("--trials", type=int, help="validate: number of campaigns (default 200)")
    v.add_argument("--seed", type=int, help="validate: seed of the run (default 0)")
    v.add_argument("--chain", action="store_true",
                   help="validate: chain campaigns (a 6-joint arm and a tracker) instead of SCARA ones")
    v.add_argument("--both", action="store_true",
                   help="validate: planar and chain campaigns, one verdict table for both")
    v.add_argument("--layout", choices=("realistic", "uniform"),
                   help="validate: production-like campaigns (default) or poses spread out")
    v.add_argument("--combos", action="store_true",
                   help="validate: a main effect plus a smaller second one")
    v.add_argument("--points", type=int, help="validate: static poses per campaign (default 300)")
    v.add_argument("--out-of-vocabulary", type=float, metavar="SHARE", dest="oov_share",
                   help="validate: share of trials (0-1, default 0) whose truth is an effect "
                        "outside the vocabulary")
    v.add_argument("--oov-kinds", metavar="K1,K2", dest="oov_kinds",
                   help="validate: which effects outside the vocabulary (default all of "
                        "radial_distortion, reach_sag, offset_bump, joint_coupling)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.campaign == VALIDATE:
        return run_validate(args)
    given = [f"--{n}" for n in ("trials", "seed", "points") if getattr(args, n) is not None]
    given += ["--combos"] if args.combos else []
    given += ["--chain"] if args.chain else []
    given += ["--both"] if args.both else []
    given += ["--layout"] if args.layout is not None else []
    given += ["--out-of-vocabulary"] if args.oov_share is not None else []
    given += ["--oov-kinds"] if args.oov_kinds is not None else []
    if given:
        raise ConfigError(f"{', '.join(given)}: only with 'cellctl diagnose validate'")
    if args.noise_mm is not None and not (args.noise_mm > 0 and math.isfinite(args.noise_mm)):
        raise ConfigError(f"--noise-mm {args.noise_mm} must be a positive number of mm")
    # One diagnosis, its imports included, makes some 30,000 objects that live until the
    # command ends and only a few hundred that are cyclic garbage (tens of KB): the cyclic
    # collector's passes over them, and its full pass when the interpreter exits, cost
    # about 14 ms of CPU, 5 % of the command, and free nothing that matters. So it is
    # paused until the report is printed, and what was made meanwhile is then frozen
    # (gc.freeze: left to reference counting, never passed over again). validate, which
    # runs hundreds of diagnoses in one process, keeps the collector.
    collecting = gc.isenabled()
    gc.disable()
    try:
        campaign, lines = load(args.campaign, args.robot, args.camera_center, args.model)
        from cell.diagnosis.answer import diagnose_campaign   # the diagnosis itself: only now
        answer = diagnose_campaign(campaign, lines, args.noise_mm)
        if args.html:
            try:
                index = answer.write_html(args.html)
            except OSError as exc:
                raise ConfigError(f"--html {args.html}: cannot write: {exc}") from None
            if not args.json:
                print(f"HTML report written to {index}")
        if args.json:
            print(json.dumps(json_safe(answer.report), indent=2, allow_nan=False))
        else:
            print(answer.text())
    finally:
        if collecting:
            gc.freeze()
            gc.enable()
    return 0


# ------------------------------------------------------------------ input
def load(target: str, robot: str = "seed000", camera_center=None, model: str | None = None
         ) -> tuple[Campaign, dict]:
    """(campaign, {table: row lines}) from a campaign directory or an SQLite cycle log (row
    lines of a planar campaign's files only); ``model`` replaces a chain campaign's model.yaml.

    Raises CampaignFormatError (campaign problems, file/line/column) or ConfigError (a cycle
    log without measured moves, an unknown robot preset)."""
    from cell.measurements import Campaign, CampaignFormatError, read_campaign
    p = Path(target)
    if p.is_dir():
        c = read_campaign(p, model)
        # a planar campaign's row lines as its reader found them, for the errors the planar
        # checks name; a chain campaign's reader has checked what names a line
        return c, dict(c.lines) if isinstance(c, Campaign) else {}
    if model:
        raise ConfigError(f"--model {model}: only with a campaign directory")
    if not p.exists():
        raise CampaignFormatError(p, "not found: give a campaign directory or an SQLite cycle log")
    with p.open("rb") as f:
        magic = f.read(len(SQLITE_MAGIC))
    if magic != SQLITE_MAGIC:
        raise CampaignFormatError(p, "neither a campaign directory nor an SQLite cycle log")
    from cell.cyclelog import CycleLog, CycleStatus
    from cell.cyclelog.export import cycles_to_campaign
    from cell.robots import PRESETS
    if robot not in PRESETS:
        raise ConfigError(f"--robot {robot!r}: unknown preset; known: {sorted(PRESETS)}")
    g = PRESETS[robot]
    log = CycleLog(p, readonly=True)
    try:
        c = cycles_to_campaign(log.cycles(status=CycleStatus.DONE), g.l1_mm, g.l2_mm,
                               command_unit_deg=g.unit[0],
                               joint_limits_deg=[list(map(float, g.limits[k])) for k in (0, 1)],
                               camera_center_mm=tuple(camera_center) if camera_center else None)
    except ValueError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    finally:
        log.close()
    c.source = str(p)
    return c, {}


# ------------------------------------------------------------------ validate
def _validate_options(args: argparse.Namespace, outside: tuple[str, ...], trials: int, points: int,
                      points_are: str, chain: bool = False) -> tuple[int, int, int, float, tuple]:
    """(trials, seed, points, outside share, outside kinds) of a validate call, defaults
    filled in. Raises ConfigError naming the option for anything out of range."""
    trials = trials if args.trials is None else args.trials
    seed = 0 if args.seed is None else args.seed
    points = points if args.points is None else args.points
    if trials < 1:
        raise ConfigError(f"--trials {trials} must be ≥ 1")
    if points < 20:
        raise ConfigError(f"--points {points} must be ≥ 20 ({points_are})")
    if seed < 0:
        raise ConfigError(f"--seed {seed} must be ≥ 0")
    if args.html:
        raise ConfigError("--html: not with 'validate' (it prints Markdown tables)")
    share = 0.0 if args.oov_share is None else args.oov_share
    if not 0.0 <= share <= 1.0:
        raise ConfigError(f"--out-of-vocabulary {args.oov_share} must be a share from 0 to 1")
    kinds = outside if args.oov_kinds is None else \
        tuple(k.strip() for k in args.oov_kinds.split(",") if k.strip())
    bad = [k for k in kinds if k not in outside]
    if bad or not kinds:
        raise ConfigError(f"--oov-kinds {args.oov_kinds!r}: unknown {', '.join(bad) or 'empty'}; "
                          f"{'with --chain ' if chain else ''}choose from {', '.join(outside)}")
    if args.oov_kinds is not None and share == 0.0:
        raise ConfigError("--oov-kinds: give --out-of-vocabulary SHARE > 0 as well")
    return trials, seed, points, share, kinds


def _print_scores(args: argparse.Namespace, module, ts: list, title: str) -> int:
    if args.json:
        print(json.dumps(json_safe(module.summarise(ts)), indent=2, allow_nan=False))
    else:
        print(module.markdown(ts, title))
    sys.stdout.flush()
    return 0


def run_validate(args: argparse.Namespace) -> int:
    if args.both:
        return run_validate_both(args)
    if args.chain:
        return run_validate_chain(args)
    from cell.diagnosis import validate
    trials, seed, points, share, kinds = _validate_options(args, validate.OUTSIDE, 200, 300,
                                                           "static poses per campaign")
    layout = args.layout or "realistic"
    with progress.bar("validate", total=trials, unit="campaign") as p:
        ts = validate.run(trials, seed, args.combos, points, outside_share=share, outside_kinds=kinds,
                          progress=lambda i, t: p.update(1), layout=layout)
    kind = "main effect + second" if args.combos else "one or two effects" \
        if layout == "realistic" else "single effect"
    moves = "0 or 4 moves" if layout == "realistic" else "6 moves"
    title = (f"Diagnosis validation, {layout} layout, {kind}: {trials} campaigns, seed {seed}, "
             f"{points} poses + {moves} each")
    if share:
        title += f", {share:g} of them outside the vocabulary ({', '.join(kinds)})"
    return _print_scores(args, validate, ts, title)


def run_validate_chain(args: argparse.Namespace) -> int:
    from cell.diagnosis.chain import validate
    if args.combos:
        raise ConfigError("--combos: not available with --chain yet (single effects only)")
    trials, seed, poses, share, kinds = _validate_options(args, validate.OUTSIDE, 100, 60,
                                                          "poses per chain campaign", chain=True)
    layout = args.layout or "realistic"
    with progress.bar("validate --chain", total=trials, unit="campaign") as p:
        ts = validate.run(trials, seed, poses, share, kinds, progress=lambda i, t: p.update(1),
                          layout=layout)
    title = (f"Chain diagnosis validation, {layout} layout: {trials} campaigns, seed {seed}, "
             f"{poses} poses × 3 markers each (UR5, tracker at an unknown pose)")
    if share:
        title += f", share {share:g} of them outside the vocabulary ({', '.join(kinds)})"
    return _print_scores(args, validate, ts, title)


def run_validate_both(args: argparse.Namespace) -> int:
    """Planar and chain validation with the same options; one verdict table for both."""
    from cell.diagnosis.chain import validate as chain
    from cell.diagnosis import validate as planar
    from cell.truth import verdict
    if args.chain or args.combos or args.points is not None or args.oov_kinds is not None:
        raise ConfigError("--both: give only --trials, --seed, --layout and --out-of-vocabulary "
                          "(each family keeps its own poses and kinds)")
    trials, seed, _, share, _ = _validate_options(args, planar.OUTSIDE, 100, 300, "")
    layout = args.layout or "realistic"
    with progress.bar("validate --both", total=2 * trials, unit="campaign") as p:
        tp = planar.run(trials, seed, False, 300, outside_share=share, layout=layout,
                        progress=lambda i, t: p.update(1))
        tc = chain.run(trials, seed, 60, share, layout=layout, progress=lambda i, t: p.update(1))
    if args.json:
        print(json.dumps(json_safe({"planar": planar.summarise(tp), "chain": chain.summarise(tc)}),
                         indent=2, allow_nan=False))
        return 0
    cmd = (f"cellctl diagnose validate --both --trials {trials} --seed {seed}"
           + (f" --layout {layout}" if args.layout else "")
           + (f" --out-of-vocabulary {share:g}" if share else ""))
    print("\n".join([f"### Validation verdicts: {trials} planar and {trials} chain campaigns, "
                     f"{layout} layout (`{cmd}`)", "", *verdict.TABLE_HEAD,
                     *verdict.table_lines("planar", tp, lambda t: t.outside),
                     *verdict.table_lines("chain", tc, lambda t: t.outside), ""]))
    print(planar.markdown(tp, f"Planar: {trials} campaigns, 300 poses each"))
    print()
    print(chain.markdown(tc, f"Chain: {trials} campaigns, 60 poses × 3 markers each"))
    sys.stdout.flush()
    return 0
