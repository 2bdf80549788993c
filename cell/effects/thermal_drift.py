"""thermal_drift: both links grow with temperature
(format: L_true = L_nominal·(1 + α·(T − T_ref)))."""
from __future__ import annotations

import numpy as np

from cell.effects.base import Effect, Linear, ParamSpec, Remedy, TempSpread

MIN_TEMP_SPREAD_C = 0.2


def thermal_drift(x, jidx, links_mm, temp_c):
    """Thermal expansion of both links: Δl_k = α·l_k·(T − T_ref), α in 1/K, T_ref (°C) the
    known temperature the nominal lengths hold at (default 20 °C, ISO 1). Acts on no single
    joint (``joints = []``); T comes from the temperature model (plant) or the log."""
    alpha, t_ref = np.asarray(x, dtype=float)
    return alpha * (np.asarray(temp_c, dtype=float)[:, None] - t_ref) * np.asarray(links_mm)[None, :]


def d_thermal_drift(x, jidx, links_mm, temp_c):
    """∂Δl_k/∂α = l_k·(T − T_ref); ∂Δl_k/∂T = α·l_k."""
    alpha, t_ref = np.asarray(x, float)
    return ([(temp_c - t_ref)[:, None] * links_mm[None, :]],
            np.tile(alpha * links_mm, (len(temp_c), 1)))


EFFECT = Effect(
    "thermal_drift", "thermal", "link", (), False,
    (ParamSpec("thermal_expansion_per_k", "1/K", "linear expansion of both links", (-2e-5, 2e-4),
               (10e-6, 30e-6), False),
     ParamSpec("thermal_ref_temp_c", "°C", "temperature of the nominal lengths (known)",
               (-50.0, 100.0), (20.0, 20.0), False, fitted=False, default=20.0)),
    "temperature", "both links grow with temperature", thermal_drift, d_thermal_drift,
    mimics=("link_length",),
    needs=(TempSpread(MIN_TEMP_SPREAD_C, "thermal growth cannot be told from link_length"),),
    remedy=Remedy("thermal", "Calibrate the kinematics at working temperature, and keep the "
                  "cell's temperature steady: the links grow with it.",
                  ("cellctl calibrate kinematics",)),
    linear=Linear(path_nuisance="thermal_ref_temp_c"))
