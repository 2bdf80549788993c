"""The diagnosis as a page a person would rather look at: ``index.html`` + PNG plots
(matplotlib, Agg backend) + ``report.json``. The one module of :mod:`cell.diagnosis` that
writes files; the page itself is :mod:`cell.diagnosis.page` (shared with chain campaigns,
:mod:`cell.diagnosis.chain.html`).

Plots: ``workspace.png`` residual vectors over the workspace before and after the cause
(quiver, one arrow scale and one colour scale for both, with its colour bar and a key
arrow); ``variables.png`` the residual in joint space against
each variable the gap could depend on (angles, directions, time, temperature, payload) and
the path residual against tool speed; ``holdout.png`` holdout residuals before and after;
``paths.png`` (with moves) residual along one holdout move before/after, and the fitted
per-station lags against σ·k.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cell.diagnosis import page
from cell.diagnosis.fit import combined
from cell.diagnosis.replay import residuals
from cell.diagnosis.report import Diagnosis
from cell.diagnosis.text import render
from cell.diagnosis.where import jacobian_cols, static_view


def write_html(dg: Diagnosis, out_dir) -> Path:
    """Write index.html, report.json and the PNGs into ``out_dir`` (created); returns the
    index path. Raises OSError if the directory cannot be written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plt = page.pyplot()
    d = dg.data
    eff = dg.decision.chosen.effects if dg.decision.chosen else []
    tp = dg.decision.chosen.path_temp_c if dg.decision.chosen else None
    rp0, rq0 = residuals(d)
    rp1, rq1 = residuals(d, eff, tp)
    pngs = []
    cmd, dirs, xy, t, temp, payload, r0 = static_view(d, rp0, rq0)
    r1 = rp1 if d.points is not None else rq1

    fig, axes = plt.subplots(1, 2, figsize=(12, 5.6), dpi=90, sharex=True, sharey=True,
                             layout="constrained")
    n0, n1 = np.hypot(*r0.T), np.hypot(*r1.T)
    scale = float(np.percentile(n0, 95)) or 1e-3
    norm = _colors().Normalize(0.0, float(max(n0.max(), n1.max(), 1e-9)))
    for ax, r, nn, title in ((axes[0], r0, n0, "nominal (before)"), (axes[1], r1, n1, "with the cause (after)")):
        q = ax.quiver(xy[:, 0], xy[:, 1], r[:, 0], r[:, 1], nn, cmap="viridis", norm=norm,
                      angles="xy", scale_units="inches", scale=scale / 0.4, width=0.003)
        ax.quiverkey(q, 0.80, 0.04, scale, f"{scale:.3f} mm", labelpos="W", coordinates="axes",
                     color="black", fontproperties={"size": 8})
        ax.set_title(f"residual {title}, rms {np.sqrt(np.mean(np.sum(r ** 2, 1))):.4f} mm",
                     loc="left", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x, mm (robot base frame)")
        ax.margins(0.08)
        if d.center is not None:
            ax.plot(*d.center, "r+", ms=12, label="camera centre")
            ax.legend(loc="upper left", fontsize=8)
    axes[0].set_ylabel("y, mm")
    fig.colorbar(q, ax=axes, shrink=0.85, label="|residual|, mm (arrow colour)")
    pngs.append(page.save_figure(plt, fig, out / "workspace.png"))

    j1, j2, _, _ = jacobian_cols(d.geometry.l1_mm, d.geometry.l2_mm, cmd)
    ok = np.abs(np.sin(np.radians(cmd[:, 1]))) > 0.15
    dq = np.full_like(r0, np.nan)
    dq[ok] = np.linalg.solve(np.stack([j1[ok], j2[ok]], 2), r0[ok][:, :, None])[:, :, 0]
    panels = [("θ1, deg", cmd[:, 0]), ("θ2, deg", cmd[:, 1]), ("j1 direction (−1 / +1)", dirs[:, 0]),
              ("j2 direction (−1 / +1)", dirs[:, 1]), ("time, s", t)]
    if temp is not None:
        panels.append(("temperature, °C", temp))
    if payload is not None:
        panels.append(("payload, kg", payload))
    n = len(panels) + bool(d.moves)
    cols = 4
    fig, axes = plt.subplots((n + cols - 1) // cols, cols, figsize=(14, 3.2 * ((n + cols - 1) // cols)),
                             dpi=80, squeeze=False)
    jitter = np.random.default_rng(0).uniform(-0.15, 0.15, len(cmd))
    for ax, (name, v) in zip(axes.ravel(), panels):
        vv = v + jitter if "direction" in name else v
        ax.plot(vv, dq[:, 0], ".", ms=3, label="Δθ1")
        ax.plot(vv, dq[:, 1], ".", ms=3, label="Δθ2")
        ax.set_xlabel(name)
        ax.set_ylabel("joint-space residual, deg")
        ax.grid(alpha=0.3)
    axes.ravel()[0].legend(fontsize=8)
    if d.moves:
        ax = axes.ravel()[len(panels)]
        xyq = d.path_cat("xy") - rq0
        sp = np.concatenate([np.hypot(*np.gradient(xyq[k:k + len(m.t)], m.t, axis=0).T)
                             for k, m in zip(np.cumsum([0] + [len(m.t) for m in d.moves[:-1]]),
                                             d.moves)])
        ax.plot(sp, np.hypot(*rq0.T), ".", ms=2)
        ax.set_xlabel("tool speed, mm/s (paths)")
        ax.set_ylabel("|residual|, mm")
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle("Nominal residual against each variable the gap could depend on", fontsize=11)
    pngs.append(page.save_figure(plt, fig, out / "variables.png"))

    s = dg.search
    hp0, hq0 = residuals(s.hold_d, [], None)
    hp1, hq1 = residuals(s.hold_d, eff, tp)
    h0 = np.hypot(*np.vstack([hp0, hq0]).T)
    h1 = np.hypot(*np.vstack([hp1, hq1]).T)
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=90)
    lo = max(min(h0.min(), h1.min()), 1e-5)
    bins = np.logspace(np.log10(lo), np.log10(max(h0.max(), h1.max(), lo * 10)), 40)
    ax.hist(h0, bins=bins, alpha=0.6, label=f"HOLDOUT before: rms {np.sqrt(np.mean(h0 ** 2)):.4f} mm")
    ax.hist(h1, bins=bins, alpha=0.6, label=f"HOLDOUT after: rms {np.sqrt(np.mean(h1 ** 2)):.4f} mm")
    ax.set_xscale("log")
    ax.set_xlabel("|residual| on the holdout rows, mm (log scale)")
    ax.set_ylabel("rows")
    ax.set_title(f"Holdout rows before/after ({dg.report['cause']['effect']}), shrink "
                 f"{dg.report['holdout']['shrink']:.3f}", loc="left", fontsize=10)
    ax.legend()
    pngs.append(page.save_figure(plt, fig, out / "holdout.png"))

    if d.moves:
        fig, axes = plt.subplots(1, 2, figsize=(12, 4), dpi=90)
        m = next((mv for mv in d.moves if not mv.fit), d.moves[0])
        k = sum(len(mm.t) for mm in d.moves[:d.moves.index(m)])
        sl = slice(k, k + len(m.t))
        axes[0].plot(m.t * 1e3, np.hypot(*rq0[sl].T), label="before")
        axes[0].plot(m.t * 1e3, np.hypot(*rq1[sl].T), label="after")
        axes[0].set_xlabel("time in move, ms")
        axes[0].set_ylabel("|residual|, mm")
        axes[0].set_title(f"move {m.move} ({'fit' if m.fit else 'holdout'})", loc="left", fontsize=10)
        axes[0].legend()
        dl = dg.delay
        if dl:
            lam = [dl["lags_ms"]["j1"], dl["lags_ms"]["j2"]]
            ci = np.array([dl["ci95_ms"]["j1"], dl["ci95_ms"]["j2"]])
            axes[1].bar(["j1", "j2"], lam, yerr=[np.array(lam) - ci[:, 0], ci[:, 1] - np.array(lam)],
                        capsize=6, alpha=0.7, label="fitted lag (95 %)")
            kk = [dl["station_position"]["j1"], dl["station_position"]["j2"]]
            axes[1].plot(["j1", "j2"], [dl["sigma_ms"] * x for x in kk], "ko--", label="σ·k")
            axes[1].set_ylabel("lag, ms")
            axes[1].legend()
            axes[1].set_title("per-station lag vs station position", loc="left", fontsize=10)
        pngs.append(page.save_figure(plt, fig, out / "paths.png"))

    rep = dg.report
    (out / "report.json").write_text(json.dumps(rep, indent=2), encoding="utf-8")
    sn, ch = s.nominal, dg.decision.chosen
    fb, fa = combined(sn.fit_points, sn.fit_paths), combined((ch or sn).fit_points, (ch or sn).fit_paths)
    fit = page.FitRms(fb.rms, fa.rms, f"{fb.n} rows")
    index = out / "index.html"
    index.write_text(page.render(rep, _figures(pngs), fit, render(rep), chain=False,
                                 chosen_label=ch.label if ch else None), encoding="utf-8")
    return index


_CAPTIONS = {
    "workspace.png": ("Where the gap lies over the workspace",
                      "Residual (measured − simulated) of every static point, before and after the "
                      "named cause; arrow length on one scale for both panels (key arrow), colour "
                      "the residual's size on one colour scale (bar)."),
    "variables.png": ("What the gap depends on",
                      "The nominal residual mapped to joint space (Δθ1, Δθ2, deg) against each "
                      "variable the gap could depend on; directions are jittered to show the spread."),
    "holdout.png": ("Held-out rows before and after",
                    "Distribution of the residual on rows the fit never saw, before and after the "
                    "cause: the HOLDOUT rms of the answer above."),
    "paths.png": ("Moves",
                  "Left: residual along one move before and after; right: the fitted per-station "
                  "lags with their 95 % intervals against σ·k (k: station position on the bus)."),
}


def _figures(pngs: list[Path]) -> list[page.Figure]:
    return [page.Figure(p.name, *_CAPTIONS.get(p.name, (p.stem, ""))) for p in pngs]


def _colors():
    import matplotlib.colors
    return matplotlib.colors
