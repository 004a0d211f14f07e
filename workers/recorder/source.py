"""The recorder's queue through pika's asyncio adapter, on the recorder's event loop.

aio-pika, with aiormq, pamqp, yarl, multidict and importlib.metadata, cost the recording process
about 5 MB of its memory; pika (which the process loads anyway, for the dead-letter keys) does
the same job here in a page of code: consume with a prefetch, ack or nack what the recorder
settles, and consume again after the broker restarts, as aio-pika's robust connection did.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from datetime import datetime, timezone
from typing import Any, TypeVar

import pika
import pika.exceptions
from pika.adapters.asyncio_connection import AsyncioConnection
from pika.channel import Channel
from pika.spec import Basic, BasicProperties

from fleetbus.broker.retry import Backoff, Stopped, async_retrying
from fleetbus.publishers.errors import CONNECTION_FAILED
from fleetbus.publishers.tls import pika_parameter_list

log = logging.getLogger("fleetbus.recorder")

T = TypeVar("T")
RECONNECT_BACKOFF = Backoff(initial=0.5, maximum=10.0, jitter=0.25)


class ConnectionLost(ConnectionError):
    """The channel a message came on is gone: it cannot be settled; the broker delivers it again."""


def amqp_time(timestamp: int | None) -> datetime | None:
    """An AMQP ``timestamp`` (seconds in UTC) as a time. Some clients send milliseconds: read as
    such when seconds would be past datetime's range (as the worker's client, pamqp, does); None
    when neither reads, so that one message's property never stops the recording."""
    if timestamp is None:
        return None
    for seconds in (timestamp, timestamp / 1000):
        try:
            return datetime.fromtimestamp(seconds, timezone.utc)
        except (ValueError, OverflowError, OSError):
            continue
    return None


class Delivery:
    """One delivered message, read as the recorder reads aio-pika's (``exchange``, ``user_id``,
    ``headers``…) and settled on the channel it came on."""

    def __init__(
        self, channel: Channel, method: Basic.Deliver, properties: BasicProperties, body: bytes
    ) -> None:
        self._channel = channel
        self._tag: int = method.delivery_tag
        self.exchange: str = method.exchange
        self.routing_key: str = method.routing_key
        self.redelivered: bool = method.redelivered
        self.body = body
        self.processed = False
        p = properties
        self.user_id: str | None = p.user_id
        self.headers: dict[str, Any] = p.headers or {}
        self.message_id: str | None = p.message_id
        self.content_type: str | None = p.content_type
        self.content_encoding: str | None = p.content_encoding
        self.delivery_mode: int | None = p.delivery_mode
        self.priority: int | None = p.priority
        self.correlation_id: str | None = p.correlation_id
        self.reply_to: str | None = p.reply_to
        self.expiration: str | None = p.expiration
        # AMQP timestamps are seconds in UTC; aio-pika gave them as times, which capture reads
        self.timestamp = amqp_time(p.timestamp)
        self.type: str | None = p.type
        self.app_id: str | None = p.app_id

    async def ack(self, multiple: bool = False) -> None:
        self._settle(lambda: self._channel.basic_ack(self._tag, multiple))

    async def nack(self, requeue: bool = True) -> None:
        self._settle(lambda: self._channel.basic_nack(self._tag, requeue=requeue))

    def _settle(self, settle: Callable[[], None]) -> None:
        if not self._channel.is_open:
            raise ConnectionLost(f"the channel of delivery {self._tag} is closed")
        settle()
        self.processed = True


