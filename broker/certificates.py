"""A certificate authority and server certificates for the broker, the management API and the HTTP
API (``fleetbus certs``), or the operator's own files.

:func:`make_certificates` keeps a CA that exists (so robots that already trust it keep trusting it)
and signs a server certificate for ``localhost``, ``127.0.0.1`` and the names given. Keys are
written with mode 0600; the CA certificate is public (robots need it to verify the broker).
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import socket
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from fleetbus.private_files import private_dir
from fleetbus.settings import Settings

CA_DAYS = 3650
# Mozilla's "intermediate" profile: a leaf certificate lives at most 366 days (`certs make` signs a
# new server certificate with the same CA; the console warns ahead of its expiry)
SERVER_DAYS = 366
CLIENT_DAYS = 366
DEFAULT_HOSTS = ("localhost", "127.0.0.1")


class CertificateError(RuntimeError):
    """Certificates could not be made or read; the message says which file and why."""


@dataclass(frozen=True)
class TlsFiles:
    """Where the CA and the server's certificate and key are (made here, or the operator's own)."""

    ca: Path
    cert: Path
    key: Path
    ca_key: Path
    """The CA's private key: only ``fleetbus certs make`` needs it (to sign server certificates)."""

    @classmethod
    def in_folder(cls, folder: Path) -> TlsFiles:
        return cls(folder / "ca.pem", folder / "server.pem", folder / "server.key", folder / "ca.key")

    @classmethod
    def for_settings(cls, settings: Settings) -> TlsFiles:
        """``FLEETBUS_TLS_CA`` / ``_CERT`` / ``_KEY`` when set, else the files in ``FLEETBUS_TLS_DIR``."""
        return cls(settings.ca_file, settings.cert_file, settings.key_file, settings.tls_folder / "ca.key")

    @property
    def issued(self) -> Path:
        """A copy of every client certificate the CA signed, by serial number (to revoke them)."""
        return self.ca_key.parent / "issued"

    @property
    def crl_dir(self) -> Path:
        """The CA's revocation list, named for the broker to find (:mod:`fleetbus.broker.revocation`)."""
        return self.ca_key.parent / "crl"

    @property
    def clients(self) -> Path:
        """Where the client certificates the CA signs (``fleetbus certs client``) are written."""
        return self.ca_key.parent / "clients"

    def server_ready(self) -> bool:
        return self.ca.exists() and self.cert.exists() and self.key.exists()


def write_file(path: Path, data: bytes, mode: int) -> None:
    private_dir(path.parent)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)
    os.chmod(tmp, mode)
    os.replace(tmp, path)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


def _make_ca(files: TlsFiles) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"fleetbus CA ({socket.gethostname()})")])
    public = key.public_key()
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(public)
        .serial_number(x509.random_serial_number())
        .not_valid_before(_now() - datetime.timedelta(minutes=5))
        .not_valid_after(_now() + datetime.timedelta(days=CA_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public), critical=False)
        .sign(key, hashes.SHA256())
    )
    write_file(files.ca_key, _key_pem(key), 0o600)
    write_file(files.ca, cert.public_bytes(serialization.Encoding.PEM), 0o600)
    return cert, key


def load_ca(files: TlsFiles) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    try:
        cert = x509.load_pem_x509_certificate(files.ca.read_bytes())
        key = serialization.load_pem_private_key(files.ca_key.read_bytes(), password=None)
    except (OSError, ValueError) as error:
        raise CertificateError(f"cannot read the CA in {files.ca} and {files.ca_key}: {error}") from error
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise CertificateError(f"{files.ca_key} is not a key fleetbus made (an EC key)")
    return cert, key


