"""``cellctl diagnose CHAIN-CAMPAIGN --html DIR``: the chain diagnosis as a page
(:mod:`cell.diagnosis.page`, the planar page's layout) with its own plots (matplotlib,
Agg), ``report.json`` beside it. Writes files; the numbers come from
:func:`cell.diagnosis.chain.report.diagnose_chain_full`.

Plots (before = registration only, after = with the named cause, both with their own
registration; residual = measured − predicted point, mm, in the measurement frame):

- ``poses.png``: each pose's rms 3-D error before and after, FIT poses and HOLDOUT poses
  in separate panels (the holdout panel is the answer's HOLDOUT rms, pose by pose);
- ``residuals.png``: residual vectors at the measured points, seen from above (x–y) and
  from the side (x–z), before and after, one arrow scale and one colour scale (|residual|
  3-D, colour bar) for all four panels;
- ``joints.png``: each pose's rms error before against each joint's reading, to see
  what the gap follows;
- ``paths.png`` (a planar campaign with measured moves): the residual along one holdout
  move before and after, and the per-station lags against σ·k (the report's ``delay``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cell.diagnosis import page
from cell.diagnosis.chain import fit as F
from cell.diagnosis.chain.report import ChainDiagnosis
from cell.diagnosis.text import render


def residuals(d: F.Data, f: F.Fit) -> np.ndarray:
    """(M, 3) measured − predicted of fit ``f`` on ``d`` (its registration kept), mm; 0 on
    an axis the sensor does not see."""
    y, _ = F.model(d, f.reg, f.params, f.values)
    return _full(d, d.xyz - y)


def _full(d: F.Data, v: np.ndarray) -> np.ndarray:
    """(M, 3) from the (M, dims) components the sensor sees, 0 on the others."""
    if d.dims == 3:
        return v
    out = np.zeros((len(v), 3))
    out[:, list(d.axes)] = v
    return out


def per_pose_rms(d: F.Data, r: np.ndarray) -> np.ndarray:
    """(P,) rms of the 3-D error of each pose's points, mm."""
    n = np.bincount(d.obs_pose, minlength=d.n_poses)
    return np.sqrt(np.bincount(d.obs_pose, np.sum(r * r, 1), d.n_poses) / np.maximum(n, 1))


