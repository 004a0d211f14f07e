"""The server's side of a broker URL: aio-pika connections (one address, or a cluster's in turn)
and the URIs RabbitMQ's shovels take, from the TLS settings :mod:`fleetbus.publishers.tls` reads."""

from __future__ import annotations

import ipaddress
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

from fleetbus.publishers.addresses import split_addresses
from fleetbus.publishers.tls import (
    AUTH_PARAMETER,
    EXTERNAL,
    VERIFY_NONE,
    VERIFY_PEER,
    TlsSettingError,
    client_context,
    split_tls,
)

if TYPE_CHECKING:
    from aio_pika.abc import AbstractConnection, AbstractRobustConnection


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


def _is_ip(host: str | None) -> bool:
    try:
        ipaddress.ip_address(host or "")
    except ValueError:
        return False
    return True
