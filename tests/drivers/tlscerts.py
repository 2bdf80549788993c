"""Certificates for the Modbus/TCP Security tests, made in the test (none is committed):
a CA, the controller's certificate, and PLC client certificates with or without the role
extension (OID 1.3.6.1.4.1.50316.802.1, a DER UTF8String as the spec writes it)."""
from __future__ import annotations

import datetime as dt
import ipaddress
import ssl
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from drivers.plc.tls import ROLE_OID

NOW = dt.datetime.now(dt.timezone.utc)


def _utf8string(text: str) -> bytes:
    raw = text.encode()
    assert len(raw) < 128
    return bytes([0x0C, len(raw)]) + raw


@dataclass
class Issued:
    cert: Path
    key: Path


class Authority:
    """A CA that writes PEM files into ``folder``."""

    def __init__(self, folder: Path, name: str = "Test PLC CA"):
        self.folder = folder
        self.name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
        self.key = ec.generate_private_key(ec.SECP256R1())
        self.cert = (x509.CertificateBuilder().subject_name(self.name).issuer_name(self.name)
                     .public_key(self.key.public_key()).serial_number(x509.random_serial_number())
                     .not_valid_before(NOW - dt.timedelta(days=1)).not_valid_after(NOW + dt.timedelta(days=30))
                     .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
                     .sign(self.key, hashes.SHA256()))
        self.path = folder / f"{name.replace(' ', '-').lower()}.pem"
        self.path.write_bytes(self.cert.public_bytes(serialization.Encoding.PEM))

    def issue(self, cn: str, role: str | None = None, server: bool = False,
              days: tuple[int, int] = (-1, 30)) -> Issued:
        key = ec.generate_private_key(ec.SECP256R1())
        b = (x509.CertificateBuilder()
             .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
             .issuer_name(self.name).public_key(key.public_key())
             .serial_number(x509.random_serial_number())
             .not_valid_before(NOW + dt.timedelta(days=days[0]))
             .not_valid_after(NOW + dt.timedelta(days=days[1])))
        if server:
            b = b.add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                             x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                                critical=False)
        if role is not None:
            b = b.add_extension(x509.UnrecognizedExtension(x509.ObjectIdentifier(ROLE_OID), _utf8string(role)),
                                critical=False)
        cert = b.sign(self.key, hashes.SHA256())
        out = Issued(self.folder / f"{cn}.pem", self.folder / f"{cn}.key")
        out.cert.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        out.key.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                              serialization.NoEncryption()))
        return out


def client_context(ca: Authority, me: Issued | None) -> ssl.SSLContext:
    """A PLC's TLS context: trusts ``ca`` for the controller, presents ``me`` (None: no
    certificate)."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_verify_locations(cafile=str(ca.path))
    ctx.check_hostname = False      # pymodbus's TLS client passes no server name; the CA still counts
    if me is not None:
        ctx.load_cert_chain(str(me.cert), str(me.key))
    return ctx