def _alt_name(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def _leaf(
    ca: x509.Certificate,
    ca_key: ec.EllipticCurvePrivateKey,
    common_name: str,
    days: int,
    usage: x509.ObjectIdentifier,
    names: list[x509.GeneralName],
) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A certificate for ``common_name`` signed by the CA, for ``usage`` (server or client) only."""
    key = ec.generate_private_key(ec.SECP256R1())
    public = key.public_key()
    builder = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)]))
        .issuer_name(ca.subject)
        .public_key(public)
        .serial_number(x509.random_serial_number())
        .not_valid_before(_now() - datetime.timedelta(minutes=5))
        .not_valid_after(_now() + datetime.timedelta(days=days))
    )
    if names:
        builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
    cert = (
        builder.add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=True,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
        .sign(ca_key, hashes.SHA256())
    )
    return cert, key


def _sign_server(
    files: TlsFiles, ca: x509.Certificate, ca_key: ec.EllipticCurvePrivateKey, hosts: list[str]
) -> None:
    names = [_alt_name(host) for host in hosts]
    cert, key = _leaf(ca, ca_key, hosts[0], SERVER_DAYS, ExtendedKeyUsageOID.SERVER_AUTH, names)
    write_file(files.key, _key_pem(key), 0o600)
    write_file(files.cert, cert.public_bytes(serialization.Encoding.PEM), 0o600)


def make_certificates(files: TlsFiles, hosts: Iterable[str] = ()) -> bool:
    """A CA (kept when it exists) and a server certificate signed by it, for ``localhost``,
    ``127.0.0.1`` and ``hosts``. Returns whether the CA was made now."""
    names = list(dict.fromkeys([*DEFAULT_HOSTS, *hosts]))
    made_ca = not files.ca.exists()
    if made_ca:
        if files.ca_key.exists():
            raise CertificateError(f"{files.ca_key} exists without {files.ca}: move it away first")
        ca, ca_key = _make_ca(files)
    else:
        ca, ca_key = load_ca(files)
    _sign_server(files, ca, ca_key, names)
    return made_ca


@dataclass(frozen=True)
class ClientFiles:
    """A robot's (or any account's) client certificate and its key."""

    cert: Path
    key: Path

    @classmethod
    def in_folder(cls, folder: Path, name: str) -> ClientFiles:
        return cls(folder / f"{name}.pem", folder / f"{name}.key")


def issue_client_certificate(files: TlsFiles, client: ClientFiles, name: str) -> None:
    """A client certificate whose common name is the account ``name``, signed by the CA in
    ``files`` (it must exist, with its key); the key is written with mode 0600. A broker that
    takes the login from the common name (EXTERNAL) logs whoever holds it in as ``name``."""
    if not files.ca_key.exists():
        raise CertificateError(
            f"signing a client certificate needs the CA's key {files.ca_key} (`fleetbus certs make`); "
            "with a CA of your own, sign the robot's certificate (CN=<its name>) with it instead"
        )
    ca, ca_key = load_ca(files)
    cert, key = _leaf(ca, ca_key, name, CLIENT_DAYS, ExtendedKeyUsageOID.CLIENT_AUTH, [])
    pem = cert.public_bytes(serialization.Encoding.PEM)
    write_file(files.issued / f"{cert.serial_number:x}.pem", pem, 0o600)  # first: it can be revoked
    write_file(client.key, _key_pem(key), 0o600)
    write_file(client.cert, pem, 0o600)


@dataclass(frozen=True)
class CertificateInfo:
    path: Path
    subject: str
    issuer: str
    names: list[str]
    not_after: datetime.datetime


def describe(path: Path) -> CertificateInfo:
    """Subject, issuer, subjectAltNames and expiry of the certificate in ``path``."""
    try:
        cert = x509.load_pem_x509_certificate(path.read_bytes())
    except (OSError, ValueError) as error:
        raise CertificateError(f"cannot read the certificate {path}: {error}") from error
    try:
        alt = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        names = [str(name.value) for name in alt]
    except x509.ExtensionNotFound:
        names = []
    return CertificateInfo(
        path, cert.subject.rfc4514_string(), cert.issuer.rfc4514_string(), names, cert.not_valid_after_utc
    )
