"""OPC UA test helpers: a real asyncua client on loopback, driven from the test thread
through a private event loop, and client certificates made the way an MES would make
them (asyncua's own generator: an independent implementation from the server's)."""
from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto import cert_gen, uacrypto
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID

from cell.opcua.space import NAMESPACE

CLIENT_URI = "urn:example:mes:client"


class Loop:
    """An asyncio loop in a thread of its own: ``run(coro)`` from the test thread."""

    def __init__(self):
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="test-opcua-client", daemon=True)
        self.thread.start()

    def run(self, coro, timeout: float = 120.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def close(self):
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


@pytest.fixture
def aio():
    loop = Loop()
    yield loop
    loop.close()


def client_certificate(folder: Path, name: str = "mes", uri: str = CLIENT_URI) -> tuple[Path, Path]:
    """(certificate DER, key PEM) of a self-signed OPC UA client application certificate."""
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key, name, {}, [x509.UniformResourceIdentifier(uri), x509.DNSName("localhost")],
        [ExtendedKeyUsageOID.CLIENT_AUTH])
    folder.mkdir(parents=True, exist_ok=True)
    cpath, kpath = folder / f"{name}.der", folder / f"{name}.pem"
    cpath.write_bytes(uacrypto.der_from_x509(cert))
    kpath.write_bytes(cert_gen.dump_private_key_as_pem(key))
    return cpath, kpath


async def connect(url: str, cert: tuple[Path, Path] | None = None, user_cert: bool = True,
                  server_cert: Path | None = None) -> Client:
    """A connected client: anonymous without ``cert``; with it, Basic256Sha256
    SignAndEncrypt (the server's certificate pinned from ``server_cert``, as an MES copies
    it) and, if ``user_cert``, the same certificate as its X.509 user."""
    c = Client(url, timeout=30)
    c.session_timeout = 600_000
    if cert is not None:
        c.application_uri = CLIENT_URI
        await c.set_security(_policy(), str(cert[0]), str(cert[1]), mode=ua.MessageSecurityMode.SignAndEncrypt,
                             server_certificate=str(server_cert) if server_cert else None)
        if user_cert:
            await c.load_client_certificate(str(cert[0]))
            await c.load_private_key(str(cert[1]))
    await c.connect()
    return c


def _policy():
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
    return SecurityPolicyBasic256Sha256


async def node(c: Client, path: str):
    """The node at dotted ``path`` in the cell's namespace."""
    idx = await c.get_namespace_index(NAMESPACE)
    return c.get_node(ua.NodeId(path, idx))
