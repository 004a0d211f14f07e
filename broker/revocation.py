"""Withdrawing client certificates before they expire.

fleetbus's CA signs a certificate revocation list (CRL) and keeps it in the hashed folder layout
that RabbitMQ's TLS library reads (Erlang's ``ssl_crl_hash_dir``: ``crl/<issuer hash>.r0``). The
broker looks the list up at every TLS handshake that presents a client certificate, so a revoked
certificate is refused at its next connection, without restarting the broker.

The CA keeps a copy of every client certificate it signs in ``issued/`` (by serial number, as
``openssl ca`` does), so that an account's certificates can be found by its name and revoked.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import hashlib
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization

from fleetbus.broker.certificates import CertificateError, TlsFiles, load_ca, write_file
from fleetbus.private_files import private_file

_WHITESPACE = re.compile(r"[ \t\n\v\f\r]+")  # what OpenSSL takes for whitespace (ASCII only)


def _length(size: int) -> bytes:
    if size < 0x80:
        return bytes([size])
    raw = size.to_bytes((size.bit_length() + 7) // 8, "big")
    return bytes([0x80 | len(raw)]) + raw


def _tlv(tag: int, content: bytes) -> bytes:
    return bytes([tag]) + _length(len(content)) + content


def _oid(dotted: str) -> bytes:
    first, second, *rest = (int(part) for part in dotted.split("."))
    body = b""
    for arc in (40 * first + second, *rest):
        chunk = [arc & 0x7F]
        arc >>= 7
        while arc:
            chunk.append(0x80 | (arc & 0x7F))
            arc >>= 7
        body += bytes(reversed(chunk))
    return _tlv(0x06, body)


def _canonical_text(value: str) -> bytes:
    """OpenSSL's canonical form of a name's string: trimmed, inner whitespace runs made one space,
    ASCII letters lowered (other characters kept as they are)."""
    text = _WHITESPACE.sub(" ", value).strip(" ")
    return "".join(c.lower() if c.isascii() else c for c in text).encode()


def subject_hash(name: x509.Name) -> str:
    """The hash ``openssl x509 -hash`` prints for a certificate with this subject, which is also
    how Erlang's ``ssl_crl_hash_dir`` names the CRL of that issuer.

    Written here because no Python library exposes it: OpenSSL hashes (SHA-1, first four bytes,
    little-endian) the DER of each relative distinguished name, one after the other, with every
    string value in canonical form and encoded as a UTF8String."""
    canonical = b""
    for rdn in name.rdns:
        entries = []
        for attribute in rdn:
            if not isinstance(attribute.value, str):
                raise CertificateError(f"a name with a binary attribute ({attribute.oid.dotted_string})")
            value = _tlv(0x0C, _canonical_text(attribute.value))
            entries.append(_tlv(0x30, _oid(attribute.oid.dotted_string) + value))
        canonical += _tlv(0x31, b"".join(sorted(entries)))  # DER orders the members of a SET
    digest = hashlib.sha1(canonical).digest()  # OpenSSL's choice of hash; not a security use
    return f"{int.from_bytes(digest[:4], 'little'):08x}"


def crl_file(files: TlsFiles, ca: x509.Certificate | None = None) -> Path:
    """Where the broker looks for the CRL of the CA in ``files`` (``ca``, when already read; the
    CA certificate must exist)."""
    if ca is None:
        try:
            ca = x509.load_pem_x509_certificate(files.ca.read_bytes())
        except (OSError, ValueError) as error:
            raise CertificateError(f"cannot read the CA {files.ca}: {error}") from error
    return files.crl_dir / f"{subject_hash(ca.subject)}.r0"


@dataclass(frozen=True)
class RevocationList:
    path: Path
    revoked: dict[int, datetime.datetime]
    """Serial number -> when it was revoked."""
    next_update: datetime.datetime | None
    number: int


def read_crl(files: TlsFiles) -> RevocationList | None:
    """The CA's CRL as the broker reads it; None when there is none."""
    path = crl_file(files)
    try:
        crl = x509.load_pem_x509_crl(path.read_bytes())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as error:
        raise CertificateError(f"cannot read the revocation list {path}: {error}") from error
    try:
        number = crl.extensions.get_extension_for_class(x509.CRLNumber).value.crl_number
    except x509.ExtensionNotFound:
        number = 0
    revoked = {entry.serial_number: entry.revocation_date_utc for entry in crl}
    return RevocationList(path, revoked, crl.next_update_utc, number)


