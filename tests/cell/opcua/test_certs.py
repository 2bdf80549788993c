"""The server's own certificate: made on first start, kept after, remade for another name."""
import os
import stat

import pytest
from cryptography import x509

from cell.errors import ConfigError
from cell.opcua.certs import application_uri, ensure_server_certificate


def test_first_start_makes_a_certificate_for_the_application_uri_and_later_starts_keep_it(tmp_path):
    uri = application_uri("cell-7")
    first = ensure_server_certificate(tmp_path / "pki", uri, hostname="cellpc")
    assert first.made and first.trusted.is_dir() and list(first.trusted.iterdir()) == []
    cert = x509.load_der_x509_certificate(first.cert.read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.UniformResourceIdentifier) == [uri]
    assert san.get_values_for_type(x509.DNSName) == ["cellpc"]
    usage = cert.extensions.get_extension_for_class(x509.KeyUsage).value
    assert usage.digital_signature and usage.key_encipherment and usage.data_encipherment
    assert cert.public_key().key_size == 2048
    assert stat.S_IMODE(os.stat(first.key).st_mode) == 0o600
    again = ensure_server_certificate(tmp_path / "pki", uri)
    assert not again.made and again.cert.read_bytes() == first.cert.read_bytes()


def test_a_renamed_cell_gets_a_new_certificate_and_the_old_pair_is_kept(tmp_path):
    old = ensure_server_certificate(tmp_path, application_uri("a")).cert.read_bytes()
    new = ensure_server_certificate(tmp_path, application_uri("b"))
    assert new.made and new.cert.read_bytes() != old
    assert len(list(tmp_path.glob("server-cert.der.*.old"))) == 1 and len(list(tmp_path.glob("server-key.pem.*.old"))) == 1


def test_a_garbled_certificate_is_refused_by_name(tmp_path):
    ensure_server_certificate(tmp_path, application_uri("a"))
    (tmp_path / "server-cert.der").write_bytes(b"not a certificate")
    with pytest.raises(ConfigError, match="server-cert.der"):
        ensure_server_certificate(tmp_path, application_uri("a"))
