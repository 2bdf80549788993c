"""One way to name device backends: a plain dict ``name -> "module:attribute"``, imported
only when a config chooses the name (python-can's interface table is the model).

Every device registry uses it: the cell's device sets (:data:`cell.devices.BACKENDS`), the
PLC link (:data:`drivers.plc.BACKENDS`), the camera (:data:`drivers.camera.BACKENDS`, the
hand camera included) and our own CAN buses (:data:`drivers.stations.bus.BACKENDS`). The
simulated twins are backends like any other, so production code never imports a
simulation module unless a config asks for one.
"""
from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from cell.errors import ConfigError


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
