"""A broker URL made into connection parameters for pika and aio-pika: the one place TLS is decided.

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

import ipaddress
import ssl
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

import pika
import pika.credentials

from fleetbus.broker.addresses import address_count, first_address, map_addresses, split_addresses

if TYPE_CHECKING:
    from aio_pika.abc import AbstractConnection, AbstractRobustConnection

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
    """pika's parameters for each address of ``url`` (:mod:`fleetbus.broker.addresses`), in order,
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


def aio_pika_arguments(url: str) -> tuple[str, dict[str, Any]]:
    """The URL and keyword arguments for ``aio_pika.connect`` / ``connect_robust``."""
    plain, options = split_tls(url)
    if options is None:
        return plain, {}
    if options.external:  # aiormq's own name for the mechanism
        parts = urlsplit(plain)
        query = urlencode([*parse_qsl(parts.query, keep_blank_values=True), ("auth", EXTERNAL)])
        plain = urlunsplit((parts.scheme, parts.netloc, parts.path, query, parts.fragment))
    return plain, {"ssl_context": client_context(options)}


async def aio_connect(url: str, **kwargs: Any) -> AbstractConnection:
    """``aio_pika.connect`` with the URL's TLS settings, to the first of its addresses that answers
    (each tried in turn; the last one's error is raised when none does)."""
    import aio_pika

    addresses = split_addresses(url)
    for index, single in enumerate(addresses):
        plain, tls = aio_pika_arguments(single)
        try:
            return await aio_pika.connect(plain, **tls, **kwargs)
        except (ConnectionError, OSError, aio_pika.exceptions.AMQPConnectionError):
            if index == len(addresses) - 1:
                raise
    raise AssertionError("unreachable: split_addresses returns at least one URL")


async def aio_connect_robust(url: str, **kwargs: Any) -> AbstractRobustConnection:
    """``aio_pika.connect_robust`` with the URL's TLS settings. With several addresses, the first
    that answers; and every reconnection after a lost connection tries the next address, then the
    others in turn (:class:`fleetbus.broker.failover.FailoverConnection`)."""
    import aio_pika

    addresses = split_addresses(url)
    if len(addresses) == 1:
        plain, tls = aio_pika_arguments(url)
        return await aio_pika.connect_robust(plain, **tls, **kwargs)
    from fleetbus.broker.failover import connect_failover

    return await connect_failover([aio_pika_arguments(single) for single in addresses], **kwargs)


def shovel_uri(url: str) -> str:
    """``url`` as RabbitMQ's shovel and federation links take it, verifying as fleetbus's clients
    do. The Erlang client of RabbitMQ 3.x checks nothing unless told (its ``verify`` defaults to
    ``verify_none``), so an ``amqps://`` URL gets ``verify=verify_peer`` and the name to check
    (``server_name_indication``) written out. It needs ``cacertfile``, and a DNS name to check: the
    Erlang client matches DNS names only, so a URL whose host is an IP address must name one
    (``server_name_indication=localhost`` for the private node). The default virtual host is
    written ``%2F``: to the Erlang client, ``amqp://host/`` means the virtual host "" instead."""
    plain, options = split_tls(url)
    parts = urlsplit(plain)
    path = "/%2F" if parts.path in ("", "/") else parts.path
    if options is None:
        return urlunsplit((parts.scheme, parts.netloc, path, parts.query, ""))
    name = options.server_name
    if options.verify:
        if not options.cacertfile:
            raise TlsSettingError(
                "a shovel's amqps:// URL needs cacertfile= (the Erlang client has no default trust store)"
            )
        if name == parts.hostname and _is_ip(name):
            raise TlsSettingError(
                f"a shovel checks the broker's certificate for a DNS name, not the address {name}: add "
                "server_name_indication=<a name in its certificate> to the URL"
            )
    query = parse_qsl(parts.query, keep_blank_values=True)
    tls = [
        ("cacertfile", options.cacertfile),
        ("certfile", options.certfile),
        ("keyfile", options.keyfile),
        ("verify", VERIFY_PEER if options.verify else VERIFY_NONE),
        ("server_name_indication", name if options.verify else None),
        (AUTH_PARAMETER, EXTERNAL if options.external else None),
    ]
    query += [(key, value) for key, value in tls if value]
    return urlunsplit((parts.scheme, parts.netloc, path, urlencode(query, safe="/"), ""))


def shovel_uris(url: str) -> list[str]:
    """``url`` as a shovel's ``src-uri`` or ``dest-uri``: one URI per node of a cluster (the
    shovel tries them in turn; the Erlang client parses one address a URI, so a comma-joined list
    is refused), each as :func:`shovel_uri` writes it."""
    return [shovel_uri(single) for single in split_addresses(url)]


def _without_login(url: str) -> str:
    parts = urlsplit(url)
    return urlunsplit(
        (parts.scheme, parts.netloc.rpartition("@")[2], parts.path, parts.query, parts.fragment)
    )


def _is_ip(host: str | None) -> bool:
    try:
        ipaddress.ip_address(host or "")
    except ValueError:
        return False
    return True
