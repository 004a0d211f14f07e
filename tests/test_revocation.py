"""Revoking client certificates: the CA's revocation list, named as the broker looks it up, and a
revoked certificate refused by the real broker at its next connection while others still log in."""

from __future__ import annotations

import datetime
import shutil
import subprocess
import uuid
from pathlib import Path

import pika.exceptions
import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from fleetbus.broker.accounts import can_login
from fleetbus.broker.certificates import (
    ClientFiles,
    TlsFiles,
    issue_client_certificate,
    load_ca,
    make_certificates,
)
from fleetbus.broker.revocation import (
    crl_file,
    ensure_crl,
    issued_certificates,
    read_crl,
    revoke,
    revoke_certificates_of,
    subject_hash,
)
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.errors import BrokerUnavailable
from fleetbus_dev.local_node import LocalNode
from tests.factories import hazard
from tests.run_tls import BROKER_TLS, run_tls_files
from tests.support import Bus, wait_for
from tests.test_client_certificates import certificate_robot

NAMES = [
    x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "fleetbus CA (base-station-7)")]),
    x509.Name(
        [
            x509.NameAttribute(NameOID.COUNTRY_NAME, "DE"),
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "  Rescue\t Robotics   GmbH "),
            x509.NameAttribute(NameOID.COMMON_NAME, "Field CA Ümlaut"),
        ]
    ),
    x509.Name.from_rfc4514_string("CN=Ops+OU=Field Team,O=ACME"),  # a multi-valued RDN
]


def _self_signed(name: x509.Name, path: Path) -> None:
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(now + datetime.timedelta(days=1))
        .sign(key, hashes.SHA256())
    )
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


@pytest.mark.parametrize("name", NAMES, ids=["fleetbus", "several", "multi-valued"])
def test_the_crl_is_named_by_the_hash_openssl_and_the_broker_use(name: x509.Name, tmp_path: Path) -> None:
    openssl = shutil.which("openssl")
    assert openssl is not None, "Debian's openssl (a dependency of rabbitmq-server) is the reference"
    pem = tmp_path / "ca.pem"
    _self_signed(name, pem)
    command = [openssl, "x509", "-hash", "-noout", "-in", str(pem)]
    printed = subprocess.run(command, capture_output=True, text=True)
    assert printed.returncode == 0, printed.stderr
    assert subject_hash(name) == printed.stdout.strip()


def test_revoking_adds_to_the_list_and_keeps_what_was_revoked(tmp_path: Path) -> None:
    files = TlsFiles.in_folder(tmp_path / "tls")
    make_certificates(files)
    assert ensure_crl(files)
    empty = read_crl(files)
    assert empty is not None and empty.revoked == {} and empty.path == crl_file(files)
    for name in ("scout", "scout", "rover"):
        issue_client_certificate(files, ClientFiles.in_folder(tmp_path / "out", name), name)
    scouts = {cert.serial for cert in issued_certificates(files, "scout")}
    assert len(scouts) == 2

    assert set(revoke_certificates_of(files, "scout")) == scouts
    assert revoke_certificates_of(files, "scout") == [], "revoked once"
    [rover] = issued_certificates(files, "rover")
    assert revoke_certificates_of(files, "rover") == [rover.serial]
    after = read_crl(files)
    assert after is not None and set(after.revoked) == scouts | {rover.serial}
    assert after.number > empty.number
    assert after.next_update is not None and after.next_update > datetime.datetime.now(datetime.timezone.utc)
    assert revoke_certificates_of(files, "nobody") == []


REVOKED_ALERT = "Certificate Revoked"
"""What the broker logs when it refuses a revoked certificate (the client may see only the
connection closing: with TLS 1.3 it sends its certificate after the handshake looks done)."""


def refused_as_revoked(url: str, log_file: Path) -> None:
    """The broker refuses ``url``'s certificate because it is revoked."""
    before = log_file.read_text().count(REVOKED_ALERT)
    with pytest.raises(pika.exceptions.AMQPConnectionError):
        can_login(url)
    wait_for(
        lambda: log_file.read_text().count(REVOKED_ALERT) > before,
        what="the broker's alert for a revoked certificate in its log",
    )


@pytest.mark.skipif(not BROKER_TLS, reason="certificate logins need the broker's TLS listener")
def test_a_revoked_certificate_is_refused_at_its_next_connection_others_still_log_in(
    killable_bus: Bus, killable_node: LocalNode, tmp_path: Path
) -> None:
    bus = killable_bus
    # names of this test only: every test of the run signs with the run's CA
    revoked, kept = (f"rv-{uuid.uuid4().hex[:8]}", f"rk-{uuid.uuid4().hex[:8]}")
    revoked_url, kept_url = certificate_robot(bus, revoked), certificate_robot(bus, kept)
    assert can_login(revoked_url) and can_login(kept_url)

    with RobotClient(revoked_url, state_dir=bus.settings.robots_dir, connect_timeout=20) as robot:
        robot.connect()
        assert revoke_certificates_of(run_tls_files(), revoked)
        # no restart: the broker reads the list at the next handshake
        log_file = killable_node.status().log_file
        assert log_file is not None
        refused_as_revoked(revoked_url, log_file)
        assert can_login(kept_url), "another robot's certificate still logs in"
        # a robot sees the handshake end, often without the reason: it is told what that means
        with RobotClient(revoked_url, state_dir=tmp_path / "again") as again:
            again.start()
            wait_for(lambda: again.last_error, 30, "the refused handshake")
            with pytest.raises(BrokerUnavailable, match="client certificate"):
                again.connect(timeout=0)
        # the connection opened before stays open (documented: remove the account to cut it off)
        robot.publish("hazard", hazard())
        assert robot.flush(timeout=20), "the broker confirmed it on the connection opened before"


def test_a_certificate_past_its_expiry_leaves_the_list(tmp_path: Path) -> None:
    """The broker refuses an expired certificate anyway: the list keeps only what it must."""
    files = TlsFiles.in_folder(tmp_path / "tls")
    make_certificates(files)
    issue_client_certificate(files, ClientFiles.in_folder(tmp_path / "out", "scout"), "scout")
    [valid] = issued_certificates(files, "scout")
    ca, ca_key = load_ca(files)
    now = datetime.datetime.now(datetime.timezone.utc)
    old = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "scout")]))
        .issuer_name(ca.subject)
        .public_key(ec.generate_private_key(ec.SECP256R1()).public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=900))
        .not_valid_after(now - datetime.timedelta(days=75))
        .sign(ca_key, hashes.SHA256())
    )
    assert revoke(files, [old.serial_number]) == [old.serial_number], "its expiry unknown here yet"
    (files.issued / f"{old.serial_number:x}.pem").write_bytes(old.public_bytes(serialization.Encoding.PEM))

    assert revoke_certificates_of(files, "scout") == [valid.serial], "the expired one is not added again"
    crl = read_crl(files)
    assert crl is not None and set(crl.revoked) == {valid.serial}, "and no longer kept"
