"""Read the dead-letter queue without consuming it.

Messages are fetched with ``basic.get`` and not acked; closing the channel puts them back in
their place (the queue is a classic queue, where that costs no delivery count).

Each letter is named by :func:`letter_id`, a digest of the whole message as the queue holds it,
which stays the same however often it is read; :mod:`fleetbus.broker.dead_letter_actions`
requeues or discards a letter by it.

The workers reject a message with ``basic.nack`` (no requeue) and the broker moves it here
itself, atomically, so a worker that dies meanwhile can never leave it twice (README, "What is
guaranteed"); the move cannot add headers, so the worker first records why in the store under
:func:`dead_letter_key`, and :func:`peek_dead_letters` joins the two when given ``reasons``.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import time
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from decimal import Decimal
from typing import TYPE_CHECKING, Any, Protocol

import pika

from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE, RECORDER_QUEUE

if TYPE_CHECKING:
    from fleetbus.broker.management import ManagementAPI


@dataclass(frozen=True)
class DeadLetter:
    message_id: str | None
    reason: str
    detail: str
    user_id: str | None
    exchange: str
    routing_key: str
    rejected_at: str | None
    size: int
    body_preview: str
    letter_id: str
    """Which letter this is (:func:`letter_id`): what a requeue or a discard names."""
    headers: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    """The message's headers as the queue holds them, the broker's ``x-death`` included."""
    body: bytes = field(default=b"", repr=False, compare=False)

    def as_dict(self) -> dict[str, Any]:
        """The description, without the headers and the body (the JSON lines of ``fleetbus dlq``)."""
        return {key: value for key, value in self.__dict__.items() if key not in ("headers", "body")}

    def headers_text(self) -> str:
        """The headers as indented JSON, for reading (bytes as text, times in ISO 8601)."""
        return json.dumps(self.headers, indent=2, sort_keys=True, default=_plain, ensure_ascii=False)


@dataclass(frozen=True)
class Listing:
    letters: list[DeadLetter]
    """The oldest letters, up to the limit asked for."""
    in_queue: int
    """How many letters the queue held when read."""


class KeptReason(Protocol):
    reason: str
    detail: str
    rejected_at: datetime


ReasonLookup = Callable[[list[str]], Mapping[str, KeptReason]]
"""The reasons kept for these dead-letter keys (``RejectionLog.rejections``)."""


def dead_letter_key(
    user_id: str | None, exchange: str, routing_key: str, message_id: str | None, body: bytes
) -> str:
    """What identifies a rejected message both in the worker's hands and in the dead-letter queue."""
    digest = hashlib.sha256()
    for part in (user_id or "", exchange, routing_key, message_id or ""):
        digest.update(part.encode())
        digest.update(b"\0")
    digest.update(body)
    return digest.hexdigest()


def _text(value: Any) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


def _plain(value: Any) -> Any:
    """What JSON cannot hold, as text: bytes, times (x-death), decimals."""
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, (bytes, Decimal)):
        return _text(value)
    return repr(value)


#: What a quorum queue writes on a message at each delivery (how often it was delivered before):
#: not the message's own, and different at every read of the dead letters on a cluster.
DELIVERY_HEADERS = frozenset({"x-delivery-count", "x-acquired-count"})


def letter_id(properties: pika.BasicProperties, body: bytes) -> str:
    """Which dead letter this is: a digest of the whole message as the queue holds it (every
    property, the headers with the broker's ``x-death`` record and its times, the body), but for
    the count of its deliveries, which each read of a quorum queue raises.

    A message id alone would not do: a robot may send none, and a message refused twice (sent
    again after an outage) is in the queue twice with the same one. Two letters share a digest
    only when they are the same bytes, refused at the same second: taking either is the same.
    """
    held = dict(vars(properties))
    if held.get("headers"):
        held["headers"] = {k: v for k, v in held["headers"].items() if k not in DELIVERY_HEADERS}
    described = json.dumps(held, sort_keys=True, default=_plain, ensure_ascii=False)
    digest = hashlib.sha256(described.encode())
    digest.update(b"\0")
    digest.update(body)
    return digest.hexdigest()[:32]


def moved_letter_key(
    headers: Mapping[str, Any] | None, user_id: str | None, message_id: str | None, body: bytes
) -> str | None:
    """The :func:`dead_letter_key` of a message the broker moved (its ``x-death`` says from where);
    None for one it did not move."""
    deaths = (headers or {}).get("x-death") or []
    if not deaths:
        return None
    death = deaths[0]
    keys = death.get("routing-keys") or [""]
    return dead_letter_key(user_id, _text(death.get("exchange", "")), _text(keys[0]), message_id, body)


def _key_of(properties: pika.BasicProperties, body: bytes) -> str | None:
    return moved_letter_key(properties.headers, properties.user_id, properties.message_id, body)


