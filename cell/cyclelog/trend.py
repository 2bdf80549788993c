"""The accuracy trend of logged cycles as a picture that answers "are we within tolerance,
and is recalibration due?" (``cellctl report``'s PNG).

Two panels over one x axis (the PLC's part number when it rises through the log, else the
time a cycle finished, UTC):

- **first arrival** (error before compensation, mm): each done part, its rolling mean
  over the drift watch's window and the **recalibration threshold** the drift watch
  compares that mean with (:func:`cell.jobs.drift_due`, ``scheduler.drift_threshold_mm``
  and ``drift_window`` of the cell config);
- **final error** (verified by the camera, mm): each done part, rolling mean and rolling
  p95 over the same window, and the **tolerance** of the recipe version each cycle ran
  with (``verify.tolerance_mm``; the version is the cycle's ``recipe_hash``, its text is
  in the log's ``recipe_versions`` table), drawn as a step line so a change shows where
  it happened.

Faulted and aborted parts are red ticks on both panels. With several recipes each has its
own colour, and its own rolling statistics and tolerance. :func:`plot_trend` returns the
figure and its named artists (tests check them, not pixels); :func:`tolerances` reads the
recipe versions. Pure apart from the log read in :func:`tolerances`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from cell.cyclelog import CycleLog, CycleRecord, CycleStatus

#: parts before a rolling statistic is drawn (fewer say little about a trend)
MIN_PERIODS = 5
#: colours of successive recipes (matplotlib's tab10 without red, which marks faults)
RECIPE_COLOURS = ("tab:blue", "tab:green", "tab:purple", "tab:orange", "tab:brown",
                  "tab:cyan", "tab:olive", "tab:pink", "tab:gray")


@dataclass(frozen=True)
class Limits:
    """The lines the trend is judged against. ``tolerance_mm``: recipe_hash → the
    ``verify.tolerance_mm`` of that recipe version (None when the version's text is not
    known); ``threshold_mm`` / ``window``: the drift watch's recalibration threshold (mm,
    on the mean first-arrival error) and window (done parts)."""

    tolerance_mm: dict[str, float | None] = field(default_factory=dict)
    threshold_mm: float = 0.5
    window: int = 20


@dataclass
class TrendPlot:
    """The figure and its artists by name: ``tolerance:<recipe>``, ``threshold``,
    ``initial_mean:<recipe>``, ``final_mean:<recipe>``, ``final_p95:<recipe>``,
    ``final:<recipe>``, ``faults``; ``x_label`` and ``title`` as drawn."""

    fig: object
    artists: dict[str, object]
    x_label: str
    title: str

    def save(self, path: Path) -> Path:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.fig.savefig(path)
        return path


def rolling(values, window: int, min_periods: int = MIN_PERIODS) -> tuple[np.ndarray, np.ndarray]:
    """(mean, p95) over the trailing ``window`` values, NaN where fewer than
    ``min(min_periods, window)`` are available."""
    v = np.asarray(values, float)
    mean, p95 = np.full(len(v), np.nan), np.full(len(v), np.nan)
    need = min(min_periods, window)
    for i in range(len(v)):
        w = v[max(0, i + 1 - window):i + 1]
        if len(w) >= need:
            mean[i], p95[i] = w.mean(), np.percentile(w, 95)
    return mean, p95


def when(c: CycleRecord) -> datetime:
    return datetime.fromisoformat(c.finished_at)


def x_axis(cycles: list[CycleRecord]) -> tuple[list, str]:
    """(x of each cycle, axis label): the part number when part numbers rise strictly
    through the log, else the finishing time (UTC)."""
    parts = [c.part_id for c in cycles]
    if all(b > a for a, b in zip(parts, parts[1:])):
        return parts, "part number (from the PLC)"
    return [when(c) for c in cycles], "cycle finished at (UTC)"


def tolerances(log: CycleLog, cycles: list[CycleRecord], recipes_dir: Path | None = None
               ) -> dict[str, float | None]:
    """recipe_hash → ``verify.tolerance_mm`` of that version: its text from the log's
    ``recipe_versions``, else a file in ``recipes_dir`` with that very hash, as that version
    was activated (:func:`cell.recipes.recorded_tolerance`); None if neither holds it."""
    from cell.recipes import content_hash, recorded_tolerance
    files: dict[str, str] = {}
    if recipes_dir is not None and Path(recipes_dir).is_dir():
        for p in sorted(Path(recipes_dir).glob("*.yaml")):
            try:
                text = p.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError):
                continue
            files[content_hash(text)] = text
    out: dict[str, float | None] = {}
    for h in {c.recipe_hash for c in cycles}:
        text = log.recipe_text(h) or files.get(h)
        out[h] = recorded_tolerance(text) if text else None
    return out


def title_of(cycles: list[CycleRecord]) -> str:
    """Recipes, date range (UTC) and counts, as the figure's title."""
    names = sorted({c.recipe for c in cycles})
    t0, t1 = min(when(c) for c in cycles), max(when(c) for c in cycles)
    span = (f"{t0:%Y-%m-%d %H:%M} – {t1:%H:%M} UTC" if t0.date() == t1.date()
            else f"{t0:%Y-%m-%d %H:%M} – {t1:%Y-%m-%d %H:%M} UTC")
    done = sum(c.status == CycleStatus.DONE for c in cycles)
    return (f"Accuracy trend, recipe{'s' if len(names) > 1 else ''} {', '.join(names)}: "
            f"{span}; {done} parts done, {len(cycles) - done} faulted/aborted")


