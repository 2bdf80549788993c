"""The read-only OPC UA server: a thread of its own ("opcua-server") running an asyncio
loop with an asyncua server, fed from a :class:`~cell.publish.Subscription`.

Never in the scan's way: the controller only appends to this server's bounded queue
(:mod:`cell.publish`); the server drains it every ``poll_s`` wall seconds on its own loop,
writes the values that changed and emits a result-ready event per settled cycle. A server
that falls behind loses its oldest messages (counted in :attr:`OpcuaServer.dropped`,
logged), never the controller's time. It runs on wall time and never touches the cell's
clock, so a simulated run is the same with it or without it.

Security (the ``opcua`` section has no switch for it, on purpose):

* always: one endpoint, Basic256Sha256 with SignAndEncrypt, the server's certificate
  from :func:`cell.opcua.certs.ensure_server_certificate`. A client's application
  certificate must be in the trust list (``pki/trusted/``: itself, or a CA that signed it;
  re-read at every new session, so adding or removing a file needs no restart), in date,
  with its application URI, and the key and extended key usages of an OPC UA client;
  the session's user must be an X.509 certificate trusted the same way;
* only for a simulated cell (``insecure=True``, ``--sim``): also an endpoint without
  security, and anonymous sessions.

Read-only for every client: the permission rules (:class:`ReadOnlyRules`) refuse Write,
AddNodes, DeleteNodes and the other changing services before they reach the address
space (Bad_UserAccessDenied), and every variable is CurrentRead only.
"""
from __future__ import annotations

import asyncio
import logging
import socket
import threading
from pathlib import Path

from asyncua import Server, ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole
from asyncua.common.utils import ServiceError
from asyncua.crypto.truststore import basic_ca_validator
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509

from cell.errors import CellError
from cell.log import get_logger
from cell.opcua.certs import application_uri, ensure_server_certificate
from cell.opcua.config import OpcuaSection
from cell.opcua.model import Fold
from cell.opcua.space import Space
from cell.publish import Publisher

log = get_logger("opcua")

#: requests a client may make: asyncua's user set without Write (History updates and
#: node management are not in it)
READ_ONLY = frozenset(ua.NodeId(t) for t in USER_TYPES if t != ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)


class OpcuaError(CellError):
    """The OPC UA server could not start (port taken, certificate folder unusable …)."""


class ReadOnlyRules(PermissionRuleset):
    """Every session, whatever its user, may browse, read, subscribe and call methods, and
    nothing else (asyncua checks this before a request reaches the address space)."""

    def check_validity(self, user, action_type_id, body) -> bool:
        return action_type_id in READ_ONLY


