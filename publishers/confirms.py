"""Pipelined publisher confirms on a pika ``BlockingChannel``.

``BlockingChannel.confirm_delivery()`` makes every ``basic_publish`` wait for its own confirm,
one round trip per message (about 1,400 msg/s here against 13,000 pipelined). This class turns
confirms on at the underlying channel instead, so a batch is written at once and its acks (often
one ``multiple`` ack for many messages) are collected afterwards.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import pika
import pika.exceptions
from pika.adapters.blocking_connection import BlockingChannel, BlockingConnection
from pika.spec import Basic

from fleetbus.publishers.errors import BrokerUnavailable, PublisherError, PublishRefused, PublishTimeout

_SLICE = 0.05


def _nothing() -> None:
    pass


class WaitStopped(PublisherError):
    """A wait for the broker's answers was given up because its caller is stopping: what it waited
    for is in doubt, as after a lost connection."""


@dataclass(frozen=True)
class Outgoing:
    exchange: str
    routing_key: str
    body: bytes
    properties: pika.BasicProperties


@dataclass(frozen=True)
class Outcome:
    nacked: set[str]
    """Message ids the broker nacked: not queued, worth sending again."""
    returned: dict[str, str]
    """Message ids the broker could not route (mandatory), with its reply: sending again will not help."""


@dataclass(frozen=True)
class Window:
    """Messages written together, awaiting their confirms: delivery tag -> message id."""

    tags: dict[int, str]


#: Seconds a service process (the worker, the command line) waits for the broker's confirm of what
#: it publishes before it gives up on it: a quorum queue without a leader, or a node cut off from
#: its cluster's majority, never confirms, and must not hold a thread for ever.
SERVICE_CONFIRM_TIMEOUT_S = 30.0
#: How many timeouts a wait goes on while the broker answers, only slowly.
SLOW_BROKER_PERIODS = 6


class PipelinedConfirms:
    def __init__(
        self,
        connection: BlockingConnection,
        channel: BlockingChannel,
        timeout: float,
        stopping: Callable[[], bool] = lambda: False,
    ) -> None:
        """``stopping``: looked at while waiting (every 50 ms); once true, a wait raises
        :class:`WaitStopped` (a slow broker may otherwise hold it ``SLOW_BROKER_PERIODS`` timeouts)."""
        self._connection = connection
        self._stopping = stopping
        self._channel = channel
        self._impl = channel._impl  # the async channel under the blocking facade
        self._next_tag = 1
        self._unconfirmed: set[int] = set()
        self._nacked: set[int] = set()
        self._returned: dict[str, str] = {}
        self._returns = 0
        """basic.return frames since the last :meth:`take_returns`."""
        self._closed_reason: str | None = None
        self._refused = False
        """The broker itself closed the channel (on a message it refused), rather than the
        connection going away under it."""
        selected: list[object] = []
        self._impl.add_on_close_callback(self._on_close)
        self._impl.add_on_return_callback(self._on_return)
        self._impl.confirm_delivery(
            ack_nack_callback=self._on_confirm, callback=lambda frame: (selected.append(frame), self._wake())
        )
        self._pump_until(lambda: bool(selected), timeout, "confirm.select")

    @property
    def closed(self) -> bool:
        return self._closed_reason is not None

    def _on_confirm(self, frame: pika.frame.Method) -> None:
        method = frame.method
        tags = (
            {t for t in self._unconfirmed if t <= method.delivery_tag}
            if method.multiple
            else {method.delivery_tag}
        )
        self._unconfirmed -= tags
        if isinstance(method, Basic.Nack):
            self._nacked |= tags
        self._wake()

    def _wake(self) -> None:
        """End the current ``process_data_events`` wait now.

        Confirms arrive on the channel underneath the blocking facade, which pika does not count
        as an event worth returning for: without this, each wait would last its whole time slice
        (a confirmed publish took 53 ms here instead of about 2, and so did turning confirms on:
        every robot's connect and reconnect).
        """
        self._connection.call_later(0, _nothing)

    def _on_return(
        self, _channel: object, method: Basic.Return, properties: pika.BasicProperties, _body: bytes
    ) -> None:
        self._returned[properties.message_id or ""] = f"{method.reply_code} {method.reply_text}"
        self._returns += 1
        self._wake()

    def _on_close(self, _channel: object, reason: Exception) -> None:
        # pika closes the channels of a connection that is lost or closed with the connection's
        # error as their reason: only a Channel.Close from the broker is an answer to a message
        self._refused = isinstance(reason, pika.exceptions.ChannelClosedByBroker)
        self._closed_reason = str(reason)
        if self._connection.is_open:
            self._wake()

    def _closed_error(self) -> Exception:
        if self._refused:
            return PublishRefused(f"the broker closed the channel: {self._closed_reason}")
        return BrokerUnavailable(f"the channel closed with its connection: {self._closed_reason}")

    def _pump_until(self, done: Callable[[], bool], timeout: float, what: str) -> None:
        """Pump pika until ``done``. ``timeout`` is how long the broker may stay silent: a broker
        that answers, only slowly (a loaded node confirms late), is waited for, up to
        ``SLOW_BROKER_PERIODS`` timeouts, rather than taken for lost. Reconnecting to a loaded
        broker adds to its load, and a team of robots doing it at once is a reconnect storm.
        Halfway through a silent period the channel is asked something cheap (``basic.qos``,
        answered by the channel itself, not by the queues that confirm): its answer shows the
        broker alive. A frozen or unreachable broker is still given up after ``timeout``."""
        started = time.monotonic()
        deadline, last = started + timeout, started + timeout * SLOW_BROKER_PERIODS
        heard, probed = self._heard(), False
        while not done():
            if self._closed_reason is not None:
                raise self._closed_error()
            if self._stopping():
                raise WaitStopped(f"stopped waiting for the {what} after {time.monotonic() - started:.1f} s")
            now = time.monotonic()
            remaining = deadline - now
            if remaining <= 0:
                if self._heard() == heard or now >= last:
                    raise PublishTimeout(f"no {what} from the broker within {now - started:.0f} s")
                deadline, heard, probed = now + timeout, self._heard(), False  # alive: wait on
                continue
            if not probed and remaining <= timeout / 2 and self._heard() == heard:
                self._impl.basic_qos(prefetch_count=0, callback=lambda _frame: self._wake())
                probed = True
            try:
                self._connection.process_data_events(time_limit=min(_SLICE, remaining))
            except pika.exceptions.AMQPError as error:
                raise BrokerUnavailable(f"connection lost while waiting for {what}: {error!r}") from error

    def _heard(self) -> int:
        """Bytes received from the broker on this connection so far."""
        return int(getattr(self._connection._impl, "bytes_received", 0))

    def send(self, messages: Sequence[Outgoing], timeout: float) -> Outcome:
        """Publish all messages, then wait until the broker answered each; say which it did not take.

        Raises :class:`PublishRefused` when the broker closed the channel (the whole batch is then
        in doubt), :class:`BrokerUnavailable` when the connection broke (also when it closed the
        channel with it) and :class:`PublishTimeout` when the confirms did not come in time.
        """
        return self.wait(self.write(messages), timeout)

    def write(self, messages: Sequence[Outgoing]) -> Window:
        """Publish without waiting: the frames go out at the next pump (any :meth:`wait`).

        Several windows may be written before the first is waited for; raises like :meth:`send`.
        """
        window = Window({})
        try:
            for message in messages:
                # registered before the write: the ack can arrive while basic_publish flushes
                window.tags[self._next_tag] = message.properties.message_id or ""
                self._unconfirmed.add(self._next_tag)
                self._next_tag += 1
                # On the channel underneath: the blocking facade writes to the socket after every
                # message (one send syscall each); these frames go out together when we pump.
                self._impl.basic_publish(
                    message.exchange, message.routing_key, message.body, message.properties, mandatory=True
                )
        except pika.exceptions.AMQPChannelError as error:
            if self._closed_reason is None:
                raise BrokerUnavailable(f"the channel is gone: {error!r}") from error
            raise self._closed_error() from error
        except pika.exceptions.AMQPError as error:
            raise BrokerUnavailable(f"connection lost while publishing: {error!r}") from error
        return window

    def write_one(self, message: Outgoing) -> int:
        """:meth:`write` for one message; its delivery tag (for :meth:`answered`, :meth:`nacked`)."""
        (tag,) = self.write([message]).tags
        return tag

    def answered(self, tag: int) -> bool:
        """Whether the broker confirmed or nacked the message written with ``tag``."""
        return tag not in self._unconfirmed

    def nacked(self, tag: int) -> bool:
        """Whether the broker nacked the message written with ``tag`` (once it :meth:`answered`)."""
        return tag in self._nacked

    def wait_for(self, tag: int, timeout: float) -> None:
        """Wait until the broker answered the message written with ``tag``; raises like :meth:`send`."""
        self._pump_until(lambda: tag not in self._unconfirmed, timeout, "publisher confirm")

    def take_returns(self) -> int:
        """How many messages the broker returned (``mandatory``: no queue bound for them) since the
        last call. RabbitMQ sends a message's basic.return before its basic.ack, so once a message
        is answered its return, if any, is counted. For a caller that counts returns rather than
        naming them by message id (a stream whose ids need not be unique): it forgets the names
        :meth:`wait` would give, so the two are not mixed on one channel."""
        count, self._returns = self._returns, 0
        self._returned.clear()
        return count

    def flush(self) -> None:
        """Put what :meth:`write` queued on the wire now, without waiting for anything."""
        try:
            self._connection.process_data_events(0)
        except pika.exceptions.AMQPError as error:
            raise BrokerUnavailable(f"connection lost while publishing: {error!r}") from error

    def wait(self, window: Window, timeout: float) -> Outcome:
        """Wait until the broker answered every message of ``window``; say which it did not take."""
        tags = window.tags
        self._pump_until(lambda: not (self._unconfirmed & tags.keys()), timeout, "publisher confirm")
        nacked = {tags[tag] for tag in self._nacked & tags.keys()}
        self._nacked -= tags.keys()
        returned = {mid: self._returned.pop(mid) for mid in list(tags.values()) if mid in self._returned}
        return Outcome(nacked, returned)

    def send_one(self, message: Outgoing, timeout: float = SERVICE_CONFIRM_TIMEOUT_S) -> Outcome:
        """:meth:`send` for one message (its ``message_id`` identifies it in the outcome)."""
        return self.send([message], timeout)

    def publish(self, messages: Sequence[Outgoing], timeout: float) -> None:
        """Publish all messages and wait for their confirms; raise if any was not taken."""
        outcome = self.send(messages, timeout)
        problems = [f"{mid}: nacked by the broker" for mid in sorted(outcome.nacked)]
        problems += [f"{mid}: unroutable ({reason})" for mid, reason in outcome.returned.items()]
        if problems:
            raise PublishRefused("; ".join(problems))
