"""The certificate a broker presents to its clients, and how long it has left.

When the broker's server certificate expires, every robot's TLS connection fails at once; the
console shows its expiry ahead of time. The certificate is read the way a client meets it: a TLS
handshake with the address, verified as that client verifies it.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass
from datetime import datetime
from urllib.parse import urlsplit

from cryptography import x509

from fleetbus.broker.management import verification
from fleetbus.publishers.addresses import first_address
from fleetbus.publishers.tls import client_context, split_tls

DEFAULT_PORTS = {"amqps": 5671, "https": 443}


@dataclass(frozen=True)
class ServedCertificate:
    address: str
    """``host:port`` it was read from."""
    subject: str
    not_after: datetime

    def days_left(self, now: datetime) -> float:
        return (self.not_after - now).total_seconds() / 86400


def served_certificate(url: str, timeout: float = 5.0) -> ServedCertificate | None:
    """The certificate the server at ``url`` (``amqps://``, a cluster's first address, or an
    ``https://`` management API) presents, verified; None for a plain ``amqp://`` or ``http://``
    URL. Raises ``OSError`` (``ssl.SSLError`` among them) when it cannot be read or verified."""
    scheme = urlsplit(url).scheme
    if scheme not in DEFAULT_PORTS:
        return None
    if scheme == "amqps":
        plain, options = split_tls(first_address(url))
        assert options is not None
        context = client_context(options)
        parts = urlsplit(plain)
        name = options.server_name or parts.hostname
    else:
        context = verification(url)
        parts = urlsplit(url)
        name = parts.hostname
    host, port = parts.hostname or "localhost", parts.port or DEFAULT_PORTS[scheme]
    with (
        socket.create_connection((host, port), timeout=timeout) as raw,
        context.wrap_socket(raw, server_hostname=name) as tls,
    ):
        der = tls.getpeercert(binary_form=True)
    if der is None:
        raise OSError(f"{host}:{port} presented no certificate")
    cert = x509.load_der_x509_certificate(der)
    return ServedCertificate(f"{host}:{port}", cert.subject.rfc4514_string(), cert.not_valid_after_utc)
