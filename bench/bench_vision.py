"""Fiducial centre accuracy against the Cramer-Rao bound, and time per 1.3 MP frame.

    .venv/bin/python bench/bench_vision.py [--quick] [--trials N] [--seed S]

Images come from the simulated camera (drivers/camera/sim.py): a disc of radius 10 px,
edge blur (Gaussian PSF) 0.9 px, contrast 160 grey levels on a background of 50, Gaussian
noise sigma = 2 and 10 grey levels, 8-bit rounding; centres at random sub-pixel positions
(seeded). Every method sees the same images.

Cramer-Rao bound, per axis, for each trial's image (centre the only unknown):
``CRB_u = sigma^2 / sum((dI/du_c)^2)``, the derivative of the noise-free image with respect to
the centre taken by central differences of the renderer itself (+-0.01 px). The table shows
the rms of the per-trial bounds; "radial" is sqrt(CRB_u + CRB_v), the bound on the 2-D
error. 8-bit rounding adds 1/12 grey level^2 of noise the bound leaves out (under 1 % here).

Timing: detect + refine of two fiducials in a 1280 x 1024 frame, median of repeats, one
thread, on whatever machine runs this.

The cell's own frames (section 3): 640 x 512 px at 0.08 mm per px, the tool's 3 mm disc
(37.5 px) and bracket-a's 1.5 mm fiducial (18.75 px), 12 mm apart as at the approach.
Accuracy against the bound at both sizes (noise 2), then CPU per find (``time.process_time``,
median of repeats): the whole frame, the window the cycle searches (around where the model
puts the fiducial, 1.2 mm off here), and a bare OpenCV baseline on the same frame (Otsu
threshold, connected components, grey-level centroid of the largest blob: no sub-pixel
model, no checks).
"""
from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cell import progress  # noqa: E402
from cell.vision import CameraModel, find_fiducial, find_fiducials  # noqa: E402
from cell.vision.calibration import CircleGridBoard, calibrate  # noqa: E402
from cell.vision.measure import MeasuringCamera  # noqa: E402
from drivers.camera.sim import Fiducial, Optics, render, render_float  # noqa: E402

RADIUS_PX, BLUR_PX, CONTRAST, BACKGROUND = 10.0, 0.9, 160.0, 50.0
NOISES = (2.0, 10.0)
METHODS = ("model", "centroid", "moments")
# 1 px = 1 mm, straight down: +x mm is +u px, +y mm is -v px.
SMALL = CameraModel.nadir(96, 96, 1.0, height_mm=1000.0)
FRAME = CameraModel.nadir(1280, 1024, 1.0, height_mm=1000.0)


def optics(noise: float) -> Optics:
    return Optics(blur_sigma_px=BLUR_PX, noise_sigma=noise, background=BACKGROUND,
                  contrast=CONTRAST)


def fisher_sums(x: float, y: float) -> tuple[float, float]:
    """sum (dI/du_c)^2 and sum (dI/dv_c)^2 of the noise-free image, grey levels^2 / px^2."""
    h, clean = 0.01, optics(0.0)

    def img(dx, dy):
        return render_float(SMALL, [Fiducial(x + dx, y + dy, RADIUS_PX)], clean)

    du = (img(h, 0) - img(-h, 0)) / (2 * h)
    dv = (img(0, -h) - img(0, h)) / (2 * h)
    return float((du ** 2).sum()), float((dv ** 2).sum())


def accuracy(trials: int, seed: int):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-3.0, 3.0, (trials, 2))
    fisher = np.array([fisher_sums(x, y) for x, y in pos])
    rows = []
    for noise in progress.each(NOISES, "noise levels", "level"):
        crb_var = noise ** 2 / fisher                        # (trials, 2)
        errs = {m: [] for m in METHODS}
        fails = {m: 0 for m in METHODS}
        for x, y in pos:
            truth = SMALL.project([(x, y)])[0]
            img = render(SMALL, [Fiducial(x, y, RADIUS_PX)], optics(noise), rng)
            for m in METHODS:
                try:
                    errs[m].append(np.subtract(find_fiducial(img, method=m).uv, truth))
                except Exception:                             # counted, never hidden
                    fails[m] += 1
        crb_axis = float(np.sqrt(crb_var.mean()))
        crb_radial = float(np.sqrt(crb_var.sum(axis=1).mean()))
        for m in METHODS:
            e = np.array(errs[m])
            rms_u, rms_v = np.sqrt((e ** 2).mean(axis=0))
            radial = float(np.sqrt((e ** 2).sum(axis=1).mean()))
            rows.append((noise, m, rms_u, rms_v, radial, crb_axis, crb_radial,
                         radial / crb_radial, fails[m]))
    return rows


