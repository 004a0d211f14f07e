"""Read the dead-letter queue without consuming it.

Messages are fetched with ``basic.get`` and not acked; closing the channel puts them back in
their place (the queue is a classic queue, where that costs no delivery count).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

import pika

from schemas.routing import DEAD_LETTER_QUEUE, DETAIL_HEADER, REASON_HEADER


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


def _text(value: Any) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


def _describe(properties: pika.BasicProperties, body: bytes, routing_key: str) -> DeadLetter:
    headers = properties.headers or {}
    reason = headers.get(REASON_HEADER)
    detail = headers.get(DETAIL_HEADER, "")
    deaths = headers.get("x-death") or []
    if reason is None and deaths:  # dead-lettered by the broker itself, e.g. delivery limit
        reason = _text(deaths[0].get("reason", "unknown"))
        detail = f"dead-lettered by the broker from queue {_text(deaths[0].get('queue', '?'))}"
    rejected_at = headers.get("x-rejected-at")
    if rejected_at is None and deaths and isinstance(deaths[0].get("time"), datetime):
        rejected_at = deaths[0]["time"].isoformat()
    return DeadLetter(
        message_id=properties.message_id,
        reason=_text(reason or "unknown"),
        detail=_text(detail),
        user_id=_text(headers.get("x-original-user-id") or properties.user_id or "") or None,
        exchange=_text(headers.get("x-original-exchange", "")),
        routing_key=_text(headers.get("x-original-routing-key", routing_key)),
        rejected_at=_text(rejected_at) if rejected_at else None,
        size=len(body),
        body_preview=body[:120].decode(errors="replace"),
    )


def peek_dead_letters(amqp_url: str, limit: int = 1000) -> list[DeadLetter]:
    connection = pika.BlockingConnection(pika.URLParameters(amqp_url))
    try:
        channel = connection.channel()
        available = channel.queue_declare(DEAD_LETTER_QUEUE, passive=True).method.message_count
        letters: list[DeadLetter] = []
        for _ in range(min(limit, available)):
            method, properties, body = channel.basic_get(DEAD_LETTER_QUEUE, auto_ack=False)
            if method is None:
                break
            letters.append(_describe(properties, body, method.routing_key))
        channel.close()  # returns every fetched message to the queue
        return letters
    finally:
        connection.close()
