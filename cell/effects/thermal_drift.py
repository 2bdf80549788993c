"""thermal_drift: the links grow with temperature
(format: L_true = L_nominal·(1 + α·(T − T_ref))). On a chain every length of the arm grows
alike, so each point in the base frame moves to (1 + α·(T − T_ref)) times itself."""
from __future__ import annotations

import numpy as np

from cell.effects.base import ChainPoses, Effect, OnChain, ParamSpec, Remedy

MIN_TEMP_SPREAD_C = 0.2
REF_TEMP_C = 20.0          # T_ref: the temperature the nominal lengths hold at (ISO 1)


def thermal_drift(x, jidx, links_mm, temp_c):
    """Thermal expansion of both links: Δl_k = α·l_k·(T − T_ref), α in 1/K, T_ref (°C) the
    known temperature the nominal lengths hold at (default 20 °C, ISO 1). Acts on no single
    joint (``joints = []``); T comes from the temperature model (plant) or the log."""
    alpha, t_ref = np.asarray(x, dtype=float)
    return alpha * (np.asarray(temp_c, dtype=float)[:, None] - t_ref) * np.asarray(links_mm)[None, :]


def chain_growth(poses: ChainPoses, k: int) -> np.ndarray:
    """Relative growth of the whole arm per unit α: T − T_ref per pose; 0 on every pose when
    the campaign records no temperature (the format's reference temperature), and on a pose
    whose temperature is not known (NaN: a sample of a measured move, paths.csv records
    none; :func:`move_growth` stands for it there)."""
    if poses.temp_c is None:
        return np.zeros(len(poses.q))
    return np.nan_to_num(np.asarray(poses.temp_c, float) - REF_TEMP_C, nan=0.0)


def move_growth(poses: ChainPoses, k: int) -> np.ndarray:
    """The nuisance of a campaign whose measured moves record no temperature while its
    static poses do: 1 on the moves' samples, so that its parameter β = α·(T_moves − T_ref)
    is the arm's relative growth while it made them (the v1 path temperature, as one
    number). 0 everywhere without a temperature column."""
    if poses.temp_c is None:
        return np.zeros(len(poses.q))
    return np.isnan(np.asarray(poses.temp_c, float)).astype(float)


def d_thermal_drift(x, jidx, links_mm, temp_c):
    """∂Δl_k/∂α = l_k·(T − T_ref); ∂Δl_k/∂T = α·l_k."""
    alpha, t_ref = np.asarray(x, float)
    return ([(temp_c - t_ref)[:, None] * links_mm[None, :]],
            np.tile(alpha * links_mm, (len(temp_c), 1)))


EXPANSION = ParamSpec("thermal_expansion_per_k", "1/K", "linear expansion of both links",
                      (-2e-5, 2e-4), (10e-6, 30e-6), False)

EFFECT = Effect(
    "thermal_drift", "thermal", "link", (), False,
    (EXPANSION,
     ParamSpec("thermal_ref_temp_c", "°C", "temperature of the nominal lengths (known)",
               (-50.0, 100.0), (REF_TEMP_C, REF_TEMP_C), False, fitted=False, default=REF_TEMP_C)),
    "temperature", "both links grow with temperature", thermal_drift, d_thermal_drift,
    mimics=("link_length",),
    remedy=Remedy("thermal", "Calibrate the kinematics at working temperature, and keep the "
                  "cell's temperature steady: the links grow with it.",
                  ("cellctl calibrate kinematics",)),
    chain=OnChain("arm", "thermal_expansion_per_k", "1/K", term=chain_growth,
                  remedy=Remedy("thermal", "Measure and calibrate the arm at working temperature "
                                "(after a warm-up), and keep its temperature steady: every "
                                "length of the arm grows with it."),
                  unseen="no temp_c column: the temperature of the poses is not known",
                  min_spread=MIN_TEMP_SPREAD_C,
                  still=f"temperature spread under {MIN_TEMP_SPREAD_C} °C over the fit poses: "
                        "growth cannot be told from constant link lengths",
                  bounds=EXPANSION.bounds,
                  nuisance=(("move_growth_rel", "1", move_growth),)))
