"""Compensation on the full plant: the cell's final error against the best the plant allows.

The cell's compensation step (:func:`cell.cycle.runner.compensate`: the first command from the
learned residual, the lattice, backlash taken up from the calibrated side) drives the
simulated plant the cell runs (:class:`cell.sim.plant.PlantArm`: joint zeros, link lengths,
backlash, thermal warm-up, and on ``untold`` gear ratios and motor-side cyclic errors;
arrival repeatability and camera noise), without CAN or rendering, for the parts of
bracket-a (placed as the simulated feeder places them). Between parts the clock moves on
by a cycle time, so the arm warms as in the cell. The part is measured by the same camera
model as the tool.

For every part, at the moment of its final arrival, the **floor** is what the best
whole-unit command reaches on the true plant: every command within ±6 units of the final
one, with backlash taken up from the approach side, the cyclic errors and the temperature
of that moment.

* *geometric floor*: the distance of the nearest command's true position (noise-free);
* *expected floor*: the least mean distance over the plant's repeatability (256 common
  draws per part): what a method that knew the plant exactly would reach on average.

The ratios are mean over mean. *moves* counts arrivals (via points are part of one);
*above tol.* counts parts whose true final error exceeds the recipe's tolerance (the cell
would verify them and move again, see ``compensation.extra_moves``).

Plants are those of ``bench/bench_calibration.py``; "calibrated" runs the kinematic
calibration of seed 001 on the simulated cell first, as ``cellctl calibrate kinematics
--sim`` does.

    .venv/bin/python bench/bench_full_plant.py                      # 5 plants, 200 parts
    .venv/bin/python bench/bench_full_plant.py --plants default --parts 50

Every number is measured in this run; nothing here is a pass/fail test.
"""
from __future__ import annotations

import argparse
import itertools
import platform
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench_calibration import calibrate, config, plant  # noqa: E402
from cell import log  # noqa: E402
from cell.calibration import calfile  # noqa: E402
from cell.clock import ManualClock  # noqa: E402
from cell.cycle.runner import OffsetMemory, compensate  # noqa: E402
from cell.effects import camera_view  # noqa: E402
from cell.kinematics import Scara  # noqa: E402
from cell.recipes import parse_recipe  # noqa: E402
from cell.sim.assembly import PartFeeder  # noqa: E402
from cell.sim.plant import Plant, PlantArm  # noqa: E402

BOX = 6                 #: floor search: ±units around the final command
DRAWS = 256             #: repeatability draws of the expected floor
CYCLE_S = 1.76          #: simulated seconds per part (bench_cell's mean cycle time)


def run(plant_dict: dict, robot: Scara, recipe, parts: int, jitter_mm: float, seed: int) -> dict:
    """``parts`` parts on a fresh plant with ``robot`` as the cell's model."""
    p = Plant.from_config(plant_dict, "bench plant")
    clock = ManualClock()
    arm = PlantArm(p, clock, robot=Scara(p.robot.g))
    feeder = PartFeeder(jitter_mm, seed)
    memory = OffsetMemory()
    z = np.random.default_rng(seed).normal(0.0, p.config.repeatability_mm, (DRAWS, 2))
    meas = np.random.default_rng([seed, 1])
    box = np.array(list(itertools.product(range(-BOX, BOX + 1), repeat=2)))
    dirs = np.asarray(robot.approach_dirs, dtype=float)
    approach = np.asarray(recipe.part.nominal_xy_mm) + np.asarray(recipe.approach.offset_mm)
    approach_units = robot.to_units(robot.ik_planar(*approach))
    out = {"moves": [], "final": [], "geo": [], "exp": [], "above": 0}
    for i in range(1, parts + 1):
        part = feeder.present(i, recipe).xy_mm
        seen = camera_view(p.effects, part[None, :], p.config.camera_center_mm)[0]
        target = seen + meas.normal(0.0, p.config.measurement_noise_mm, 2)
        arm.move_and_measure(approach_units)                     # wait beside the part
        res = compensate(robot, arm, memory, recipe, target, from_units=approach_units)
        final = float(np.hypot(*(arm.true_point - part)))
        cands = np.asarray(res.final.command_units) + box
        truth = p.true_points(robot.from_units(cands), dirs, clock.now()) - part
        out["moves"].append(res.moves)
        out["final"].append(final)
        out["geo"].append(float(np.min(np.hypot(*truth.T))))
        out["exp"].append(float(np.min(np.mean(np.hypot(*(truth[:, None, :] + z[None]).transpose(2, 0, 1)),
                                               axis=1))))
        out["above"] += final > recipe.verify.tolerance_mm
        memory.learn(recipe.name, OffsetMemory.residual(robot, [s.as_dict() for s in res.steps]))
        clock.sleep(CYCLE_S)
    return {k: (np.array(v) if isinstance(v, list) else v) for k, v in out.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", default="default,untold,random-2,random-3,random-4",
                    help="comma-separated: default, untold, random-<seed>")
    ap.add_argument("--parts", type=int, default=200, help="parts per run (default 200)")
    ap.add_argument("--seed", type=int, default=0, help="feeder and noise seed (default 0)")
    args = ap.parse_args(argv)
    log.configure("console", "ERROR")
    recipe_path = REPO / "recipes" / "bracket-a.yaml"
    recipe = parse_recipe(recipe_path.read_text(encoding="utf-8"), str(recipe_path))
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="bench-full-plant-"))
    try:
        for name in [n for n in args.plants.split(",") if n]:
            pl = plant(name)
            pf, calf = tmp / f"{name}.yaml", tmp / f"{name}-robot.json"
            pf.write_text(yaml.safe_dump(pl))
            cfg = config(tmp, pf, calf, tmp / f"{name}-cal.sqlite")
            nominal = Scara(Plant.from_config(pl, name).robot.g)
            kin = calibrate(cfg, [])[0]
            models = [("nominal", nominal)]
            if kin.holdout.passed:
                models.append(("calibrated", calfile.calibrated_robot(
                    nominal, calfile.load(calf, nominal, cfg.name))))
            for label, robot in models:
                r = run(pl, robot, recipe, args.parts, cfg.sim.part_jitter_mm, args.seed)
                rows.append(f"| {name} | {label} | {len(r['final'])} | {np.mean(r['moves']):.2f} | "
                            f"{np.mean(r['final']):.4f} | {np.mean(r['geo']):.4f} | "
                            f"{np.mean(r['exp']):.4f} | {np.mean(r['final']) / np.mean(r['geo']):.2f} | "
                            f"{np.mean(r['final']) / np.mean(r['exp']):.2f} | {r['above']} |")
            if not kin.holdout.passed:
                rows.append(f"| {name} | (not calibrated: held-out check failed) | | | | | | | | |")
            print(f"{name}: done", file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"## Compensation on the full plant: {args.parts} parts of bracket-a per run\n")
    print(f"Machine: {platform.machine()}, Python {platform.python_version()}.\n")
    print(f"Reproduce: `.venv/bin/python bench/bench_full_plant.py --plants {args.plants} "
          f"--parts {args.parts} --seed {args.seed}`\n")
    print("| plant | model | parts | moves per part | final error mean mm (true) | geometric floor mm | "
          "expected floor mm | final ÷ geometric | final ÷ expected | above tol. |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
