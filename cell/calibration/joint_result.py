"""Seed 004 single-joint calibration results: what :func:`cell.calibration.joint.analyse`
returns, and :func:`plot`, the only function here that writes a file (PNG; matplotlib with
the Agg backend is imported inside it, never at module import; temporary file + atomic
replace). The rest is plain frozen data, no I/O.

Units: angles, errors, backlash, offset, harmonic amplitude and phase in deg (arcsec only on
the plot's right axis); gear-ratio error ε dimensionless (:attr:`JointResult.gear_ratio_ppm`
= 1e6·ε); the circle in mm of the camera plane. Every :class:`Estimate` is a value with its
95 % interval [low, high]. Arrays (R, 2, M) are indexed run, pass (0 forward, 1 return),
nominal angle in forward order (+limit first). Signs and the model
e = c − dir·b/2 + ε·θ + Σ_k A_k·sin(2πkθ/P + φ_k) are those of :mod:`cell.calibration.joint`;
:meth:`JointResult.as_dict` gives JSON-ready plain types (8 significant digits, NaN → None).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cell import paths

if TYPE_CHECKING:  # annotation only: joint imports this module
    from cell.calibration.joint import CircleFit


# ------------------------------------------------------------------ results
@dataclass(frozen=True)
class Estimate:
    """A value with its 95 % interval [low, high], in ``unit``."""
    value: float
    low: float
    high: float
    unit: str

    def scaled(self, k: float, unit: str) -> "Estimate":
        return Estimate(self.value * k, self.low * k, self.high * k, unit)

    def as_dict(self) -> dict:
        return {"value": _r(self.value), "low": _r(self.low), "high": _r(self.high), "unit": self.unit}


@dataclass(frozen=True)
class Harmonic:
    """Fitted cyclic harmonic k: A·sin(2πkθ/P + φ); ``period_deg`` = P/k."""
    k: int
    period_deg: float
    amplitude: Estimate
    phase: Estimate


@dataclass(frozen=True)
class HarmonicTest:
    """Why harmonic k is in or out: ``status`` accepted | fixed | rejected | not identifiable."""
    k: int
    period_deg: float
    status: str
    reason: str
    p_value: float | None = None


@dataclass(frozen=True)
class Row:
    """Run means at one nominal angle, deg: pass errors, their run-to-run sd (NaN for one
    run), forward − return, and the error of the single step ending here (NaN: none)."""
    nominal_deg: float
    forward_deg: float
    forward_sd_deg: float
    return_deg: float
    return_sd_deg: float
    difference_deg: float
    forward_step_deg: float
    return_step_deg: float


@dataclass(frozen=True)
class JointResult:
    """What :func:`analyse` found. ``errors_deg``, ``step_errors_deg`` (R, 2, M): per run, pass
    (forward, return), nominal angle; ``dirs`` (2, M) approach directions; ``rows`` the run
    means; ``repeatability_deg`` the pooled run-to-run sd of the errors less each run's
    offset (None for one run); ``residual_rms_deg`` of the model; ``dof`` its residual dof."""
    joint: str
    circle: CircleFit
    sense: int
    step_deg: float
    period_deg: float
    nominal_deg: np.ndarray
    dirs: np.ndarray
    rows: tuple[Row, ...]
    errors_deg: np.ndarray
    step_errors_deg: np.ndarray
    backlash_deg: Estimate
    gear_ratio_error: Estimate
    offset_deg: Estimate
    harmonics: tuple[Harmonic, ...]
    harmonic_tests: tuple[HarmonicTest, ...]
    n_runs: int
    n_images: int
    dof: int
    residual_rms_deg: float
    repeatability_deg: float | None

    @property
    def gear_ratio_ppm(self) -> Estimate:
        return self.gear_ratio_error.scaled(1e6, "ppm")

    def model_deg(self, theta_deg, direction) -> np.ndarray:
        """Fitted error, deg, at nominal angles ``theta_deg`` approached moving ``direction``."""
        th = np.asarray(theta_deg, dtype=float)
        out = self.offset_deg.value - np.asarray(direction) * self.backlash_deg.value / 2 \
            + self.gear_ratio_error.value * th
        for h in self.harmonics:
            out = out + h.amplitude.value * np.sin(2 * np.pi * th / h.period_deg + np.radians(h.phase.value))
        return out

    def as_dict(self) -> dict:
        """JSON-ready plain types, 8 significant digits; NaN becomes None."""
        c = self.circle
        return {
            "joint": self.joint, "n_runs": self.n_runs, "n_images": self.n_images,
            "step_deg": _r(self.step_deg), "sense": self.sense, "period_deg": _r(self.period_deg),
            "circle": {"center_mm": [_r(v) for v in c.center], "radius_mm": _r(c.radius),
                       "rms_mm": _r(c.rms), "sd_mm": [_r(math.sqrt(v)) for v in np.diag(c.cov)],
                       "n": c.n, "iterations": c.iterations, "start": c.start},
            "backlash_deg": self.backlash_deg.as_dict(),
            "gear_ratio_error": self.gear_ratio_error.as_dict(),
            "gear_ratio_error_ppm": self.gear_ratio_ppm.as_dict(),
            "offset_deg": self.offset_deg.as_dict(),
            "harmonics": [{"k": h.k, "period_deg": _r(h.period_deg), "amplitude_deg":
                           h.amplitude.as_dict(), "phase_deg": h.phase.as_dict()} for h in self.harmonics],
            "harmonic_tests": [{"k": t.k, "period_deg": _r(t.period_deg), "status": t.status,
                                "reason": t.reason, "p_value": _r(t.p_value)} for t in self.harmonic_tests],
            "dof": self.dof, "residual_rms_deg": _r(self.residual_rms_deg),
            "repeatability_deg": _r(self.repeatability_deg),
            "table": [{k: _r(v) for k, v in vars(row).items()} for row in self.rows],
        }


def _r(v, digits: int = 8):
    """A plain float rounded to ``digits`` significant digits; None for None/NaN."""
    return None if v is None or not math.isfinite(float(v)) else float(f"{float(v):.{digits}g}")


# ------------------------------------------------------------------ plot
def plot(result: JointResult, path) -> Path:
    """Write a PNG of the error (deg; arcsec on the right) against the nominal angle: run means
    per pass with run-to-run sd bars, the fitted model per pass, the estimates in the title.
    Saved to a temporary file beside ``path``, then renamed (atomic); returns the path.
    Imports matplotlib (Agg) only here. Raises OSError if it cannot be written."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    r, out = result, Path(path)
    fig = Figure(figsize=(9, 5.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    grid = np.linspace(r.nominal_deg.min(), r.nominal_deg.max(), 400)
    sds = (None, None) if r.n_runs < 2 else np.std(r.errors_deg, axis=0, ddof=1)
    for i, (name, d, mk) in enumerate((("forward (moving −)", -1, "v"), ("return (moving +)", 1, "^"))):
        ax.errorbar(r.nominal_deg, r.errors_deg[:, i].mean(axis=0), yerr=sds[i], fmt=mk, ms=4,
                    color=f"C{i}", capsize=2, label=f"{name}, mean of {r.n_runs} run(s) ± sd")
        ax.plot(grid, r.model_deg(grid, d), "-", color=f"C{i}", lw=1, label=f"model, {name.split()[0]}")
    ax.axhline(0, color="0.6", lw=0.6)
    ax.set_xlabel("nominal joint angle θ, deg")
    ax.set_ylabel("error (actual − nominal), deg")
    ax.secondary_yaxis("right", functions=(lambda d: d * 3600, lambda s: s / 3600)).set_ylabel("arcsec")
    b, g = r.backlash_deg, r.gear_ratio_ppm
    ax.set_title(f"{r.joint}: {r.n_runs} run(s), step {r.step_deg:g}°; backlash {b.value:.4g}° "
                 f"[{b.low:.3g}, {b.high:.3g}], gear-ratio error {g.value:.4g} ppm "
                 f"[{g.low:.3g}, {g.high:.3g}] (95 %)", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = paths.temp_beside(out)
    try:
        with os.fdopen(fd, "wb") as f:
            fig.savefig(f, format="png", dpi=100)
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return out


__all__ = ["Estimate", "Harmonic", "HarmonicTest", "JointResult", "Row", "plot"]
