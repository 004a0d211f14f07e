"""`fleetbus certs make | show | client`: a CA kept across runs, a server certificate it signs for
the names clients use, client certificates for accounts, keys readable by their owner only."""

from __future__ import annotations

import os
import re
import ssl
import stat
import subprocess
import sys
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

from fleetbus.broker.certificates import ClientFiles, TlsFiles, _leaf, describe, load_ca
from fleetbus.broker.revocation import issued_certificates


def certs(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fleetbus", "certs", *args],
        env={**os.environ, "COLUMNS": "200", **(env or {})},
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_make_keeps_the_ca_and_signs_a_server_certificate_for_the_names_given(tmp_path: Path) -> None:
    files = TlsFiles.in_folder(tmp_path / "tls")
    made = certs("make", "--dir", str(tmp_path / "tls"), "--host", "hub.lan", "--host", "10.1.2.3")
    assert made.returncode == 0, made.stderr
    assert "made the CA" in made.stdout
    for key in (files.ca_key, files.key):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600
    assert describe(files.cert).names == ["localhost", "127.0.0.1", "hub.lan", "10.1.2.3"]
    ca = files.ca.read_bytes()

    again = certs("make", "--dir", str(tmp_path / "tls"), "--host", "hub.lan")
    assert again.returncode == 0, again.stderr
    assert "kept the CA" in again.stdout
    assert files.ca.read_bytes() == ca  # robots that trust it keep trusting it
    assert describe(files.cert).names == ["localhost", "127.0.0.1", "hub.lan"]
    # the new server certificate is signed by that CA, and its key is the one beside it
    server_cert = x509.load_pem_x509_certificate(files.cert.read_bytes())
    server_cert.verify_directly_issued_by(x509.load_pem_x509_certificate(ca))
    ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(files.cert, files.key)  # raises on a mismatch

    shown = certs("show", "--dir", str(tmp_path / "tls"))
    assert shown.returncode == 0, shown.stderr
    assert "names: localhost, 127.0.0.1, hub.lan" in shown.stdout
    assert "issuer: CN=fleetbus CA" in shown.stdout


def test_show_reads_the_settings_and_names_what_is_missing(tmp_path: Path) -> None:
    shown = certs("show", env={"FLEETBUS_TLS_DIR": str(tmp_path / "nothing")})
    assert shown.returncode == 0, shown.stderr
    assert f"{tmp_path / 'nothing' / 'ca.pem'} is missing" in shown.stdout


def test_make_refuses_to_overwrite_the_operators_own_files(tmp_path: Path) -> None:
    own = tmp_path / "own.pem"
    refused = certs("make", env={"FLEETBUS_TLS_CERT": str(own), "FLEETBUS_DATA_DIR": str(tmp_path)})
    assert refused.returncode == 1
    assert "FLEETBUS_TLS_CA, _CERT or _KEY" in refused.stderr and not own.exists()


def test_client_signs_a_certificate_whose_common_name_is_the_account(tmp_path: Path) -> None:
    files = TlsFiles.in_folder(tmp_path / "tls")
    assert certs("make", "--dir", str(tmp_path / "tls")).returncode == 0
    made = certs("client", "scout-1", "--dir", str(tmp_path / "tls"))
    assert made.returncode == 0, made.stderr
    client = ClientFiles.in_folder(files.clients, "scout-1")
    assert stat.S_IMODE(client.key.stat().st_mode) == 0o600
    assert "auth_mechanism=external" in made.stdout
    assert client.key.read_text() not in made.stdout
    cert = x509.load_pem_x509_certificate(client.cert.read_bytes())
    cert.verify_directly_issued_by(x509.load_pem_x509_certificate(files.ca.read_bytes()))
    assert cert.subject.rfc4514_string() == "CN=scout-1"
    usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert list(usage) == [ExtendedKeyUsageOID.CLIENT_AUTH]  # not a server certificate
    ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT).load_cert_chain(client.cert, client.key)


def test_client_needs_the_cas_key_and_a_valid_name(tmp_path: Path) -> None:
    files = TlsFiles.in_folder(tmp_path / "tls")
    assert certs("make", "--dir", str(tmp_path / "tls")).returncode == 0
    files.ca_key.unlink()  # an operator's own CA: fleetbus cannot sign with it
    refused = certs("client", "scout-1", "--dir", str(tmp_path / "tls"))
    assert refused.returncode == 1 and "needs the CA's key" in refused.stderr
    wrong = certs("client", "no/such name", "--dir", str(tmp_path / "tls"))
    assert wrong.returncode == 1


def test_revoke_lists_and_revokes_an_accounts_certificates(tmp_path: Path) -> None:
    folder = str(tmp_path / "tls")
    files = TlsFiles.in_folder(tmp_path / "tls")
    assert certs("make", "--dir", folder).returncode == 0
    for name in ("scout-1", "scout-1", "rover-2"):
        signed = certs("client", name, "--dir", folder)
        assert signed.returncode == 0, signed.stderr
    shown = certs("show", "--dir", folder)
    assert shown.returncode == 0, shown.stderr
    assert "0 revoked" in shown.stdout and shown.stdout.count("valid") >= 3

    bad = certs("revoke", "scout-1", "--serial", "not-hex", "--dir", folder)
    assert bad.returncode == 1 and "not a hexadecimal serial number" in bad.stderr
    [rover] = issued_certificates(files, "rover-2")
    assert f"{rover.serial:x}" in shown.stdout
    wrong = certs("revoke", "scout-1", "--serial", f"{rover.serial:x}", "--dir", folder)
    assert wrong.returncode == 1 and "no certificate" in wrong.stderr, "another account's serial"

    revoked = certs("revoke", "scout-1", "--dir", folder)
    assert revoked.returncode == 0, revoked.stderr
    assert "revoked 2 certificate(s) of scout-1" in revoked.stdout
    again = certs("revoke", "scout-1", "--dir", folder)
    assert again.returncode == 0 and "nothing to revoke" in again.stdout
    after = certs("show", "--dir", folder)
    assert "2 revoked" in after.stdout
    rows = [line for line in after.stdout.splitlines() if "scout-1" in line or "rover-2" in line]
    assert [("revoked" in row) for row in rows if "scout-1" in row] == [True, True], after.stdout
    assert [("valid" in row) for row in rows if "rover-2" in row] == [True], after.stdout


def test_show_marks_a_client_certificate_near_its_expiry(tmp_path: Path) -> None:
    folder = tmp_path / "tls"
    files = TlsFiles.in_folder(folder)
    assert certs("make", "--dir", str(folder)).returncode == 0
    ca, ca_key = load_ca(files)
    cert, _ = _leaf(ca, ca_key, "old-scout", 10, ExtendedKeyUsageOID.CLIENT_AUTH, [])  # signed long ago
    files.issued.mkdir()
    (files.issued / f"{cert.serial_number:x}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    shown = certs("show", "--dir", str(folder))
    assert shown.returncode == 0, shown.stderr
    [row] = [line for line in shown.stdout.splitlines() if "old-scout" in line]
    assert re.search(r"expires in (9|10) days", row), row
