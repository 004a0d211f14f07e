"""A broker URL made into connection parameters: the one place TLS is decided, for the robot
client (pika) and, through :mod:`fleetbus.broker.tls`, for the server (aio-pika) and its shovels.

An ``amqps://`` URL carries its TLS settings as RabbitMQ's own URI query parameters, so the very
same URL also works for the broker's shovel and federation links::

    amqps://user:pw@host:5671/vhost?cacertfile=/etc/fleetbus/ca.pem&server_name_indication=host

- ``cacertfile``: the CA that signed the broker's certificate (without it: the system's trust store);
- ``certfile``, ``keyfile``: a client certificate, when the broker asks for one;
- ``verify``: ``verify_peer`` (the default) checks the certificate and the host name;
  ``verify_none`` checks nothing, and is the only way to turn verification off;
- ``server_name_indication``: the name checked against the certificate (and sent as SNI) when it
  is not the URL's host, e.g. a broker reached by its IP address;
- ``auth_mechanism``: ``external`` logs in with the client certificate (``certfile``, ``keyfile``)
  instead of a password: the broker takes the account's name from the certificate
  (RabbitMQ's EXTERNAL mechanism, ``rabbitmq_auth_mechanism_ssl``); ``plain``, the default, sends
  the URL's user and password.

``amqp://`` URLs are passed through unchanged. Base install: the standard library and pika only.
"""

from __future__ import annotations

import ssl
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

import pika
import pika.credentials

from fleetbus.publishers.addresses import address_count, first_address, map_addresses, split_addresses

TLS_PARAMETERS = ("cacertfile", "certfile", "keyfile", "verify", "server_name_indication")
AUTH_PARAMETER = "auth_mechanism"
EXTERNAL = "external"
PLAIN = "plain"
VERIFY_PEER = "verify_peer"
VERIFY_NONE = "verify_none"


class TlsSettingError(ValueError):
    """A broker URL's TLS parameters are wrong (unknown ``verify``, a file that is missing...)."""


@dataclass(frozen=True)
class TlsOptions:
    """What an ``amqps://`` URL says about TLS (RabbitMQ's URI query parameters)."""

    cacertfile: str | None = None
    certfile: str | None = None
    keyfile: str | None = None
    verify: bool = True
    server_name: str | None = None
    """The name the certificate must carry: ``server_name_indication``, else the URL's host."""
    external: bool = False
    """``auth_mechanism=external``: log in with the client certificate, not a password."""


def split_tls(url: str) -> tuple[str, TlsOptions | None]:
    """The URL without its TLS parameters, and those parameters (None for ``amqp://``)."""
    parts = urlsplit(url)
    query = parse_qsl(parts.query, keep_blank_values=True)
    ours = (*TLS_PARAMETERS, AUTH_PARAMETER)
    given = {key: value for key, value in query if key in ours}
    rest = [(key, value) for key, value in query if key not in ours]
    plain = urlunsplit((parts.scheme, parts.netloc, parts.path, urlencode(rest), parts.fragment))
    mechanism = given.pop(AUTH_PARAMETER, PLAIN).lower()
    if mechanism not in (PLAIN, EXTERNAL):
        raise TlsSettingError(f"auth_mechanism={mechanism!r} in a broker URL: use {PLAIN} or {EXTERNAL}")
    if parts.scheme != "amqps":
        if mechanism == EXTERNAL:
            raise TlsSettingError("auth_mechanism=external logs in with a client certificate: amqps:// only")
        if given:
            raise TlsSettingError(
                f"{', '.join(sorted(given))} in a broker URL apply to amqps:// only, not {parts.scheme}://"
            )
        return plain, None
    if mechanism == EXTERNAL and not given.get("certfile"):
        raise TlsSettingError(
            "auth_mechanism=external needs the client certificate: add certfile= and keyfile="
        )
    verify = given.get("verify", VERIFY_PEER)
    if verify not in (VERIFY_PEER, VERIFY_NONE):
        raise TlsSettingError(f"verify={verify!r} in a broker URL: use {VERIFY_PEER} or {VERIFY_NONE}")
    options = TlsOptions(
        cacertfile=given.get("cacertfile") or None,
        certfile=given.get("certfile") or None,
        keyfile=given.get("keyfile") or None,
        verify=verify == VERIFY_PEER,
        server_name=given.get("server_name_indication") or parts.hostname,
        external=mechanism == EXTERNAL,
    )
    return plain, options