def timing(repeats: int, seed: int):
    rng = np.random.default_rng(seed)
    scene = [Fiducial(-212.3, 101.7, RADIUS_PX, "tool"), Fiducial(305.6, -250.2, RADIUS_PX, "part")]
    t_render = []
    for _ in range(2):            # the first render of a model also unprojects its pixel grid, once
        t0 = time.perf_counter()
        frame = render(FRAME, scene, optics(2.0), rng)
        t_render.append(time.perf_counter() - t0)
    rows = []
    for m in METHODS:
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            found = find_fiducials(frame, expected=2, method=m)
            ts.append(time.perf_counter() - t0)
        assert len(found) == 2
        rows.append((m, 1e3 * float(np.median(ts)), 1e3 * float(np.min(ts))))
    return rows, t_render


CELL = CameraModel.nadir(640, 512, 0.08, centre_mm=(250.0, 930.0))
CELL_OPTICS = Optics(supersample=2)            # cell/sim/assembly.py CAMERA_OPTICS
TOOL_MM, PART_MM = 3.0, 1.5
TOOL_AT, PART_AT = (250.4, 930.3), (262.4, 930.3)


def cell_accuracy(trials: int, seed: int):
    """Model-fit centre error against the bound for the cell's two disc sizes (noise 2)."""
    rows = []
    for name, r_mm in (("tool", TOOL_MM), ("part", PART_MM)):
        r_px = r_mm / 0.08
        model = CameraModel.nadir(160, 160, 1.0, height_mm=1000.0)
        clean, noisy = Optics(blur_sigma_px=BLUR_PX, noise_sigma=0.0, background=BACKGROUND,
                              contrast=CONTRAST), optics(2.0)
        rng = np.random.default_rng([seed, int(r_px * 100)])
        errs, crb = [], []
        for x, y in rng.uniform(-3.0, 3.0, (trials, 2)):
            h = 0.01

            def img(dx, dy):
                return render_float(model, [Fiducial(x + dx, y + dy, r_px)], clean)
            du = (img(h, 0) - img(-h, 0)) / (2 * h)
            dv = (img(0, -h) - img(0, h)) / (2 * h)
            crb.append(4.0 / np.array([(du ** 2).sum(), (dv ** 2).sum()]))
            fix = find_fiducial(render(model, [Fiducial(x, y, r_px)], noisy, rng),
                                min_radius_px=0.7 * r_px, max_radius_px=1.3 * r_px)
            errs.append(np.subtract(fix.uv, model.project([(x, y)])[0]))
        e, c = np.array(errs), np.array(crb)
        radial, bound = float(np.sqrt((e ** 2).sum(axis=1).mean())), float(np.sqrt(c.sum(axis=1).mean()))
        rows.append((name, r_px, radial, bound, radial / bound))
    return rows


