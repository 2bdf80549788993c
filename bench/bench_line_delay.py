"""Straight lines under CAN station delays. Prints Markdown tables.

Seed 002 robot (l1 = l2 = 200 mm, tool (0, 0, −50)), 4 stations in bus order j1..j4
(λ_i = σ·i), segments T = 10 ms. A planar line at x = 300 mm, z = −30 mm, phi = 0, centred
on y = 0, 50 segments (0.5 s), so its length is speed × 0.5 s. Each plan is executed by the
station simulation of :func:`cell.motion.line.simulate_line` (each joint starts every
segment λ_i late, moves at its commanded velocity until it reaches the target, holds).

Reported: the maximum and mean perpendicular deviation from the line over the whole
simulated path (50 samples per segment) and the maximum at the interpolation instants k·T, for the uncorrected
velocities Δθ/T and the corrected Δθ/(T − λ). When T ≤ λ4 the correction does not exist
(the planner refuses it) and the table says so.

    .venv/bin/python bench/bench_line_delay.py [--quick]
"""
from __future__ import annotations

import argparse

import numpy as np

from cell.errors import TrajectoryError
from cell.kinematics import Scara
from cell.motion.line import joint_delays, max_line_deviation, plan_line, simulate_line

T = 0.010
N_SEGMENTS = 50
X, Z = 300.0, -30.0


def deviations(robot: Scara, plan, lam, samples: int) -> tuple[float, float, float]:
    """(max over the path, mean over the path, max at the interpolation instants), mm."""
    sim = simulate_line(robot, plan, lam, samples_per_segment=samples)
    a, b = plan.poses[0, :3], plan.poses[-1, :3]
    per_sample = [max_line_deviation(p[None, :], a, b) for p in sim.xyz_mm]
    return (max(per_sample), float(np.mean(per_sample)),
            max_line_deviation(sim.xyz_mm[sim.point_index], a, b))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one speed, two delays, coarse grid")
    args = ap.parse_args()
    speeds = (300.0,) if args.quick else (100.0, 300.0, 500.0)
    sigmas_ms = (0.0, 1.0, 4.0) if args.quick else (0.0, 0.5, 1.0, 2.0, 4.0)
    samples = 10 if args.quick else 50
    robot = Scara.preset("seed002")

    print(f"### Straight line under station delays (seed 002 robot, T = {T * 1e3:g} ms, "
          f"{N_SEGMENTS} segments, 4 stations j1..j4, {samples} samples per segment)\n")
    print("Deviation from the line in mm, uncorrected (Δθ/T) → corrected (Δθ/(T − λ)).\n")
    print("| speed mm/s | line mm | σ ms | λ4 ms | max uncorr. | max corr. | mean uncorr. "
          "| mean corr. | at points uncorr. | at points corr. |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for v in speeds:
        length = v * N_SEGMENTS * T
        start, end = (X, -length / 2, Z, 0.0), (X, length / 2, Z, 0.0)
        plain = plan_line(robot, start, end, N_SEGMENTS, T)
        for s in sigmas_ms:
            lam = joint_delays(s / 1e3)
            du = deviations(robot, plain, lam, samples)
            try:
                dc = deviations(robot, plan_line(robot, start, end, N_SEGMENTS, T, lam), lam, samples)
                corr = [f"{dc[0]:.4f}", f"{dc[1]:.4f}", f"{dc[2]:.1e}"]
            except TrajectoryError:
                corr = ["n/a (T ≤ λ4)"] * 3
            print(f"| {v:.0f} | {length:.0f} | {s:g} | {lam[-1] * 1e3:g} | {du[0]:.4f} | {corr[0]} "
                  f"| {du[1]:.4f} | {corr[1]} | {du[2]:.4f} | {corr[2]} |")
    print("\nσ = 0 rows: the chord error of joint-linear motion between interpolation points, "
          "which no delay correction removes.")


if __name__ == "__main__":
    main()