@contextlib.contextmanager
def _locked(files: TlsFiles) -> Iterator[None]:
    """One writer of the CRL at a time (two revocations at once must not lose one)."""
    with open(private_file(files.crl_dir / ".lock"), "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _sign(files: TlsFiles, revoked: dict[int, datetime.datetime], number: int) -> None:
    if not files.ca_key.exists():
        raise CertificateError(
            f"the revocation list is signed with the CA's key {files.ca_key}, which is missing"
        )
    ca, ca_key = load_ca(files)
    now = datetime.datetime.now(datetime.timezone.utc)
    builder = (
        x509.CertificateRevocationListBuilder()
        .issuer_name(ca.subject)
        .last_update(now - datetime.timedelta(minutes=5))
        # valid as long as the CA: a list past its next update makes the broker refuse every
        # certificate login, so it must not lapse while nobody revokes anything
        .next_update(ca.not_valid_after_utc)
        .add_extension(x509.CRLNumber(number), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
    )
    for serial, at in sorted(revoked.items()):
        builder = builder.add_revoked_certificate(
            x509.RevokedCertificateBuilder().serial_number(serial).revocation_date(at).build()
        )
    crl = builder.sign(ca_key, hashes.SHA256())
    write_file(crl_file(files, ca), crl.public_bytes(serialization.Encoding.PEM), 0o600)


def ensure_crl(files: TlsFiles) -> bool:
    """Make an empty CRL for fleetbus's CA unless there is one; whether one is there now (there
    cannot be without the CA's key, unless the operator put their own CA's list there)."""
    if not files.ca.exists():
        return False
    with _locked(files):
        if crl_file(files).exists():
            return True
        if not files.ca_key.exists():
            return False
        _sign(files, {}, 1)
        return True


def revoke(files: TlsFiles, serials: Iterable[int]) -> list[int]:
    """Add ``serials`` to the CA's CRL; the ones not revoked before, in order.

    The list does not grow for ever: a certificate past its expiry is refused by the broker
    anyway, so it is neither added nor kept (the CA's copy in ``issued/`` says when it expires)."""
    with _locked(files):
        current = read_crl(files)
        now = datetime.datetime.now(datetime.timezone.utc)
        expired = {cert.serial for cert in issued_certificates(files) if cert.not_after < now}
        before = current.revoked if current else {}
        kept = {serial: at for serial, at in before.items() if serial not in expired}
        new = sorted(serial for serial in set(serials) if serial not in kept and serial not in expired)
        if new or current is None or len(kept) < len(before):
            kept.update((serial, now) for serial in new)
            _sign(files, kept, (current.number if current else 0) + 1)
        return new


@dataclass(frozen=True)
class IssuedCertificate:
    name: str
    serial: int
    not_after: datetime.datetime
    path: Path


def issued_certificates(files: TlsFiles, name: str | None = None) -> list[IssuedCertificate]:
    """The client certificates the CA signed (for the account ``name``, or all), oldest first."""
    found = []
    for path in sorted(files.issued.glob("*.pem")) if files.issued.is_dir() else []:
        try:
            cert = x509.load_pem_x509_certificate(path.read_bytes())
        except ValueError as error:
            raise CertificateError(f"cannot read the issued certificate {path}: {error}") from error
        [common_name] = cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME) or [None]
        cn = str(common_name.value) if common_name is not None else ""
        if name is None or cn == name:
            found.append(IssuedCertificate(cn, cert.serial_number, cert.not_valid_after_utc, path))
    return sorted(found, key=lambda issued: issued.path.stat().st_mtime)


def cannot_revoke(files: TlsFiles, name: str) -> str | None:
    """Why the certificates the CA signed for ``name`` cannot be revoked here (there are some, and
    the CA's key is missing); None when they can, or there are none. An account is made or removed
    only when they can: a later account of that name must not inherit them."""
    if issued_certificates(files, name) and not files.ca_key.exists():
        return f"{name} has certificates in {files.issued}; revoking them needs the CA's key {files.ca_key}"
    return None


def revoke_certificates_of(files: TlsFiles, name: str) -> list[int]:
    """Revoke every certificate the CA signed for the account ``name``; the serial numbers revoked
    now. Nothing to revoke (or no CA here) changes nothing."""
    serials = [issued.serial for issued in issued_certificates(files, name)]
    if not serials:
        return []
    return revoke(files, serials)


def revoked_summary(name: str, serials: list[int]) -> str:
    """What :func:`revoke_certificates_of` did, in words, for the operator's console or log."""
    listed = ", ".join(f"{serial:x}" for serial in serials)
    return f"revoked {len(serials)} earlier certificate(s) of {name} (serial {listed})"