def write_chain_html(cd: ChainDiagnosis, out_dir) -> Path:
    """Write index.html, report.json and the PNGs into ``out_dir`` (created); returns the
    index path. Raises OSError if the directory cannot be written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plt = page.pyplot()
    rep, s, dec = cd.report, cd.search, cd.decision
    f0 = s.nominal.fit
    f1 = dec.chosen.fit if dec.chosen else f0
    after = dec.chosen.label if dec.chosen else "registration only"
    r = {(k, w): residuals(d, f) for k, d in (("fit", s.fit_d), ("hold", s.hold_d))
         for w, f in (("before", f0), ("after", f1))}
    figs = [_poses(plt, s, r, after, out), _vectors(plt, s, r, after, out), _joints(plt, s, r, out)]
    if cd.reading is not None and cd.reading.d.moves:
        figs.append(_moves(plt, cd.reading, rep.get("delay"), out))
    (out / "report.json").write_text(json.dumps(rep, indent=2), encoding="utf-8")
    fit = page.FitRms(rep["registration"]["rms_mm"], rep["noise"]["fit_rms_mm"],
                      f"{rep['split']['fit_poses']} poses, {rep['split']['fit_rows']} points")
    index = out / "index.html"
    index.write_text(page.render(rep, figs, fit, render(rep),
                                 chosen_label=dec.chosen.label if dec.chosen else None),
                     encoding="utf-8")
    return index


def _poses(plt, s, r, after: str, out: Path) -> page.Figure:
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), dpi=90, sharey=True, layout="constrained",
                             gridspec_kw={"width_ratios": [max(s.fit_d.n_poses, 1),
                                                          max(s.hold_d.n_poses, s.fit_d.n_poses / 2)]})
    for ax, k, d, name in ((axes[0], "fit", s.fit_d, "FIT poses"), (axes[1], "hold", s.hold_d, "HOLDOUT poses")):
        b, a = per_pose_rms(d, r[(k, "before")]), per_pose_rms(d, r[(k, "after")])
        x = np.arange(1, d.n_poses + 1)
        ax.vlines(x, np.minimum(a, b), np.maximum(a, b), color="0.75", lw=1)
        ax.plot(x, b, "o", color="tab:gray", ms=5, label="registration only (before)")
        ax.plot(x, a, "o", color="tab:blue", ms=5, label=f"{after} (after)")
        rb, ra = np.sqrt(np.mean(b ** 2)), np.sqrt(np.mean(a ** 2))
        ax.set_title(f"{name}: rms {rb:.3f} → {ra:.3f} mm", loc="left", fontsize=10)
        ax.set_xlabel("pose (campaign order within the set)")
        ax.set_ylim(bottom=0)
        ax.margins(x=0.04)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("rms 3-D point error of the pose, mm")
    axes[1].legend(fontsize=8, loc="upper right")
    png = page.save_figure(plt, fig, out / "poses.png").name
    return page.Figure(png, "Pose by pose, fitted and held out",
                       "Each pose's error before (registration only) and after the named cause. "
                       "Left: the poses the model was fitted on (FIT); right: poses it never saw "
                       "(HOLDOUT, the answer's held-out check).")


def _vectors(plt, s, r, after: str, out: Path) -> page.Figure:
    xyz = np.vstack([_full(s.fit_d, s.fit_d.xyz), _full(s.hold_d, s.hold_d.xyz)])
    rb = np.vstack([r[("fit", "before")], r[("hold", "before")]])
    ra = np.vstack([r[("fit", "after")], r[("hold", "after")]])
    nb, na = np.linalg.norm(rb, axis=1), np.linalg.norm(ra, axis=1)
    import matplotlib.colors as mcolors
    norm = mcolors.Normalize(0.0, float(max(nb.max(), na.max(), 1e-9)))
    scale = float(np.percentile(nb, 95)) or 1e-3
    fig, axes = plt.subplots(2, 2, figsize=(12, 9), dpi=90, layout="constrained")
    q = None
    for row, (res, nn, name) in enumerate(((rb, nb, "registration only (before)"),
                                           (ra, na, f"{after} (after)"))):
        for col, (i, j, plane) in enumerate(((0, 1, "seen from above, x–y"), (0, 2, "from the side, x–z"))):
            ax = axes[row, col]
            q = ax.quiver(xyz[:, i], xyz[:, j], res[:, i], res[:, j], nn, cmap="viridis", norm=norm,
                          angles="xy", scale_units="inches", scale=scale / 0.35, width=0.003)
            ax.quiverkey(q, 0.80, 0.04, scale, f"{scale:.2f} mm", labelpos="W", coordinates="axes",
                         fontproperties={"size": 8})
            ax.set_aspect("equal", adjustable="datalim")
            ax.margins(0.1)
            ax.set_xlabel(f"{'xyz'[i]}, mm (measurement frame)")
            ax.set_ylabel(f"{'xyz'[j]}, mm")
            ax.set_title(f"{name}, {plane}: rms {np.sqrt(np.mean(nn ** 2)):.3f} mm", loc="left",
                         fontsize=10)
            ax.grid(alpha=0.25)
    fig.colorbar(q, ax=axes, shrink=0.7, label="|residual| 3-D, mm (arrow colour)")
    png = page.save_figure(plt, fig, out / "residuals.png").name
    return page.Figure(png, "Where the gap lies",
                       "Residual (measured − predicted) at every measured point, fit and holdout "
                       "poses, projected on two planes; arrow length on one scale for all panels "
                       "(key arrow), colour the 3-D size on one colour scale (bar).")


def _joints(plt, s, r, out: Path) -> page.Figure:
    chain = s.fit_d.chain
    read = np.vstack([s.fit_d.readings, s.hold_d.readings])
    e = np.concatenate([per_pose_rms(s.fit_d, r[("fit", "before")]),
                        per_pose_rms(s.hold_d, r[("hold", "before")])])
    held = np.r_[np.zeros(s.fit_d.n_poses, bool), np.ones(s.hold_d.n_poses, bool)]
    panels = [(read[:, k], f"{jt.column} {jt.name}, "
               + ("mm" if str(getattr(jt.type, "value", jt.type)) == "prismatic" else "deg"))
              for k, jt in enumerate(chain.joints)]
    if s.fit_d.temp_c is not None and s.hold_d.temp_c is not None:
        panels.append((np.r_[s.fit_d.temp_c, s.hold_d.temp_c], "temperature, °C"))
    n = len(panels)
    cols = 4
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(12, 2.8 * rows), dpi=80, squeeze=False,
                             sharey=True, layout="constrained")
    for ax, (x, label) in zip(axes.ravel(), panels):
        ax.plot(x[~held], e[~held], "o", ms=4, color="tab:gray", label="fit poses")
        ax.plot(x[held], e[held], "s", ms=4, color="tab:orange", label="holdout poses")
        ax.set_xlabel(label, fontsize=9)
        ax.margins(0.08)
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel("pose rms error\nbefore, mm")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=8)
    png = page.save_figure(plt, fig, out / "joints.png").name
    return page.Figure(png, "What the gap follows",
                       "Each pose's error after registration alone against each joint's reading "
                       "(revolute in deg, prismatic in mm), and against its temperature when "
                       "the campaign records one.")


def _moves(plt, pr, delay: dict | None, out: Path) -> page.Figure:
    d = pr.d
    fig, axes = plt.subplots(1, 2, figsize=(12, 4), dpi=90)
    m = next((mv for mv in d.moves if not mv.fit), d.moves[0])
    k = sum(len(mm.t) for mm in d.moves[:d.moves.index(m)])
    sl = slice(k, k + len(m.t))
    for name, r in (("before", pr.nominal), ("after", pr.named)):
        axes[0].plot(m.t * 1e3, np.hypot(*pr.rows.paths(r)[sl].T), label=name)
    axes[0].set_xlabel("time in move, ms")
    axes[0].set_ylabel("|residual|, mm")
    axes[0].set_title(f"move {m.move} ({'fit' if m.fit else 'holdout'})", loc="left", fontsize=10)
    axes[0].legend()
    if delay:
        names = sorted(delay["lags_ms"])
        lam = np.array([delay["lags_ms"][j] for j in names])
        ci = np.array([delay["ci95_ms"][j] for j in names])
        axes[1].bar(names, lam, yerr=[lam - ci[:, 0], ci[:, 1] - lam], capsize=6, alpha=0.7,
                    label="fitted lag (95 %)")
        axes[1].plot(names, [delay["sigma_ms"] * delay["station_position"][j] for j in names],
                     "ko--", label="σ·k")
        axes[1].set_ylabel("lag, ms")
        axes[1].legend()
        axes[1].set_title("per-station lag vs station position", loc="left", fontsize=10)
    png = page.save_figure(plt, fig, out / "paths.png").name
    return page.Figure(png, "Moves",
                       "The residual along one held-out move before and after the named cause; "
                       "the lag fitted per station against σ times its bus position.")
