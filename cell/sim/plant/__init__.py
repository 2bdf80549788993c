"""The plant: the simulated "real" robot that stands in for the real cell.

* :mod:`cell.sim.plant.config` — the plant file model (``PlantConfig``) and loading with
  file:line:field errors.
* :mod:`cell.sim.plant.core` — :class:`Plant`, the true state and the truth.
* :mod:`cell.sim.plant.arm` — :class:`PlantArm`, the plant as a compensation Arm.

The effects it applies are the vocabulary of :mod:`cell.effects`.
"""
from cell.sim.plant.arm import PlantArm
from cell.sim.plant.config import (EffectConfig, PlantConfig, TemperatureModel, config_from_mapping,
                               load_plant_config)
from cell.sim.plant.core import Plant

__all__ = ["EffectConfig", "Plant", "PlantArm", "PlantConfig", "TemperatureModel",
           "config_from_mapping", "load_plant_config"]
