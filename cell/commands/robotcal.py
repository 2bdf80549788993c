"""``cellctl calibrate joint|kinematics``: calibrate the robot from its own hand camera.

* ``calibrate joint J`` — seed 004 on joint J (j1, j2, j4; or 1, 2, 4): the target lies
  under the hand camera at the all-zero pose; the joint sweeps the range over which the
  target stays in view, forward and back, ``--runs`` times. Prints the per-step table
  (errors per pass, their difference, single-step errors), the backlash, gear-ratio error
  and cyclic error with 95 % intervals, and writes a PNG of error against angle. It
  records the joint's terms in the calibration file (a new version; ``--dry-run`` writes
  nothing): the backlash always applies (every arrival's via point clears it); a gear-ratio
  or cyclic term only when the kinematic fit, redone on the file's own poses with it,
  predicts the held-out poses better. It prints which apply and why the others do not
  (:mod:`cell.calibration.joint_terms`), and adds a row to the audit trail.
* ``calibrate kinematics`` — seed 001: the board of known points (``calibration.board``)
  lies on the work plane; the robot visits ``--poses`` poses chosen for identifiability and
  ``--holdout`` more for the check. Prints the held-out error before/after, the identified
  parameters with 95 % intervals and what the measurement cannot tell apart; writes the
  versioned calibration file (``calibration.file``, or ``--out``) only if the held-out
  check passes: the held-out rms improves, no held-out figure (rms, max) gets worse, and
  the residual is not far above the noise (:mod:`cell.calibration.check`); exit 2
  otherwise, nothing written, ``--dry-run`` included. ``--accept-worse`` writes a failing
  one anyway, with ``accept_worse: true`` and the ``warning`` in the file and a row in the
  audit trail (the config's cycle log, or ``--db``). The cell loads it at its next start
  (a cell running under the PLC applies a PLC-started calibration at once; the PLC never
  accepts a failed check).
* ``calibrate kinematics CAMPAIGN`` — the same fit and check on a chain campaign
  (:mod:`cell.calibration.chain`); writes the calibrated model directory (``--out``) with
  ``calibration.json``; ``--db`` adds a row to that cycle log's audit trail.

``--sim`` runs on the simulated cell (``--plant FILE``: a plant with effects the
calibration is not told); without it, on the hardware of ``--config`` (stop the cell
service first: the drives take one master).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from cell import paths, progress
from cell.commands import png_path
from cell.errors import ConfigError

DEFAULT_PNG = "var/calibration/{joint}-errors.png"   #: in the project folder (cell.paths)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="calibrate the robot from its hand camera (seed 004 joint, "
                                         "seed 001 kinematics)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND")
    j = kinds.add_parser("joint", help="seed 004: one joint's backlash, gear-ratio and cyclic error")
    j.add_argument("joint", help="j1, j2 or j4 (or 1, 2, 4)")
    j.add_argument("--runs", type=int, help="runs to average (default: calibration.runs, 3)")
    j.add_argument("--step-deg", type=float, help="step between images, deg (default: range / 10)")
    j.add_argument("--range-deg", type=float, help="sweep at most ±this, deg (default: as far as the "
                                                   "target stays in view)")
    j.add_argument("--period-deg", type=float, default=360.0,
                   help="period of the cyclic error, joint deg (default 360; a motor-side cycle of "
                        "a ratio-N drive is 360/N)")
    j.add_argument("--png", help=f"error plot to write, or a folder for it (default {DEFAULT_PNG.format(joint='<joint>')})")
    j.add_argument("--out", help="calibration file to record the joint's terms in (default: calibration.file)")
    j.add_argument("--dry-run", action="store_true", help="measure and report; write no calibration")
    j.add_argument("--db", help="cycle log whose audit trail records the write (default: the cell "
                                "config's log; none with --sim)")
    _common(j)
    j.set_defaults(func=run_joint)
    k = kinds.add_parser("kinematics", help="seed 001: DH parameters from poses over the board, "
                                            "or of any chain from a campaign")
    k.add_argument("campaign", nargs="?", metavar="CAMPAIGN",
                   help="a chain campaign (kinematics dh or urdf): fit it offline instead of "
                        "measuring; --out DIR gets the calibrated model (default CAMPAIGN-calibrated)")
    k.add_argument("--poses", type=int, help="poses for the fit (default: calibration.poses, 24)")
    k.add_argument("--holdout", type=int, help="held-out poses for the check (default: calibration.holdout, 12)")
    k.add_argument("--out", help="calibration file to write (default: calibration.file); with "
                                 "CAMPAIGN, the directory of the calibrated model")
    k.add_argument("--dry-run", action="store_true", help="measure and report; write nothing")
    k.add_argument("--accept-worse", action="store_true",
                   help="write the calibration even when its check fails (a held-out figure got "
                        "worse, or the residual is far above the noise); the warning goes into "
                        "the written file and the audit trail")
    k.add_argument("--db", help="cycle log whose audit trail records the write (default: the cell "
                                "config's log.path; with CAMPAIGN, none unless given)")
    _common(k)
    k.set_defaults(func=run_kinematics)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sim", action="store_true", help="the simulated cell")
    p.add_argument("--plant", help="with --sim: plant file (default: the config's, deploy/plants/default.yaml)")
    p.add_argument("--config", help="cell config (required without --sim)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _config(args):
    from cell.commands.run import load_config
    if not args.sim and not args.config:
        raise ConfigError("calibrate: --config is required without --sim")
    if args.plant and not args.sim:
        raise ConfigError("calibrate: --plant needs --sim")
    cfg = load_config(args.config, args.sim)
    if args.plant:
        if not Path(args.plant).is_file():
            raise ConfigError(f"{args.plant}: plant file not found")
        cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"plant": args.plant})})
    return cfg


def _session(args, body):
    """Bring the devices up, run ``body(calibrator)`` on their clock, take them down."""
    cfg = _config(args)
    if getattr(args, "out", None):
        cfg = cfg.model_copy(update={"calibration": cfg.calibration.model_copy(update={"file": args.out})})
    with _sole_master(cfg, args.sim):
        return _run_session(cfg, args, body)


@contextlib.contextmanager
def _sole_master(cfg, sim: bool):
    """On hardware, hold the cell's log lock for the session: the drives take one master, so
    a calibration beside a running controller is refused before any drive is touched (the
    simulated cell's devices are this process's own: nothing to hold)."""
    from cell.errors import LogError
    from cell.cyclelog.file import LogLock
    if sim:
        yield
        return
    lock = LogLock(Path(cfg.log.path))
    try:
        Path(cfg.log.path).parent.mkdir(parents=True, exist_ok=True)
        lock.acquire()
    except (LogError, OSError) as exc:
        raise ConfigError(f"calibrate: {exc}; a calibration on hardware needs the cell to itself "
                          "(the drives take one master): stop the cell service first") from None
    try:
        yield
    finally:
        lock.release()


def _run_session(cfg, args, body):
    from cell.calibration.service import CellCalibrator, load_active
    from cell.devices import open_devices
    devices = open_devices(cfg, "sim" if args.sim else "hardware")
    try:
        with devices.clock.attach("calibrate"):
            try:
                robot, caldoc = load_active(cfg, devices.robot)   # a bad calibration file refuses here
                devices.start()
                return body(CellCalibrator(cfg, devices, devices.robot, robot=robot,
                                           version=int(caldoc["version"]) if caldoc else 0))
            finally:
                devices.stop()
    finally:
        close = getattr(devices.clock, "close", None)
        if close is not None:
            close()


def _joint_name(text: str) -> str:
    name = text if text.startswith("j") else f"j{text}"
    if name not in ("j1", "j2", "j3", "j4"):
        raise ConfigError(f"calibrate joint: {text!r} is not a joint (j1, j2, j4)")
    return name


# ---------------------------------------------------------------------- joint
def run_joint(args: argparse.Namespace) -> int:
    from cell.calibration.joint import plot
    joint = _joint_name(args.joint)
    if args.runs is not None and args.runs < 1:
        raise ConfigError(f"--runs {args.runs} must be ≥ 1")
    from cell.calibration import calfile
    with progress.bar(f"calibrate {joint}", unit="image") as bar:
        cal, (plan, result) = _session(args, lambda cal: (cal, cal.joint(
            joint, runs=args.runs, step_deg=args.step_deg, range_deg=args.range_deg,
            period_deg=args.period_deg, progress=progress.callback(bar), write=not args.dry_run)))
    png = png_path(args.png, f"{joint}-errors.png") if args.png else paths.project(DEFAULT_PNG.format(joint=joint))
    png.parent.mkdir(parents=True, exist_ok=True)
    plot(result, png)
    doc = cal.written
    terms = (doc.get("joints") or {}).get(joint) if doc else None
    written = None if doc is None else {"path": str(cal.path), "version": doc["version"],
                                        "id": calfile.calibration_id(doc), "applied": terms["applied"],
                                        "why": terms["why"]}
    if doc is not None:
        db = args.db or (None if args.sim else cal.config.log.path)
        if db:
            audit_calibration(db, "calibration_write", cal.path,
                              f"{calfile.calibration_id(doc)}: seed 004 {joint}: applied "
                              f"{', '.join(['backlash', *terms['applied']])}", str(doc.get("sha256", "")))
    if args.json:
        print(json.dumps({"plan": plan.as_dict(), "result": result.as_dict(), "png": str(png),
                          "written": written}, indent=2))
        return 0
    _print_joint(plan, result, png)
    if written:
        print(f"written: {written['path']} ({written['id']}); applied: "
              f"{', '.join(['backlash', *written['applied']])}")
        if written["why"]:
            print(f"  not applied: {written['why']}")
    else:
        print("written: nothing (--dry-run)")
    return 0


def _print_joint(plan, result, png: Path) -> None:
    print(f"{plan.joint}: {result.n_runs} run(s) × {len(plan.nominal_deg)} angles, step {plan.step_deg:g}°, "
          f"range {plan.nominal_deg[-1]:+g}° .. {plan.nominal_deg[0]:+g}° ({plan.reason})")
    print(f"circle: centre ({result.circle.center[0]:.3f}, {result.circle.center[1]:.3f}) mm, radius "
          f"{result.circle.radius:.3f} mm, fit rms {result.circle.rms * 1000:.1f} µm")
    print()
    print(f"{'nominal °':>10} {'forward °':>10} {'return °':>10} {'fwd−ret °':>10} {'fwd step °':>11} "
          f"{'ret step °':>11}")
    for r in result.rows:
        def f(v):
            return f"{v:+.5f}" if v is not None and v == v else "-"
        print(f"{r.nominal_deg:>+10.4f} {f(r.forward_deg):>10} {f(r.return_deg):>10} "
              f"{f(r.difference_deg):>10} {f(r.forward_step_deg):>11} {f(r.return_step_deg):>11}")
    print()

    def est(name, e, k=1.0, unit=""):
        print(f"{name:<22} {e.value * k:+.5g} {unit}   95 % [{e.low * k:+.5g}, {e.high * k:+.5g}]")
    est("backlash", result.backlash_deg, 3600, "arcsec")
    est("gear-ratio error", result.gear_ratio_error, 1e6, "ppm")
    est("offset at the zero image", result.offset_deg, 3600, "arcsec")
    for h in result.harmonics:
        est(f"cyclic k={h.k} (P {h.period_deg:g}°)", h.amplitude, 3600, "arcsec amplitude")
    shut = [t for t in result.harmonic_tests if t.status == "not identifiable"]
    for t in result.harmonic_tests:
        if t.status not in ("accepted", "not identifiable"):
            print(f"  cyclic k={t.k}: {t.status}: {t.reason}")
    if shut:
        print(f"  cyclic k={', '.join(str(t.k) for t in shut)} (periods {shut[0].period_deg:g}°.."
              f"{shut[-1].period_deg:g}°): not identifiable over this range ({shut[0].reason.split(': ')[-1]} "
              "for the first)")
    rep = f"{result.repeatability_deg * 3600:.3g} arcsec" if result.repeatability_deg is not None else "n/a"
    print(f"model residual rms {result.residual_rms_deg * 3600:.3g} arcsec; run-to-run repeatability {rep}")
    print(f"plot: {png}")


# ---------------------------------------------------------------------- kinematics
def run_kinematics(args: argparse.Namespace) -> int:
    if args.campaign:
        return run_chain(args)
    from cell.calibration import calfile

    with progress.bar("calibrate kinematics", unit="pose") as bar:
        cal, out = _session(args, lambda cal: (cal, cal.kinematics(
            poses=args.poses, holdout=args.holdout, write=not args.dry_run,
            accept_worse=args.accept_worse, progress=progress.callback(bar))))
    doc = out.document
    report = {"parameters": out.parameters(cal.nominal), **out.report(),
              "gear_ratio": out.gear_ratio, "joints": out.joints,
              "written": None if doc is None else
              {"path": str(cal.path), "version": doc["version"], "id": calfile.calibration_id(doc)},
              "accept_worse": bool(doc and doc["accept_worse"]), "warning": doc["warning"] if doc else None}
    if doc is not None:
        db = args.db or (None if args.sim else cal.config.log.path)
        if db:
            audit_calibration(db, "calibration_write", cal.path,
                              f"{calfile.calibration_id(doc)}: " + (doc["warning"] or "check passed"),
                              str(doc.get("sha256", "")))
    from cell.jsonsafe import json_safe
    if args.json:
        print(json.dumps(json_safe(report), indent=2, allow_nan=False))
    else:
        _print_kinematics(out, report)
    return _verdict_exit(out.holdout.passed, out.holdout.reason, doc is not None)


def run_chain(args: argparse.Namespace) -> int:
    """Seed 001 on a chain campaign (:mod:`cell.calibration.chain`): no cell, no devices."""
    given = [f"--{n}" for n in ("poses", "holdout", "plant", "config") if getattr(args, n) is not None]
    given += ["--sim"] if args.sim else []
    if given:
        raise ConfigError(f"{', '.join(given)}: not with a CAMPAIGN (the campaign holds the poses)")
    from cell.calibration.chain import calibrate_chain, write_calibrated
    from cell.jsonsafe import json_safe
    from cell.measurements import Campaign, read_campaign
    c = read_campaign(args.campaign)
    if isinstance(c, Campaign):
        raise ConfigError(f"{args.campaign}: a SCARA campaign; CAMPAIGN must be a chain (kinematics dh "
                          "or urdf). The SCARA is calibrated from its hand camera: omit CAMPAIGN")
    out = Path(args.out) if args.out else Path(str(Path(args.campaign)).rstrip("/") + "-calibrated")
    if out.resolve() == Path(args.campaign).resolve():
        raise ConfigError(f"--out {out}: would overwrite the campaign itself")
    cal = calibrate_chain(c)
    report = cal.report()
    written = None
    if (cal.passed or args.accept_worse) and not args.dry_run:
        try:
            written = write_calibrated(cal, out, accept_worse=args.accept_worse)
        except OSError as exc:
            raise ConfigError(f"--out {out}: cannot write: {exc}") from None
        if args.db:
            audit_calibration(args.db, "chain_calibration_write", written["report"],
                              written["warning"] or "written; check passed")
    report["written"] = written
    report["accept_worse"] = written is not None and written["warning"] is not None
    report["warning"] = written["warning"] if written else None
    if args.json:
        print(json.dumps(json_safe(report), indent=2, allow_nan=False))
    else:
        _print_chain(report)
    return _verdict_exit(cal.passed, report["check"]["reason"], written is not None)


def _verdict_exit(passed: bool, reason: str, written: bool) -> int:
    """0 when the check passed; when it failed, 0 if the calibration was written anyway
    (``--accept-worse``, warned on stderr), else 2 with the reason on stderr."""
    if passed:
        return 0
    if written:
        print(f"cellctl calibrate kinematics: warning: written with --accept-worse although the "
              f"check failed: {reason}", file=sys.stderr)
        return 0
    print(f"cellctl calibrate kinematics: error: check failed, nothing written: {reason}"
          + ("" if "--accept-worse" in reason else " (--accept-worse writes it anyway, with a warning)"),
          file=sys.stderr)
    return 2


def audit_calibration(db, action: str, written, result: str, hash_: str | None = None) -> None:
    """One row in the audit trail of the cycle log ``db`` (created if missing): ``action`` on
    the ``written`` file (its SHA-256 unless ``hash_`` is given), ``result`` in words
    (the warning of a calibration written with ``--accept-worse``)."""
    import hashlib
    from cell.cyclelog import CycleLog
    from cell.errors import LogError
    try:
        log = CycleLog(db)
    except LogError as exc:
        raise ConfigError(f"--db {db}: cannot record the calibration in the audit trail: {exc}") from None
    try:
        log.audit("cellctl", action, str(written), hash_ or hashlib.sha256(Path(written).read_bytes()).hexdigest(),
                  result)
    finally:
        log.close()


def _print_chain(r: dict) -> None:
    h, f, s = r["holdout"], r["fit"], r["split"]
    print(f"held-out poses ({s['holdout_poses']}): rms {h['rms_before_mm']:.4f} → {h['rms_after_mm']:.4f} mm "
          f"(shrink {h['shrink']:.3f}), max {h['max_before_mm']:.4f} → {h['max_after_mm']:.4f} mm "
          f"(before: nominal model, registration fitted)")
    print(f"fit ({s['fit_poses']} poses): rms {f['rms_before_mm']:.4f} → {f['rms_after_mm']:.4f} mm; "
          f"leave-one-pose-out {f['cv_rms_before_mm']:.4f} → {f['cv_rms_after_mm']:.4f} mm")
    idn = r["identifiability"]
    print(f"identifiability: rank {idn['rank']} of {idn['columns']} (registration included), "
          f"condition number {idn['condition']:.3g}")
    print()
    print(f"{'parameter':<26} {'value':>10} {'std error':>10} {'95 % interval':>24} unit")
    for name, p in r["parameters"].items():
        print(f"{name:<26} {p['value']:>+10.4f} {p['se']:>10.4f} [{p['low']:>+10.4f}, {p['high']:>+10.4f}] "
              f"{p['unit']}")
    if r["not_selected"]:
        print(f"  identifiable but not improving left-out poses (kept nominal): {', '.join(r['not_selected'])}")
    absorbed = [n for n, why in r["not_identifiable"].items() if "registration" in why]
    if absorbed:
        print(f"  absorbed by the registration (kept nominal): {', '.join(absorbed)}")
    for n, why in r["not_identifiable"].items():
        if "registration" not in why:
            print(f"  {n}: {why} (kept nominal)")
    print()
    _print_check(r["check"])
    if r["written"]:
        print(f"written: {r['written']['model']}; diagnose on it with "
              f"'cellctl diagnose {r['written']['dir']}'")
        if r["warning"]:
            print(f"WARNING: {r['warning']}")


def _print_check(check: dict) -> None:
    """The check's verdict: PASSED with the held-out figures, or FAILED with each failed rule."""
    for n in check["noise"]:
        if n["sigma"] is not None:
            print(f"noise: residual σ {n['residual_sigma']:.4g} {n['unit']} per axis, measured noise σ "
                  f"{n['sigma']:.4g} {n['unit']} ({n['source']}): {n['ratio']:.3g}×")
        else:
            print(f"noise: unknown ({n['source']}); residual σ {n['residual_sigma']:.4g} {n['unit']} per axis")
    if check["passed"]:
        print(f"check: {check['reason']}: PASSED")
        return
    print("check: FAILED")
    for line in check["failures"]:
        print(f"  {line}")