def with_client_certificate(url: str, certfile: str | Path, keyfile: str | Path) -> str:
    """``url`` (``amqps://``, every address of a cluster's) logging in with a client certificate:
    its user without a password, ``certfile``, ``keyfile`` and ``auth_mechanism=external``."""
    if address_count(url) > 1:
        return map_addresses(url, lambda single: with_client_certificate(single, certfile, keyfile))
    parts = urlsplit(url)
    if parts.scheme != "amqps":
        raise TlsSettingError(
            f"a client certificate needs the broker's amqps:// address, not {parts.scheme}://"
        )
    netloc = parts.netloc
    if "@" in netloc:
        login, _, host = netloc.rpartition("@")
        netloc = f"{login.partition(':')[0]}@{host}"
    ours = ("certfile", "keyfile", AUTH_PARAMETER)
    query = [(key, value) for key, value in parse_qsl(parts.query, keep_blank_values=True) if key not in ours]
    query += [("certfile", str(certfile)), ("keyfile", str(keyfile)), (AUTH_PARAMETER, EXTERNAL)]
    return urlunsplit((parts.scheme, netloc, parts.path or "/", urlencode(query, safe="/"), ""))


class _NamedContext(ssl.SSLContext):
    """A client context that checks (and sends as SNI) a given name instead of the host dialled:
    asyncio always passes the URL's host, and RabbitMQ's ``server_name_indication`` overrides it."""

    server_name: str | None = None

    def wrap_socket(self, sock: Any, *args: Any, **kwargs: Any) -> ssl.SSLSocket:
        kwargs["server_hostname"] = self.server_name or kwargs.get("server_hostname")
        return super().wrap_socket(sock, *args, **kwargs)

    def wrap_bio(self, incoming: Any, outgoing: Any, *args: Any, **kwargs: Any) -> ssl.SSLObject:
        kwargs["server_hostname"] = self.server_name or kwargs.get("server_hostname")
        return super().wrap_bio(incoming, outgoing, *args, **kwargs)


def client_context(options: TlsOptions) -> ssl.SSLContext:
    """The client's TLS context: the URL's CA (else the system's), host name checked, unless
    ``verify_none`` turned both off."""
    context = _NamedContext(ssl.PROTOCOL_TLS_CLIENT)
    context.server_name = options.server_name
    try:
        if options.cacertfile:
            context.load_verify_locations(cafile=options.cacertfile)
        else:
            context.load_default_certs(ssl.Purpose.SERVER_AUTH)
        if options.certfile:
            context.load_cert_chain(options.certfile, options.keyfile)
    except (OSError, ssl.SSLError) as error:
        raise TlsSettingError(f"cannot load the TLS files a broker URL names: {error}") from error
    if not options.verify:
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
    return context


def pika_parameters(url: str) -> pika.URLParameters:
    """pika's parameters for ``url``'s first address; for ``amqps://``, with its verified TLS
    context. A cluster's URL: :func:`pika_parameter_list`."""
    plain, options = split_tls(first_address(url))
    if options is not None and options.external:
        plain = _without_login(plain)  # the certificate names the account; pika wants a password
    if options is None:
        return pika.URLParameters(plain)
    # Given amqps://, pika first builds a context from the system's trust store (about 20 ms of
    # CPU, at every connection) that ours replaces: give it amqp:// and the port amqps:// means.
    parts = urlsplit(plain)
    netloc = parts.netloc if parts.port else f"{parts.netloc}:{pika.ConnectionParameters.DEFAULT_SSL_PORT}"
    parameters = pika.URLParameters(urlunsplit(("amqp", netloc, parts.path, parts.query, parts.fragment)))
    parameters.ssl_options = pika.SSLOptions(client_context(options), server_hostname=options.server_name)
    if options.external:
        parameters.credentials = pika.credentials.ExternalCredentials()
    return parameters


def pika_parameter_list(url: str, **attributes: Any) -> list[pika.URLParameters]:
    """pika's parameters for each address of ``url`` (:mod:`fleetbus.publishers.addresses`), in order,
    each with ``attributes`` set (``socket_timeout=5``...). ``pika.BlockingConnection`` takes the
    list and tries each address in turn: a node that is down means a connection to the next."""
    parameters = [pika_parameters(single) for single in split_addresses(url)]
    for each in parameters:
        for name, value in attributes.items():
            setattr(each, name, value)
    return parameters


def blocking_connection(url: str, **attributes: Any) -> pika.BlockingConnection:
    """A pika connection to the first of ``url``'s addresses that answers."""
    return pika.BlockingConnection(pika_parameter_list(url, **attributes))


def _without_login(url: str) -> str:
    parts = urlsplit(url)
    return urlunsplit(
        (parts.scheme, parts.netloc.rpartition("@")[2], parts.path, parts.query, parts.fragment)
    )


