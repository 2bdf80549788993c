"""The rule every calibration command applies before it writes (pure numerics, no I/O).

A calibration is written only if it passes; ``--accept-worse`` writes a failing one
anyway, with the :func:`warning` stored in the written file (``accept_worse: true``,
``warning``) and in the audit trail. Two rules, each checked on its own:

* **No held-out figure worse.** Every figure measured on poses (or views) the fit did not
  use — rms *and* max — must not be larger after the calibration than before it (the
  nominal model with only its registration fitted). One figure getting worse fails the
  check, whatever the others do: a calibration that trades a better rms for a worse
  worst case moves some part of the work space away from where it was.
* **Residual not far above the measured noise.** The fit's residual σ per axis
  (√(RSS/dof)) is compared with σ of the measurement noise estimated apart from the fit
  (the command names where it comes from: revisited poses, the markers' rigid
  constellation within each pose, each camera view fitted alone, the detector's own
  centre uncertainty). It is *far* above when both hold:

  - σ_residual > :data:`FAR_FACTOR` × σ_noise: what the model leaves unexplained,
    √(σ_res² − σ_noise²), is then at least √3 ≈ 1.7 × the noise itself, so the calibrated
    model misses by more than the measurement scatters;
  - the excess is significant: the one-sided F test of the two variances (dof of the
    fit, dof of the noise estimate) gives p < :data:`ALPHA`, so a noise estimate from few
    degrees of freedom does not refuse a good calibration by chance.

  Then the model lacks something the data show (an effect outside the fitted vocabulary,
  a bumped target, inconsistent views) and its parameters absorb it in ways the
  held-out poses need not share.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from cell.diagnosis.chain.noise import revisits_disagree as f_test_p

FAR_FACTOR = 2.0     #: residual σ above this multiple of the noise σ is "far" (if significant)
ALPHA = 1e-3         #: ... and significant at this level (one-sided F test of the variances)


@dataclass(frozen=True)
class Figure:
    """One held-out figure before and after the calibration (same unit)."""

    name: str
    before: float
    after: float
    unit: str

    @property
    def worse(self) -> bool:
        return self.after > self.before

    def text(self) -> str:
        d = self.after - self.before
        rel = f", {d / self.before:+.1%}" if self.before > 0 else ""
        return f"{self.name} {self.before:.4g} → {self.after:.4g} {self.unit} ({d:+.4g} {self.unit}{rel})"


@dataclass(frozen=True)
class Noise:
    """The residual against the measurement noise: σ per axis and degrees of freedom of
    each, where the noise estimate came from, the ratio, the F test's p and the verdict."""

    residual: float
    residual_dof: int
    sigma: float | None
    dof: int
    source: str
    unit: str
    ratio: float = math.nan
    p: float = 1.0
    far: bool = False

    def text(self) -> str:
        if self.sigma is None:
            return f"measurement noise unknown ({self.source}); residual σ {self.residual:.4g} {self.unit}"
        return (f"residual σ {self.residual:.4g} {self.unit} per axis is {self.ratio:.3g}× the measured "
                f"noise σ {self.sigma:.4g} {self.unit} ({self.source}; F test p = {self.p:.2g})")

    def as_dict(self) -> dict:
        return {"residual_sigma": _r(self.residual), "residual_dof": int(self.residual_dof),
                "sigma": _r(self.sigma), "dof": int(self.dof), "source": self.source,
                "unit": self.unit, "ratio": _r(self.ratio), "p": _r(self.p, 12), "far": self.far,
                "rule": f"far when σ_res > {FAR_FACTOR:g}× σ_noise and the F test gives p < {ALPHA:g}"}


def noise_check(residual: float, residual_dof: int, sigma: float | None, dof: int, source: str,
                unit: str) -> Noise:
    """:class:`Noise` for a residual σ (``residual_dof``) against a noise σ (``dof``), see the
    module doc. ``sigma`` None (no noise estimate): never far."""
    if sigma is None or not (sigma > 0) or dof <= 0 or residual_dof <= 0 or not math.isfinite(residual):
        return Noise(residual, residual_dof, None if sigma is None or not sigma > 0 else sigma, dof, source, unit)
    ratio = residual / sigma
    p = f_test_p(residual, residual_dof, sigma, dof)
    return Noise(residual, residual_dof, sigma, dof, source, unit, ratio, p,
                 bool(ratio > FAR_FACTOR and p < ALPHA))


@dataclass(frozen=True)
class Verdict:
    """The check of one calibration: the held-out ``figures``, the ``noise`` comparisons
    and any ``other`` failed rule of the command's own (text)."""

    figures: tuple[Figure, ...] = ()
    noise: tuple[Noise, ...] = ()
    other: tuple[str, ...] = field(default_factory=tuple)

    @property
    def worse(self) -> list[Figure]:
        return [f for f in self.figures if f.worse]

    @property
    def far(self) -> list[Noise]:
        return [n for n in self.noise if n.far]

    @property
    def passed(self) -> bool:
        return not self.worse and not self.far and not self.other

    def failures(self) -> list[str]:
        """Each failed rule in words (empty when passed)."""
        return ([f"held-out {f.text()} got worse" for f in self.worse]
                + [f"{n.text()}: far above the noise" for n in self.far] + list(self.other))

    def reason(self) -> str:
        if self.passed:
            said = [f"held-out {f.text()}" for f in self.figures] + [n.text() for n in self.noise]
            return "; ".join(said) or "no held-out figure and no noise estimate to compare with"
        return "; ".join(self.failures())

    def as_dict(self) -> dict:
        return {"passed": self.passed, "reason": self.reason(), "failures": self.failures(),
                "worse": [{"figure": f.name, "before": _r(f.before), "after": _r(f.after), "unit": f.unit}
                          for f in self.worse],
                "figures": [{"figure": f.name, "before": _r(f.before), "after": _r(f.after), "unit": f.unit,
                             "worse": f.worse} for f in self.figures],
                "noise": [n.as_dict() for n in self.noise],
                "other": list(self.other)}


def warning(verdict: Verdict) -> str:
    """The warning a calibration written with ``--accept-worse`` carries."""
    return "written with --accept-worse although its check failed: " + "; ".join(verdict.failures())


def _r(v, nd: int = 6):
    return None if v is None or not math.isfinite(v) else round(float(v), nd)
