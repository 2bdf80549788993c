#!/usr/bin/env python3
"""Seed 002 straight lines streamed to simulated CANopen drives, measured in simulated time.
Prints Markdown tables.

Everything runs on the simulated clock (cell/sim/clock.py): the drives apply a set-point at
the exact instant its frame ends on the virtual wire plus their own latency, so a run is
exact and the same every time, whatever the host is doing.

Set-up: seed 002's robot (l1 = l2 = 200 mm, tool (0, 0, −50) mm), four drives on a 1 Mbit/s
wire in bus order j1..j4; drive i applies a received set-point σ·i after its frame ends
(seed 002's λᵢ = σ·i); 2^20-increment encoders (a 0.1 µm position step at the tool, so
quantisation stays below the figures); positions reported on change only (TPDO event timer
10 s), as a streaming application sets its drives. The controller (the real JointStations
driver) measures each drive's latency on the bus at start-up.

Two lines, each with the seed's equal steps (``time_law="linear"``): seed 002's own example
(400, 0, −50, 0) → (300, 0, −20, 45), which starts at full stretch (the singularity), and a
line well inside the workspace (250, −60, −30, 0) → (250, 60, −30, 0). For every σ, number of
segments n and tool speed v (segment time T = length / v / n), three modes:

* ``none`` — on reception, ωᵢ = Δθᵢ/T;
* ``corrected`` — on reception, ωᵢ = Δθᵢ/(T − λᵢ) with this burst's λᵢ (frame bits + latency);
* ``sync`` — written ahead, applied by all drives on one SYNC frame, ωᵢ = Δθᵢ/T.

Measured: the drives' true positions sampled on the clock, through forward kinematics.
"at the instants": perpendicular distance from the line at the instant each interpolation
point is due (the end of its segment; in sync mode plus the SYNC frame's own time on the
wire, when the drives apply it). "between": the largest over 20 samples per segment and the
settling tail. "chord floor": the same with every joint perfectly in step, i.e. the chord
error of joint-space interpolation, which no synchronisation removes. "|meas − model|": the
largest distance between the measured path and seed 002's jitter-free model
(``cell.motion.line.joint_positions_at``: each joint starts segment k λ late and runs
at its commanded speed until it arrives) fed with the delays the controller planned with.
"late bursts": bursts whose first frame found the wire busy (a heartbeat in flight, or in
``none`` mode with T < λ a drive's acknowledgement of the last segment), so they started
later than planned; "clipped": a commanded speed above the drive's 5000 units/s, which the
drive clips (``none`` and ``sync`` do not refuse it; near the stretched arm the joints
must turn fast). The model knows neither.

    .venv/bin/python bench/bench_can.py [--quick]
"""
from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import can  # noqa: E402
import numpy as np  # noqa: E402

from cell import progress  # noqa: E402
from cell.errors import TrajectoryError  # noqa: E402
from cell.kinematics import JOINT_NAMES, Scara  # noqa: E402
from cell.log import configure  # noqa: E402
from cell.motion.line import joint_positions_at, plan_line, tool_positions  # noqa: E402
from cell.motion.mover import segments_for  # noqa: E402
from cell.sim.clock import VirtualClock  # noqa: E402
from drivers.stations.bus import frame_time_s  # noqa: E402
from drivers.stations.config import StationConfig, StationsConfig  # noqa: E402
from drivers.stations.driver import JointStations  # noqa: E402
from drivers.stations.sim import SimStationSet  # noqa: E402

ROBOT = Scara.preset("seed002")
LINES = {
    "seed 002 (from full stretch)": (np.array([400.0, 0.0, -50.0, 0.0]), np.array([300.0, 0.0, -20.0, 45.0])),
    "inner (x = 250 mm)": (np.array([250.0, -60.0, -30.0, 0.0]), np.array([250.0, 60.0, -30.0, 0.0])),
}
MODES = ("none", "corrected", "sync")
SAMPLES = 20
ENCODER = 1 << 20


def stations_config() -> StationsConfig:
    return StationsConfig(channel=f"line-{uuid.uuid4().hex[:8]}", delays_s="measure", tpdo_event_ms=10_000,
                          stations=tuple(StationConfig(joint=j, node_id=i + 1, encoder_increments=ENCODER,
                                                       limits=tuple(ROBOT.g.limits[i]), max_velocity=5000.0)
                                         for i, j in enumerate(JOINT_NAMES)))


