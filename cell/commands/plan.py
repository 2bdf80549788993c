"""``cellctl plan``: straight-line moves with CAN delay correction (seed 002) and time laws
through joint way-points (seed 003).

    cellctl plan line --from 250,930,-20,0 --to 300,900,-20,0 \\
        [--config cell.yaml | --robot seed002] [--points 20] [--segment-ms 10] [--sigma-ms 1] \\
        [--stations j1,j2,j3,j4] [--json]
    cellctl plan line --robot seed002 --from 400,0,-50,0 --to 300,0,-20,45
    cellctl plan timelaw --waypoints "0,0;10,5;30,20;45,40" --duration-s 4 \\
        [--law quintic-poly|quintic-bspline|septic-bspline|all] [--timing uniform|chord]
        [--json] [--plot out.png]

``plan line`` plans for the cell's own robot: the ``robot`` section of ``--config``, else
that of the built-in cell config (:class:`cell.config.CellConfig`, preset seed000, l1 = l2 =
500 mm: the robot the simulated cell and the recipes' part positions are for). ``--robot
PRESET`` plans for a preset instead, e.g. seed 002's 200 mm arm.

Bad input (malformed way-points, T ≤ λ, unreachable poses) raises a
:class:`~cell.errors.CellError`; :mod:`cell.cli` prints it and exits with code 2.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from cell.commands import float_list, preset_name
from cell.errors import CellError, TrajectoryError
from cell.motion.names import LAWS, TIMINGS

if TYPE_CHECKING:
    import numpy as np

DEFAULT_STATIONS = "j1,j2,j3,j4"   # the kinematic order, cell.kinematics.JOINT_NAMES
#: what ``plan line --help`` says of its default robot (tests hold it to CellConfig().robot)
DEFAULT_ROBOT = ("the robot section of --config, else of the built-in cell config (preset "
                 "seed000, l1 = l2 = 500 mm, the simulated cell's)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan straight lines (seed 002) or time laws (seed 003)",
                       description="Plan straight-line moves with CAN delay correction (seed 002) "
                                   "or time laws through joint way-points (seed 003).")
    psub = p.add_subparsers(dest="plan_command", required=True, metavar="KIND")

    ln = psub.add_parser("line", help="straight line with per-segment joint targets and velocities",
                         description="Split a straight move into equal steps, print each segment's "
                                     "joint targets and velocities (uncorrected Δθ/T and corrected "
                                     "Δθ/(T−λ)), and the simulated deviation from the line. "
                                     "The robot is the cell's own: " + DEFAULT_ROBOT + ".")
    which = ln.add_mutually_exclusive_group()
    which.add_argument("--config", metavar="CELL.yaml",
                       help="plan for the robot (and elbow) of this cell config")
    which.add_argument("--robot", type=preset_name, default=None, metavar="PRESET",
                       help="plan for a robot preset instead of the cell's robot: seed002 (seed "
                            "002's arm, l1 = l2 = 200 mm) or seed000")
    ln.add_argument("--from", dest="start", type=float_list(4), required=True, metavar="X,Y,Z,PHI",
                    help="start pose: mm, mm, mm, deg")
    ln.add_argument("--to", dest="end", type=float_list(4), required=True, metavar="X,Y,Z,PHI",
                    help="target pose: mm, mm, mm, deg")
    ln.add_argument("--points", type=int, default=20, help="number of interpolation segments n (default 20)")
    ln.add_argument("--segment-ms", type=float, default=10.0, help="segment time T, ms (default 10)")
    ln.add_argument("--sigma-ms", type=float, default=1.0, help="per-frame bus delay σ, ms (default 1)")
    ln.add_argument("--stations", default=DEFAULT_STATIONS, metavar="J,J,J,J",
                    help="bus order of the joint stations (default j1,j2,j3,j4)")
    ln.add_argument("--elbow", choices=("right", "left"), default=None,
                    help="elbow (default: the cell config's, right in the built-in one)")
    ln.add_argument("--json", action="store_true", help="print the plan as JSON")
    ln.set_defaults(func=run_line)

    tl = psub.add_parser("timelaw", help="quintic polynomial / quintic / septic B-spline through way-points",
                         description="Fit time laws through joint way-points and print their peak "
                                     "velocity, acceleration and jerk.")
    tl.add_argument("--waypoints", required=True, metavar="Q;Q;...",
                    help="way-points, rows separated by ';', joints by ',' (deg or mm)")
    tl.add_argument("--duration-s", type=float, required=True, help="total duration, s")
    tl.add_argument("--law", choices=(*LAWS, "all"), default="all", help="law (default all)")
    tl.add_argument("--timing", choices=TIMINGS, default="uniform",
                    help="knot times: uniform or chord-length (default uniform)")
    tl.add_argument("--samples", type=int, default=200, help="samples per knot interval for peaks (default 200)")
    tl.add_argument("--json", action="store_true", help="print the results as JSON")
    tl.add_argument("--plot", default=None, metavar="PNG",
                    help="write position/velocity/acceleration plots to this file, or to "
                         "timelaw.png in this folder (.png added when it has no suffix)")
    tl.set_defaults(func=run_timelaw)


# --------------------------------------------------------------------------- line
def _station_order(text: str) -> tuple[str, ...]:
    from cell.kinematics import JOINT_NAMES
    order = tuple(s.strip() for s in text.split(",") if s.strip())
    if sorted(order) != sorted(JOINT_NAMES):
        raise TrajectoryError(f"--stations {text!r} must name each of {', '.join(JOINT_NAMES)} exactly once")
    return order


def _robot(args: argparse.Namespace):
    """(robot, its name, elbow) of ``plan line``: the ``--robot`` preset, else the robot
    section of ``--config``, else of the built-in cell config. Raises ConfigError naming
    file, line and field for a bad config."""
    from cell.kinematics import Scara
    if args.robot:
        return Scara.preset(args.robot), args.robot, args.elbow or "right"
    from cell.config import CellConfig
    section = (CellConfig.load(args.config) if args.config else CellConfig()).robot
    robot = section.scara()
    return robot, robot.g.name, args.elbow or section.elbow


def run_line(args: argparse.Namespace) -> int:
    from cell.kinematics import JOINT_NAMES
    from cell.motion.line import joint_delays, max_line_deviation, plan_line, simulate_line
    robot, robot_name, elbow = _robot(args)
    order = _station_order(args.stations)
    T = args.segment_ms / 1e3
    lam = joint_delays(args.sigma_ms / 1e3, order)
    plain = plan_line(robot, args.start, args.end, args.points, T, None, elbow, station_order=order)
    corr = plan_line(robot, args.start, args.end, args.points, T, lam, elbow, station_order=order)
    a, b = plain.poses[0, :3], plain.poses[-1, :3]
    dev = {}
    for name, plan in (("uncorrected", plain), ("corrected", corr)):
        sim = simulate_line(robot, plan, lam)
        dev[name] = {"max_mm": max_line_deviation(sim.xyz_mm, a, b),
                     "at_points_mm": max_line_deviation(sim.xyz_mm[sim.point_index], a, b),
                     "end_s": float(sim.times_s[-1])}
    if args.json:
        print(json.dumps({
            "robot": robot_name, "elbow": elbow, "from": args.start, "to": args.end, "points": args.points,
            "segment_ms": args.segment_ms, "sigma_ms": args.sigma_ms, "stations": list(order),
            "delays_ms": (lam * 1e3).tolist(),
            "segments": [{"index": s.index, "start_ms": s.start_s * 1e3, "target": s.target_deg.tolist(),
                          "velocity_uncorrected": s.velocity_deg_s.tolist(),
                          "velocity_corrected": c.velocity_deg_s.tolist()}
                         for s, c in zip(plain.segments, corr.segments)],
            "deviation": dev}, indent=2))
        return 0
    print(f"line {robot_name} (l1 = {robot.g.l1_mm:g} mm, l2 = {robot.g.l2_mm:g} mm, {elbow} elbow): "
          f"{tuple(args.start)} -> {tuple(args.end)}, n = {args.points}, "
          f"T = {args.segment_ms:g} ms, σ = {args.sigma_ms:g} ms, stations {','.join(order)} "
          f"(delays j1..j4 = {', '.join(f'{v:g}' for v in lam * 1e3)} ms)")
    print("θ* = segment target (deg, j3 mm); ω = Δθ/T uncorrected; ωc = Δθ/(T−λ) corrected "
          "(deg/s, j3 mm/s)")
    head = " | ".join(" ".join(f"{p + n:>9}" for n in JOINT_NAMES) for p in ("θ*", "ω ", "ωc "))
    print(f"{'k':>3} {'t ms':>7} | {head}")
    for s, c in zip(plain.segments, corr.segments):
        cols = " | ".join(" ".join(f"{v:>9.3f}" for v in arr)
                          for arr in (s.target_deg, s.velocity_deg_s, c.velocity_deg_s))
        print(f"{s.index:>3} {s.start_s * 1e3:>7.2f} | {cols}")
    for name in ("uncorrected", "corrected"):
        d = dev[name]
        print(f"max deviation from the line, {name:<11}: {d['max_mm']:.4f} mm over the path, "
              f"{d['at_points_mm']:.4f} mm at the interpolation instants (simulated, delays as above)")
    return 0


# --------------------------------------------------------------------------- time laws
def parse_waypoints(text: str) -> np.ndarray:
    """``"0,0;10,5;30,20"`` → array (m, J). Raises TrajectoryError naming the bad row."""
    import numpy as np
    rows = [r.strip() for r in text.strip().strip(";").split(";")]
    out: list[list[float]] = []
    for i, row in enumerate(rows):
        if not row:
            raise TrajectoryError(f"--waypoints: way-point {i} is empty in {text!r}")
        try:
            vals = [float(v) for v in row.split(",")]
        except ValueError:
            raise TrajectoryError(f"--waypoints: way-point {i} {row!r} is not a comma-separated "
                                  "list of numbers") from None
        if out and len(vals) != len(out[0]):
            raise TrajectoryError(f"--waypoints: way-point {i} {row!r} has {len(vals)} joints, "
                                  f"way-point 0 has {len(out[0])}")
        out.append(vals)
    return np.array(out, dtype=float)


def _plot(path: Path, trajs, samples: int) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # Agg only; no pyplot state
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 9), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    styles = ("-", "--", ":")
    for tr, style in zip(trajs, styles):
        t = tr.sample_times(samples)
        for nu, ax in enumerate(axes):
            y = tr(t, nu)
            for j in range(y.shape[1]):
                ax.plot(t, y[:, j], style, color=f"C{j}", label=f"{tr.law} q{j + 1}" if nu == 0 else None)
    axes[0].plot(trajs[0].knots_s, trajs[0].waypoints, "ko", ms=3)
    for ax, lab in zip(axes, ("position", "velocity /s", "acceleration /s²")):
        ax.set_ylabel(lab)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time, s")
    axes[0].legend(fontsize=7, ncol=3)
    try:
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise CellError(f"--plot {path}: cannot write the plot: {exc.strerror or exc}") from None


def run_timelaw(args: argparse.Namespace) -> int:
    from cell.commands import plot_file
    from cell.motion.timelaw import plan_timelaw
    q = parse_waypoints(args.waypoints)
    if args.samples < 2:
        raise TrajectoryError(f"--samples {args.samples} must be at least 2")
    plot = plot_file(args.plot or "", "timelaw.png", "--plot")
    if plot is not None and not plot.parent.is_dir():
        raise CellError(f"--plot {args.plot}: no folder {plot.parent} to write the plot in")
    laws = LAWS if args.law == "all" else (args.law,)
    trajs = [plan_timelaw(q, args.duration_s, law, args.timing) for law in laws]
    peaks = [tr.peaks(args.samples) for tr in trajs]
    if plot is not None:
        _plot(plot, trajs, args.samples)
    if args.json:
        print(json.dumps({
            "waypoints": q.tolist(), "duration_s": args.duration_s, "timing": args.timing,
            "knots_s": trajs[0].knots_s.tolist(),
            "laws": {tr.law: {"peak_velocity": pk.velocity.tolist(), "peak_acceleration": pk.acceleration.tolist(),
                              "peak_jerk": pk.jerk.tolist(), "overall": pk.overall}
                     for tr, pk in zip(trajs, peaks)}}, indent=2))
        return 0
    print(f"{q.shape[0]} way-points × {q.shape[1]} joints over {args.duration_s:g} s, {args.timing} knot times; "
          f"units per second of the way-point units")
    print(f"{'law':<16} {'joint':>5} {'peak |v|':>12} {'peak |a|':>12} {'peak |jerk|':>12}")
    for tr, pk in zip(trajs, peaks):
        for j in range(q.shape[1]):
            print(f"{tr.law:<16} {'q' + str(j + 1):>5} {pk.velocity[j]:>12.4f} "
                  f"{pk.acceleration[j]:>12.4f} {pk.jerk[j]:>12.4f}")
        o = pk.overall
        print(f"{tr.law:<16} {'all':>5} {o['velocity']:>12.4f} {o['acceleration']:>12.4f} {o['jerk']:>12.4f}")
    if plot is not None:
        print(f"plot written to {plot}")
    return 0
