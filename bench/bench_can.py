#!/usr/bin/env python3
"""CAN benchmark for the joint stations (issue 3). Prints Markdown tables.

1. Set-point frames per second (8-byte RPDO frames, one sender, back to back) through the
   rate-limited virtual bus at 1 Mbit/s and through python-can's unlimited virtual bus.
2. Seed 002 straight line (400, 0, −50, 0) → (300, 0, −20, 45) with per-frame delay
   σ = 1, 2, 4 ms (station i applies its set-points σ·i late): uncorrected velocities,
   corrected with the configured σ·i, corrected with delays measured on the bus, and
   SYNC mode. Real simulated stations on the virtual bus; the tool path is the forward
   kinematics (Scara.preset("seed002")) of the actual positions the stations report by
   TPDO, interpolated on the TPDO timestamps. "error at points": tool distance from
   interpolation point k at the instant it is due (segment k's send time + T), max over k;
   "max path deviation": largest distance of the tool path from the straight line (this
   includes the chord error of joint-linear segments, 0.72 mm here even without delay).
   "model" is cell.trajectory.line.simulate_line with the configured σ·i delays (SYNC: none),
   i.e. the same motion without bus, thread latency or TPDO sampling.

    .venv/bin/python bench/bench_can.py [--quick]
"""
from __future__ import annotations

import argparse
import sys
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import can  # noqa: E402
import numpy as np  # noqa: E402

from cell.kinematics import Scara  # noqa: E402
from cell.log import configure  # noqa: E402
from cell.trajectory.line import (joint_delays, max_line_deviation, plan_line, simulate_line,  # noqa: E402
                                  tool_positions)
from drivers.stations.bus import frame_time_s, open_bus  # noqa: E402
from drivers.stations.config import StationsConfig  # noqa: E402
from drivers.stations.driver import JointStations  # noqa: E402
from cell.sim.stations import SimStationSet  # noqa: E402

ROBOT = Scara.preset("seed002")
START, END = np.array([400.0, 0.0, -50.0, 0.0]), np.array([300.0, 0.0, -20.0, 45.0])


def bench_rate(n: int) -> list[str]:
    rows = []
    msg = can.Message(arbitration_id=0x201, data=bytes(range(8)), is_extended_id=False)
    for label, limited in (("rate-limited virtual, 1 Mbit/s", True), ("python-can virtual (unlimited)", False)):
        ch = f"bench-{uuid.uuid4().hex[:6]}"
        tx, rx = open_bus("virtual", ch, rate_limited=limited), open_bus("virtual", ch, rate_limited=limited)
        try:
            t0 = time.perf_counter()
            for _ in range(n):
                tx.send(msg)
            stamps = [rx.recv(5.0).timestamp for _ in range(n)]
            wall = time.perf_counter() - t0
        finally:
            tx.shutdown()
            rx.shutdown()
        span = stamps[-1] - stamps[0]
        rows.append(f"| {label} | {n} | {wall * 1e3:.1f} | {n / wall:,.0f} | "
                    f"{(n - 1) / span:,.0f} | {1 / frame_time_s(msg, 1_000_000):,.0f} |")
    return ["| bus | frames | wall ms | frames/s (wall) | frames/s (rx timestamps) | 1 Mbit/s bound for this frame |",
            "|---|---|---|---|---|---|", *rows]


def _sampled(rec):
    """Joint positions (N, 4) on a common grid from the TPDO samples (time, joint, value)."""
    rec = np.asarray(rec)
    tr = [rec[rec[:, 1] == j] for j in range(4)]
    return lambda t: np.column_stack([np.interp(t, tr[j][:, 0], tr[j][:, 2]) for j in range(4)]), \
        max(x[0, 0] for x in tr), min(x[-1, 0] for x in tr)


