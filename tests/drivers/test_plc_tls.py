"""Modbus/TCP Security (issue 12, part 1): mutual TLS on its own listener, the role taken from
the client certificate's role extension, rights per role, refusals answered 01 and kept for
the audit trail; bad certificates named at start-up. Real TLS clients (pymodbus's
``ModbusTlsClient`` and ``ssl`` sockets) on loopback; certificates are made in the test."""
from __future__ import annotations

import datetime as dt
import socket
import ssl

import pytest
from pymodbus.client import ModbusTcpClient, ModbusTlsClient

from cell.clock import ManualClock
from cell.errors import ConfigError
from drivers.plc import PlcConfig, TlsConfig
from drivers.plc.register_map import PLC_MAP
from drivers.plc.server import PlcLink
from drivers.plc.tls import check_client_certificate, role_of, roles_table, server_context
from tests.drivers.tlscerts import Authority, client_context

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")

HB, CMD = PLC_MAP["plc_heartbeat"].address, PLC_MAP["command_word"].address
RECIPE, PART = PLC_MAP["recipe_select"].address, PLC_MAP["part_id"].address
EXECUTE, RESET = 1, 2


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pki")
    ca = Authority(folder)
    return {"ca": ca, "server": ca.issue("controller", server=True),
            **{r: ca.issue(f"plc-{r}", role=r.capitalize()) for r in ("operator", "maintenance", "monitor")},
            "norole": ca.issue("plc-norole"), "stranger": ca.issue("plc-stranger", role="Visitor"),
            "other_ca": Authority(folder, "Other CA")}


@pytest.fixture
def link(pki):
    cfg = TlsConfig(enabled=True, port=0, cert=str(pki["server"].cert), key=str(pki["server"].key),
                    ca=str(pki["ca"].path))
    link = PlcLink(clock=ManualClock(100.0), heartbeat_timeout_s=1.0, tls=cfg.listener())
    link.start()
    yield link
    link.stop()


def _tls(link, pki, who: str) -> ModbusTlsClient:
    # a generous upper bound, not a deadline: these tests are about roles, and on a loaded
    # machine (the suite beside running cells) one answer took longer than 3 s
    c = ModbusTlsClient("127.0.0.1", port=link.tls_port, sslctx=client_context(pki["ca"], pki[who]),
                        timeout=30, retries=0)
    assert c.connect(), who
    return c


def _exc(rr) -> int | None:
    return rr.exception_code if rr.isError() else None


def test_an_operator_runs_cycles_but_cannot_select_recipes_or_reset(link, pki):
    c = _tls(link, pki, "operator")
    try:
        assert _exc(c.write_register(HB, 1)) is None                  # owns the link
        assert link.owner.endswith("(Operator)") and link.last_heartbeat_change == 100.0
        assert _exc(c.write_registers(PART, [0, 4242])) is None
        assert _exc(c.write_register(CMD, EXECUTE)) is None
        assert _exc(c.write_register(RECIPE, 7)) == 1 and link.read("recipe_select") == 0
        assert _exc(c.write_register(CMD, EXECUTE | RESET)) == 1 and link.read("command_word") == EXECUTE
        assert c.read_holding_registers(0, count=3).registers[0] == PLC_MAP.version
        assert [(w.name, w.value) for w in link.drain_writes()] == [("part_id", 4242), ("command_word", 1)]
        got = {(r.role, r.reason): r.count for r in link.take_refusals()}
        assert got == {("Operator", "role lacks right recipe"): 1, ("Operator", "role lacks right reset"): 1}
        assert link.take_refusals() == []                             # taken once
    finally:
        c.close()


def test_maintenance_also_selects_recipes_and_resets(link, pki):
    c = _tls(link, pki, "maintenance")
    try:
        assert _exc(c.write_register(HB, 1)) is None
        assert _exc(c.write_register(RECIPE, 7)) is None
        assert _exc(c.write_register(CMD, RESET)) is None
        assert [w.name for w in link.drain_writes()] == ["recipe_select", "command_word"]
    finally:
        c.close()


def test_a_monitor_reads_but_can_neither_write_nor_keep_the_link_alive(link, pki):
    c = _tls(link, pki, "monitor")
    try:
        assert c.read_holding_registers(0, count=1).registers == [PLC_MAP.version]
        assert _exc(c.write_register(HB, 1)) == 1
        assert link.last_heartbeat_change is None and link.owner is None
        assert _exc(c.write_register(CMD, EXECUTE)) == 1 and link.read("command_word") == 0
        reasons = {r.reason for r in link.take_refusals()}
        assert reasons == {"role lacks right any right (the role reads only)", "role lacks right run"}
    finally:
        c.close()


