"""The PLC link: Modbus TCP server over one named register map, plus its twin.

- :mod:`drivers.plc.register_map`: the one table (addresses, types, access, ranges, meanings)
  and the documents generated from it.
- :mod:`drivers.plc.server`: :class:`~drivers.plc.server.PlcLink`, what the controller uses.
- :mod:`drivers.plc.conformance`: spec fixes in front of pymodbus 3.16.1.
- :mod:`cell.sim.plc`: :class:`~cell.sim.plc.SimPlc`, the simulated PLC, a
  real Modbus TCP client running a PLC-style scan loop.

The controller depends only on :class:`PlcPort` and gets its object from :func:`open_link`
(backends by name, imported lazily); the cell config's ``plc``
section is :class:`PlcConfig`.
"""
from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import TYPE_CHECKING, Protocol

from pydantic import BaseModel, ConfigDict, Field

from cell.errors import ConfigError

if TYPE_CHECKING:
    from drivers.plc.register_map import RegisterMap
    from drivers.plc.server import PlcWrite


class PlcPort(Protocol):
    """What the controller needs from the PLC link (see :class:`drivers.plc.server.PlcLink`)."""

    map: RegisterMap

    def start(self, host: str = "127.0.0.1", port: int = 0) -> int: ...
    def stop(self) -> None: ...
    def read(self, name: str) -> int: ...
    def read_bits(self, name: str) -> dict[str, bool]: ...
    def write(self, name: str, value: int) -> None: ...
    def write_many(self, values: Mapping[str, int]) -> None: ...
    def set_bits(self, name: str, **flags: bool) -> int: ...
    def snapshot(self) -> dict[str, int]: ...
    def next_write(self, timeout: float | None = 0.0) -> PlcWrite | None: ...
    def drain_writes(self) -> list[PlcWrite]: ...
    @property
    def last_heartbeat_change(self) -> float | None: ...


#: Backend name -> "module:class", imported only when chosen.
BACKENDS: dict[str, str] = {
    "modbus_tcp": "drivers.plc.server:PlcLink",
}


class PlcConfig(BaseModel):
    """The ``plc`` section of the cell config. Unknown keys are rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    backend: str = "modbus_tcp"
    host: str = "0.0.0.0"
    port: int = Field(502, ge=0, le=65535)
    heartbeat_timeout_s: float = Field(1.0, gt=0, le=60)


def open_link(backend: str = "modbus_tcp", **kwargs) -> PlcPort:
    """Construct (not start) the PLC link backend named ``backend``; kwargs go to its class.

    Raises :class:`cell.errors.ConfigError` for an unknown backend name.
    """
    try:
        target = BACKENDS[backend]
    except KeyError:
        raise ConfigError(f"plc.backend: unknown backend {backend!r} "
                          f"(known: {', '.join(sorted(BACKENDS))})") from None
    module, cls = target.split(":")
    return getattr(importlib.import_module(module), cls)(**kwargs)
