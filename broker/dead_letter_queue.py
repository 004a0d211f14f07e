"""Read the dead-letter queue without consuming it.

Messages are fetched with ``basic.get`` and not acked; closing the channel puts them back in
their place (the queue is a classic queue, where that costs no delivery count).

The workers reject a message with ``basic.nack`` (no requeue) and the broker moves it here
itself, atomically, so a worker that dies meanwhile can never leave it twice (README, "What is
guaranteed"); the move cannot add headers, so the worker first records why in the store under
:func:`dead_letter_key`, and :func:`peek_dead_letters` joins the two when given ``reasons``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Protocol

import pika

from fleetbus.schemas.routing import DEAD_LETTER_QUEUE, RECORDER_QUEUE


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

    def as_dict(self) -> dict[str, Any]:
        return self.__dict__.copy()


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


def _describe(
    properties: pika.BasicProperties, body: bytes, routing_key: str, kept: KeptReason | None
) -> DeadLetter:
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
        user_id=_text(headers.get("x-original-user-id") or properties.user_id or "") or None,
        exchange=_text(headers.get("x-original-exchange", death.get("exchange", ""))),
        routing_key=_text(headers.get("x-original-routing-key", original_keys[0])),
        rejected_at=_text(rejected_at) if rejected_at else None,
        size=len(body),
        body_preview=body[:120].decode(errors="replace"),
    )


def peek_dead_letters(
    amqp_url: str, limit: int = 1000, reasons: ReasonLookup | None = None
) -> list[DeadLetter]:
    """Up to ``limit`` dead letters, oldest first; ``reasons`` finds why the workers refused each."""
    fetched = _peek(amqp_url, limit)
    keys = [key for _, properties, body in fetched if (key := _key_of(properties, body))]
    kept = reasons(keys) if reasons is not None and keys else {}
    return [
        _describe(properties, body, routing_key, kept.get(_key_of(properties, body) or ""))
        for routing_key, properties, body in fetched
    ]


def _peek(amqp_url: str, limit: int) -> list[tuple[str, pika.BasicProperties, bytes]]:
    connection = pika.BlockingConnection(pika.URLParameters(amqp_url))
    try:
        channel = connection.channel()
        available = channel.queue_declare(DEAD_LETTER_QUEUE, passive=True).method.message_count
        fetched: list[tuple[str, pika.BasicProperties, bytes]] = []
        for _ in range(min(limit, available)):
            method, properties, body = channel.basic_get(DEAD_LETTER_QUEUE, auto_ack=False)
            if method is None:
                break
            fetched.append((method.routing_key, properties, body))
        channel.close()  # returns every fetched message to the queue
        return fetched
    finally:
        connection.close()
