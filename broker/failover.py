"""aio-pika's robust connection over several broker addresses: each reconnection tries the next.

``aio_pika.connect_robust`` takes one URL and reconnects to it for ever, which is an outage when
that node is the one that died. :class:`FailoverConnection` is aio-pika's own
:class:`~aio_pika.RobustConnection` (channels, queues, consumers restored after each
reconnection) whose address moves on by one at every connection attempt after the first: the
first reconnection after a lost node goes to the next node, and a run of failed attempts walks
the list round and round, ``reconnect_interval`` apart.

The hook is the attribute ``transport``, which ``RobustConnection`` sets to None as each
connection attempt begins (aio-pika 9.x); ``tests/test_broker_addresses.py`` pins that behaviour,
and ``tests/cluster/`` the worker's failover when a node dies.
"""

from __future__ import annotations

import asyncio
import logging
import ssl
from collections.abc import Sequence
from typing import Any

from aio_pika import RobustConnection
from aio_pika.connection import make_url
from yarl import URL

log = logging.getLogger("fleetbus.broker")


class FailoverConnection(RobustConnection):
    """A robust connection over ``addresses`` (each ``(url, ssl_context or None)``), tried in turn."""

    def __init__(
        self,
        url: URL,
        loop: asyncio.AbstractEventLoop | None = None,
        *,
        addresses: Sequence[tuple[URL, ssl.SSLContext | None]] = (),
        **kwargs: Any,
    ) -> None:
        self._addresses = list(addresses) or [(URL(url), kwargs.get("ssl_context"))]
        self._index = 0
        self._attempts = 0
        self._transport: Any = None
        super().__init__(url, loop, **kwargs)

    @property  # type: ignore[override]
    def transport(self) -> Any:
        return self._transport

    @transport.setter
    def transport(self, value: Any) -> None:
        if value is None:  # a connection attempt begins (or the connection closes)
            self._next_attempt()
        self._transport = value

    def _next_attempt(self) -> None:
        """A connection attempt begins (or the connection closes): every attempt after the first
        goes to the next address."""
        if not hasattr(self, "kwargs"):  # Connection.__init__ sets transport before kwargs
            return
        self._attempts += 1
        if self._attempts > 1:
            self._index = (self._index + 1) % len(self._addresses)
        url, context = self._addresses[self._index]
        self.url = url
        self.kwargs["context"] = context
        if self._attempts > 1:
            log.info(
                "broker connection: trying %s (address %d of %d)", self, self._index + 1, len(self._addresses)
            )

    @property
    def address_index(self) -> int:
        """Which of the addresses the connection uses (or tries) now, from 0."""
        return self._index


async def connect_failover(
    addresses: Sequence[tuple[str, dict[str, Any]]], **kwargs: Any
) -> FailoverConnection:
    """A :class:`FailoverConnection` over ``addresses`` (each a URL and its TLS keyword arguments,
    :func:`fleetbus.broker.tls.aio_pika_arguments`), connected to the first that answers. Its list
    starts with that address (a robust connection that failed its first attempt is closed for good,
    so each address gets a connection of its own until one answers)."""
    urls = [(make_url(url), tls.get("ssl_context")) for url, tls in addresses]
    for start in range(len(urls)):
        rotated = urls[start:] + urls[:start]
        url, context = rotated[0]
        connection = FailoverConnection(url, addresses=rotated, ssl_context=context, **kwargs)
        try:
            await connection.connect(timeout=kwargs.get("timeout"))
        except Exception:  # this address does not answer (or refuses): the next one, unless none is left
            await connection.close()
            if start == len(urls) - 1:
                raise
            continue
        return connection
    raise AssertionError("unreachable: at least one address")