def test_the_heartbeat_is_owned_across_listeners_and_roles_decide_the_rest(pki):
    cfg = TlsConfig(enabled=True, port=0, cert=str(pki["server"].cert), key=str(pki["server"].key),
                    ca=str(pki["ca"].path))
    link = PlcLink(clock=ManualClock(0.0), heartbeat_timeout_s=1.0, tls=cfg.listener())
    link.start()
    plain = ModbusTcpClient("127.0.0.1", port=link.port, timeout=30, retries=0)   # as _tls
    secure = _tls(link, pki, "maintenance")
    try:
        assert plain.connect() and _exc(plain.write_register(HB, 1)) is None   # the plain PLC owns it
        assert _exc(secure.write_register(HB, 9)) == 1               # its heartbeat does not count
        assert link.read("plc_heartbeat") == 1 and link.owner.startswith("127.0.0.1:")
        assert _exc(secure.write_register(RECIPE, 3)) is None        # maintenance may select
        operator = _tls(link, pki, "operator")
        try:
            assert _exc(operator.write_register(RECIPE, 4)) == 1     # an operator may not
        finally:
            operator.close()
        assert link.read("recipe_select") == 3
    finally:
        plain.close()
        secure.close()
        link.stop()


def _handshake(link, ctx: ssl.SSLContext) -> bytes | Exception:
    """Open a TLS connection, send one FC3 read; the answer, or the error met."""
    raw = socket.create_connection(("127.0.0.1", link.tls_port), timeout=5)
    try:
        s = ctx.wrap_socket(raw)
        s.sendall(bytes.fromhex("000100000006010300000001"))
        return s.recv(64)
    except (OSError, ssl.SSLError) as exc:
        return exc
    finally:
        raw.close()


@pytest.mark.parametrize("who", ["norole", "stranger"])
def test_a_certificate_without_a_known_role_is_closed_at_connect(link, pki, who, capsys):
    got = _handshake(link, client_context(pki["ca"], pki[who]))
    assert got == b"" or isinstance(got, OSError), got            # closed, nothing answered
    assert link.owner is None
    err = capsys.readouterr()
    text = err.out + err.err
    assert "plc_tls_client_refused" in text
    assert ("no role extension" in text) if who == "norole" else ("'Visitor' is not in plc.tls.roles" in text)


def test_unknown_and_missing_client_certificates_fail_the_handshake(link, pki):
    other = pki["other_ca"].issue("plc-other", role="Maintenance")
    for ctx in (client_context(pki["ca"], other), client_context(pki["ca"], None)):
        got = _handshake(link, ctx)
        assert isinstance(got, OSError) or got == b"", got
    assert link.read("recipe_select") == 0 and link.owner is None


def test_a_request_sent_with_the_last_handshake_message_is_answered(link, pki):
    """A client may send its first request right behind its Finished; on a loaded server
    both come in one read, and asyncio hands the request on before the handshake's task
    resumes. It is answered once the role is taken, not dropped (the client would wait for
    its time-out). The client here sends both in one segment, as load makes them arrive."""
    ctx = client_context(pki["ca"], pki["operator"])
    incoming, outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
    tls = ctx.wrap_bio(incoming, outgoing)
    with socket.create_connection(("127.0.0.1", link.tls_port), timeout=10) as raw:
        while True:
            try:
                tls.do_handshake()
                break
            except ssl.SSLWantReadError:
                raw.sendall(outgoing.read())
                incoming.write(raw.recv(65536))
        tls.write(bytes.fromhex("000100000006010300000001"))         # FC3: map_version
        raw.sendall(outgoing.read())                                  # Finished + request at once
        answer = b""
        while len(answer) < 11:
            data = raw.recv(65536)
            assert data, "closed without an answer"
            incoming.write(data)
            try:
                answer += tls.read(64)
            except ssl.SSLWantReadError:
                pass
    assert answer == bytes.fromhex("000100000005010302") + PLC_MAP.version.to_bytes(2, "big")


def test_role_extension_is_read_from_der(pki):
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding
    der = x509.load_pem_x509_certificate(pki["operator"].cert.read_bytes()).public_bytes(Encoding.DER)
    assert role_of(der) == ("Operator", "CN=plc-operator")
    der = x509.load_pem_x509_certificate(pki["norole"].cert.read_bytes()).public_bytes(Encoding.DER)
    assert role_of(der) == (None, "CN=plc-norole")


# ------------------------------------------------------------------ bad input at start-up
def test_startup_names_the_field_of_a_bad_certificate_file(pki, tmp_path):
    s, ca = pki["server"], pki["ca"]
    old = pki["ca"].issue("controller-old", server=True, days=(-30, -1))
    notpem = tmp_path / "junk.pem"
    notpem.write_text("not a certificate\n")
    cases = [
        (dict(cert=old.cert, key=old.key, ca=ca.path), "plc.tls.cert", "expired on"),
        (dict(cert=s.cert, key=tmp_path / "none.key", ca=ca.path), "plc.tls.key", "no such file"),
        (dict(cert=s.cert, key=pki["operator"].key, ca=ca.path), "plc.tls.key", "does not fit"),
        (dict(cert=s.cert, key=s.key, ca=notpem), "plc.tls.ca", "is not a PEM certificate"),
        (dict(cert=tmp_path / "gone.pem", key=s.key, ca=ca.path), "plc.tls.cert", "cannot read"),
    ]
    for files, field, words in cases:
        with pytest.raises(ConfigError) as exc:
            server_context(**files)
        assert str(exc.value).startswith(field + ":") and words in str(exc.value), exc.value


