"""Modbus/TCP Security (the Modbus Organization's "MB-TCP-Security", port 802): TLS 1.2 or
newer, mutual X.509 authentication, and a role in the client certificate that the server
maps to rights.

* The PDU travels with its MBAP header, as on plain Modbus TCP, inside the TLS stream.
* The client's role is the certificate extension ``1.3.6.1.4.1.50316.802.1`` (the spec's
  RoleOID), an ASN.1 ``UTF8String`` such as ``Operator``. A certificate without it, or
  with a role the config does not list, is closed at connect and logged with its subject.
* Rights (:data:`RIGHTS`) say which registers and command bits a role may change. A write
  that needs a right the role lacks is refused with exception 01, logged, and audited by
  the controller (:meth:`drivers.plc.server.PlcLink.take_refusals`).

Start-up checks (:func:`server_context`) name the config field at fault: a file that is
missing or not PEM, a certificate expired or not yet valid, a key that does not fit its
certificate. :func:`check_client_certificate` checks a PLC's certificate before it is
installed (``cellctl plc check-cert``).
"""
from __future__ import annotations

import datetime as dt
import ssl
from collections.abc import Mapping
from pathlib import Path

from cell.errors import ConfigError

ROLE_OID = "1.3.6.1.4.1.50316.802.1"

#: right -> what it lets a role change. ``run``: execute, abort, acknowledge and part_id
#: (and the heartbeat: any role with a right may own the link); ``recipe``: recipe_select;
#: ``reset``: the reset bit; ``calibrate``: the calibrate bit and calibration_select.
RIGHTS = ("run", "recipe", "reset", "calibrate")
_REGISTER_RIGHT = {"part_id": "run", "recipe_select": "recipe", "calibration_select": "calibrate"}
_COMMAND_BIT_RIGHT = {"execute": "run", "abort": "run", "acknowledge": "run", "reset": "reset",
                      "calibrate": "calibrate"}

#: the issue's example: the operator runs cycles, maintenance also selects recipes, resets
#: and calibrates, the monitor only reads
DEFAULT_ROLES: dict[str, list[str]] = {"operator": ["run"],
                                       "maintenance": ["run", "recipe", "reset", "calibrate"],
                                       "monitor": []}


def rights_needed(register_map, new: Mapping[str, int], current: Mapping[str, int]) -> set[str]:
    """The rights a write of ``new`` (register name -> value, map-validated) needs, given the
    image's ``current`` values: a command bit needs its right only if the write changes it;
    the heartbeat needs some right (returned as ``"any"``)."""
    need: set[str] = set()
    for name, value in new.items():
        if name == "plc_heartbeat":
            need.add("any")
        elif name == "command_word":
            before = register_map.bits(name, current.get(name, 0))
            after = register_map.bits(name, value)
            need |= {_COMMAND_BIT_RIGHT.get(b, "run") for b in after if after[b] != before.get(b)}
        else:
            need.add(_REGISTER_RIGHT.get(name, "run"))
    return need


def missing_right(rights: frozenset[str], need: set[str]) -> str | None:
    """The first right in ``need`` that ``rights`` lacks (``"any"``: the role has none)."""
    for r in sorted(need):
        if r == "any":
            if not rights:
                return "any right (the role reads only)"
        elif r not in rights:
            return r
    return None


def _der_string(value: bytes) -> str | None:
    """An ASN.1 UTF8String / PrintableString / IA5String from DER, else None."""
    if len(value) < 2 or value[0] not in (0x0C, 0x13, 0x16):
        return None
    n, body = value[1], value[2:]
    if n & 0x80:
        k = n & 0x7F
        if k == 0 or k > 2 or len(body) < k:
            return None
        n, body = int.from_bytes(body[:k], "big"), body[k:]
    if len(body) != n:
        return None
    try:
        return body.decode("utf-8").strip()
    except UnicodeDecodeError:
        return None


def role_of(der: bytes) -> tuple[str | None, str]:
    """(role, subject) of a DER certificate; role None if it carries no readable role."""
    from cryptography import x509
    cert = x509.load_der_x509_certificate(der)
    subject = cert.subject.rfc4514_string()
    try:
        ext = cert.extensions.get_extension_for_oid(x509.ObjectIdentifier(ROLE_OID))
    except x509.ExtensionNotFound:
        return None, subject
    raw = getattr(ext.value, "value", b"")
    return _der_string(raw), subject