def _print_kinematics(out, report: dict) -> None:
    h = out.holdout
    ident = out.identification
    print(f"held-out poses ({h.n_hold}): rms {h.rms_xy_before_mm:.4f} → {h.rms_xy_after_mm:.4f} mm, "
          f"max {h.max_xy_before_mm:.4f} → {h.max_xy_after_mm:.4f} mm "
          f"(before: nominal model with the board's place fitted)")
    print(f"fit ({len(out.q_fit)} poses): rms {ident.rms_xy_mm:.4f} mm, rank {ident.report.rank}, "
          f"condition {ident.condition_number:.3g}")
    print()
    print(f"{'parameter':<10} {'value':>10} {'std error':>10} {'95 % interval':>24} unit")
    for name, p in report["parameters"].items():
        print(f"{name:<10} {p['value']:>+10.4f} {p['se']:>10.4f} [{p['low']:>+10.4f}, {p['high']:>+10.4f}] "
              f"{p['unit']}")
    for f in ident.report.fixed:
        if f["reason"] == "merged":
            into = " + ".join(f"{c:+.3g}·{k}" for k, c in f["merged_into"].items())
            print(f"  {f['param']}: appears only together with {into}; merged there")
    unseen = ident.report.unobservable
    if unseen:
        print(f"  not observable from x, y over the board (fixed at nominal): {', '.join(unseen)}")
    g = out.gear_ratio or {}
    for j in (k for k in g if k not in ("applied", "why")):
        e = g[j]
        print(f"{j + ' gear':<10} {e['value'] * 1e6:>+10.1f} {'':>10} [{e['low'] * 1e6:>+10.1f}, "
              f"{e['high'] * 1e6:>+10.1f}] ppm{': applied' if j in g['applied'] else ''}")
    if g.get("why"):
        print(f"  gear ratios not applied: {g['why']}")
    for j, e in (out.joints or {}).items():
        print(f"  seed 004 {j}: applied {', '.join(['backlash', *e['applied']])}"
              + (f"; {e['why']}" if e["why"] else ""))
    print()
    if h.passed:
        print(f"check: {h.reason}: PASSED")
    else:
        print("check: FAILED")
        for line in h.reason.split("; "):
            print(f"  {line}")
    w = report["written"]
    if w:
        print(f"written: {w['path']} (version {w['version']}, id {w['id']}); the cell uses it from its next start")
        if report["warning"]:
            print(f"WARNING: {report['warning']}")
    elif h.passed:
        print("not written (--dry-run)")