def describe(
    properties: pika.BasicProperties, body: bytes, routing_key: str, kept: KeptReason | None = None
) -> DeadLetter:
    """A letter as fetched from the queue; ``kept``: why the workers refused it, from the store."""
    headers = properties.headers or {}
    reason: object = None
    detail = ""
    deaths = headers.get("x-death") or []
    rejected_at = headers.get("x-rejected-at")
    if kept is not None:  # rejected by a worker, moved here by the broker
        reason, detail, rejected_at = kept.reason, kept.detail, kept.rejected_at.isoformat()
    elif reason is None and deaths and _text(deaths[0].get("queue", "")) == RECORDER_QUEUE:
        reason = "unstorable" if _text(deaths[0].get("reason", "")) == "rejected" else deaths[0].get("reason")
        detail = f"the recorder could not keep it ({_text(reason)}; the recorder's log says more)"
    elif reason is None and deaths:  # dead-lettered by the broker itself, e.g. delivery limit
        reason = _text(deaths[0].get("reason", "unknown"))
        detail = f"dead-lettered by the broker from queue {_text(deaths[0].get('queue', '?'))}"
    if rejected_at is None and deaths and isinstance(deaths[0].get("time"), datetime):
        rejected_at = deaths[0]["time"].isoformat()
    death = deaths[0] if deaths else {}
    original_keys = death.get("routing-keys") or [routing_key]
    return DeadLetter(
        message_id=properties.message_id,
        reason=_text(reason or "unknown"),
        detail=_text(detail),
        # the sender is the user id the broker validated; where it went, the broker's record of
        # the death: headers a publisher chose (x-original-...) could name another robot
        user_id=_text(properties.user_id or "") or None,
        exchange=_text(death.get("exchange", "")),
        routing_key=_text(original_keys[0]),
        rejected_at=_text(rejected_at) if rejected_at else None,
        size=len(body),
        body_preview=body[:120].decode(errors="replace"),
        letter_id=letter_id(properties, body),
        headers=headers,
        body=body,
    )


Fetched = list[tuple[str, pika.BasicProperties, bytes]]


def peek_dead_letters(
    amqp_url: str, limit: int = 1000, reasons: ReasonLookup | None = None
) -> list[DeadLetter]:
    """Up to ``limit`` dead letters, oldest first; ``reasons`` finds why the workers refused each."""
    _, fetched = _peek(amqp_url, limit)
    keys = _keys(fetched)
    return _described(fetched, reasons(keys) if reasons is not None and keys else {})


AsyncReasonLookup = Callable[[list[str]], Awaitable[Mapping[str, KeptReason]]]


async def read_dead_letters(amqp_url: str, limit: int, reasons: AsyncReasonLookup) -> Listing:
    """:func:`peek_dead_letters` for an event loop (the queue read on a thread, the reasons
    awaited), with how many letters the queue held."""
    in_queue, fetched = await asyncio.to_thread(_peek, amqp_url, limit)
    keys = _keys(fetched)
    return Listing(_described(fetched, await reasons(keys) if keys else {}), in_queue)


def _keys(fetched: Fetched) -> list[str]:
    return [key for _, properties, body in fetched if (key := _key_of(properties, body))]


def _described(fetched: Fetched, kept: Mapping[str, KeptReason]) -> list[DeadLetter]:
    return [
        describe(properties, body, routing_key, kept.get(_key_of(properties, body) or ""))
        for routing_key, properties, body in fetched
    ]


#: The longest a listing waits for the letters it read to be back in the queue.
RETURN_WAIT_S = 2.0


def _wait_returned(connection: pika.BlockingConnection, ready: int) -> None:
    """Until the queue holds as many ready letters as before the listing read some (a quorum
    queue takes them back a moment after the channel closed: a listing right after would see
    none), or :data:`RETURN_WAIT_S` passed (another listing holding some)."""
    channel = connection.channel()
    deadline = time.monotonic() + RETURN_WAIT_S
    while channel.queue_declare(DEAD_LETTER_QUEUE, passive=True).method.message_count < ready:
        if time.monotonic() >= deadline:
            break
        connection.sleep(0.01)
    channel.close()


def _peek(amqp_url: str, limit: int) -> tuple[int, Fetched]:
    connection = blocking_connection(amqp_url)
    try:
        channel = connection.channel()
        available = channel.queue_declare(DEAD_LETTER_QUEUE, passive=True).method.message_count
        fetched: Fetched = []
        for _ in range(min(limit, available)):
            method, properties, body = channel.basic_get(DEAD_LETTER_QUEUE, auto_ack=False)
            if method is None:
                break
            fetched.append((method.routing_key, properties, body))
        channel.close()  # returns every fetched message to the queue
        _wait_returned(connection, available)
        return available, fetched
    finally:
        connection.close()


def dead_letters_waiting(management: ManagementAPI, vhost: str) -> int:
    """How many letters the dead-letter queue holds (ready, or being read), as the management API
    counts them (its statistics lag the broker by a few seconds)."""
    queue = management.get_queue(vhost, DEAD_LETTER_QUEUE)
    return int(queue.get("messages_ready") or 0) + int(queue.get("messages_unacknowledged") or 0)