class RecorderQueue:
    """Consumes one queue into ``deliver`` until :meth:`close`, connecting again whenever the
    connection is lost (the messages in hand then cannot be settled: the broker redelivers them)."""

    def __init__(self, url: str, queue: str, prefetch: int, name: str) -> None:
        # every address of a cluster's URL: each new connection after a failed or lost one goes
        # to the next address
        self._parameters = pika_parameter_list(url, client_properties={"connection_name": name})
        self._address = 0
        self._queue = queue
        self._prefetch = prefetch
        self._connection: AsyncioConnection | None = None
        self._channel: Channel | None = None
        self._consumer_tag: str | None = None
        self._deliver: Callable[[Delivery], None] | None = None
        self._closing = asyncio.Event()
        self._lost = asyncio.Event()
        self._keeper: asyncio.Task[None] | None = None
        self._keeping = asyncio.Event()
        self._closed_by: BaseException | None = None

    async def open(self) -> None:
        """Connect and open a channel (raises when the broker does not answer)."""
        await self._connect()

    async def consume(self, deliver: Callable[[Delivery], None]) -> None:
        """Deliver every message to ``deliver``, now and after each reconnection."""
        self._deliver = deliver
        await self._start_consuming()
        self._keeper = asyncio.create_task(self._keep_connected())
        self._keeping.set()

    async def kept(self) -> None:
        """Return when the connection is no longer kept: closed, or given up on (then raises what
        ended it, so that the recorder ends and its parent starts it again, never half-alive)."""
        await self._keeping.wait()
        assert self._keeper is not None
        await asyncio.shield(self._keeper)

    async def cancel(self) -> None:
        """Take no more messages (those in hand can still be settled)."""
        channel, tag, self._consumer_tag = self._channel, self._consumer_tag, None
        self._deliver = None  # and none again after a reconnection
        if channel is not None and channel.is_open and tag is not None:
            done = asyncio.get_running_loop().create_future()
            channel.basic_cancel(tag, callback=lambda _: done.done() or done.set_result(None))
            await asyncio.wait({done}, timeout=5.0)

    async def close(self) -> None:
        self._closing.set()
        if self._keeper is not None:
            await self._keeper
        connection = self._connection
        if connection is not None and connection.is_open:
            connection.close()
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._lost.wait(), 5.0)

    async def _connect(self) -> None:
        loop = asyncio.get_running_loop()
        opened: asyncio.Future[AsyncioConnection] = loop.create_future()

        def on_open(connection: Any) -> None:
            opened.done() or opened.set_result(connection)

        def on_open_error(_: Any, error: BaseException | str) -> None:
            self._next_address()
            if not opened.done():
                opened.set_exception(
                    error if isinstance(error, BaseException) else pika.exceptions.AMQPConnectionError(error)
                )

        def on_close(closed: Any, error: BaseException) -> None:
            if closed is not self._connection:
                return  # an earlier connection, closing late: the current one is not lost
            self._closed_by = error
            if not self._closing.is_set():
                log.warning("broker connection closed: %r", error)
                self._next_address()
            self._lost.set()

        parameters = self._parameters[self._address]
        AsyncioConnection(parameters, on_open, on_open_error, on_close, custom_ioloop=loop)
        self._lost.clear()
        self._connection = connection = await opened
        channel_open: asyncio.Future[Channel] = loop.create_future()
        connection.channel(on_open_callback=lambda channel: channel_open.set_result(channel))
        self._channel = channel = await self._unless_lost(channel_open)
        channel.add_on_close_callback(self._on_channel_closed)
        qos: asyncio.Future[None] = loop.create_future()
        channel.basic_qos(prefetch_count=self._prefetch, callback=lambda _: qos.set_result(None))
        await self._unless_lost(qos)

    def _next_address(self) -> None:
        self._address = (self._address + 1) % len(self._parameters)

    async def _unless_lost(self, step: asyncio.Future[T]) -> T:
        """The step's result; :class:`ConnectionLost` when the channel or connection closes first
        (the broker refused: a queue that does not exist, a permission)."""
        lost = asyncio.ensure_future(self._lost.wait())
        await asyncio.wait({step, lost}, return_when=asyncio.FIRST_COMPLETED)
        lost.cancel()
        if not step.done():
            step.cancel()
            raise ConnectionLost(f"the broker closed the channel: {self._closed_by!r}")
        return step.result()

    def _on_channel_closed(self, closed: Channel, error: BaseException) -> None:
        if closed is not self._channel:
            return
        self._closed_by = error
        if not self._closing.is_set():
            log.warning("broker channel closed: %r", error)
        connection = self._connection
        if connection is not None and connection.is_open:
            connection.close()  # one channel per connection: a new connection brings a new channel
        self._lost.set()

    async def _start_consuming(self) -> None:
        assert self._channel is not None and self._deliver is not None
        deliver = self._deliver
        started: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._consumer_tag = self._channel.basic_consume(
            self._queue,
            lambda channel, method, properties, body: deliver(Delivery(channel, method, properties, body)),
            callback=lambda _: started.set_result(None),
        )
        await self._unless_lost(started)

    async def _keep_connected(self) -> None:
        while True:
            lost = asyncio.ensure_future(self._lost.wait())
            closing = asyncio.ensure_future(self._closing.wait())
            await asyncio.wait({lost, closing}, return_when=asyncio.FIRST_COMPLETED)
            lost.cancel()
            closing.cancel()
            if self._closing.is_set():
                return
            reconnect = async_retrying(
                "the broker",
                # CONNECTION_FAILED: a TLS handshake reset while the broker starts ends pika's
                # connection workflow with its own error, which is no AMQPError
                on=(pika.exceptions.AMQPError, ConnectionError, OSError, *CONNECTION_FAILED),
                backoff=RECONNECT_BACKOFF,
                stop=self._closing,
                logger=log,
            )
            try:
                await reconnect(self._reconnect)
            except Stopped:
                return

    async def _reconnect(self) -> None:
        await self._connect()
        if self._deliver is not None:
            await self._start_consuming()
        log.info("consuming %s again", self._queue)
