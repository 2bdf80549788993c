"""``cellctl compensate``: run a compensation method on the nominal robot model and print its trace."""
from __future__ import annotations

import argparse
import json

from cell.commands import float_list
from cell.errors import KinematicsError

METHODS = ("lattice", "paper")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="run grid (paper) or lattice compensation on the nominal model",
                       description="Compensate the planar position towards a target on the nominal "
                                   "model (seed 000's simulation set-up by default) and print the trace.")
    p.add_argument("--method", choices=METHODS, default="lattice",
                   help="lattice (ours, default) or paper (seed 000's grid model)")
    p.add_argument("--l1", type=float, default=500.0, help="link 1 length, mm (default 500)")
    p.add_argument("--l2", type=float, default=500.0, help="link 2 length, mm (default 500)")
    p.add_argument("--start-deg", type=float_list(2), default=None, metavar="T1,T2",
                   help="first joint command in degrees (default: IK of the target)")
    p.add_argument("--unit-deg", type=float, default=0.01, help="joint command unit, degrees (default 0.01)")
    p.add_argument("--k", type=int, default=16, help="paper: first grid spacing in command units (default 16)")
    p.add_argument("--target", type=float_list(2), required=True, metavar="X,Y", help="target, mm")
    p.add_argument("--json", action="store_true", help="print the trace as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cell.compensation.arms import NominalArm
    from cell.compensation.lattice import run_lattice
    from cell.compensation.paper import run_paper
    from cell.kinematics import Scara
    from cell.robots import Geometry
    if not args.unit_deg > 0:
        raise KinematicsError(f"--unit-deg {args.unit_deg} must be > 0")
    try:
        geometry = Geometry(name="cli", l1_mm=args.l1, l2_mm=args.l2, unit=(args.unit_deg,) * 4)
    except ValueError as exc:
        raise KinematicsError(f"robot geometry: {exc}") from None
    robot = Scara(geometry)
    start = None
    if args.start_deg is not None:
        robot.check_limits(args.start_deg, joints=(0, 1))
        start = robot.to_units(args.start_deg)
    arm = NominalArm(robot)
    if args.method == "paper":
        result = run_paper(robot, arm, args.target, k=args.k, start_units=start)
    else:
        result = run_lattice(robot, arm, args.target, start_units=start)
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
        return 0
    print(f"method {result.method}, target ({args.target[0]:.4f}, {args.target[1]:.4f}) mm")
    print(f"{'step':>4} {'k':>3} {'θ1 deg':>10} {'θ2 deg':>10} {'x mm':>11} {'y mm':>11} "
          f"{'error mm':>9} {'moved':>5}  note")
    for i, s in enumerate(result.steps):
        print(f"{i:>4} {s.spacing_units:>3} {s.joints_deg[0]:>10.2f} {s.joints_deg[1]:>10.2f} "
              f"{s.point_mm[0]:>11.4f} {s.point_mm[1]:>11.4f} {s.error_mm:>9.4f} "
              f"{'yes' if s.moved else 'no':>5}  {s.note}")
    print(f"final error {result.final_error_mm:.4f} mm after {result.moves} moves")
    return 0
