"""Follow an account's stream: live messages, or recent history first (``fleetbus tail``).

Every operator owns a stream queue, ``<user>.stream``; the service binds the beacon exchange to it
and, while a robot is mounted, that robot's events exchange. A stream is read without consuming
it (``x-stream-offset``: ``next`` for live messages, a time to replay from), so several tails and
tools can follow it at once. Each message keeps its origin: the exchange it was published to
(``<robot>.events`` can only be written by that robot), its routing key, and the ``user_id`` the
broker validated.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from typing import Any
from urllib.parse import unquote, urlsplit

import aiormq.exceptions
from aio_pika.abc import AbstractIncomingMessage

from fleetbus.broker.tls import aio_connect
from fleetbus.schemas.routing import stream_queue
from fleetbus.schemas.topics import topic_matches

#: Stream offsets by time are found per chunk, so a replay may start a little early: messages
#: stamped more than this before the requested time are left out.
CHUNK_SLACK = timedelta(seconds=1)


class StreamClosed(Exception):
    """The broker ended a follow: it closed the connection or the channel (an administrator, the
    account disabled or deleted, the node shutting down)."""


@dataclass(frozen=True)
class Seen:
    offset: int | None
    exchange: str
    routing_key: str
    user_id: str | None
    type: str | None
    timestamp: datetime | None
    body: bytes

    def summary(self, width: int = 100) -> str:
        try:
            data: Any = json.loads(self.body)
        except ValueError:
            return f"{len(self.body)} bytes"
        if isinstance(data, dict) and "body" in data:
            text = f"seq {data.get('seq')} " + json.dumps(data["body"], separators=(",", ":"))
        else:
            text = json.dumps(data, separators=(",", ":"))
        return text if len(text) <= width else text[: width - 1] + "…"

    def as_dict(self) -> dict[str, Any]:
        return {
            "offset": self.offset,
            "exchange": self.exchange,
            "routing_key": self.routing_key,
            "user_id": self.user_id,
            "type": self.type,
            "timestamp": self.timestamp.isoformat() if self.timestamp else None,
            "body": self.body.decode(errors="replace"),
        }


def _seen(message: AbstractIncomingMessage) -> Seen:
    offset = (message.headers or {}).get("x-stream-offset")
    stamp = message.timestamp
    if stamp is not None and stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=timezone.utc)
    return Seen(
        offset=int(offset) if isinstance(offset, int) else None,
        exchange=message.exchange or "",
        routing_key=message.routing_key or "",
        user_id=message.user_id,
        type=message.type,
        timestamp=stamp,
        body=message.body,
    )


async def follow(
    amqp_url: str,
    pattern: str = "#",
    *,
    since: datetime | None = None,
    on_message: Callable[[Seen], None],
    count: int | None = None,
    idle_timeout: float | None = None,
    on_ready: Callable[[], None] | None = None,
    user: str | None = None,
) -> int:
    """Show what the account's stream receives (from ``since``, else from now) whose routing key
    matches ``pattern``; stop after ``count`` messages or ``idle_timeout`` seconds of silence.
    Returns how many were shown; raises :class:`StreamClosed` when the broker ends it first."""
    connection = await aio_connect(amqp_url)
    shown = 0
    async with connection:
        channel = await connection.channel()
        closed: list[BaseException | None] = []
        channel.close_callbacks.add(lambda _, error: closed.append(error))
        await channel.set_qos(prefetch_count=200)  # a stream consumer needs a prefetch
        owner = user or unquote(urlsplit(amqp_url).username or "")
        queue = await channel.get_queue(stream_queue(owner))
        offset: Any = since if since is not None else "next"
        async with queue.iterator(arguments={"x-stream-offset": offset}) as messages:
            if on_ready is not None:
                on_ready()
            iterator = messages.__aiter__()
            while count is None or shown < count:
                try:
                    message = await asyncio.wait_for(iterator.__anext__(), idle_timeout)
                except asyncio.TimeoutError:
                    break
                except StopAsyncIteration:  # what ends the iterator: its channel closed
                    raise StreamClosed(_why(closed[0] if closed else None)) from None
                if not channel.is_closed:  # else the messages it had taken are shown, then it ends
                    await message.ack()
                seen = _seen(message)
                if since is not None and seen.timestamp is not None and seen.timestamp < since - CHUNK_SLACK:
                    continue
                if topic_matches(pattern, seen.routing_key):
                    on_message(seen)
                    shown += 1
    return shown


def _why(error: BaseException | None) -> str:
    """What ended the follow's channel: the broker closing it or the connection (with its reply
    text), or the connection lost."""
    if error is None:
        return "the broker closed the connection"
    if isinstance(error, aiormq.exceptions.ChannelClosed | aiormq.exceptions.ConnectionClosed):
        what = "channel" if isinstance(error, aiormq.exceptions.ChannelClosed) else "connection"
        return f"the broker closed the {what}: {_reply_text(error)}"
    return f"the connection to the broker was lost: {error!r}"


def _reply_text(error: BaseException) -> str:
    """The broker's reply text of a close (aiormq's error holds its code, then the text)."""
    code_and_text = len(error.args) == 2 and isinstance(error.args[1], str)
    return error.args[1] if code_and_text else str(error)
