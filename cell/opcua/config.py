"""The ``opcua`` section of the cell config: where the read-only OPC UA server listens and
where it keeps its certificates. Absent (the default): no server.

Security is not configurable on purpose: a cell on hardware serves only Basic256Sha256
SignAndEncrypt, to clients whose application certificate is in the trust list and who
identify with a trusted X.509 certificate; the simulated cell (``--sim``) also offers an
endpoint without security and anonymous sessions (:mod:`cell.opcua.server`).
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

#: the port OPC UA servers listen on by default (IANA ``opcua-tcp``)
DEFAULT_PORT = 4840


class OpcuaSection(BaseModel):
    """``host``/``port``: where the server listens (port 0: any free port, for tests).
    ``pki``: folder of the server's certificate and key (made on first start:
    ``server-cert.der``, ``server-key.pem``) and of ``trusted/``, the client certificates
    or CA certificates (PEM or DER) whose clients may connect; relative paths as for
    every path of the config. ``poll_s``: how often (wall s) the server takes what the
    Publisher has queued for it. ``queue``: how many messages it may fall behind by
    before the oldest are dropped (counted, logged; never the controller delayed)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = Field(default="127.0.0.1", min_length=1)
    port: int = Field(default=DEFAULT_PORT, ge=0, le=65535)
    pki: str = "var/opcua"
    poll_s: float = Field(default=0.05, gt=0, le=5)
    queue: int = Field(default=1000, ge=10, le=1_000_000)


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``--opcua``) as ``(host, port)``; ``:PORT`` means 127.0.0.1.

    :raises ValueError: no port, or a port outside 0..65535."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"--opcua {text!r}: give HOST:PORT (e.g. 127.0.0.1:4840; port 0: any free port)")
    return (host.strip("[]") or "127.0.0.1"), int(port)