def _errors(q_at, t_points, t_lo, t_hi, plan) -> tuple[float, float, float]:
    """(max and RMS tool error at the interpolation points, max path deviation), mm."""
    at_points = tool_positions(ROBOT, q_at(t_points))
    err = np.linalg.norm(at_points - tool_positions(ROBOT, plan.joints_deg[1:]), axis=1)
    path = tool_positions(ROBOT, q_at(np.linspace(t_lo, t_hi, 4000)))
    return float(err.max()), float(np.sqrt(np.mean(err ** 2))), max_line_deviation(path, START[:3], END[:3])


def run_line(js: JointStations, plan, mode: str) -> tuple[float, float, float]:
    js.move_to(plan.joints_deg[0], 200.0)
    js.wait_reached(timeout_s=5.0, tol=1e-3)
    time.sleep(0.02)
    js.start_recording()
    report = js.stream(plan.segments, mode=mode)
    js.wait_reached(timeout_s=5.0, tol=1e-3)
    time.sleep(0.02)
    q_at, lo, hi = _sampled(js.stop_recording())
    # segment k was sent (first frame / SYNC) at report.sent[k-1]; its point is due T later
    return _errors(q_at, report.sent + plan.segment_s, lo, hi, plan)


def bench_line(sigmas, n_points: int, segment_s: float) -> list[str]:
    rows = []
    for sigma in sigmas:
        cfg = StationsConfig(channel=f"bench-{uuid.uuid4().hex[:6]}", tpdo_event_ms=2, heartbeat_ms=100,
                             heartbeat_tolerance=3.0)
        lam_cfg = joint_delays(sigma, [s.joint for s in cfg.stations])
        sims = SimStationSet(cfg, [sigma * (i + 1) for i in range(4)], initial_positions=[0, 0, 0, 0]).start()
        js = JointStations.from_config(cfg)
        try:
            js.start()
            lam_meas = js.measure_delays(rounds=7)
            variants = [("uncorrected", None, "reception"), ("corrected, configured σ·i", lam_cfg, "reception"),
                        ("corrected, measured", lam_meas, "reception"), ("SYNC", None, "sync")]
            for label, lam, mode in variants:
                plan = plan_line(ROBOT, START, END, n_points, segment_s, delays_s=lam)
                point_err, point_rms, path_dev = run_line(js, plan, mode)
                sim = simulate_line(ROBOT, plan, np.zeros(4) if mode == "sync" else lam_cfg)
                m_point = float(np.max(np.linalg.norm(sim.xyz_mm[sim.point_index[1:]]
                                                      - tool_positions(ROBOT, plan.joints_deg[1:]), axis=1)))
                m_path = max_line_deviation(sim.xyz_mm, START[:3], END[:3])
                rows.append(f"| {sigma * 1e3:.0f} | {label} | {point_err:.3f} | {point_rms:.3f} | {m_point:.3f} | {path_dev:.3f} | "
                            f"{m_path:.3f} | "
                            + ("-" if lam is None else " / ".join(f"{x * 1e3:.2f}" for x in lam)) + " |")
        finally:
            js.shutdown()
            sims.stop()
    return ["| σ ms | velocities | error at points, max mm | RMS mm | model max mm | max path deviation mm | "
            "model mm | delays used j1/j2/j3/j4 ms |", "|---|---|---|---|---|---|---|---|", *rows]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames, σ = 2 ms only")
    args = ap.parse_args(argv)
    configure(level="WARNING")
    n = 500 if args.quick else 3000
    sigmas = (0.002,) if args.quick else (0.001, 0.002, 0.004)
    n_points, segment_s = 10, 0.05
    print("## Set-point frames per second\n")
    print("\n".join(bench_rate(n)))
    print(f"\n## Seed 002 straight line (400, 0, −50, 0) → (300, 0, −20, 45), n = {n_points}, "
          f"T = {segment_s * 1e3:.0f} ms, station i delayed σ·i\n")
    print("\n".join(bench_line(sigmas, n_points, segment_s)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