def cell_timing(repeats: int, seed: int):
    """CPU ms per find on a cell frame: whole frame, the cycle's window, bare OpenCV."""
    board = CircleGridBoard(cols=11, rows=7, pitch_mm=4.0, radius_mm=1.0,
                            origin_mm=(230.0, 918.0), angle_deg=0.0)
    cal = calibrate([(render(CELL, [board], CELL_OPTICS, np.random.default_rng(seed)), board)],
                    distortion=False, u_axis_deg=0.0)
    frame = render(CELL, [Fiducial(*PART_AT, PART_MM, "part"), Fiducial(*TOOL_AT, TOOL_MM, "tool")],
                   CELL_OPTICS, np.random.default_rng(seed + 1))
    cam = MeasuringCamera(None, cal, tool_radius_mm=TOOL_MM)
    near_tool, near_part = (TOOL_AT[0] + 1.0, TOOL_AT[1] - 0.7), (PART_AT[0] - 0.8, PART_AT[1] + 0.5)

    def bare():
        _, mask = cv2.threshold(frame, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        i = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        x, y, w, h = stats[i, :4]
        roi = frame[y:y + h, x:x + w].astype(np.float64) * (labels[y:y + h, x:x + w] == i)
        vv, uu = np.mgrid[y:y + h, x:x + w]
        return (roi * uu).sum() / roi.sum(), (roi * vv).sum() / roi.sum()

    cases = [("tool, whole frame", lambda: cam.find(frame, TOOL_MM, "tool")),
             ("tool, window (cycle)", lambda: cam.find(frame, TOOL_MM, "tool", near_mm=near_tool)),
             ("part, whole frame", lambda: cam.find(frame, PART_MM, "part")),
             ("part, window (cycle)", lambda: cam.find(frame, PART_MM, "part", near_mm=near_part,
                                                      within_mm=4.0)),
             ("bare OpenCV: Otsu, components, centroid", bare)]
    rows = []
    for name, f in cases:
        f()
        ts = []
        for _ in range(repeats):
            t0 = time.process_time()
            f()
            ts.append(time.process_time() - t0)
        rows.append((name, 1e3 * float(np.median(ts)), 1e3 * float(np.min(ts))))
    assert cam.window_misses == 0
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="50 trials, 5 timing repeats")
    ap.add_argument("--trials", type=int, default=300)
    ap.add_argument("--seed", type=int, default=2024)
    args = ap.parse_args(argv)
    trials, repeats = (50, 5) if args.quick else (args.trials, 20)

    print(f"## Fiducial centre error vs Cramer-Rao bound ({trials} trials per noise level, "
          f"seed {args.seed})\n")
    print(f"Disc radius {RADIUS_PX:g} px, edge blur {BLUR_PX:g} px, contrast {CONTRAST:g} "
          f"grey levels, 8-bit. Errors in px; 'radial' = rms of the 2-D error.\n")
    print("| noise σ | method | rms u | rms v | rms radial | CRB per axis | CRB radial "
          "| radial / CRB | failures |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for noise, m, ru, rv, rr, ca, cr, ratio, nf in accuracy(trials, args.seed):
        print(f"| {noise:g} | {m} | {ru:.4f} | {rv:.4f} | {rr:.4f} | {ca:.4f} | {cr:.4f} "
              f"| {ratio:.2f} | {nf} |")
    rows, t_render = timing(repeats, args.seed)
    print(f"\n## Time per 1280 x 1024 frame, two fiducials, detect + refine "
          f"({repeats} repeats)\n")
    print("| method | median ms | min ms |")
    print("|---|---:|---:|")
    for m, med, mn in rows:
        print(f"| {m} | {med:.1f} | {mn:.1f} |")
    print(f"\nRendering that frame in the simulator took {1e3 * t_render[1]:.0f} ms "
          f"({1e3 * t_render[0]:.0f} ms the first time: a camera model's first frame unprojects "
          f"its whole pixel grid, kept for the next frames). "
          f"Python {platform.python_version()}, {platform.machine()}.")
    cell_trials = max(20, trials // 3)
    print(f"\n## The cell's frames: tool disc {TOOL_MM:g} mm and part fiducial {PART_MM:g} mm at "
          f"0.08 mm per px ({cell_trials} trials, noise 2)\n")
    print("| disc | radius px | rms radial | CRB radial | radial / CRB |")
    print("|---|---:|---:|---:|---:|")
    for name, r_px, rr, cr, ratio in cell_accuracy(cell_trials, args.seed):
        print(f"| {name} | {r_px:.2f} | {rr:.4f} | {cr:.4f} | {ratio:.2f} |")
    print(f"\n## CPU per find on a cell frame, 640 x 512 ({repeats * 2} repeats, same run)\n")
    print("| search | median CPU ms | min CPU ms |")
    print("|---|---:|---:|")
    for name, med, mn in cell_timing(repeats * 2, args.seed):
        print(f"| {name} | {med:.2f} | {mn:.2f} |")


if __name__ == "__main__":
    main()
