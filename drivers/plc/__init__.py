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

from collections.abc import Mapping
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from drivers import registry

if TYPE_CHECKING:
    from drivers.plc.register_map import RegisterMap
    from drivers.plc.server import PlcWrite, Refusal


@runtime_checkable
class PlcPort(Protocol):
    """What the controller needs from the PLC link (see :class:`drivers.plc.server.PlcLink`):
    the register image, the PLC's writes, who owns the link and the writes it refused."""

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
    @property
    def owner(self) -> str | None: ...
    def take_refusals(self) -> list[Refusal]: ...


#: Backend name -> "module:class", imported only when chosen.
BACKENDS: dict[str, str] = {
    "modbus_tcp": "drivers.plc.server:PlcLink",
}


class TlsConfig(BaseModel):
    """The ``plc.tls`` section: Modbus/TCP Security (:mod:`drivers.plc.tls`). Relative
    paths are taken from the config file's folder. Files are checked when the link starts."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = Field(802, ge=0, le=65535)
    #: a client that has not finished its TLS handshake this long after connecting is closed
    handshake_timeout_s: float = Field(5.0, gt=0, le=60)
    #: the controller's certificate (PEM; may hold its chain) and private key
    cert: str = "tls/controller.pem"
    key: str = "tls/controller.key"
    #: the CA(s) whose client certificates are accepted (PEM)
    ca: str = "tls/plc-ca.pem"
    #: role (from the certificate's role extension) -> rights (run, recipe, reset, calibrate)
    roles: dict[str, list[str]] = Field(default_factory=lambda: {
        "operator": ["run"], "maintenance": ["run", "recipe", "reset", "calibrate"], "monitor": []})

    @field_validator("roles")
    @classmethod
    def _rights_known(cls, v: dict[str, list[str]]) -> dict[str, list[str]]:
        from drivers.plc.tls import RIGHTS
        for role, rights in v.items():
            bad = [r for r in rights if r not in RIGHTS]
            if bad:
                raise ValueError(f"role {role!r}: unknown right {bad[0]!r} (rights: {', '.join(RIGHTS)})")
        return v

    def resolved(self, base) -> "TlsConfig":
        """This section with relative file paths taken from folder ``base``."""
        from pathlib import Path
        return self.model_copy(update={k: str(Path(base) / getattr(self, k))
                                       for k in ("cert", "key", "ca")})

    def listener(self):
        """The :class:`~drivers.plc.server.TlsListener` of this section: files checked
        (ConfigError naming ``plc.tls.cert|key|ca``), roles mapped to rights."""
        from pathlib import Path

        from drivers.plc.server import TlsListener
        from drivers.plc.tls import roles_table, server_context
        ctx = server_context(Path(self.cert), Path(self.key), Path(self.ca))
        return TlsListener(ctx, roles_table(self.roles), self.host, self.port, self.handshake_timeout_s)


class PlcConfig(BaseModel):
    """The ``plc`` section of the cell config. Unknown keys are rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    backend: str = "modbus_tcp"
    host: str = "127.0.0.1"
    port: int = Field(502, ge=0, le=65535)
    heartbeat_timeout_s: float = Field(1.0, gt=0, le=60)
    #: addresses or networks a client may connect from (``10.0.0.5``, ``10.0.0.0/24``)
    allow: list[str] = Field(default_factory=list)
    #: listen on every interface with no allow-list: must be said, never a default
    allow_any: bool = False
    max_connections: int = Field(8, ge=1, le=1000)
    #: connections one client host may hold (the owner's not counted); at most max_connections
    max_connections_per_host: int = Field(4, ge=1, le=1000)
    idle_timeout_s: float = Field(60.0, gt=0, le=3600)
    frame_timeout_s: float = Field(5.0, gt=0, le=600)
    #: serve plain Modbus TCP on host:port (false: Modbus/TCP Security only)
    plain_tcp: bool = True
    tls: TlsConfig = TlsConfig()

    @field_validator("allow")
    @classmethod
    def _allow_parses(cls, v: list[str]) -> list[str]:
        from drivers.plc.access import parse_allow
        parse_allow(v, "allow")          # ValueError names allow[i] and the entry
        return v

    @model_validator(mode="after")
    def _quota_within_the_cap(self) -> "PlcConfig":
        if self.max_connections_per_host > self.max_connections:
            exc = ValueError(f"max_connections_per_host ({self.max_connections_per_host}) is more than "
                             f"max_connections ({self.max_connections}): one host could take every "
                             "connection; give at most max_connections")
            exc.loc = ("max_connections_per_host",)   # where the problem is (for file:line)
            raise exc
        return self

    @model_validator(mode="after")
    def _wildcard_needs_a_list(self) -> "PlcConfig":
        if not self.plain_tcp and not self.tls.enabled:
            raise ValueError("plain_tcp is false and tls.enabled is false: the PLC could not connect")
        if self.plain_tcp and self.host in ("0.0.0.0", "::", "") and not self.allow and not self.allow_any:
            raise ValueError(f"host {self.host!r} listens on every interface and allow is empty: "
                             "any host that reaches the port could drive the robot. List the "
                             "PLC's address in allow (e.g. allow: [10.0.0.5]), or write "
                             "allow_any: true to mean it")
        return self

    def access_policy(self):
        """The :class:`~drivers.plc.access.AccessPolicy` of this section: the allow-list
        (none for a loopback listener or with ``allow_any``), the cap, the per-host quota
        and the time-outs."""
        import ipaddress

        from drivers.plc.access import AccessPolicy, parse_allow
        try:
            loopback = ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            loopback = self.host == "localhost"
        allow = None if (self.allow_any or (loopback and not self.allow)) else parse_allow(self.allow)
        return AccessPolicy(allow, self.max_connections, self.idle_timeout_s, self.frame_timeout_s,
                            max_per_host=self.max_connections_per_host)


def open_link(backend: str = "modbus_tcp", **kwargs) -> PlcPort:
    """Construct (not start) the PLC link backend named ``backend``; kwargs go to its class.

    Raises :class:`cell.errors.ConfigError` for an unknown backend name.
    """
    return registry.load(BACKENDS, backend, "plc.backend")(**kwargs)