def plot_trend(cycles: list[CycleRecord], limits: Limits, size_in=(11.0, 7.5), dpi: int = 100
               ) -> TrendPlot:
    """The two-panel figure (see the module doc) of ``cycles`` (id order, any status).
    Raises ValueError when ``cycles`` is empty."""
    if not cycles:
        raise ValueError("no cycles to plot")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    xs, x_label = x_axis(cycles)
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=size_in, dpi=dpi, sharex=True,
                                   layout="constrained")
    art: dict[str, object] = {}
    w = limits.window
    for k, name in enumerate(sorted({c.recipe for c in cycles})):
        col = RECIPE_COLOURS[k % len(RECIPE_COLOURS)]
        idx = [i for i, c in enumerate(cycles) if c.recipe == name and c.status == CycleStatus.DONE
               and c.final_error_mm is not None]
        if not idx:
            continue
        x = [xs[i] for i in idx]
        ini = np.array([np.nan if cycles[i].initial_error_mm is None else cycles[i].initial_error_mm
                        for i in idx])
        fin = np.array([cycles[i].verify_error_mm if cycles[i].verify_error_mm is not None
                        else cycles[i].final_error_mm for i in idx])
        ax0.plot(x, ini, ".", color=col, alpha=0.45, ms=5, label=f"{name}: each part")
        m0, _ = rolling(ini, w)
        art[f"initial_mean:{name}"], = ax0.plot(x, m0, "-", color=col, lw=2,
                                                label=f"{name}: mean of last {w} parts")
        art[f"final:{name}"], = ax1.plot(x, fin, ".", color=col, alpha=0.45, ms=5,
                                         label=f"{name}: each part")
        m1, p1 = rolling(fin, w)
        art[f"final_mean:{name}"], = ax1.plot(x, m1, "-", color=col, lw=2,
                                              label=f"{name}: rolling mean ({w} parts)")
        art[f"final_p95:{name}"], = ax1.plot(x, p1, "--", color=col, lw=1.5,
                                             label=f"{name}: rolling p95 ({w} parts)")
        tol = [limits.tolerance_mm.get(cycles[i].recipe_hash) for i in idx]
        if any(t is not None for t in tol):
            tv = np.array([np.nan if t is None else t for t in tol])
            known = sorted({t for t in tol if t is not None})
            art[f"tolerance:{name}"], = ax1.step(
                x, tv, where="post", color=col, lw=2.2, ls=(0, (6, 2, 1, 2)),
                label=f"{name}: tolerance {', '.join(f'{t:g}' for t in known)} mm (recipe)")
            last = next(t for t in reversed(tol) if t is not None)
            ax1.annotate(f"tolerance {last:g} mm", (1.0, last), xycoords=("axes fraction", "data"),
                         xytext=(-4, -3), textcoords="offset points", ha="right", va="top",
                         fontsize=8, color=col)
        else:
            ax1.plot([], [], " ", label=f"{name}: tolerance unknown (recipe version not in the log)")
    art["threshold"] = ax0.axhline(limits.threshold_mm, color="black", lw=1.8, ls="-.",
                                   label=f"recalibration threshold {limits.threshold_mm:g} mm "
                                         f"(mean of last {w})")
    ax0.annotate(f"recalibration threshold {limits.threshold_mm:g} mm", (1.0, limits.threshold_mm),
                 xycoords=("axes fraction", "data"), xytext=(-4, -3), textcoords="offset points",
                 ha="right", va="top", fontsize=8)
    bad = [xs[i] for i, c in enumerate(cycles) if c.status != CycleStatus.DONE]
    for ax in (ax0, ax1):
        lines = [ax.axvline(x, color="tab:red", lw=0.9, alpha=0.55) for x in bad]
        if ax is ax1:
            art["faults"] = lines
    if bad:
        ax1.plot([], [], "|", color="tab:red", ms=12, mew=1.5,
                 label=f"faulted/aborted part ({len(bad)})")
    ax0.set_ylabel("first-arrival error, mm")
    ax0.set_title("Before compensation: is recalibration due?", loc="left", fontsize=10)
    ax1.set_ylabel("final error (camera-verified), mm")
    ax1.set_title("After compensation: within the recipe's tolerance?", loc="left", fontsize=10)
    ax1.set_xlabel(x_label)
    if isinstance(xs[0], int):
        ax1.xaxis.get_major_locator().set_params(integer=True)
    for ax in (ax0, ax1):
        ax.set_ylim(bottom=0)
        ax.margins(x=0.02, y=0.08)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    title = title_of(cycles)
    fig.suptitle(title, fontsize=11)
    return TrendPlot(fig, art, x_label, title)


def write_png(db: Path, cycles: list[CycleRecord], path: Path, recipes_dir: Path | None = None,
              threshold_mm: float | None = None, window: int | None = None) -> None:
    """Draw the trend of ``cycles`` from the log at ``db`` into the PNG ``path``: the one
    picture ``cellctl report`` and the HMI show. ``threshold_mm``/``window``: the drift
    watch's (``scheduler`` section of the cell config; None: its defaults)."""
    from cell.config import SchedulerSection
    sched = SchedulerSection()
    log = CycleLog(db, readonly=True)
    try:
        tol = tolerances(log, cycles, recipes_dir)
    finally:
        log.close()
    tp = plot_trend(cycles, Limits(tol, sched.drift_threshold_mm if threshold_mm is None else threshold_mm,
                                   sched.drift_window if window is None else window))
    try:
        tp.save(path)
    finally:
        import matplotlib.pyplot as plt
        plt.close(tp.fig)
