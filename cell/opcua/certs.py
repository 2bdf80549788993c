"""The OPC UA server's own certificate and the folder of trusted client certificates.

Layout of the ``pki`` folder (``opcua.pki``, ``var/opcua`` by default)::

    server-cert.der   the server's application instance certificate (self-signed, DER)
    server-key.pem    its RSA key (PKCS #8, unencrypted, mode 0600)
    trusted/          client certificates, or the CAs that issued them (PEM or DER):
                      a client is served only if its certificate is here or signed here

On first start :func:`ensure_server_certificate` makes a self-signed certificate as OPC
10000-6 §6.2.2 asks of one (RSA 2048, SHA-256, the application URI and the host name in
subjectAltName, serverAuth and clientAuth) with the ``cryptography`` package; later starts
reuse it, so a client that pinned it keeps trusting the cell. A certificate that no longer
names this server's application URI (the cell was renamed) is replaced, the old pair kept
beside it. Files only: no asyncua here.
"""
from __future__ import annotations

import datetime as dt
import os
import socket
from dataclasses import dataclass
from pathlib import Path

from cell.errors import ConfigError

CERT, KEY, TRUSTED = "server-cert.der", "server-key.pem", "trusted"
VALID_DAYS = 5 * 365           #: validity of a generated server certificate
KEY_BITS = 2048                #: Basic256Sha256 allows 2048..4096


@dataclass(frozen=True)
class ServerPki:
    """Paths of the server's certificate, key and trust folder; ``made``: this start made
    the certificate."""

    cert: Path
    key: Path
    trusted: Path
    made: bool = False


def application_uri(cell_name: str) -> str:
    """The server's application URI, which its certificate must carry."""
    return f"urn:cell-controller:{cell_name}:opcua"


def ensure_server_certificate(pki: str | Path, uri: str, hostname: str | None = None,
                              now: dt.datetime | None = None) -> ServerPki:
    """The server certificate and key in ``pki``, made there if missing (see module doc),
    and the ``trusted/`` folder, made empty if missing.

    :raises ConfigError: the folder cannot be written, or the files there cannot be read."""
    from cryptography import x509
    folder = Path(pki)
    cert_path, key_path, trusted = folder / CERT, folder / KEY, folder / TRUSTED
    try:
        trusted.mkdir(parents=True, exist_ok=True)
        if cert_path.is_file() and key_path.is_file():
            cert = x509.load_der_x509_certificate(cert_path.read_bytes())
            if uri in _uris(cert):
                return ServerPki(cert_path, key_path, trusted)
            stamp = (now or dt.datetime.now(dt.timezone.utc)).strftime("%Y%m%dT%H%M%SZ")
            for p in (cert_path, key_path):            # another name: keep the old pair, make a new one
                p.rename(p.with_name(f"{p.name}.{stamp}.old"))
        key_pem, cert_der = _self_signed(uri, hostname or socket.gethostname(), now)
        fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(key_pem)
        cert_path.write_bytes(cert_der)
    except OSError as exc:
        raise ConfigError(f"opcua.pki {folder}: cannot keep the server certificate there: {exc}") from exc
    except ValueError as exc:
        raise ConfigError(f"opcua.pki {cert_path}: not a DER certificate ({exc}); move it away "
                          "and a new one is made at the next start") from exc
    return ServerPki(cert_path, key_path, trusted, made=True)


def _uris(cert) -> list[str]:
    from cryptography import x509
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return []
    return san.get_values_for_type(x509.UniformResourceIdentifier)


def _self_signed(uri: str, hostname: str, now: dt.datetime | None) -> tuple[bytes, bytes]:
    """(key PEM, certificate DER) of a new self-signed OPC UA application certificate."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
    key = rsa.generate_private_key(public_exponent=65537, key_size=KEY_BITS)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"cell-controller OPC UA {hostname}"),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, "cell-controller")])
    start = (now or dt.datetime.now(dt.timezone.utc)) - dt.timedelta(minutes=5)   # clocks a little apart
    pub = key.public_key()
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(pub)
            .serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(start + dt.timedelta(days=VALID_DAYS))
            .add_extension(x509.SubjectAlternativeName([x509.UniformResourceIdentifier(uri),
                                                        x509.DNSName(hostname)]), critical=False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True, key_encipherment=True,
                                         data_encipherment=True, key_agreement=False, key_cert_sign=True,
                                         crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(pub), critical=False)
            .sign(key, hashes.SHA256()))
    key_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption())
    return key_pem, cert.public_bytes(serialization.Encoding.DER)
