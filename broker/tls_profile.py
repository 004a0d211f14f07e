"""The TLS profile every listener fleetbus configures serves: Mozilla's "intermediate" configuration
(server-side TLS guidelines 6.0), in the one place it is written down.

- TLS 1.2 and 1.3 only (SSL 3, TLS 1.0 and 1.1 are refused);
- forward-secret AEAD suites only: the three TLS 1.3 suites, and on TLS 1.2 ECDHE key exchange
  with AES-GCM or ChaCha20-Poly1305 (no static RSA or ECDH key exchange, no CBC, no CCM);
- the client's order of preference: every suite offered is strong, and a robot without AES
  instructions in its CPU can ask for ChaCha20-Poly1305.

It is rendered into each form a listener takes it in: ``rabbitmq.conf`` keys (``ssl_options.*`` for
AMQPS, ``management.ssl.*`` for the management API's HTTPS), the terms of an ``ssl_options`` list
in ``advanced.config`` (the private node's AMQPS listener, whose revocation list can be given only
there), and a Python :class:`ssl.SSLContext` (``fleetbus api --tls``). The key names and values are
ones RabbitMQ 3.10 (Erlang 25) and 4.0 (Erlang 27) both read. The copies in
``docs/operations/tls.md`` and ``compose.yaml`` are checked against these functions by a test.
"""

from __future__ import annotations

import ssl

#: Erlang's names, newest first.
VERSIONS = ("tlsv1.3", "tlsv1.2")
#: The TLS 1.3 suites (IANA names, which OpenSSL and Erlang use too).
TLS13_SUITES = ("TLS_AES_128_GCM_SHA256", "TLS_AES_256_GCM_SHA384", "TLS_CHACHA20_POLY1305_SHA256")
#: The TLS 1.2 suites, in OpenSSL's names (which Erlang reads too).
TLS12_SUITES = (
    "ECDHE-ECDSA-AES128-GCM-SHA256",
    "ECDHE-RSA-AES128-GCM-SHA256",
    "ECDHE-ECDSA-AES256-GCM-SHA384",
    "ECDHE-RSA-AES256-GCM-SHA384",
    "ECDHE-ECDSA-CHACHA20-POLY1305",
    "ECDHE-RSA-CHACHA20-POLY1305",
)
#: Whether the server's order of the suites wins over the client's (Mozilla: the client's).
HONOR_CIPHER_ORDER = False

#: The prefixes of a RabbitMQ listener's TLS keys in ``rabbitmq.conf``.
AMQPS = "ssl_options"
MANAGEMENT = "management.ssl"


def ciphers() -> tuple[str, ...]:
    """Every suite, TLS 1.3's first: Erlang takes one list for both versions, and a TLS 1.3
    handshake fails when the list holds none of its suites."""
    return TLS13_SUITES + TLS12_SUITES


def _erlang_boolean(value: bool) -> str:
    return "true" if value else "false"


def rabbitmq_conf(prefix: str = AMQPS) -> str:
    """The profile as ``rabbitmq.conf`` lines for the listener whose keys start with ``prefix``
    (:data:`AMQPS` or :data:`MANAGEMENT`)."""
    lines = [f"{prefix}.versions.{index} = {version}" for index, version in enumerate(VERSIONS, 1)]
    lines += [f"{prefix}.ciphers.{index} = {suite}" for index, suite in enumerate(ciphers(), 1)]
    lines.append(f"{prefix}.honor_cipher_order = {_erlang_boolean(HONOR_CIPHER_ORDER)}")
    return "\n".join(lines) + "\n"


def erlang_terms() -> list[str]:
    """The profile as terms of an ``ssl_options`` list in ``advanced.config``."""
    versions = ", ".join(f"'{version}'" for version in VERSIONS)
    suites = ", ".join(f'"{suite}"' for suite in ciphers())
    return [
        f"{{versions, [{versions}]}}",
        f"{{ciphers, [{suites}]}}",
        f"{{honor_cipher_order, {_erlang_boolean(HONOR_CIPHER_ORDER)}}}",
    ]


def apply(context: ssl.SSLContext) -> ssl.SSLContext:
    """Restrict a server's ``context`` to the profile; returns it.

    Python's ``ssl`` sets no TLS 1.3 suites: OpenSSL's defaults are the profile's three, which is
    checked here, so a system OpenSSL configured otherwise fails loudly instead of serving more."""
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.set_ciphers(":".join(TLS12_SUITES))
    if HONOR_CIPHER_ORDER:
        context.options |= ssl.OP_CIPHER_SERVER_PREFERENCE
    else:
        context.options &= ~ssl.OP_CIPHER_SERVER_PREFERENCE
    extra = {
        suite["name"]
        for suite in context.get_ciphers()
        if suite["protocol"] == "TLSv1.3" and suite["name"] not in TLS13_SUITES
    }
    if extra:
        raise ssl.SSLError(f"OpenSSL enables TLS 1.3 suites outside the profile: {sorted(extra)}")
    return context
