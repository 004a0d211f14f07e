"""A broker URL that names several nodes of one cluster: the one place it is split and joined.

A cluster's URL lists its nodes' ``host:port`` pairs, comma-separated, between the login and the
virtual host; everything else (scheme, login, virtual host, query) is the nodes' common part::

    amqp://user:pw@10.0.0.1:5672,10.0.0.2:5672,10.0.0.3:5672/fleet

:func:`split_addresses` makes it one ordinary URL per node, in the order given, which is the
order clients try them in (:mod:`fleetbus.broker.tls` turns them into connection parameters). A
URL with one address is returned as it is.
"""

from __future__ import annotations

from collections.abc import Callable
from urllib.parse import urlsplit, urlunsplit


def _hosts(netloc: str) -> tuple[str, list[str]]:
    """The login part (with its ``@``, or empty) and the ``host[:port]`` items of ``netloc``."""
    login, at, hosts = netloc.rpartition("@")
    return (login + at), [item.strip() for item in hosts.split(",") if item.strip()]


def split_addresses(url: str) -> list[str]:
    """One URL per address of ``url`` (at least one), login, virtual host and query kept."""
    parts = urlsplit(url)
    login, hosts = _hosts(parts.netloc)
    if len(hosts) <= 1:
        return [url]
    return [
        urlunsplit((parts.scheme, login + host, parts.path, parts.query, parts.fragment)) for host in hosts
    ]


def first_address(url: str) -> str:
    """The URL of ``url``'s first node: what code that talks to one node at a time starts with."""
    return split_addresses(url)[0]


def join_addresses(urls: list[str]) -> str:
    """The inverse of :func:`split_addresses`: URLs alike but for their ``host:port`` made one."""
    if not urls:
        raise ValueError("no broker addresses to join")
    parts = [urlsplit(url) for url in urls]
    first = parts[0]
    login, _ = _hosts(first.netloc)
    hosts = [_hosts(part.netloc)[1][0] for part in parts]
    return urlunsplit((first.scheme, login + ",".join(hosts), first.path, first.query, first.fragment))


def map_addresses(url: str, change: Callable[[str], str]) -> str:
    """``url`` with ``change`` (a function of one single-address URL) applied to each address."""
    return join_addresses([change(single) for single in split_addresses(url)])


def address_count(url: str) -> int:
    return len(split_addresses(url))