def roles_table(roles: Mapping[str, list[str]], field: str = "plc.tls.roles") -> dict[str, frozenset[str]]:
    """Role name (case-folded) -> rights; ConfigError naming ``field.<role>`` for an unknown
    right."""
    out = {}
    for role, rights in roles.items():
        bad = [r for r in rights if r not in RIGHTS]
        if bad:
            raise ConfigError(f"{field}.{role}: unknown right {bad[0]!r} (rights: {', '.join(RIGHTS)})")
        out[str(role).casefold()] = frozenset(rights)
    return out


def _load_cert(path: Path, field: str, now: dt.datetime):
    from cryptography import x509
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{field}: cannot read {path}: {exc.strerror or exc}") from None
    try:
        certs = x509.load_pem_x509_certificates(data)
    except ValueError:
        raise ConfigError(f"{field}: {path} is not a PEM certificate") from None
    for cert in certs:
        who = cert.subject.rfc4514_string()
        if cert.not_valid_after_utc < now:
            raise ConfigError(f"{field}: certificate {who!r} in {path} expired on "
                              f"{cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC")
        if cert.not_valid_before_utc > now:
            raise ConfigError(f"{field}: certificate {who!r} in {path} is not valid before "
                              f"{cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC")
    return certs


def check_client_certificate(path: Path, ca: Path, roles: Mapping[str, list[str]],
                             now: dt.datetime | None = None) -> tuple[str, frozenset[str]]:
    """Check a PLC's client certificate before it is installed: readable, in date, issued
    by ``ca``, with a role the config lists. Returns (role, rights); raises ConfigError
    naming what is wrong (``client certificate``, ``role extension``, ``plc.tls.roles``)."""
    from cryptography.hazmat.primitives.serialization import Encoding
    now = now or dt.datetime.now(dt.timezone.utc)
    cert = _load_cert(path, "client certificate", now)[0]
    issuers = _load_cert(ca, "plc.tls.ca", now)
    if not any(cert.issuer == i.subject and _signed_by(cert, i) for i in issuers):
        raise ConfigError(f"client certificate: {cert.subject.rfc4514_string()!r} in {path} is not "
                          f"issued by a CA in plc.tls.ca ({ca}): the controller would refuse it")
    role, subject = role_of(cert.public_bytes(Encoding.DER))
    if role is None:
        raise ConfigError(f"client certificate: {subject!r} in {path} has no role extension "
                          f"(OID {ROLE_OID}, a UTF8String such as Operator)")
    table = roles_table(roles)
    if role.casefold() not in table:
        raise ConfigError(f"plc.tls.roles: the certificate's role {role!r} is not listed "
                          f"(listed: {', '.join(sorted(table))})")
    return role, table[role.casefold()]


def _signed_by(cert, issuer) -> bool:
    try:
        cert.verify_directly_issued_by(issuer)
        return True
    except Exception:       # InvalidSignature, or a key type that cannot sign
        return False


def server_context(cert: Path, key: Path, ca: Path, now: dt.datetime | None = None,
                   field: str = "plc.tls") -> ssl.SSLContext:
    """A server SSLContext for Modbus/TCP Security: TLS >= 1.2, client certificates required
    and verified against ``ca``. Every file is checked first; ConfigError names the field
    (``plc.tls.cert``, ``plc.tls.key``, ``plc.tls.ca``) and the file."""
    now = now or dt.datetime.now(dt.timezone.utc)
    _load_cert(cert, f"{field}.cert", now)
    _load_cert(ca, f"{field}.ca", now)
    if not key.is_file():
        raise ConfigError(f"{field}.key: cannot read {key}: no such file")
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.verify_mode = ssl.CERT_REQUIRED
    try:
        ctx.load_cert_chain(str(cert), str(key))
    except ssl.SSLError as exc:
        raise ConfigError(f"{field}.key: {key} does not fit {field}.cert {cert} ({exc.reason or exc})") from None
    except OSError as exc:
        raise ConfigError(f"{field}.key: cannot read {key}: {exc.strerror or exc}") from None
    try:
        ctx.load_verify_locations(cafile=str(ca))
    except ssl.SSLError as exc:
        raise ConfigError(f"{field}.ca: {ca}: {exc.reason or exc}") from None
    return ctx