def test_client_certificate_check_names_what_is_wrong(pki):
    roles = TlsConfig().roles
    ca = pki["ca"].path
    assert check_client_certificate(pki["operator"].cert, ca, roles) == ("Operator", frozenset({"run"}))
    with pytest.raises(ConfigError, match=r"client certificate: .* has no role extension \(OID 1.3.6.1.4.1.50316.802.1"):
        check_client_certificate(pki["norole"].cert, ca, roles)
    with pytest.raises(ConfigError, match=r"plc.tls.roles: the certificate's role 'Visitor' is not listed"):
        check_client_certificate(pki["stranger"].cert, ca, roles)
    other = pki["other_ca"].issue("plc-elsewhere", role="Operator")
    with pytest.raises(ConfigError, match="is not issued by a CA in plc.tls.ca"):
        check_client_certificate(other.cert, ca, roles)
    late = pki["ca"].issue("plc-late", role="Operator", days=(-10, -2))
    with pytest.raises(ConfigError, match="client certificate: .* expired on"):
        check_client_certificate(late.cert, ca, roles)
    lasting = pki["ca"].issue("plc-lasting", role="Operator", days=(-1, 800))
    future = dt.datetime.now(dt.timezone.utc) + dt.timedelta(days=365)     # the CA lives 30 days
    with pytest.raises(ConfigError, match="plc.tls.ca: .* expired on"):
        check_client_certificate(lasting.cert, ca, roles, now=future)


def test_tls_config_names_bad_rights_and_a_link_with_no_listener():
    with pytest.raises(ValueError, match="role 'operator': unknown right 'drive'"):
        TlsConfig(roles={"operator": ["drive"]})
    with pytest.raises(ValueError, match="plain_tcp is false and tls.enabled is false"):
        PlcConfig(plain_tcp=False)
    with pytest.raises(ConfigError, match=r"plc.tls.roles.x: unknown right 'y'"):
        roles_table({"x": ["y"]})


def test_relative_certificate_paths_are_taken_from_the_config_folder(tmp_path):
    from cell.config import CellConfig
    (tmp_path / "cell.yaml").write_text("plc:\n  tls:\n    cert: tls/c.pem\n    ca: /etc/ca.pem\n")
    tls = CellConfig.load(tmp_path / "cell.yaml").plc.tls
    assert tls.cert == str(tmp_path / "tls/c.pem") and tls.ca == "/etc/ca.pem"
    assert tls.key == str(tmp_path / "tls/controller.key")


def test_secure_only_link_listens_on_tls_alone(pki):
    cfg = TlsConfig(enabled=True, port=0, cert=str(pki["server"].cert), key=str(pki["server"].key),
                    ca=str(pki["ca"].path))
    link = PlcLink(clock=ManualClock(0.0), tls=cfg.listener(), plain=False)
    try:
        assert link.start() == link.tls_port and link.port is None
    finally:
        link.stop()


# ------------------------------------------------------------------ the commands
def _tls_config(tmp_path, pki, server=None):
    import shutil

    import yaml
    folder = tmp_path / "etc"
    (folder / "tls").mkdir(parents=True)
    server = server or pki["server"]
    shutil.copy(server.cert, folder / "tls/controller.pem")
    shutil.copy(server.key, folder / "tls/controller.key")
    shutil.copy(pki["ca"].path, folder / "tls/plc-ca.pem")
    path = folder / "cell.yaml"          # relative paths: from the config's folder, not the shell's
    path.write_text(yaml.safe_dump({"plc": {"tls": {"enabled": True, "port": 0}},
                                    "log": {"path": str(tmp_path / "cell.sqlite")}}))
    return path


def test_check_cert_prints_the_role_or_names_what_is_wrong(pki, tmp_path, capsys, monkeypatch):
    from cell.cli import main
    cfg = _tls_config(tmp_path, pki)
    monkeypatch.chdir(tmp_path)
    assert main(["plc", "check-cert", str(pki["maintenance"].cert), "--config", str(cfg)]) == 0
    out = capsys.readouterr().out
    assert "role 'Maintenance', rights: calibrate, recipe, reset, run" in out
    assert main(["plc", "check-cert", str(pki["norole"].cert), "--config", str(cfg)]) == 2
    assert "has no role extension (OID 1.3.6.1.4.1.50316.802.1" in capsys.readouterr().err


def test_serve_with_an_expired_controller_certificate_stops_naming_the_field(pki, tmp_path):
    import subprocess
    import sys

    from tests.system.conftest import REPO
    old = pki["ca"].issue("controller-expired", server=True, days=(-60, -3))
    cfg = _tls_config(tmp_path, pki, server=old)
    out = subprocess.run([sys.executable, "-m", "cell.cli", "serve", "--sim", "--config", str(cfg),
                          "--port", "0", "--seconds", "0"], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2, out.stderr
    assert "plc.tls.cert: certificate 'CN=controller-expired'" in out.stderr and "expired on" in out.stderr
    assert "Traceback" not in out.stderr