def deviation(xyz: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Perpendicular distance (mm) of each row of ``xyz`` from the line a → b."""
    u = (b - a) / np.linalg.norm(b - a)
    d = xyz - a
    return np.linalg.norm(d - np.outer(d @ u, u), axis=1)


@dataclasses.dataclass
class Row:
    line: str
    sigma_ms: float
    n: int
    speed: float
    mode: str
    T_ms: float
    at_points_um: float = float("nan")
    between_um: float = float("nan")
    floor_um: float = float("nan")
    model_um: float = float("nan")
    late: int = 0
    clipped: bool = False
    lam_ms: tuple = ()
    refused: str = ""


class Rig:
    """One σ: a clock, four drives and the controller's driver, started once."""

    def __init__(self, sigma: float):
        self.sigma = sigma
        self.clock = VirtualClock()
        self.cfg = stations_config()
        home = [0.0, 0.0, 0.0, 0.0]              # seed 002's start pose: the arm stretched along x
        self.sims = SimStationSet(self.cfg, [sigma * (i + 1) for i in range(4)], home, clock=self.clock)
        self.js = JointStations.from_config(self.cfg, clock=self.clock)
        self.sync_s = frame_time_s(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False), self.cfg.bitrate)
        # this thread keeps the clock's time for the rig's whole life: no simulated time may
        # pass while it computes between runs, or the runs would depend on the host
        self._attached = self.clock.attach("bench")
        self._attached.__enter__()
        self.sims.start()
        self.js.start()

    def close(self) -> None:
        self.js.shutdown()
        self.sims.stop()
        self._attached.__exit__(None, None, None)
        self.clock.close()

    def positions(self) -> np.ndarray:
        return np.array(self.sims.positions())

    def run(self, name: str, n: int, speed: float, mode: str) -> Row:
        a, b = LINES[name]
        length = float(np.linalg.norm(b[:3] - a[:3]))
        T = length / speed / n
        row = Row(name, self.sigma * 1e3, n, speed, mode, T * 1e3)
        plan = plan_line(ROBOT, a, b, n, T, time_law="linear")
        self.js.move_to(plan.joints_deg[0], 200.0)
        self.js.wait_reached(30.0, tol=1e-5)
        self.clock.sleep(0.05)
        try:
            segs, lams = segments_for(self.js, plan.joints_deg, T, mode)
        except TrajectoryError as exc:
            row.refused = ("T ≤ λ" if "not longer than the delay" in str(exc)
                           else "speed > max_velocity" if "max_velocity" in str(exc) else str(exc))
            return row
        if mode == "sync" and T <= float(np.max(lams)):
            row.refused = "T ≤ λ"
            return row
        lead = float(np.max(lams)) + 0.005 if mode == "sync" else 0.0
        start = self.clock.now() + lead
        shift = self.sync_s if mode == "sync" else 0.0     # drives apply at the SYNC frame's end
        tail = float(np.max(lams)) + T
        grid = np.linspace(0.0, n * T + tail, n * SAMPLES + 1 + int(SAMPLES * tail / T))
        instants = np.arange(n + 1) * T + shift
        times = np.unique(np.concatenate([grid, instants]))
        seen: dict[float, np.ndarray] = {}
        for t in times:
            self.clock.call_at(start + t, lambda t=t: seen.__setitem__(t, self.positions()))
        report = self.js.stream(segs, mode="sync" if mode == "sync" else "reception", lead_s=lead)
        self.clock.sleep_until(start + times[-1] + 1e-6)
        first_frame = report.sent - report.t0 - np.array([s.start_s for s in segs])
        first = self.cfg.stations[0]
        planned = (np.full(n, self.sync_s) if mode == "sync"
                   else lams[:, first.joint_index] - self.js.latency_s[first.joint_index])
        row.late = int(np.sum(first_frame - planned > 1e-9))
        top = np.array([self.cfg.station(j).max_velocity for j in JOINT_NAMES])
        row.clipped = bool(np.any(np.abs([s.velocity_deg_s for s in segs]) > top))
        q = np.array([seen[t] for t in times])
        xyz = tool_positions(ROBOT, q)
        dev = deviation(xyz, a[:3], b[:3]) * 1e3
        at = np.isin(times, instants)
        row.at_points_um = float(np.max(dev[at]))
        row.between_um = float(np.max(dev))
        model_plan = dataclasses.replace(plan, segments=segs)
        model_lam = lams if mode != "sync" else np.full((n, 4), shift)
        model = tool_positions(ROBOT, joint_positions_at(model_plan, model_lam, times))
        row.model_um = float(np.max(np.linalg.norm(model - xyz, axis=1))) * 1e3
        floor_plan = plan_line(ROBOT, a, b, n, T, time_law="linear")
        floor = tool_positions(ROBOT, joint_positions_at(floor_plan, np.zeros(4), grid))
        row.floor_um = float(np.max(deviation(floor, a[:3], b[:3]))) * 1e3
        row.lam_ms = tuple(round(float(x) * 1e3, 3) for x in np.mean(lams, axis=0))
        return row