class TrustList:
    """Client certificates checked against ``pki/trusted/``: a certificate is trusted if it
    is there itself (a self-signed one) or chains to a CA there, and is in date. The folder
    is re-read at every new session; an empty or missing folder trusts nobody."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self._store = None
        #: time, application URI, key usages and clientAuth, as OPC 10000-4 §6.1.3 lists them
        self._checks = CertificateValidator(CertificateValidatorOptions.EXT_VALIDATION
                                            | CertificateValidatorOptions.PEER_CLIENT)
        self._policy = x509.verification.PolicyBuilder().extension_policies(
            ca_policy=x509.verification.ExtensionPolicy.permit_all().require_present(
                x509.BasicConstraints, x509.verification.Criticality.AGNOSTIC, basic_ca_validator),
            ee_policy=x509.verification.ExtensionPolicy.permit_all())

    def load(self) -> int:
        """Re-read the folder; returns how many certificates it trusts (unreadable files
        are logged and left out)."""
        certs = []
        for f in sorted(self.folder.glob("*")) if self.folder.is_dir() else []:
            if f.suffix.lower() not in (".der", ".pem", ".crt", ".cer"):
                continue
            try:
                data = f.read_bytes()
                certs.append(x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----")
                             else x509.load_der_x509_certificate(data))
            except (OSError, ValueError) as exc:
                log.warning("opcua_trusted_file_unreadable", file=str(f), error=str(exc))
        self._store = x509.verification.Store(certs) if certs else None
        return len(certs)

    async def validate(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        """asyncua's certificate validator for a session's client certificate: raises a
        ServiceError (Bad_CertificateUntrusted, Bad_CertificateUriInvalid …) to refuse it."""
        await self._checks.validate(cert, app)
        self.load()
        if not self.trusted(cert):
            log.warning("opcua_client_refused", subject=cert.subject.rfc4514_string(), reason="not trusted")
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)

    def trusted(self, cert: x509.Certificate | bytes) -> bool:
        """``cert`` (or its DER) is in date and in, or issued by a CA in, the list last loaded."""
        if isinstance(cert, bytes):
            try:
                cert = x509.load_der_x509_certificate(cert)
            except ValueError:
                return False
        if self._store is None:
            return False
        try:
            self._policy.store(self._store).build_client_verifier().verify(cert, [])
        except x509.verification.VerificationError:
            return False
        return True


class Users:
    """asyncua user manager: a session with a certificate (the X.509 user token, or the
    channel's for an anonymous token) is a user if the certificate is trusted; an anonymous
    session without one only if ``anonymous`` (a simulated cell)."""

    def __init__(self, trust: TrustList, anonymous: bool):
        self.trust, self.anonymous = trust, anonymous

    def get_user(self, iserver, username=None, password=None, certificate=None) -> User | None:
        if username is not None:
            return None
        if certificate:
            return User(role=UserRole.User, name="certificate") if self.trust.trusted(bytes(certificate)) else None
        return User(role=UserRole.Anonymous) if self.anonymous else None


class OpcuaServer:
    """The server of one cell. Subscribes at construction (nothing published after it is
    missed); :meth:`start` returns once it listens, :meth:`stop` takes it down.

    :param section: the ``opcua`` config section (host, port, pki, poll_s, queue).
    :param publisher: the cell's :class:`~cell.publish.Publisher`.
    :param name: the cell's name (server name, application URI).
    :param robot_model: what ``Robot/Model`` shows (the robot preset or calibration).
    :param insecure: also serve without security and to anonymous clients (``--sim`` only).
    """

    def __init__(self, section: OpcuaSection, publisher: Publisher, name: str, robot_model: str = "",
                 insecure: bool = False):
        self.section, self.name, self.robot_model, self.insecure = section, name, robot_model, insecure
        self.sub = publisher.subscribe(("status", "cycle"), maxlen=section.queue)
        self.port: int | None = None
        self.url = ""
        self.dropped = 0                 #: messages the Publisher dropped because this server fell behind
        self.results = 0                 #: result-ready events emitted
        self._fold = Fold()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    # ------------------------------------------------------------------ lifecycle (any thread)
    def start(self, timeout_s: float = 60.0) -> int:
        """Start the thread; returns the TCP port once the server listens.

        :raises OpcuaError: it could not start (the reason), or did not within ``timeout_s``."""
        self._thread = threading.Thread(target=self._main, name="opcua-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            self.stop()
            raise OpcuaError(f"OPC UA server did not start within {timeout_s:g} s")
        if self._error is not None:
            self._thread.join(10)
            self.sub.close()
            raise OpcuaError(f"OPC UA server on {self.section.host}:{self.section.port}: {self._error}") \
                from self._error
        return self.port

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop serving (open sessions are closed) and leave the Publisher."""
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:                   # the loop ended meanwhile
                pass
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("opcua_server_did_not_stop")
        self.sub.close()

    # ------------------------------------------------------------------ the thread
    def _main(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:               # noqa: BLE001 -- reported to start() or logged
            if not self._ready.is_set():
                self._error = exc
                self._ready.set()
            else:
                log.error("opcua_server_failed", error=repr(exc))

    async def _serve(self) -> None:
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        logging.getLogger("asyncua").setLevel(logging.WARNING)     # its INFO is per request
        s = self.section
        uri = application_uri(self.name)
        pki = ensure_server_certificate(s.pki, uri)
        if pki.made:
            log.info("opcua_certificate_made", cert=str(pki.cert))
        port = s.port or _free_port(s.host)
        trust = TrustList(pki.trusted)
        trust.load()
        server = Server(user_manager=Users(trust, anonymous=self.insecure))
        await server.init()
        server.set_endpoint(f"opc.tcp://{_url_host(s.host)}:{port}")
        server.set_server_name(f"cell-controller {self.name}")
        await server.set_application_uri(uri)
        await server.load_certificate(str(pki.cert))
        await server.load_private_key(str(pki.key))
        policies = [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt]
        tokens: list[type] = [ua.X509IdentityToken]
        if self.insecure:
            policies.append(ua.SecurityPolicyType.NoSecurity)
            tokens.append(ua.AnonymousIdentityToken)
        server.set_security_policy(policies, permission_ruleset=ReadOnlyRules())
        server.set_identity_tokens(tokens)
        server.set_certificate_validator(trust.validate)
        server.allow_remote_admin(False)
        space = await Space.build(server, self.robot_model)
        await server.start()
        self.port, self.url = port, f"opc.tcp://{_url_host(s.host)}:{port}"
        log.info("opcua_server_started", url=self.url, security="Basic256Sha256 SignAndEncrypt"
                 + (" + none, anonymous (simulated cell)" if self.insecure else ""))
        self._ready.set()
        try:
            while not self._stop.is_set():
                await self._pump(space)
                try:
                    await asyncio.wait_for(self._stop.wait(), s.poll_s)
                except asyncio.TimeoutError:
                    pass
            await self._pump(space)                 # what came before the stop
        finally:
            await server.stop()
            log.info("opcua_server_stopped", url=self.url)

    async def _pump(self, space: Space) -> None:
        """Take every queued message; show the last status and each new result."""
        msgs = self.sub.drain()
        if self.sub.dropped != self.dropped:
            log.warning("opcua_fell_behind", dropped=self.sub.dropped - self.dropped)
            self.dropped = self.sub.dropped
        if not msgs:
            return
        status, results = self._fold.take(msgs)
        if status is not None:
            await space.show_status(status)
        for r in results:
            await space.result_ready(r)
            self.results += 1


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def _free_port(host: str) -> int:
    """A port free on ``host`` now (port 0 asked for: tests); asyncua must know its port
    before it listens, as the port is in the endpoint URLs it hands out."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]
