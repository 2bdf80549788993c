"""One way to name device backends: a plain dict ``name -> "module:attribute"``, imported
only when a config chooses the name (python-can's interface table is the model).

Every device registry uses it: the cell's device sets (:data:`cell.devices.BACKENDS`), the
PLC link (:data:`drivers.plc.BACKENDS`), the camera (:data:`drivers.camera.BACKENDS`, the
hand camera included) and our own CAN buses (:data:`drivers.stations.bus.BACKENDS`). The
simulated twins are backends like any other and live beside their drivers, as python-can's
virtual bus does (``drivers/camera/sim.py``, ``drivers/stations/sim.py``); production code
never imports a simulation module (:func:`is_simulation`) unless a config asks for one.
"""
from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from cell.errors import ConfigError


def is_simulation(module: str) -> bool:
    """Whether ``module`` is simulation code: the simulated cell (``cell.sim`` and below) or
    a driver's simulated twin (a module ``sim`` or ``sim_*`` of a ``drivers`` package).
    The tests hold production code to importing none of them."""
    if module == "cell.sim" or module.startswith("cell.sim."):
        return True
    parts = module.split(".")
    return parts[0] == "drivers" and any(p == "sim" or p.startswith("sim_") for p in parts[1:])


def load(table: Mapping[str, str], name: str, what: str) -> Any:
    """The class or function ``table[name]`` names (``"module:attribute"``), its module
    imported now.

    :param what: the config key that chose ``name``, for the message (``camera.backend``).
    :raises ConfigError: ``"<what>: unknown backend 'x' (known: a, b)"``.
    """
    try:
        target = table[name]
    except (KeyError, TypeError):
        raise ConfigError(f"{what}: unknown backend {name!r} (known: {', '.join(sorted(table))})") from None
    module, attribute = target.split(":")
    return getattr(importlib.import_module(module), attribute)