def fmt(v: float, digits: int = 3) -> str:
    return "–" if v != v else f"{v:.{digits}f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="σ 1 ms only, n 10 and 50, 100 and 500 mm/s")
    args = ap.parse_args()
    configure("console", "ERROR")
    sigmas = (0.001,) if args.quick else (0.0005, 0.001, 0.002, 0.004)
    ns = (10, 50) if args.quick else (10, 50, 200)
    speeds = (100.0, 500.0) if args.quick else (100.0, 300.0, 500.0)
    t_wall = time.perf_counter()
    rows: list[Row] = []
    for sigma in progress.each(sigmas, "bus delays σ", "σ"):
        rig = Rig(sigma)
        try:
            for name in LINES:
                for n in ns:
                    for v in speeds:
                        for mode in MODES:
                            rows.append(rig.run(name, n, v, mode))
        finally:
            rig.close()
    wall = time.perf_counter() - t_wall

    print(f"#### Seed 002 lines on simulated CANopen drives, simulated time "
          f"(σ {', '.join(f'{s * 1e3:g}' for s in sigmas)} ms; n {', '.join(map(str, ns))}; "
          f"{', '.join(f'{v:g}' for v in speeds)} mm/s; Python {platform.python_version()}, {wall:.0f} s wall)\n")
    print("Maximum over every σ, n and speed the mode can run; deviations from the straight line in µm. "
          "\"as modelled\": the runs in which every burst found the wire free and no commanded speed "
          "was above the drive's limit (which clips it); \"all\": every run.\n")
    print("| line | mode | runs | refused (T ≤ λ, or a joint above max_velocity) | runs with a late burst "
          "| runs clipped by the drive | at the instants, as modelled | at the instants, all | between "
          "| chord floor | \\|meas − model\\|, as modelled | \\|meas − model\\|, all |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")

    def worst(runs, f):
        return max((f(r) for r in runs), default=float("nan"))
    for name in LINES:
        for mode in MODES:
            sel = [r for r in rows if r.line == name and r.mode == mode]
            ok = [r for r in sel if not r.refused]
            clean = [r for r in ok if not r.late and not r.clipped]
            print(f"| {name} | {mode} | {len(ok)} | {len(sel) - len(ok)} | {sum(1 for r in ok if r.late)} | "
                  f"{sum(1 for r in ok if r.clipped)} | "
                  f"{fmt(worst(clean, lambda r: r.at_points_um))} | {fmt(worst(ok, lambda r: r.at_points_um))} | "
                  f"{fmt(worst(ok, lambda r: r.between_um))} | {fmt(worst(ok, lambda r: r.floor_um))} | "
                  f"{fmt(worst(clean, lambda r: r.model_um), 4)} | {fmt(worst(ok, lambda r: r.model_um), 4)} |")
    print()
    print("#### Every run (µm; λ: mean per joint j1/j2/j3/j4 of the bursts, ms)\n")
    print("| line | σ ms | n | mm/s | T ms | mode | at the instants | between | chord floor | \\|meas − model\\| "
          "| late bursts | clipped | λ ms |")
    print("|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---|---|")
    for r in rows:
        if r.refused:
            print(f"| {r.line} | {r.sigma_ms:g} | {r.n} | {r.speed:g} | {r.T_ms:.3f} | {r.mode} | "
                  f"refused: {r.refused} | | | | | | |")
            continue
        print(f"| {r.line} | {r.sigma_ms:g} | {r.n} | {r.speed:g} | {r.T_ms:.3f} | {r.mode} | "
              f"{fmt(r.at_points_um)} | {fmt(r.between_um)} | {fmt(r.floor_um)} | {fmt(r.model_um, 4)} | "
              f"{r.late} | {'yes' if r.clipped else ''} | {'/'.join(f'{x:.3f}' for x in r.lam_ms)} |")


if __name__ == "__main__":
    main()
